"""Broad phase: control-hull separation and the parametric window of support spans.

A B-spline (or NURBS with positive weights) surface lies in the convex hull of its control
points, and each sample lies in the hull of the `(k+1)(l+1)` control points whose basis
functions are non-zero there (thesis §3.2.3, §3.3.3.1–2). Both facts give conservative tests:
when they say "apart", the surface and the tool cannot meet.

`hulls_apart`, `sample_window` and `parametric_window` are compiled at the public boundary
(`bsjax._boundary.compiled`); the queries of `collide.contact` call the private kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled

_FW_STEPS = 24


def _points(x, name: str):
    """`x` as a floating `(p, 3)` array with finite entries (structure now, values when run)."""
    _checks.check_real(x, name)
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    _checks.check_ndim(x, name, 2, last=3)
    if x.shape[0] < 1:
        _checks.fail(name, "at least one point", f"shape {x.shape}")
    return _checks.finite(x, name)


@compiled
def hulls_apart(
    a: Float[Array, "p 3"],
    b: Float[Array, "q 3"],
    margin: Float[Array, ""] | float = 0.0,
    steps: int = _FW_STEPS,
) -> Bool[Array, ""]:
    """Certify that `dist(conv(a), conv(b)) > margin` (False means "maybe touching").

    **Arguments:** point sets `a (p, 3)`, `b (q, 3)` (finite); `margin` ≥ 0 (`inf` allowed:
    never apart); `steps` (static int ≥ 1) iterations.

    **Returns:** `()` bool, without gradient (a decision).

    Gilbert-type iteration (Frank–Wolfe on the Minkowski difference `conv(a) − conv(b)`) with a
    fixed number of steps: `x` is the current point of the difference, `s` the support point in
    direction `−x`; the plane with normal `x̂` separates the hulls by `x̂·s` whenever that is
    positive, so `x̂·s > margin` is an exact certificate (thesis §3.3.3.1 separating plane).
    """
    steps = _checks.check_count(steps, "steps")
    a, b = _points(a, "a"), _points(b, "b")
    dtype = jnp.result_type(a.dtype, b.dtype)
    margin = jnp.asarray(margin, dtype)
    if margin.shape != ():
        _checks.fail("margin", "a scalar", f"shape {margin.shape}")
    margin = _checks.check(margin, ~(margin >= 0), "margin", "a value >= 0 (inf allowed)", "< 0 or NaN")
    return _hulls_apart(a.astype(dtype), b.astype(dtype), margin, steps)


def _hulls_apart(a, b, margin, steps: int = _FW_STEPS):
    """The kernel of `hulls_apart` (no checks; called inside the compiled queries)."""
    a, b, margin = jax.lax.stop_gradient((a, b, margin))  # a decision: no gradient
    x0 = a[0] - b[0]

    def support(d):
        return a[jnp.argmin(a @ d)] - b[jnp.argmax(b @ d)]

    def undecided(carry):
        # `x` lies in the Minkowski difference, so `|x| ≥ dist ≥ any gap`: once `|x| ≤ margin`
        # no later step can certify, and once certified the answer stays — the remaining
        # steps of the fixed count would not change the result (the early exit of a touching
        # tool, the common case of a contact query)
        i, x, certified = carry
        return (i < steps) & ~certified & (_safe.norm(x) > margin)

    def body(carry):
        i, x, certified = carry
        s = support(x)
        gap = jnp.where(jnp.any(x != 0), _safe.ratio(jnp.dot(s, x), _safe.norm(x)), -jnp.inf)
        certified = certified | (gap > margin)
        d = x - s
        gamma = jnp.clip(_safe.ratio(jnp.dot(x, d), jnp.sum(d * d)), 0, 1)
        return i + 1, x - gamma * d, certified

    _, _, certified = jax.lax.while_loop(undecided, body, (0, x0, jnp.zeros((), bool)))
    return certified


def unless_apart(apart, narrow, *args, empty=None):
    """`narrow(*args)`, or `empty(structure)` (default: zeros of the narrow phase's output
    structure, a pytree of `jax.ShapeDtypeStruct`s) when the broad phase certified `apart`
    (the early exit of thesis §3.3.3.1: `lax.cond` skips the narrow phase at run time; under
    `vmap` both branches run and the result is selected).

    The narrow phase is traced once: `lax.cond` traces its first branch first, and the zero
    branch takes that trace's output shapes (a second trace, by `jax.eval_shape`, only if a JAX
    version traced the branches the other way round). Tracing it twice had been a third of
    `surface_contacts`' first call.
    """
    shapes = []

    def narrow_traced(*a):
        out = narrow(*a)
        shapes.append(jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), out))
        return out

    def separated(*a):
        structure = shapes[-1] if shapes else jax.eval_shape(narrow, *a)
        if empty is not None:
            return empty(structure)
        return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), structure)

    return jax.lax.cond(jnp.logical_not(apart), narrow_traced, separated, *args)


def support_start(a: Float[Array, "m r"], degree: int, periodic: bool) -> Array:
    """First control index of each sample's support (cyclic for periodic directions).

    The support of row `a` is a run of at most `degree + 1` consecutive (cyclically, if periodic)
    non-zero basis functions; a clamped start is capped at `r − degree − 1` so that the block of
    `degree + 1` control points from the start always covers the support. (A kernel of the
    compiled queries.)
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


@compiled
def parametric_window(mask: Bool[Array, "m n"], params_u: Float[Array, " m"], params_v: Float[Array, " n"]):
    """`[u_min, u_max, v_min, v_max]` of the True entries of an `(m, n)` mask.

    **Arguments:** `mask (m, n)` bool, the grid's parameters `params_u (m,)`, `params_v (n,)`.

    **Returns:** `(4,)`; an empty mask gives `[1, 0, 1, 0]` (min > max).
    """
    mask = jnp.asarray(mask)
    if mask.dtype != jnp.bool_:
        raise TypeError(f"mask: expected a bool array, got dtype {mask.dtype}")
    _checks.check_ndim(mask, "mask", 2)
    params_u, params_v = jnp.asarray(params_u), jnp.asarray(params_v)
    for name, p, size in (("params_u", params_u, mask.shape[0]), ("params_v", params_v, mask.shape[1])):
        if p.shape != (size,):
            _checks.fail(name, f"shape ({size},) (the mask's {name[-1]} size)", f"shape {p.shape}")
    params_u, params_v = _checks.finite(params_u, "params_u"), _checks.finite(params_v, "params_v")
    return _parametric_window(mask, params_u, params_v)


def _parametric_window(mask, params_u, params_v):
    """The kernel of `parametric_window` (no checks)."""
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
