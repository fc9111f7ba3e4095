"""The persistent compilation cache (`bsjax.enable_compilation_cache`), the store of whole
compiled programs beside it (`bsjax._executables`) and the compiled boundary's failure codes
that make its programs storable.

A program holding a host callback (`eqx.error_if`'s) cannot be stored by JAX; bsjax's direct
calls return a failure code instead, so a second process loads every program from disk: that
is asserted by counting JAX's own trace events and cache hits and misses in two fresh processes
(the direct call itself is neither traced nor compiled there: its executable is loaded whole).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsjax
from bsjax import _cache, _checks
from bsjax._boundary import compiled

_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    from jax import monitoring
    jax.config.update("jax_enable_x64", True)
    counts = {"hits": 0, "misses": 0, "traced": []}
    def listen(event, **kwargs):
        if event == "/jax/compilation_cache/cache_hits":
            counts["hits"] += 1
        elif event == "/jax/compilation_cache/cache_misses":
            counts["misses"] += 1
    def timed(event, duration, **kwargs):
        if event == "/jax/core/compile/jaxpr_trace_duration":
            counts["traced"].append(kwargs.get("fun_name"))
    monitoring.register_event_listener(listen)
    monitoring.register_event_duration_secs_listener(timed)
    import bsjax
    where = bsjax.enable_compilation_cache()
    from bsjax import collide, shapes
    s = shapes.plate(6, 6)
    b = s.blending(12, 12)
    out = collide.contacts(b, s.ctrl, collide.Sphere([0.5, 0.5, 0.05], 0.2))
    jax.block_until_ready(out)
    if sys.argv[1:] == ["second"]:  # other checks first: a per-process numbering would shift
        try:
            collide.contacts(b, s.ctrl, collide.Sphere([0.5, 0.5, 0.05], -1.0))
        except ValueError:
            pass
    try:
        collide.contacts(b, s.ctrl.at[0, 0, 0].set(float("nan")), collide.Sphere([0.5, 0.5, 0.05], 0.2))
    except ValueError as err:
        failure = str(err)
    stored = sorted(p.name for p in where.glob("*-exe"))
    print(json.dumps({**counts, "dir": str(where), "hit": int(out.hit.sum()), "stored": stored,
                      "failure": failure}))
    """
)


def _run(env, *args) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT, *args], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_second_process_loads_every_program_from_the_cache(tmp_path):
    env = {**os.environ, "BSJAX_CACHE_DIR": str(tmp_path / "cache")}
    for key in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"):
        env.pop(key, None)
    first = _run(env)
    assert first["dir"] == str(tmp_path / "cache")
    assert first["misses"] > 0 and first["hit"] > 0
    assert "contacts" in first["traced"] and len(first["stored"]) == 1
    assert first["failure"].startswith("ctrl: expected finite values, got")
    second = _run(env, "second")
    assert second["misses"] == 0, second
    assert "contacts" not in second["traced"], second  # loaded whole from the store
    assert second["hits"] == first["misses"] - 1  # the rest (setup programs) from JAX's cache
    assert second["hit"] == first["hit"] and second["stored"] == first["stored"]
    assert second["failure"] == first["failure"]  # the stored program's own messages


def test_cache_dir_off_and_default(monkeypatch, tmp_path):
    monkeypatch.setenv("BSJAX_CACHE_DIR", "off")
    assert bsjax.enable_compilation_cache() is None
    assert bsjax.enable_compilation_cache(tmp_path) is None  # off wins over a path
    monkeypatch.delenv("BSJAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if sys.platform.startswith("linux"):
        assert _cache.cache_dir() == tmp_path / "xdg" / "bsjax" / "jax"
    monkeypatch.setenv("BSJAX_CACHE_DIR", str(tmp_path / "moved"))
    assert _cache.cache_dir() == tmp_path / "moved"


def test_trim_removes_the_least_recently_written_entries_beyond_the_bound(tmp_path):
    """`trim` (run once per directory by `enable_compilation_cache`) keeps the newest entries
    (JAX's and the stored programs) within the bound, removes older ones with JAX's access
    stamps, and leaves other files."""
    for i in range(5):
        entry = tmp_path / f"k{i}-cache"
        entry.write_bytes(bytes(100))
        (tmp_path / f"k{i}-atime").write_bytes(bytes(8))
        os.utime(entry, ns=(10**18 + i * 10**9,) * 2)  # k0 the oldest
    (tmp_path / "other.txt").write_text("kept")
    stored = tmp_path / "s0-exe"  # a whole program (bsjax._executables), older than every entry
    stored.write_bytes(bytes(100))
    os.utime(stored, ns=(10**18 - 10**9,) * 2)
    assert _cache.trim(tmp_path, max_bytes=250) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "k3-atime",
        "k3-cache",
        "k4-atime",
        "k4-cache",
        "other.txt",
    ]
    assert _cache.trim(tmp_path, max_bytes=250) == 0
    assert jax.config.jax_compilation_cache_max_size == -1  # pyright: ignore[reportAttributeAccessIssue]


_LAPACK_SCRIPT = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import bsjax
bsjax.enable_compilation_cache()
from bsjax import sketch
t = np.linspace(0, 1, 40)
curves = sketch.fit_stroke(np.stack([t, np.sin(3 * t)], -1), tol=1e-3, split=False)
print(json.dumps([np.asarray(c.ctrl).tolist() for c in curves]))
"""


def test_a_stored_program_calling_lapack_runs_in_a_process_that_never_lowered_one(tmp_path):
    """`sketch.fit_stroke`'s fit solves by LAPACK (jaxlib's CPU kernels take their function
    pointers from scipy when an operation is lowered): the second process loads the programs
    untraced and must not jump to a null pointer (it crashed the test worker once)."""
    env = {**os.environ, "BSJAX_CACHE_DIR": str(tmp_path)}
    runs = []
    for _ in range(2):
        done = subprocess.run(
            [sys.executable, "-c", _LAPACK_SCRIPT], env=env, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr[-2000:]
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert list(tmp_path.glob("*-exe"))
    assert runs[0] == runs[1]


@compiled
def _checked_sqrt(x):
    x = _checks.positive(x, "x")
    return jnp.sqrt(x)


@compiled
def _outer(x, flag: bool):
    """A nested compiled call, at the program's own level and inside a `cond` branch."""
    y = _checked_sqrt(x)
    return jax.lax.cond(x[0] > 100.0, lambda: _checked_sqrt(-x), lambda: y) if flag else y


@compiled
def _two_checks(x):
    """A check of the program itself, then one inside a `cond` branch (an `eqx.error_if`)."""
    x = _checks.finite(x, "first")
    return jax.lax.cond(x[0] > 0, lambda: _checks.positive(x, "second"), lambda: x)


def test_the_first_failed_check_in_program_order_is_the_one_reported():
    with pytest.raises(ValueError, match=r"^first: expected finite values"):
        _two_checks(jnp.array([1.0, np.nan]))  # both fail: the branch's error_if yields to "first"
    with pytest.raises(ValueError, match=r"^second: expected finite values > 0"):
        _two_checks(jnp.array([1.0, -1.0]))  # only the branch's check fails
    np.testing.assert_allclose(_two_checks(jnp.array([-1.0, 2.0])), [-1.0, 2.0])


def test_a_failed_check_raises_its_message_in_every_form():
    good = jnp.array([1.0, 4.0])
    np.testing.assert_allclose(_checked_sqrt(good), [1.0, 2.0])
    with pytest.raises(ValueError, match=r"^x: expected finite values > 0, got"):
        _checked_sqrt(jnp.array([1.0, -4.0]))  # a direct call: the program's failure code
    with pytest.raises(ValueError, match=r"^x: expected finite values > 0"):
        _outer(jnp.array([1.0, np.nan]), False)  # the nested call's check joins the outer program
    with pytest.raises(ValueError, match=r"^x: expected finite values > 0"):
        _outer(jnp.array([200.0, 1.0]), True)  # inside a cond branch: an eqx.error_if, same message
    np.testing.assert_allclose(_outer(good, True), [1.0, 2.0])
    with pytest.raises(Exception, match=r"x: expected finite values > 0"):
        jax.block_until_ready(jax.jit(_checked_sqrt)(jnp.array([-1.0])))  # the caller's jit
    with pytest.raises(Exception, match=r"x: expected finite values > 0"):
        jax.block_until_ready(jax.vmap(_checked_sqrt)(jnp.array([[1.0], [-1.0]])))


def test_a_direct_call_holds_no_host_callback():
    """The program of a direct call (its failure code beside the result) has no callback; the
    same function under the caller's `jit` keeps its `eqx.error_if` (which has one)."""
    x = jnp.array([1.0, 4.0])
    _checked_sqrt(x)
    jax.jit(_checked_sqrt)(x)
    texts = {key[-1]: jitted.lower([x]).as_text() for key, jitted in _checked_sqrt._cache.items()}
    assert set(texts) == {True, False}
    assert "callback" not in texts[True]
    assert "callback" in texts[False]


def _plates():
    from bsjax import shapes

    flat = shapes.plate(5, 5)
    tilted = flat.with_ctrl(flat.ctrl.at[..., 2].set(0.3 * (flat.ctrl[..., 0] - 0.5)))
    return flat, tilted


def _surface_contacts():
    from bsjax import collide

    flat, tilted = _plates()
    b = flat.blending(16, 16)
    # capacity 4 overflows: the exact pass, then the flat pass (two programs)
    collide.surface_contacts(b, flat.ctrl, b, tilted.ctrl, capacity=4)


def _surface_penetration():
    from bsjax import collide

    flat, tilted = _plates()
    b = flat.blending(16, 16)
    collide.surface_penetration(b, flat.ctrl, b, tilted.ctrl, reach=0.1)


def _merge_refit():
    from bsjax import merge

    flat, _ = _plates()
    nets = [flat.ctrl, flat.ctrl.at[..., 0].add(1.0)]
    layout = merge.plan([flat.with_ctrl(c) for c in nets], "u", 0, samples=8)
    merge.refit(layout, nets)


def _simulate_coupled():
    from bsjax import mss

    flat, _ = _plates()
    lattice, coupling = mss.surface_lattice(flat.blending(6, 6), flat.ctrl, mss.JELLY)
    state = mss.State(lattice.rest_positions, jnp.zeros_like(lattice.rest_positions))
    mss.simulate_coupled(lattice, coupling, state, 1e-5, 4, 2)


def _simulate_scene():
    from bsjax import mss

    flat, tilted = _plates()
    bodies = [mss.Body.from_surface(s, (5, 5, 2), mss.JELLY, thickness=0.01) for s in (flat, tilted)]
    scene = mss.Scene(tuple(bodies))
    mss.simulate_scene(scene, mss.scene_init(scene), 1e-6, 3)


def _vsofm_report():
    from bsjax import shapes, vsofm

    ball = shapes.sphere(1.0)
    pts = ball.blending(12, 12).points(ball.ctrl).reshape(-1, 3)
    vsofm.report(pts, vsofm.fit(pts, (4, 4, 4), cycles=5))


_LOOPS_AND_BRANCHES = [
    _surface_contacts,
    _surface_penetration,
    _merge_refit,
    _simulate_coupled,
    _simulate_scene,
    _vsofm_report,
]


@pytest.mark.parametrize("call", _LOOPS_AND_BRANCHES, ids=lambda f: f.__name__.strip("_"))
def test_the_loops_and_branches_of_a_direct_call_hold_no_host_callback(monkeypatch, call):
    """Direct calls whose programs call public methods in a loop body or a branch (there under
    `_checks.trusted`, or through their kernels) hold no `eqx.error_if`, so JAX can store every
    program of theirs on disk."""
    from bsjax import _boundary

    ran = []
    run = _boundary._Compiled._run
    record = lambda jitted, dynamic, functional: (
        ran.append((jitted, dynamic)) or run(jitted, dynamic, functional)
    )
    monkeypatch.setattr(_boundary._Compiled, "_run", staticmethod(record))
    call()
    assert ran  # the calls went through the boundary
    jits = [(getattr(jitted, "jitted", jitted), dynamic) for jitted, dynamic in ran]  # a Stored one's jit
    with_callback = [
        jitted.__name__ for jitted, dynamic in jits if "callback" in jitted.lower(dynamic).as_text()
    ]
    assert not with_callback


def test_checks_are_not_built_inside_trusted():
    @compiled
    def f(x):
        with _checks.trusted():
            return jax.lax.cond(x[0] > 0, lambda: _checks.positive(x, "x"), lambda: x)

    np.testing.assert_allclose(f(jnp.array([1.0, -1.0])), [1.0, -1.0])  # not checked: as built
    (jitted,) = f._cache.values()
    assert "callback" not in jitted.lower([jnp.array([1.0, -1.0])]).as_text()


def test_quick_compilation_adds_its_flags_and_never_overrides_the_users():
    """`bsjax._xla.prefer_quick_compilation` (the CLI's and this suite's compiler options)."""
    from bsjax._xla import QUICK_FLAGS, prefer_quick_compilation

    env = {}
    assert prefer_quick_compilation(env).split() == list(QUICK_FLAGS)
    assert prefer_quick_compilation(env) == env["XLA_FLAGS"] == " ".join(QUICK_FLAGS)  # idempotent
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    assert prefer_quick_compilation(env).split() == ["--xla_force_host_platform_device_count=4", *QUICK_FLAGS]
    env = {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}  # the user's choice wins
    assert prefer_quick_compilation(env) == "--xla_cpu_use_fusion_emitters=true"
    assert prefer_quick_compilation(env, flags=("--xla_backend_optimization_level=0",)).split() == [
        "--xla_cpu_use_fusion_emitters=true",
        "--xla_backend_optimization_level=0",
    ]  # other flags (the suite's TEST_FLAGS)
    assert set(QUICK_FLAGS) <= set(os.environ["XLA_FLAGS"].split())  # this run's (tests/conftest.py)


def test_boundary_options_are_the_quick_flags_unless_xla_flags_names_them(monkeypatch):
    """`bsjax._xla.boundary_options`: the classic emitters for bsjax's own programs on CPU; a
    flag of the same name in the user's `XLA_FLAGS` wins (then no option is passed)."""
    from bsjax._xla import boundary_options

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
    assert boundary_options() == {"xla_cpu_use_fusion_emitters": False}
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert boundary_options() is None


_OPTIONS_SCRIPT = """
import json, jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from bsjax import collide, shapes
from bsjax._xla import boundary_options
s = shapes.plate(6, 6)
b = s.blending(12, 12)
tool = collide.Sphere(jnp.array([0.5, 0.5, 0.05]), 0.1)
direct = collide.contacts(b, s.ctrl, tool).depth
jitted = jax.jit(lambda c: collide.contacts(b, c, tool).depth)(s.ctrl)
lifted = jax.grad(lambda c: collide.contacts(b, c, tool).depth.sum())(s.ctrl)
kvs = {key[-1]: [list(kv) for kv in (sorted(p.compiler_options.items()) if key[-1]  # top level
                                      else p._jit_info.compiler_options_kvs)]
       for key, p in collide.contacts._cache.items()}
print(json.dumps({
    "options": boundary_options(),
    "top_level": kvs[True],
    "nested": kvs[False],
    "same": bool(jnp.array_equal(direct, jitted)),
    "grad_finite": bool(jnp.isfinite(lifted).all()),
}))
"""


def test_direct_calls_compile_with_the_boundary_options_and_nest_without_them():
    """Without `XLA_FLAGS` (a user's process), a direct call's program carries the boundary's
    compiler options; the same entry inside the caller's `jit`/`grad` is inlined without them
    (JAX refuses compiler options on a nested `jit`), with the same result."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    done = subprocess.run(
        [sys.executable, "-c", _OPTIONS_SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["options"] == {"xla_cpu_use_fusion_emitters": False}
    assert out["top_level"] == [["xla_cpu_use_fusion_emitters", False]]
    assert out["nested"] == []
    assert out["same"] and out["grad_finite"]


# --- the store of whole programs (bsjax._executables) ---------------------------------------------

_TRACED: list = []  # one entry per trace of `_scaled`


@compiled
def _scaled(x, n: int, *, by):
    _TRACED.append(n)
    return _checks.finite(x, "x") * by * n


@compiled
def _mapped(x, fn):
    return fn(x)


@pytest.fixture
def store(tmp_path, monkeypatch):
    """The caches (JAX's and the store) in `tmp_path`, this module's functions keyable, nothing
    compiled yet; the run's caches again afterwards."""
    from bsjax import _executables

    monkeypatch.setattr(_executables, "_OWNERS", (*_executables._OWNERS, "tests"))
    assert bsjax.enable_compilation_cache(tmp_path) == tmp_path
    _TRACED.clear()
    forget()
    yield tmp_path
    forget()
    bsjax.enable_compilation_cache()


def forget():
    """A new process's view of the store: nothing compiled in memory."""
    for fn in (_scaled, _mapped):
        fn.clear_cache()
    jax.clear_caches()


def _stored(path) -> list[str]:
    return sorted(p.name for p in path.glob("*-exe"))


def test_a_stored_program_is_loaded_untraced_and_keyed_by_everything_that_decides_it(store, monkeypatch):
    from bsjax import _executables

    x = jnp.arange(3.0)
    expected = np.arange(3.0)
    np.testing.assert_array_equal(_scaled(x, 2, by=0.5), expected)
    assert _TRACED == [2] and len(_stored(store)) == 1
    forget()
    np.testing.assert_array_equal(_scaled(x, 2, by=0.25), expected / 2)  # a new float: the same program
    np.testing.assert_array_equal(_scaled(x.tolist(), 2, by=0.25), expected / 2)  # a list: the same
    assert _TRACED == [2] and len(_stored(store)) == 1  # loaded, not traced
    _scaled(jnp.arange(4.0), 2, by=1.0)  # another shape
    _scaled(x, 3, by=1.0)  # another static value
    _scaled(x.astype(jnp.float32), 2, by=1.0)  # another dtype
    assert _TRACED == [2, 2, 3, 2] and len(_stored(store)) == 4
    forget()
    # the same program under other keys: traced again, then found in JAX's cache (not stored)
    with jax.numpy_dtype_promotion("standard"):  # another trace context (the suite's is strict)
        _scaled(x, 2, by=1.0)
    assert len(_TRACED) == 5
    forget()
    monkeypatch.setattr(_executables, "_source_digest", lambda: "an edited bsjax")
    _scaled(x, 2, by=1.0)
    assert len(_TRACED) == 6 and len(_stored(store)) == 4


def test_a_stored_program_keeps_its_value_checks(store):
    bad = jnp.array([1.0, np.nan])
    with pytest.raises(ValueError, match=r"^x: expected finite values, got"):
        _scaled(bad, 2, by=1.0)  # compiled and stored
    forget()
    with pytest.raises(ValueError, match=r"^x: expected finite values, got"):
        _scaled(bad, 2, by=1.0)  # loaded
    assert _TRACED == [2] and len(_stored(store)) == 1


def test_a_call_holding_the_users_code_is_never_stored(store):
    x = jnp.arange(3.0)
    from bsjax import _safe

    np.testing.assert_allclose(_mapped(x, _safe.norm), np.sqrt(5.0))  # bsjax's: keyable
    assert len(_stored(store)) == 1
    np.testing.assert_array_equal(_mapped(x, lambda y: 2 * y), 2 * np.arange(3.0))  # a lambda

    def double(y):
        return 2 * y

    np.testing.assert_array_equal(_mapped(x, double), 2 * np.arange(3.0))  # a local function
    assert len(_stored(store)) == 1


def test_an_unreadable_entry_is_removed_and_the_program_compiled_again(store):
    x = jnp.arange(3.0)
    _scaled(x, 2, by=1.0)
    (entry,) = store.glob("*-exe")
    whole = entry.read_bytes()
    entry.write_bytes(whole[: len(whole) // 2])  # truncated
    forget()
    np.testing.assert_array_equal(_scaled(x, 2, by=1.0), 2 * np.arange(3.0))  # from JAX's cache
    assert _TRACED == [2, 2] and not entry.exists()  # (JAX's copy of it is not stored: module doc)
    for path in store.glob("*-cache"):
        path.unlink()
    forget()
    np.testing.assert_array_equal(_scaled(x, 2, by=1.0), 2 * np.arange(3.0))  # compiled
    assert _TRACED == [2, 2, 2] and len(entry.read_bytes()) > 0
    forget()
    np.testing.assert_array_equal(_scaled(x, 2, by=1.0), 2 * np.arange(3.0))
    assert _TRACED == [2, 2, 2]  # the new entry loads


_DEVICES_SCRIPT = """
import json
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
from bsjax import shapes
s = shapes.plate(4, 4)
b = s.blending(6, 6)
here = b.points(s.ctrl)
there = b.points(jax.device_put(s.ctrl, jax.devices()[1]))
again = b.points(s.ctrl)
print(json.dumps({
    "devices": [sorted(d.id for d in x.devices()) for x in (here, there, again)],
    "same": bool(jnp.array_equal(here, jax.device_put(there, jax.devices()[0]))),
}))
"""


def test_a_direct_call_runs_where_its_arrays_are_committed():
    """As under `jax.jit`: an argument committed to another device gets a program there (the
    programs of a direct call are compiled per placement, not only per shape)."""
    env = {
        **os.environ,
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2",
    }
    done = subprocess.run(
        [sys.executable, "-c", _DEVICES_SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out == {"devices": [[0], [1], [0]], "same": True}
