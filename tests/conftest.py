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

The suite is compile-bound (two thirds of a test's time is XLA's backend compilation), so it also
compiles without LLVM's optimisations (`TEST_FLAGS`: backend compilation 56 % shorter, the whole
run 997 → 567 s on 2 cores; results differ from optimised code by rounding only). The LLVM module
is then emitted in one part: XLA:CPU 0.10's default split of an unoptimised module into parallel
parts miscompiled a program (`construct.rail_rotation`'s `max_error` 27.6 instead of 6.7e-4).
A test whose outcome follows a chaotic rollout, and so its rounding, is marked
`@pytest.mark.users_compiler`: it runs in a pytest subprocess with the flags users compile with
(`pytest_pyfunc_call` below). `XLA_FLAGS=--xla_backend_optimization_level=2 make test` runs
everything optimised.
"""

import os
import shutil
import subprocess
import sys
import tempfile

from bsjax._xla import prefer_quick_compilation

# the CLI's compiler options (bsjax._xla), as the first process of the run found them
USERS_XLA_FLAGS = os.environ.setdefault("BSJAX_TEST_USERS_XLA_FLAGS", prefer_quick_compilation())
TEST_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_parallel_codegen_split_count=1")
_AS_USERS = "BSJAX_TEST_AS_USERS"  # set in the subprocess of a `users_compiler` test
if not os.environ.get(_AS_USERS):
    prefer_quick_compilation(flags=TEST_FLAGS)  # inherited by every subprocess
_RUN_CACHE = None
if "BSJAX_CACHE_DIR" not in os.environ and "PYTEST_XDIST_WORKER" not in os.environ:
    _RUN_CACHE = tempfile.mkdtemp(prefix="bsjax-test-cache-")
    os.environ["BSJAX_CACHE_DIR"] = _RUN_CACHE

import jax  # noqa: E402
import pytest  # noqa: E402

import bsjax  # noqa: E402
from tests import xdist_scheduling  # noqa: E402
from tests.helpers import CHROMIUM  # noqa: E402

bsjax.enable_compilation_cache()  # this process (and each worker)
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")


def pytest_configure(config):
    """How the tests spread over xdist's workers (`tests/xdist_scheduling.py`), when it runs."""
    config.addinivalue_line("markers", "users_compiler: run with the users' XLA flags (module docstring)")
    if config.pluginmanager.hasplugin("xdist"):
        config.pluginmanager.register(xdist_scheduling, "bsjax-xdist-scheduling")


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem):
    """A `users_compiler` test runs in a pytest subprocess compiling with `USERS_XLA_FLAGS`."""
    if pyfuncitem.get_closest_marker("users_compiler") is None or os.environ.get(_AS_USERS):
        return None
    env = {**os.environ, _AS_USERS: "1", "XLA_FLAGS": USERS_XLA_FLAGS}
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist"]
    proc = subprocess.run(
        [*command, pyfuncitem.nodeid], cwd=pyfuncitem.config.rootpath, env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        pytest.fail(
            f"with XLA_FLAGS={USERS_XLA_FLAGS!r}:\n{proc.stdout[-6000:]}{proc.stderr[-2000:]}", pytrace=False
        )
    return True


def pytest_runtest_teardown(item, nextitem):
    """After a file's last test in this process, every compiled program is dropped (bsjax's
    entry points and JAX's caches; the next file loads what it shares from the run's disk cache).
    Each live XLA:CPU executable holds three memory maps: a worker keeping the ~22 000 programs
    of half the suite reaches Linux's default `vm.max_map_count` (65 530), where LLVM's JIT fails
    ("Cannot allocate memory") and the worker dies (a segfault serialising an executable, an
    abort compiling one)."""
    if nextitem is None or nextitem.path != item.path:
        bsjax.clear_caches()
        jax.clear_caches()


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


def pytest_unconfigure(config):
    """The run's own cache goes with the run (the process that made it removes it)."""
    if _RUN_CACHE is not None:
        shutil.rmtree(_RUN_CACHE, ignore_errors=True)
