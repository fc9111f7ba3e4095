"""Tests run in float64 (geometry needs the precision) with strict dtype and rank promotion.

One persistent compilation cache per test run: the first process of the run (the xdist
controller, or a plain pytest) makes a new empty directory and names it in `BSJAX_CACHE_DIR`,
which the workers and every CLI, demo and notebook-kernel subprocess inherit, so a program one
of them compiled is loaded by the others (the annotation re-run of `test_typing`, the demo, the
notebooks) instead of compiled again; it is removed at the end of the run. Nothing is carried
from one run to the next. `BSJAX_CACHE_DIR=DIR make test` uses (and keeps) DIR instead;
`BSJAX_CACHE_DIR=off` runs without one. `tests/test_cache.py` checks the cache itself.

The suite compiles with the CLI's XLA:CPU options (`bsjax._xla`: the classic emitters, 20–36 %
less compilation), inherited by every subprocess; `XLA_FLAGS=--xla_cpu_use_fusion_emitters=true
make test` runs it with XLA's default emitters instead.
"""

import os
import shutil
import tempfile

from bsjax._xla import prefer_quick_compilation

prefer_quick_compilation()  # the CLI's compiler options, inherited by every subprocess (bsjax._xla)
_RUN_CACHE = None
if "BSJAX_CACHE_DIR" not in os.environ and "PYTEST_XDIST_WORKER" not in os.environ:
    _RUN_CACHE = tempfile.mkdtemp(prefix="bsjax-test-cache-")
    os.environ["BSJAX_CACHE_DIR"] = _RUN_CACHE

import jax  # noqa: E402
import pytest  # noqa: E402

import bsjax  # noqa: E402
from tests.helpers import CHROMIUM  # noqa: E402

bsjax.enable_compilation_cache()  # this process (and each worker)
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
    import resource
    import time

    import pytest
    from jax import monitoring

    _PHASES = {
        "/jax/core/compile/jaxpr_trace_duration": "trace_s",
        "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
        "/jax/core/compile/backend_compile_duration": "compile_s",
    }
    _spent: dict = {}

    def _listen(event: str, duration: float, fun_name: str = "?", **_) -> None:
        if event in _PHASES:
            _spent[_PHASES[event]] = _spent.get(_PHASES[event], 0.0) + duration
            if event.endswith("backend_compile_duration"):
                _spent["programs"] = _spent.get("programs", 0) + 1
                by_name = _spent.setdefault("compiled", {})  # seconds per compiled function
                by_name[fun_name] = by_name.get(fun_name, 0.0) + duration

    monitoring.register_event_duration_secs_listener(_listen)

    def _cpu() -> float:
        """CPU seconds of this process and of its finished children (subprocesses, kernels)."""
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + children.ru_utime + children.ru_stime

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _spent.clear()
        t0, c0 = time.perf_counter(), _cpu()
        yield
        row = {"test": item.nodeid, "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0, **_spent}
        with open(os.environ["BSJAX_TEST_PROFILE"], "a") as f:
            f.write(json.dumps(row) + "\n")


# --- the two workers (pytest-xdist) ----------------------------------------------------------------
# A file's tests run on one worker, one after another: the programs a test compiles are still in
# that worker's memory for the next test of its file (its fixtures too), where per-test
# distribution compiled or loaded them in both (a sample of six files: 7 % less CPU, 6 % less
# wall). The notebooks share nothing in process (each runs in its own kernel), so they go one by
# one; the slowest files go first so that both workers finish together.
SLOWEST_FIRST = (
    "tests/test_notebooks.py", "tests/test_optimise.py", "tests/test_collide.py",
    "tests/test_construct.py", "tests/test_mesh_tool.py", "tests/test_mss_scene.py",
    "tests/test_collide_speed.py", "tests/test_mss.py", "tests/test_tool_family.py",
    "tests/test_vsofm.py", "tests/test_sweep.py", "tests/test_basis_banded.py",
)  # fmt: skip
ONE_BY_ONE = ("tests/test_notebooks.py",)


def pytest_collection_modifyitems(config, items):
    def rank(item):
        path = item.nodeid.split("::", 1)[0]
        return SLOWEST_FIRST.index(path) if path in SLOWEST_FIRST else len(SLOWEST_FIRST)

    items.sort(key=rank)  # stable: the order within a file, and of the other files, is kept


def pytest_xdist_make_scheduler(config, log):
    """File scope for `-n N` (the default `--dist load`); an explicit other `--dist` is kept."""
    if config.option.dist != "load":
        return None
    from xdist.scheduler import LoadFileScheduling

    class ByFile(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return nodeid if nodeid.startswith(ONE_BY_ONE) else super()._split_scope(nodeid)

    config.option.loadscopereorder = False  # keep the order above (not by number of tests)
    return ByFile(config, log)


def pytest_unconfigure(config):
    """The run's own cache goes with the run (the process that made it removes it)."""
    if _RUN_CACHE is not None:
        shutil.rmtree(_RUN_CACHE, ignore_errors=True)
