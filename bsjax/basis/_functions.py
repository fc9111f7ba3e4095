"""B-spline basis functions and blending matrices (thesis ch. 3).

A blending matrix holds every basis function (or its derivative) of one direction at a list of
parameters: `A[a, i] = B_{i,k}(u_a)` (thesis eq. 3.6). A tensor-product surface sampled on a
grid is then two small matrix products, `M = A_u P A_v^T`, so evaluation, refitting, collision,
merging and physics never recompute basis functions at run time.

Conventions: parameters live on [0, 1]; clamped knot vectors have `degree + 1` equal knots at
each end; the periodic (closed) basis is the uniform one of thesis eq. 3.3, on [0, 1).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks, _safe
from bsjax._declared import declared
from bsjax._typing import ArrayLike, HostArray
from bsjax.basis._knots import periodic_knots


def _raise_degree(lower, knots, t, p, xp):
    """Cox–de Boor step (thesis eq. 3.2): degree p−1 values `(..., L − p)` at `t (..., 1)` →
    degree p values `(..., L − p − 1)`; `knots (..., L)` broadcast to the rank of `t`."""
    L = knots.shape[-1]
    k = lambda a, b: knots[..., a:b]
    left = _safe.ratio(t - k(0, L - p - 1), k(p, L - 1) - k(0, L - p - 1), xp)
    right = _safe.ratio(k(p + 1, L) - t, k(p + 1, L) - k(1, L - p), xp)
    return lower[..., :-1] * left + lower[..., 1:] * right


def _differentiate(lower, knots, p, xp):
    """Derivative step (The NURBS Book eq. 2.9): `N'_{i,p} = p (N_{i,p−1}/Δ_i − N_{i+1,p−1}/Δ_{i+1})`."""
    L = knots.shape[-1]
    k = lambda a, b: knots[..., a:b]
    left = _safe.ratio(xp.ones_like(k(0, L - p - 1)), k(p, L - 1) - k(0, L - p - 1), xp)
    right = _safe.ratio(xp.ones_like(k(p + 1, L)), k(p + 1, L) - k(1, L - p), xp)
    return p * (lower[..., :-1] * left - lower[..., 1:] * right)


def _along(v, t):
    """A vector `v (L,)` as `(1, …, 1, L)`, to meet values of shape `t.shape + (1,)`."""
    return v.reshape((1,) * t.ndim + v.shape)


def _host_or_traced(*arrays):
    """`(xp, arrays)`: the array module that computes the basis (`bsjax._checks.xp`: numpy when
    every input is concrete, so a blending matrix is built on the host without compiling a
    program; `jax.numpy` when any is traced) and the inputs as its arrays."""
    xp = _checks.xp(*arrays)
    return xp, tuple(xp.asarray(a) for a in arrays)


@declared
def basis_functions(knots: Float[HostArray, " L"], degree: int, t: Float[HostArray, "..."], nu: int = 0):
    """The nu-th derivative of all `L − degree − 1` basis functions at parameters `t`: `knots`
    a finite 1-D array of at least `degree + 2` values, `t` finite (checked; the knots' order is
    the caller's — `blending_matrix` checks it too).

    Parameters are clipped to the domain `[t_k, t_{n}]` (by `where`, so the derivative in `t` at
    the domain ends is the one-sided derivative, not halved as `clip`'s would be); the right end
    belongs to the last non-empty span, so `t = 1` is included. Differentiable in `t` and in the
    knots; computed in numpy when every input is concrete (`_host_or_traced`).

    **Returns:** `(..., L − degree − 1)` (one row per parameter); at most `degree + 1` entries of
    a row are non-zero.
    """
    check_order(nu)
    _checks.check_real(knots, "knots")
    _checks.check_real(t, "t")
    _checks.check_ndim(knots, "knots", 1)
    _checks.check_degree(degree, "degree", np.shape(knots)[0] - degree - 1, "the knot vector")
    xp = _checks.xp(knots, t)
    knots, t = _checks.finite(xp.asarray(knots), "knots"), _checks.finite(xp.asarray(t), "t")
    return _checks.on_device(basis_derivatives(knots, degree, t, (nu,))[0])


def basis_derivatives(
    knots: Float[HostArray, " L"], degree: int, t: Float[HostArray, "..."], orders: tuple[int, ...]
):
    """`basis_functions` of each derivative order in `orders`, `(len(orders), ..., L − degree − 1)`:
    one Cox–de Boor triangle (thesis eq. 3.2) shared by all orders, order nu branching off at
    degree `degree − nu` into nu derivative steps (The NURBS Book eq. 2.9)."""
    for nu in orders:
        check_order(nu)
    xp, (knots, t) = _host_or_traced(knots, t)
    L = knots.shape[0]
    n_ctrl = L - degree - 1
    t, span = _clip_and_span(knots, degree, t, xp)
    at, wide = t[..., None], _along(knots, t)  # explicit ranks (no rank promotion)
    triangle = [(_along(xp.arange(L - 1, dtype=np.int32), t) == span[..., None]).astype(knots.dtype)]
    for p in range(1, degree - min(orders, default=0) + 1):
        triangle.append(_raise_degree(triangle[-1], wide, at, p, xp))
    out = []
    for nu in orders:
        if nu > degree:
            out.append(xp.zeros((*t.shape, n_ctrl), dtype=knots.dtype))
            continue
        values = triangle[degree - nu]
        for p in range(degree - nu + 1, degree + 1):
            values = _differentiate(values, wide, p, xp)
        out.append(values)
    return xp.stack(out)


def _clip_and_span(knots, degree: int, t, xp):
    """`(t clipped to the domain, span)` of parameters `t (...)`: the knot span
    `t_span ≤ t < t_{span+1}` whose `degree + 1` basis functions `span − degree … span` are the
    only ones non-zero at `t` (The NURBS Book A2.1, with the last non-empty span at or left of
    `t`, so the right end `t = 1` is included)."""
    n_ctrl = knots.shape[0] - degree - 1
    lo, hi = knots[degree], knots[n_ctrl]
    t = xp.where(t < lo, lo, xp.where(t > hi, hi, t))
    domain = knots[degree : n_ctrl + 1]
    # a count, not searchsorted's binary search: its while loop costs ~3× the compile of the
    # whole basis triangle, and the knot vectors are short
    span = xp.sum(_along(domain, t) <= t[..., None], axis=-1, dtype=np.int32) - 1
    nonempty = xp.where(xp.diff(domain) > 0, xp.arange(n_ctrl - degree, dtype=np.int32), 0)
    return t, xp.minimum(span, xp.max(nonempty)) + degree


def support(knots, degree: int, params) -> Int[HostArray, "m k1"]:
    """Indices `span − degree … span` of the `degree + 1` basis functions that can be non-zero
    (with all their derivatives) at each parameter, `(m, degree + 1)` int32 (a kernel; no checks).
    Every other entry of the row `basis_functions(knots, degree, t, nu)` is exactly zero."""
    xp, (knots, params) = _host_or_traced(knots, params)
    first = _clip_and_span(knots, degree, params, xp)[1] - degree
    return first[..., None] + _along(xp.arange(degree + 1, dtype=np.int32), first)


def _periodic(n_ctrl: int, degree: int, params):
    """`(xp, knots, params modulo 1)` of the uniform closed basis (thesis eq. 3.3)."""
    xp, (params,) = _host_or_traced(params)
    knots = xp.asarray(periodic_knots(n_ctrl, degree, dtype=params.dtype))
    return xp, knots, params - xp.floor(params)


def periodic_support(n_ctrl: int, degree: int, params) -> Int[HostArray, "m k1"]:
    """`support` of the uniform closed basis (thesis eq. 3.3): the unwrapped indices taken modulo
    `n_ctrl` (distinct, since `degree < n_ctrl`)."""
    _, knots, params = _periodic(n_ctrl, degree, params)
    return support(knots, degree, params) % n_ctrl


def rows(knots, degree: int, params, orders: tuple[int, ...]):
    """`basis_functions` of each derivative order in `orders` at every parameter, stacked
    `(len(orders), m, n_ctrl)` (the blending-matrix kernel; no checks)."""
    return basis_derivatives(knots, degree, params, orders)


def periodic_rows(n_ctrl: int, degree: int, params, orders: tuple[int, ...]):
    """`rows` of the uniform closed basis (thesis eq. 3.3), parameters taken modulo 1."""
    _, knots, params = _periodic(n_ctrl, degree, params)
    return _fold(rows(knots, degree, params, orders), n_ctrl)


def fold_periodic(unwrapped: Float[HostArray, "... n_plus_k"], n_ctrl: int) -> Float[Array, "... n_ctrl"]:
    """Add the last `k` columns (wrapped copies of the first `k` functions) onto the first `k`."""
    return _checks.on_device(_fold(unwrapped, n_ctrl))


def _fold(unwrapped, n_ctrl: int):
    """`fold_periodic` in the array module of its input (a host-side basis stays on the host)."""
    xp, (unwrapped,) = _host_or_traced(unwrapped)
    head, tail = unwrapped[..., :n_ctrl], unwrapped[..., n_ctrl:]
    k = tail.shape[-1]
    return xp.concatenate([head[..., :k] + tail, head[..., k:]], axis=-1)


def _blending_matrix(knots, degree: int, params, nu: int):
    knots = _checks.monotone(knots, "knots")
    n_ctrl = knots.shape[0] - degree - 1
    outside = ~((params >= knots[degree]) & (params <= knots[n_ctrl]))  # NaN is outside
    params = _checks.check(
        params, outside, "params", "parameters in the knot domain", "a value outside (or NaN)"
    )
    return _checks.on_device(rows(knots, degree, params, (nu,))[0])


@declared
def blending_matrix(
    knots: ArrayLike, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix `A[a, i] = B^{(nu)}_{i,k}(u_a)` (thesis eq. 3.6) for a clamped knot vector.

    **Arguments:**
    - `knots`: `(n_ctrl + degree + 1,)` non-decreasing (any array-like).
    - `degree`: k ≥ 1.
    - `params`: `(m,)` parameters in the knot domain `[t_k, t_{n}]`.
    - `nu`: derivative order ≥ 0 (0 = the functions themselves).

    **Returns:** `(m, n_ctrl)`. Concrete inputs are checked and the matrix computed on the host
    (numpy, no program compiled); traced ones inside the caller's program.
    """
    check_order(nu)
    _checks.check_real(knots, "knots")
    _checks.check_real(params, "params")
    dtype = _checks.float_dtype(knots, params)
    knots, params = jnp.asarray(knots, dtype), jnp.asarray(params, dtype)
    _checks.check_ndim(knots, "knots", 1)
    _checks.check_degree(degree, "degree", knots.shape[0] - degree - 1, "the knot vector")
    _checks.check_ndim(params, "params", 1)
    return _blending_matrix(knots, degree, params, nu)


def _periodic_blending_matrix(n_ctrl: int, degree: int, params, nu: int):
    params = _checks.finite(params, "params")
    return _checks.on_device(periodic_rows(n_ctrl, degree, params, (nu,))[0])


@declared
def periodic_blending_matrix(
    n_ctrl: int, degree: int, params: ArrayLike, nu: int = 0
) -> Float[Array, "m n_ctrl"]:
    """Blending matrix of the uniform closed basis (thesis eq. 3.3) on [0, 1).

    `B_{i,k}(u) = B_{0,k}((n u − i) mod n)`: every row is a cyclic shift of one pattern, and at
    a knot the row of a cubic is `[1/6, 2/3, 1/6, 0, …]`. Parameters are taken modulo 1.

    **Returns:** `(len(params), n_ctrl)` (on the host for concrete `params`, as `blending_matrix`).
    """
    _checks.check_count(n_ctrl, "n_ctrl", 2)
    _checks.check_degree(degree, "degree", n_ctrl, "the periodic direction")
    check_order(nu)
    _checks.check_real(params, "params")
    params = jnp.asarray(params, _checks.float_dtype(params))
    _checks.check_ndim(params, "params", 1)
    return _periodic_blending_matrix(n_ctrl, degree, params, nu)


def check_order(nu, name: str = "nu") -> None:
    """A derivative order: an int ≥ 0."""
    if isinstance(nu, bool) or not isinstance(nu, (int, np.integer)) or nu < 0:
        _checks.fail(name, "a derivative order (int >= 0)", nu)
