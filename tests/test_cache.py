"""The persistent compilation cache (`bsjax.enable_compilation_cache`) and the compiled boundary's
failure codes that make its programs storable.

A program holding a host callback (`eqx.error_if`'s) cannot be stored by JAX; bsjax's direct
calls return a failure code instead, so a second process loads every program of a direct call
from disk: that is asserted by counting JAX's own cache hits and misses in two fresh processes.
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
    counts = {"hits": 0, "misses": 0}
    def listen(event, **kwargs):
        if event == "/jax/compilation_cache/cache_hits":
            counts["hits"] += 1
        elif event == "/jax/compilation_cache/cache_misses":
            counts["misses"] += 1
    monitoring.register_event_listener(listen)
    import bsjax
    where = bsjax.enable_compilation_cache()
    from bsjax import collide, shapes
    s = shapes.plate(6, 6)
    b = s.blending(12, 12)
    out = collide.contacts(b, s.ctrl, collide.Sphere([0.5, 0.5, 0.05], 0.2))
    jax.block_until_ready(out)
    print(json.dumps({**counts, "dir": str(where), "hit": int(out.hit.sum())}))
    """
)


def _run(env) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, timeout=300
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
    second = _run(env)
    assert second["misses"] == 0, second
    assert second["hits"] >= first["misses"]
    assert second["hit"] == first["hit"]


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
