"""Broad phase: control-hull separation and the parametric window of support spans.

A B-spline (or NURBS with positive weights) surface lies in the convex hull of its control
points, and each sample lies in the hull of the `(k+1)(l+1)` control points whose basis
functions are non-zero there (thesis §3.2.3, §3.3.3.1–2). Both facts give conservative tests:
when they say "apart", the surface and the tool cannot meet.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

_FW_STEPS = 24


def hulls_apart(
    a: Float[Array, "p 3"],
    b: Float[Array, "q 3"],
    margin: Float[Array, ""] | float = 0.0,
    steps: int = _FW_STEPS,
) -> Bool[Array, ""]:
    """Certify that `dist(conv(a), conv(b)) > margin` (False means "maybe touching").

    Gilbert-type iteration (Frank–Wolfe on the Minkowski difference `conv(a) − conv(b)`) with a
    fixed number of steps: `x` is the current point of the difference, `s` the support point in
    direction `−x`; the plane with normal `x̂` separates the hulls by `x̂·s` whenever that is
    positive, so `x̂·s > margin` is an exact certificate (thesis §3.3.3.1 separating plane).
    """
    x0 = a[0] - b[0]

    def support(d):
        return a[jnp.argmin(a @ d)] - b[jnp.argmax(b @ d)]

    def body(_, carry):
        x, certified = carry
        s = support(x)
        nx = jnp.sqrt(jnp.sum(x * x))
        gap = jnp.where(nx > 0, jnp.dot(s, x) / jnp.where(nx > 0, nx, 1), -jnp.inf)
        certified = certified | (gap > margin)
        d = x - s
        dd = jnp.sum(d * d)
        gamma = jnp.clip(jnp.where(dd > 0, jnp.dot(x, d) / jnp.where(dd > 0, dd, 1), 0), 0, 1)
        return x - gamma * d, certified

    x, certified = jax.lax.fori_loop(0, steps, body, (x0, jnp.zeros((), bool)))
    return jax.lax.stop_gradient(certified)


def support_start(a: Float[Array, "m r"], degree: int, periodic: bool) -> Array:
    """First control index of each sample's support (cyclic for periodic directions).

    The support of row `a` is a run of at most `degree + 1` consecutive (cyclically, if periodic)
    non-zero basis functions; a clamped start is capped at `r − degree − 1` so that the block of
    `degree + 1` control points from the start always covers the support.
    """
    nz = a > 0
    r = a.shape[1]
    if periodic:
        starts = nz & ~jnp.roll(nz, 1, axis=1)
        return jnp.where(jnp.any(starts, 1), jnp.argmax(starts, 1), 0)
    return jnp.minimum(jnp.argmax(nz, 1), r - degree - 1)


def _blocks(ctrl, k, l, periodic_u, periodic_v):
    """Bounding boxes of every `(k+1) × (l+1)` block of control points, `(r', s', 3)` lo and hi."""

    def extend(x, size, axis, periodic):
        if periodic:
            return jnp.concatenate([x, jax.lax.slice_in_dim(x, 0, size, axis=axis)], axis=axis)
        return x

    r, s = ctrl.shape[:2]
    ext = extend(extend(ctrl, k, 0, periodic_u), l, 1, periodic_v)
    nu = r if periodic_u else r - k
    nv = s if periodic_v else s - l
    win = (k + 1, l + 1, 1)
    big = jnp.array(jnp.inf, ext.dtype)
    lo = jax.lax.reduce_window(ext, big, jax.lax.min, win, (1, 1, 1), "VALID")[:nu, :nv]
    hi = jax.lax.reduce_window(ext, -big, jax.lax.max, win, (1, 1, 1), "VALID")[:nu, :nv]
    return lo, hi


def sample_window(blending, ctrl, tool) -> tuple[Bool[Array, "m n"], Float[Array, "4"]]:
    """Samples whose local control hull may meet `tool`, and the parametric window they span.

    **Returns:** `(mask (m, n), window [u_min, u_max, v_min, v_max])`; an empty window is
    `[1, 0, 1, 0]` (min > max).
    """
    su = support_start(blending.a_u[0], blending.degree_u, blending.periodic_u)
    sv = support_start(blending.a_v[0], blending.degree_v, blending.periodic_v)
    lo, hi = _blocks(ctrl, blending.degree_u, blending.degree_v, blending.periodic_u, blending.periodic_v)
    block_hit = tool.box_overlap(lo, hi)
    mask = block_hit[su[:, None], sv[None, :]]
    return mask, parametric_window(mask, blending.params_u, blending.params_v)


def parametric_window(mask, params_u, params_v) -> Float[Array, "4"]:
    """`[u_min, u_max, v_min, v_max]` of the True entries of an `(m, n)` mask."""
    rows, cols = jnp.any(mask, 1), jnp.any(mask, 0)
    one, zero = jnp.ones((), params_u.dtype), jnp.zeros((), params_u.dtype)
    return jnp.stack(
        [
            jnp.min(jnp.where(rows, params_u, one)),
            jnp.max(jnp.where(rows, params_u, zero)),
            jnp.min(jnp.where(cols, params_v, one)),
            jnp.max(jnp.where(cols, params_v, zero)),
        ]
    )
