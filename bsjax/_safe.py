"""Safe division, square roots, norms and normalisation — the one place for singular operations.

Every function is finite with a finite gradient everywhere, including exactly at the singular
point (the "double where" of STYLE: the unsafe branch never sees the singular input). Norms are
scaled by the largest component first, so vectors of size 1e-160 or 1e300 normalise correctly.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def ratio(num, den, xp=jnp):
    """`num / den`, and 0 where `den == 0` (e.g. repeated knots in Cox–de Boor); `xp`: the array
    module (`numpy` for host-side precomputation, see `bsjax._checks.xp`)."""
    ok = den != 0
    return xp.where(ok, num / xp.where(ok, den, 1), 0)


def sqrt(x):
    """`sqrt(max(x, 0))` with a finite gradient at and below 0."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def norm(x, axis=-1, keepdims=False):
    """Euclidean norm along `axis`, overflow- and underflow-safe, gradient finite at 0."""
    scale = _reduce(jnp.maximum, jnp.max, jnp.abs(x), axis)
    ok = scale > 0
    safe_scale = jnp.where(ok, scale, 1)
    y = jnp.where(ok, x / safe_scale, 0)
    sq = _reduce(jnp.add, jnp.sum, y * y, axis)
    sq_ok = sq > 0
    out = jnp.where(sq_ok, safe_scale * jnp.sqrt(jnp.where(sq_ok, sq, 1)), 0)
    return out if keepdims else jnp.squeeze(out, axis=axis)


def _reduce(op, reduction, x, axis):
    """`reduction(x, axis, keepdims=True)`, written out with `op` over a short axis (≤ 4, e.g.
    xyz): XLA on CPU then fuses it with its neighbours into one elementwise loop, where a
    reduction is a separate library call costing 10–40 µs even on a (1600, 3) array."""
    size = x.shape[axis]
    if not 0 < size <= 4:
        return reduction(x, axis=axis, keepdims=True)
    out = jax.lax.index_in_dim(x, 0, axis)
    for i in range(1, size):
        out = op(out, jax.lax.index_in_dim(x, i, axis))
    return out


def dot(a, b, axis=-1):
    """`Σ a b` along `axis` (e.g. xyz), written out over a short axis (see `_reduce`)."""
    return jnp.squeeze(_reduce(jnp.add, jnp.sum, a * b, axis), axis=axis)


def unit(x, axis=-1):
    """`x / |x|`, and 0 where `|x| = 0`; finite gradients everywhere."""
    n = norm(x, axis=axis, keepdims=True)
    ok = n > 0
    return jnp.where(ok, x / jnp.where(ok, n, 1), 0)


def unit_or_zero(x, tiny=None):
    """`(x / |x|, ok)` with `ok = |x| > tiny` (default: the dtype's smallest normal); 0 where not ok."""
    n = norm(x)
    tiny = jnp.finfo(x.dtype).tiny if tiny is None else tiny
    ok = n > tiny
    return jnp.where(ok[..., None], x / jnp.where(ok, n, 1)[..., None], 0), ok
