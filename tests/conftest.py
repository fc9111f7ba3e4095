"""Tests run in float64 (geometry needs the precision) with strict dtype and rank promotion.

The persistent compilation cache is off for the suite (`BSJAX_CACHE_DIR=off`, inherited by the
CLI, demo and notebook-kernel subprocesses): in one full run with a cache shared by both xdist
workers, jaxlib 0.10.2's CPU executable serialisation segfaulted twice (once writing an entry,
once reading one), and a damaged entry on disk could make such a crash repeat on the rerun.
`BSJAX_CACHE_DIR=.cache/jax-tests make test` shares one among all the run's processes;
`tests/test_cache.py` checks the cache itself, in processes run one after the other.
"""

import os

_CACHE = os.environ.setdefault("BSJAX_CACHE_DIR", "off")
if _CACHE.strip().lower() not in ("off", "0", "false", "no", "none", ""):
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _CACHE)  # notebook kernels: JAX reads it at import
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

import bsjax  # noqa: E402
from tests.helpers import CHROMIUM  # noqa: E402

bsjax.enable_compilation_cache()  # this process too (JAX may have been imported before the env)
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="module")
def browser():
    """A real headless Chromium (Playwright) for the page tests; skipped without a system one."""
    if CHROMIUM is None:
        pytest.skip("no system Chromium")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM)
        yield b
        b.close()


# --- where the suite's time goes (BSJAX_TEST_PROFILE=FILE: one JSON line per test) ----------------
if os.environ.get("BSJAX_TEST_PROFILE"):
    import json
    import time

    import pytest
    from jax import monitoring

    _PHASES = {
        "/jax/core/compile/jaxpr_trace_duration": "trace_s",
        "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
        "/jax/core/compile/backend_compile_duration": "compile_s",
    }
    _spent: dict[str, float] = {}

    def _listen(event: str, duration: float, **_) -> None:
        if event in _PHASES:
            _spent[_PHASES[event]] = _spent.get(_PHASES[event], 0.0) + duration

    monitoring.register_event_duration_secs_listener(_listen)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _spent.clear()
        t0 = time.perf_counter()
        yield
        row = {"test": item.nodeid, "wall_s": time.perf_counter() - t0, **_spent}
        with open(os.environ["BSJAX_TEST_PROFILE"], "a") as f:
            f.write(json.dumps(row) + "\n")
