"""Safe division, square roots, norms and normalisation — the one place for singular operations.

Every function is finite with a finite gradient everywhere, including exactly at the singular
point (the "double where" of STYLE: the unsafe branch never sees the singular input). Norms are
scaled by the largest component first, so vectors of size 1e-160 or 1e300 normalise correctly.
"""

from __future__ import annotations

import jax.numpy as jnp


def ratio(num, den):
    """`num / den`, and 0 where `den == 0` (e.g. repeated knots in Cox–de Boor)."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), 0)


def sqrt(x):
    """`sqrt(max(x, 0))` with a finite gradient at and below 0."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def norm(x, axis=-1, keepdims=False):
    """Euclidean norm along `axis`, overflow- and underflow-safe, gradient finite at 0."""
    scale = jnp.max(jnp.abs(x), axis=axis, keepdims=True)
    ok = scale > 0
    safe_scale = jnp.where(ok, scale, 1)
    y = jnp.where(ok, x / safe_scale, 0)
    sq = jnp.sum(y * y, axis=axis, keepdims=True)
    sq_ok = sq > 0
    out = jnp.where(sq_ok, safe_scale * jnp.sqrt(jnp.where(sq_ok, sq, 1)), 0)
    return out if keepdims else jnp.squeeze(out, axis=axis)


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
