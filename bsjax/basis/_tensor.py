"""Tensor-product contraction, rational (NURBS) derivatives and the surface unit normal.

Shared by `BSplineSurface` (arbitrary (u, v)) and `Blending` (grids), so the two agree exactly.
"""

from __future__ import annotations

from math import comb

import jax.numpy as jnp

from bsjax import _checks
from bsjax._safe import norm, unit


def homogeneous(ctrl, weights):
    """`(..., d)` control net → `(..., d + 1)` homogeneous net `[w P, w]` (or `ctrl` if no weights)."""
    if weights is None:
        return ctrl
    return jnp.concatenate([ctrl * weights[..., None], weights[..., None]], axis=-1)


def grid(a_u, ctrl, a_v):
    """`M = A_u P A_v^T` per coordinate (thesis eq. 3.6): `(m, r) (r, s, d) (n, s) → (m, n, d)`."""
    return jnp.einsum("ai,ijc,bj->abc", a_u, ctrl, a_v)


def banded_grid(support_u, band_u, ctrl, a_v):
    """`M = A_u P A_v^T` with `A_u` given by its band: `(m, k+1) (m, k+1) (r, s, d) (n, s) → (m, n, d)`.

    Row `a` of `A_u` has its only non-zeros `band_u[a, c]` in the columns `support_u[a, c]`, so
    `M[a] = Σ_c band_u[a, c] Q[support_u[a, c]]` with `Q = P A_v^T` `(r, n, d)` (thesis eq. 3.6
    evaluated span by span, as The NURBS Book A3.5 does for one point): the `u` stage costs
    `m (k+1) n d` multiply-adds instead of `m r n d`, and each gathered row of `Q` is a contiguous
    `(n, d)` slab, which XLA on the CPU fuses into one loop (a gather on the `v` axis, whose slabs
    are `d` numbers long, measured slower than the dense product there, so that stage stays dense).
    The indices are in range by construction (`SplineDirection.support`).
    """
    q = jnp.einsum("bj,ijc->ibc", a_v, ctrl)
    out = None
    for c in range(support_u.shape[1]):
        term = band_u[:, c, None, None] * q.at[support_u[:, c]].get(mode="promise_in_bounds")
        out = term if out is None else out + term
    return out


def prefer_banded(m: int, n: int, r: int, s: int, k: int) -> bool:
    """Whether `banded_grid` does no more multiply-adds than the best order of the dense product
    `grid` for an `(m, r) (r, s) (n, s)` shape with degree `k` along `u` (a static choice made when
    the blending matrices are built). Dense wins only when `m` is much smaller than `n` (then
    `A_u P` first is cheap); at equal counts the banded form is chosen, since it measured faster
    (the dense `einsum` pays for its layout changes)."""
    banded = n * s * r + m * (k + 1) * n
    dense = min(m * r * s + m * s * n, r * s * n + m * r * n)
    return banded <= dense


def pointwise(rows_u, ctrl, rows_v):
    """Row-wise contraction for scattered parameters: `(k, r) (r, s, d) (k, s) → (k, d)`."""
    return jnp.einsum("ki,ijc,kj->kc", rows_u, ctrl, rows_v)


def rational_derivatives(h, nu: int, nv: int):
    """Derivatives of `S = H / w` from those of the homogeneous map (NURBS Book A4.4).

    **Arguments:** `h[(k, l)]` the (k, l)-th partial derivative of `[w S, w]`, `(..., 4)`, for
    all `k ≤ nu`, `l ≤ nv`.
    **Returns:** `s[(k, l)]`, `(..., d)`, the partial derivatives of the rational map (a surface,
    or a curve with `nv = 0`; points of any dimension `d`, the weight last).
    """
    w = {kl: v[..., -1:] for kl, v in h.items()}
    s = {}
    for k in range(nu + 1):
        for l in range(nv + 1):
            value = h[(k, l)][..., :-1]
            for i in range(k + 1):
                for j in range(l + 1):
                    if i or j:
                        value = value - comb(k, i) * comb(l, j) * w[(i, j)] * s[(k - i, l - j)]
            s[(k, l)] = value / w[(0, 0)]
    return s


def unit_normal(t_u, t_v, t_uv, u, v):
    """Unit normal `T_u × T_v / |T_u × T_v|`, with the limit normal at degenerate points.

    Where a row collapses to a pole (`T_v = 0`, e.g. the tip of the teardrop) the normal is the
    limit `±T_u × T_uv` (first-order expansion `T_v ≈ (u − u₀) T_uv`), its sign set by which end
    of the domain the pole is at; likewise `±T_uv × T_v` where `T_u = 0`. Never NaN.

    **Arguments:** `(..., 3)` derivatives; `u`, `v` broadcastable parameters in [0, 1].
    """
    n = jnp.cross(t_u, t_v)
    scale = jnp.sum(t_u * t_u, -1) + jnp.sum(t_v * t_v, -1)
    tol = jnp.sqrt(jnp.finfo(n.dtype).eps) * scale
    degenerate = norm(n) <= tol
    pole_in_v = jnp.sum(t_v * t_v, -1) <= jnp.sum(t_u * t_u, -1)
    sign_u = jnp.where(u < 0.5, 1.0, -1.0)[..., None]
    sign_v = jnp.where(v < 0.5, 1.0, -1.0)[..., None]
    limit = jnp.where(pole_in_v[..., None], sign_u * jnp.cross(t_u, t_uv), sign_v * jnp.cross(t_uv, t_v))
    return unit(jnp.where(degenerate[..., None], limit, n))


def pseudo_inverse(a):
    """`(A^+, full column rank)` of a blending matrix `A (m, n)` via SVD, computed once (the stored
    least-squares refit of thesis eq. 3.7); `(None, True)` when `A` has fewer rows than columns
    (structural: then no refit). In numpy for a concrete `A` (`bsjax._checks.xp`); singular
    values below `10 max(m, n) ε σ_max` are dropped (JAX's `pinv` default, asked of both)."""
    xp = _checks.xp(a)
    if a.shape[0] < a.shape[1]:
        return None, xp.ones((), bool)
    s = xp.linalg.svd(a, compute_uv=False)
    eps = max(a.shape) * xp.finfo(a.dtype).eps
    return xp.linalg.pinv(a, rtol=10 * eps), s[-1] > s[0] * eps
