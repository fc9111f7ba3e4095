"""B-spline basis functions and blending matrices (thesis ch. 3).

A blending matrix holds every basis function (or its derivative) of one direction at a list of
parameters: `A[a, i] = B_{i,k}(u_a)` (thesis eq. 3.6). A tensor-product surface sampled on a
grid is then two small matrix products, `M = A_u P A_v^T`, so evaluation, refitting, collision,
merging and physics never recompute basis functions at run time.

Conventions: parameters live on [0, 1]; clamped knot vectors have `degree + 1` equal knots at
each end; the periodic (closed) basis is the uniform one of thesis eq. 3.3, on [0, 1).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax._typing import ArrayLike
from bsjax.basis._knots import float_dtype, periodic_knots


def _raise_degree(lower, knots, t, p):
    """Cox–de Boor step (thesis eq. 3.2): degree p−1 values → degree p values."""
    L = knots.shape[0]
    left = _safe.ratio(t - knots[: L - p - 1], knots[p : L - 1] - knots[: L - p - 1])
    right = _safe.ratio(knots[p + 1 :] - t, knots[p + 1 :] - knots[1 : L - p])
    return lower[:-1] * left + lower[1:] * right


def _differentiate(lower, knots, p):
    """Derivative step (The NURBS Book eq. 2.9): `N'_{i,p} = p (N_{i,p−1}/Δ_i − N_{i+1,p−1}/Δ_{i+1})`."""
    L = knots.shape[0]
    left = _safe.ratio(jnp.ones_like(knots[: L - p - 1]), knots[p : L - 1] - knots[: L - p - 1])
    right = _safe.ratio(jnp.ones_like(knots[p + 1 :]), knots[p + 1 :] - knots[1 : L - p])
    return p * (lower[:-1] * left - lower[1:] * right)


def basis_functions(knots: Float[Array, " L"], degree: int, t: Float[Array, ""], nu: int = 0):
    """The nu-th derivative of all `L − degree − 1` basis functions at one parameter `t` (a kernel:
    no checks; callers validate).

    Parameters are clipped to the domain `[t_k, t_{n}]` (by `where`, so the derivative in `t` at
    the domain ends is the one-sided derivative, not halved as `clip`'s would be); the right end
    belongs to the last non-empty span, so `t = 1` is included. Differentiable in `t` and in the
    knots.

    **Returns:** `(L − degree − 1,)`; at most `degree + 1` entries are non-zero.
    """
    return basis_derivatives(knots, degree, t, (nu,))[0]


def basis_derivatives(knots: Float[Array, " L"], degree: int, t: Float[Array, ""], orders: tuple[int, ...]):
    """`basis_functions` of each derivative order in `orders`, `(len(orders), L − degree − 1)`:
    one Cox–de Boor triangle (thesis eq. 3.2) shared by all orders, order nu branching off at
    degree `degree − nu` into nu derivative steps (The NURBS Book eq. 2.9)."""
    for nu in orders:
        check_order(nu)
    L = knots.shape[0]
    n_ctrl = L - degree - 1
    t, span = _clip_and_span(knots, degree, t)
    triangle = [(jnp.arange(L - 1, dtype=jnp.int32) == span).astype(knots.dtype)]
    for p in range(1, degree - min(orders, default=0) + 1):
        triangle.append(_raise_degree(triangle[-1], knots, t, p))
    out = []
    for nu in orders:
        if nu > degree:
            out.append(jnp.zeros((n_ctrl,), dtype=knots.dtype))
            continue
        values = triangle[degree - nu]
        for p in range(degree - nu + 1, degree + 1):
            values = _differentiate(values, knots, p)
        out.append(values)
    return jnp.stack(out)


def _clip_and_span(knots, degree: int, t):
    """`(t clipped to the domain, span)`: the knot span `t_span ≤ t < t_{span+1}` whose `degree + 1`
    basis functions `span − degree … span` are the only ones non-zero at `t` (The NURBS Book A2.1,
    with the last non-empty span at or left of `t`, so the right end `t = 1` is included)."""
    n_ctrl = knots.shape[0] - degree - 1
    lo, hi = knots[degree], knots[n_ctrl]
    t = jnp.where(t < lo, lo, jnp.where(t > hi, hi, t))
    domain = knots[degree : n_ctrl + 1]
    # a count, not jnp.searchsorted's binary search: its while loop costs ~3× the compile of the
    # whole basis triangle, and the knot vectors are short
    span = jnp.sum(domain <= t, dtype=jnp.int32) - 1
    nonempty = jnp.where(jnp.diff(domain) > 0, jnp.arange(n_ctrl - degree, dtype=jnp.int32), 0)
    return t, jnp.minimum(span, jnp.max(nonempty)) + degree


def support(knots, degree: int, params) -> Int[Array, "m k1"]:
    """Indices `span − degree … span` of the `degree + 1` basis functions that can be non-zero
    (with all their derivatives) at each parameter, `(m, degree + 1)` int32 (a kernel; no checks).
    Every other entry of the row `basis_functions(knots, degree, t, nu)` is exactly zero."""
    first = jax.vmap(lambda t: _clip_and_span(knots, degree, t)[1])(params) - degree
    return first[:, None] + jnp.arange(degree + 1, dtype=jnp.int32)[None, :]


def periodic_support(n_ctrl: int, degree: int, params) -> Int[Array, "m k1"]:
    """`support` of the uniform closed basis (thesis eq. 3.3): the unwrapped indices taken modulo
    `n_ctrl` (distinct, since `degree < n_ctrl`)."""
    knots = periodic_knots(n_ctrl, degree, dtype=params.dtype)
    return support(knots, degree, params - jnp.floor(params)) % n_ctrl


def rows(knots, degree: int, params, orders: tuple[int, ...]):
    """`basis_functions` of each derivative order in `orders` at every parameter, stacked
    `(len(orders), m, n_ctrl)` (the blending-matrix kernel; no checks)."""
    return jnp.moveaxis(jax.vmap(lambda t: basis_derivatives(knots, degree, t, orders))(params), 0, 1)


def periodic_rows(n_ctrl: int, degree: int, params, orders: tuple[int, ...]):
    """`rows` of the uniform closed basis (thesis eq. 3.3), parameters taken modulo 1."""
    knots = periodic_knots(n_ctrl, degree, dtype=params.dtype)
    unwrapped = rows(knots, degree, params - jnp.floor(params), orders)
    return jax.vmap(fold_periodic, in_axes=(0, None))(unwrapped, n_ctrl)


def fold_periodic(unwrapped: Float[Array, "m n_plus_k"], n_ctrl: int) -> Float[Array, "m n_ctrl"]:
    """Add the last `k` columns (wrapped copies of the first `k` functions) onto the first `k`."""
    head, tail = unwrapped[:, :n_ctrl], unwrapped[:, n_ctrl:]
    return head.at[:, : tail.shape[1]].add(tail)


@compiled
def _blending_matrix(knots, degree: int, params, nu: int):
    knots = _checks.monotone(knots, "knots")
    n_ctrl = knots.shape[0] - degree - 1
    outside = (params < knots[degree]) | (params > knots[n_ctrl])
    params = _checks.check(
        params, outside, "params", "parameters in the knot domain", "a value outside (or NaN)"
    )
    return rows(knots, degree, params, (nu,))[0]


def blending_matrix(
    knots: ArrayLike, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix `A[a, i] = B^{(nu)}_{i,k}(u_a)` (thesis eq. 3.6) for a clamped knot vector.

    **Arguments:**
    - `knots`: `(n_ctrl + degree + 1,)` non-decreasing (any array-like).
    - `degree`: k ≥ 1.
    - `params`: `(m,)` parameters in the knot domain `[t_k, t_{n}]`.
    - `nu`: derivative order ≥ 0 (0 = the functions themselves).

    **Returns:** `(m, n_ctrl)`. Compiled once per (shapes, degree, nu).
    """
    check_order(nu)
    dtype = float_dtype(knots, params)
    knots, params = jnp.asarray(knots, dtype), jnp.asarray(params, dtype)
    _checks.check_ndim(knots, "knots", 1)
    _checks.check_degree(degree, "degree", knots.shape[0] - degree - 1, "the knot vector")
    _checks.check_ndim(params, "params", 1)
    return _blending_matrix(knots, degree, params, nu)


@compiled
def _periodic_blending_matrix(n_ctrl: int, degree: int, params, nu: int):
    params = _checks.finite(params, "params")
    return periodic_rows(n_ctrl, degree, params, (nu,))[0]


def periodic_blending_matrix(
    n_ctrl: int, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix of the uniform closed basis (thesis eq. 3.3) on [0, 1).

    `B_{i,k}(u) = B_{0,k}((n u − i) mod n)`: every row is a cyclic shift of one pattern, and at
    a knot the row of a cubic is `[1/6, 2/3, 1/6, 0, …]`. Parameters are taken modulo 1.

    **Returns:** `(len(params), n_ctrl)`.
    """
    _checks.check_count(n_ctrl, "n_ctrl", 2)
    _checks.check_degree(degree, "degree", n_ctrl, "the periodic direction")
    check_order(nu)
    params = jnp.asarray(params, float_dtype(params))
    _checks.check_ndim(params, "params", 1)
    return _periodic_blending_matrix(n_ctrl, degree, params, nu)


def check_order(nu, name: str = "nu") -> None:
    """A derivative order: an int ≥ 0."""
    if isinstance(nu, bool) or not isinstance(nu, (int, np.integer)) or nu < 0:
        _checks.fail(name, "a derivative order (int >= 0)", nu)
