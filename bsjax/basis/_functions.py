"""Knot vectors, B-spline basis functions and blending matrices (thesis ch. 3, SPEC §2).

A blending matrix holds every basis function (or its derivative) of one direction at a list of
parameters: `A[a, i] = B_{i,k}(u_a)` (thesis eq. 3.6). A tensor-product surface sampled on a
grid is then two small matrix products, `M = A_u P A_v^T`, so evaluation, refitting, collision,
merging and physics never recompute basis functions at run time.

Conventions: parameters live on [0, 1]; clamped knot vectors have `degree + 1` equal knots at
each end; the periodic (closed) basis is the uniform one of thesis eq. 3.3, on [0, 1).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks

__all__ = [
    "basis_functions",
    "blending_matrix",
    "clamped_knots",
    "direction_matrix",
    "greville",
    "periodic_blending_matrix",
    "periodic_knots",
]


def _float_dtype(*xs):
    """The floating dtype to work in: that of the inputs, else JAX's default float."""
    dtype = jnp.result_type(*[x for x in xs if x is not None]) if xs else None
    if dtype is None or not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return dtype


def clamped_knots(n_ctrl: int, degree: int, dtype=None) -> Float[Array, " n_ctrl+degree+1"]:
    """Clamped (open) uniform knot vector on [0, 1].

    **Arguments:**
    - `n_ctrl`: number of control points, > `degree`.
    - `degree`: polynomial degree k ≥ 1.

    **Returns:** `[0]*(k+1) + uniform interior + [1]*(k+1)`, length `n_ctrl + degree + 1`.
    """
    _checks.check_degree(degree, "degree", n_ctrl, "this direction")
    interior = np.linspace(0.0, 1.0, n_ctrl - degree + 1)[1:-1]
    knots = np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])
    return jnp.asarray(knots, dtype=dtype or _float_dtype())


def periodic_knots(n_ctrl: int, degree: int, dtype=None) -> Float[Array, " n_ctrl+2*degree+1"]:
    """The unclamped uniform knot vector behind the periodic basis: `(j − k) / n`, j = 0…n+2k.

    Its `n_ctrl + degree` basis functions cover the domain `[t_k, t_{n+k}] = [0, 1]`; the last
    `degree` of them are the first `degree` again (wrapped), which is thesis eq. 3.3.
    """
    _checks.check_degree(degree, "degree", n_ctrl, "the periodic direction")
    j = np.arange(n_ctrl + 2 * degree + 1)
    return jnp.asarray((j - degree) / n_ctrl, dtype=dtype or _float_dtype())


def greville(knots: ArrayLike, degree: int) -> np.ndarray:
    """Greville abscissae `(t_{i+1} + … + t_{i+k}) / k` (NURBS Book eq. 9.8), one per control point."""
    t = np.asarray(knots, dtype=np.float64)
    n_ctrl = len(t) - degree - 1
    return np.array([t[i + 1 : i + degree + 1].mean() for i in range(n_ctrl)])


def _safe_ratio(num, den):
    """num / den, and 0 where den == 0 (repeated knots); gradients stay finite (double where)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), 0)


def _raise_degree(lower, knots, t, p):
    """Cox–de Boor step (thesis eq. 3.2): degree p−1 values → degree p values."""
    L = knots.shape[0]
    left = _safe_ratio(t - knots[: L - p - 1], knots[p : L - 1] - knots[: L - p - 1])
    right = _safe_ratio(knots[p + 1 :] - t, knots[p + 1 :] - knots[1 : L - p])
    return lower[:-1] * left + lower[1:] * right


def _differentiate(lower, knots, p):
    """Derivative step (NURBS Book eq. 2.9): `N'_{i,p} = p (N_{i,p−1}/Δ_i − N_{i+1,p−1}/Δ_{i+1})`."""
    L = knots.shape[0]
    left = _safe_ratio(jnp.ones_like(knots[: L - p - 1]), knots[p : L - 1] - knots[: L - p - 1])
    right = _safe_ratio(jnp.ones_like(knots[p + 1 :]), knots[p + 1 :] - knots[1 : L - p])
    return p * (lower[:-1] * left - lower[1:] * right)


def basis_functions(knots: Float[Array, " L"], degree: int, t: Float[Array, ""], nu: int = 0):
    """The nu-th derivative of all `L − degree − 1` basis functions at one parameter `t`.

    Parameters are clipped to the domain `[t_k, t_{n}]`; the right end belongs to the last
    non-empty span, so `t = 1` is included. Differentiable in `t` and in the knots.

    **Returns:** `(L − degree − 1,)`; at most `degree + 1` entries are non-zero.
    """
    _check_nu(nu)
    L = knots.shape[0]
    n_ctrl = L - degree - 1
    if nu > degree:
        return jnp.zeros((n_ctrl,), dtype=knots.dtype)
    t = jnp.clip(t, knots[degree], knots[n_ctrl])
    # Last non-empty span at or left of t; at the right end this is the last interval.
    domain = knots[degree : n_ctrl + 1]
    span = jnp.searchsorted(domain, t, side="right").astype(jnp.int32) - 1
    nonempty = jnp.where(jnp.diff(domain) > 0, jnp.arange(n_ctrl - degree, dtype=jnp.int32), 0)
    span = jnp.minimum(span, jnp.max(nonempty)) + degree
    values = (jnp.arange(L - 1, dtype=jnp.int32) == span).astype(knots.dtype)
    for p in range(1, degree - nu + 1):
        values = _raise_degree(values, knots, t, p)
    for p in range(degree - nu + 1, degree + 1):
        values = _differentiate(values, knots, p)
    return values


def blending_matrix(
    knots: ArrayLike, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix `A[a, i] = B^{(nu)}_{i,k}(u_a)` (thesis eq. 3.6) for a clamped knot vector.

    **Arguments:**
    - `knots`: `(n_ctrl + degree + 1,)` non-decreasing.
    - `degree`: k ≥ 1.
    - `params`: `(m,)` parameters in the knot domain.
    - `nu`: derivative order ≥ 0 (0 = the functions themselves).

    **Returns:** `(m, n_ctrl)`.
    """
    _check_clamped_args(knots, degree, params)
    _check_nu(nu)
    dtype = _float_dtype(knots, params)
    return _rows(jnp.asarray(knots, dtype=dtype), degree, jnp.asarray(params, dtype=dtype), (nu,))[0]


@functools.partial(jax.jit, static_argnums=(1, 3))
def _rows(knots, degree: int, params, orders: tuple[int, ...]):
    """`basis_functions` of each derivative order in `orders` at every parameter, stacked
    `(len(orders), m, n_ctrl)`; compiled once per shape (the blending-matrix kernel)."""
    return jnp.stack([jax.vmap(lambda t: basis_functions(knots, degree, t, nu))(params) for nu in orders])


def periodic_blending_matrix(
    n_ctrl: int, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix of the uniform closed basis (thesis eq. 3.3) on [0, 1).

    `B_{i,k}(u) = B_{0,k}((n u − i) mod n)`: every row is a cyclic shift of one pattern, and at
    a knot the row of a cubic is `[1/6, 2/3, 1/6, 0, …]`. Parameters are taken modulo 1.

    **Returns:** `(len(params), n_ctrl)`.
    """
    _checks.check_ndim(params, "params", 1)
    _check_nu(nu)
    return _periodic_rows(n_ctrl, degree, params, (nu,))[0]


def _periodic_rows(n_ctrl, degree, params, orders):
    dtype = _float_dtype(params)
    knots = periodic_knots(n_ctrl, degree, dtype=dtype)
    params = jnp.asarray(params, dtype=dtype)
    return jax.vmap(fold_periodic, in_axes=(0, None))(
        _rows(knots, degree, params - jnp.floor(params), orders), n_ctrl
    )


def fold_periodic(unwrapped: Float[Array, "m n_plus_k"], n_ctrl: int) -> Float[Array, "m n_ctrl"]:
    """Add the last `k` columns (wrapped copies of the first `k` functions) onto the first `k`."""
    head, tail = unwrapped[:, :n_ctrl], unwrapped[:, n_ctrl:]
    return head.at[:, : tail.shape[1]].add(tail)


def direction_matrix(knots, degree: int, periodic: bool, n_ctrl: int, params, nu: int = 0):
    """Blending matrix of one surface direction, clamped (`knots`) or periodic (`knots=None`)."""
    if periodic:
        return periodic_blending_matrix(n_ctrl, degree, params, nu)
    return blending_matrix(knots, degree, params, nu)


def direction_matrices(knots, degree: int, periodic: bool, n_ctrl: int, params, orders=(0, 1, 2)):
    """`direction_matrix` for several derivative orders in one compiled call, `(len(orders), m, n_ctrl)`."""
    for nu in orders:
        _check_nu(nu)
    if periodic:
        _checks.check_ndim(params, "params", 1)
        return _periodic_rows(n_ctrl, degree, params, tuple(orders))
    _check_clamped_args(knots, degree, params)
    dtype = _float_dtype(knots, params)
    return _rows(jnp.asarray(knots, dtype=dtype), degree, jnp.asarray(params, dtype=dtype), tuple(orders))


def _check_clamped_args(knots, degree, params) -> None:
    _checks.check_ndim(knots, "knots", 1)
    _checks.check_degree(degree, "degree", len(knots) - degree - 1, "the knot vector")
    _checks.check_monotone(knots, "knots")
    _checks.check_ndim(params, "params", 1)


def _check_nu(nu: int, name: str = "nu") -> None:
    if isinstance(nu, bool) or not isinstance(nu, (int, np.integer)) or nu < 0:
        _checks.fail(name, "a derivative order (int >= 0)", nu)


# The surface and blending objects live in their own files; re-exported here so that
# `bsjax.basis.BSplineSurface` is where a reader looks for it.
from bsjax._blending import Blending  # noqa: E402
from bsjax._refine import elevate_degree, insert_knots, reduce_degree  # noqa: E402
from bsjax._surface import BSplineSurface  # noqa: E402

__all__ += ["BSplineSurface", "Blending", "elevate_degree", "insert_knots", "reduce_degree"]
