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


def jit_vmap_grad(
    f, x, far, reduce=lambda y: jnp.sum(jnp.sin(y)), close=None, n_dirs=2, eps=1e-6, rtol=1e-5, atol=1e-7
):
    """The jit, vmap and gradient checks of `f` in one compiled program,
    `jit(vmap(value_and_grad(reduce ∘ f)))`, over the batch `[x, x + eps d_i, x − eps d_i, far]`
    (`x`, `far`: pytrees of arrays; `d_i`: `n_dirs` random directions, as `tests.helpers.check_grad`
    draws them; the batch is built and the differences taken in numpy, so nothing else compiles):
    its `f` at `x` and at `far` equal the direct (eager) calls `f(x)`, `f(far)` (`far` far from
    `x`: the batch's elements are not mixed up) to `close` (assert_allclose's arguments, default
    `atol=1e-13`); the gradient at `x` is finite and matches the central differences of
    `reduce(f)` along each `d_i` (`check_grad`'s tolerances). Returns the batched outputs of `f`,
    their reduced values and the gradient at `x` (numpy)."""
    leaves, tree = jax.tree.flatten(jax.tree.map(np.asarray, x))
    rng = np.random.default_rng(0)
    dirs = [[rng.normal(size=a.shape) for a in leaves] for _ in range(n_dirs)]
    points = [leaves] + [[a + eps * d for a, d in zip(leaves, ds)] for ds in dirs]
    points += [[a - eps * d for a, d in zip(leaves, ds)] for ds in dirs] + [jax.tree.leaves(far)]
    batch = jax.tree.unflatten(
        tree, [np.stack([np.asarray(p[i]) for p in points]) for i in range(len(leaves))]
    )

    def loss(p):
        y = f(p)
        return reduce(y), y

    out = jax.jit(jax.vmap(jax.value_and_grad(loss, has_aux=True)))(batch)
    (values, outs), grads = jax.tree.map(np.asarray, out)
    close = {"atol": 1e-13} if close is None else close
    for k, point in ((0, x), (-1, far)):
        direct = f(jax.tree.map(jnp.asarray, point))
        jax.tree.map(lambda o, e: np.testing.assert_allclose(o[k], e, **close), outs, direct)
    g = [a[0] for a in jax.tree.leaves(grads)]
    assert all(np.isfinite(a).all() for a in g), "gradient has non-finite entries"
    for i, ds in enumerate(dirs):
        fd = (values[1 + i] - values[1 + n_dirs + i]) / (2 * eps)
        an = sum(float(np.vdot(a, d)) for a, d in zip(g, ds))
        assert abs(float(fd - an)) <= atol + rtol * abs(float(fd)), (float(fd), float(an))
    return outs, values, jax.tree.unflatten(tree, g)
