"""Reference surfaces and a finite-difference gradient check shared by the tests."""

from __future__ import annotations

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax.basis import BSplineSurface, clamped_knots


def random_knots(rng, n_ctrl: int, degree: int) -> np.ndarray:
    """A random clamped, non-uniform knot vector on [0, 1] (interior multiplicity 1)."""
    n_interior = n_ctrl - degree - 1
    interior = np.sort(rng.uniform(0.05, 0.95, n_interior))
    # keep interior knots distinct enough that the basis is well conditioned
    interior = np.maximum.accumulate(interior + np.arange(n_interior) * 1e-3)
    interior = interior / max(1.0, interior[-1] / 0.97) if n_interior else interior
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def random_surface(rng, r=6, s=5, k=3, l=2, uniform=False, weights=False) -> BSplineSurface:
    """A random bumpy surface over [0, 1]² with random (or uniform) clamped knots."""
    tu = clamped_knots(r, k) if uniform else random_knots(rng, r, k)
    tv = clamped_knots(s, l) if uniform else random_knots(rng, s, l)
    x, y = np.meshgrid(np.linspace(0, 1, r), np.linspace(0, 1, s), indexing="ij")
    ctrl = np.stack([x, y, 0.2 * rng.normal(size=x.shape)], axis=-1)
    w = rng.uniform(0.5, 2.0, (r, s)) if weights else None
    return BSplineSurface(ctrl, tu, tv, k, l, weights=w)


def check_grad(f, x, eps: float = 1e-6, rtol: float = 1e-5, atol: float = 1e-7, n_dirs: int = 4, seed=0):
    """Compare `jax.grad(f)(x)` with central differences along random directions.

    One compiled program, `jax.value_and_grad(f)`, serves the gradient and the differences'
    values (a second program for `f` alone would compile its forward pass again; eagerly, every
    operation would be a program of its own)."""
    x = jnp.asarray(x)
    value_and_grad = jax.jit(jax.value_and_grad(f))
    _, g = value_and_grad(x)
    assert bool(jnp.all(jnp.isfinite(g))), "gradient has non-finite entries"
    rng = np.random.default_rng(seed)
    for _ in range(n_dirs):
        d = jnp.asarray(rng.normal(size=x.shape))
        fd = (value_and_grad(x + eps * d)[0] - value_and_grad(x - eps * d)[0]) / (2 * eps)
        an = jnp.vdot(g, d)
        assert abs(float(fd - an)) <= atol + rtol * abs(float(fd)), (float(fd), float(an))
    return g


def raises_both(fn, *arrays, match: str, errors=(ValueError, TypeError)):
    """`fn(*arrays)` raises a clear error eagerly and inside `jax.jit` with the same message.

    Eagerly: one of `errors` whose message matches `match` (a regex). Under `jax.jit(fn)`: the
    same (a structure error raised while tracing), or the runtime error of an `eqx.error_if`
    value check, whose text carries the same message.
    """
    import pytest

    with pytest.raises(errors, match=match):
        out = fn(*arrays)
        jax.block_until_ready(out)
    with pytest.raises((*errors, jax.errors.JaxRuntimeError), match=match):
        out = jax.jit(fn)(*arrays)
        jax.block_until_ready(out)


# --- a real headless Chromium for the page tests (the `browser` fixture is in conftest.py) ---------
CHROMIUM = shutil.which("chromium-headless-shell") or shutil.which("chromium")
needs_browser = pytest.mark.skipif(
    CHROMIUM is None, reason="no system Chromium (apt-get install chromium-headless-shell)"
)
