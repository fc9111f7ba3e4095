"""`Blending`: pre-computed blending matrices of a sample grid and their least-squares inverses.

Built once per surface basis and sample grid (thesis §3.2); every later operation is a pair of
small matrix products: points `M = A_u P A_v^T` (eq. 3.6), tangents with `A'_u`, `A'_v`, and
the refit `P = A_u^+ M (A_v^+)^T` (eq. 3.7, `A^+ = (A^T A)^{-1} A^T`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks, _tensor
from bsjax.basis import direction_matrices

_ORDERS = 3  # basis, first and second derivative matrices are stored


class Blending(eqx.Module):
    """Blending matrices of an `m × n` sample grid of a surface basis.

    **Fields:**
    - `params_u (m,)`, `params_v (n,)`: the sample parameters.
    - `a_u (3, m, r)`, `a_v (3, n, s)`: basis, first- and second-derivative blending matrices.
    - `refit_u (r, m)`, `refit_v (s, n)`: the pseudo-inverses `A^+`, or `None` when the grid has
      fewer samples than control points in that direction (or for a window/LOD view).
    - `weights (r, s)` or `None`; `knots_u`, `knots_v` (clamped) or `None` (periodic).
    - `index_u (m,)`, `index_v (n,)`: rows of the full grid this view holds.
    - `degree_u`, `degree_v`, `periodic_u`, `periodic_v` (static).
    """

    params_u: Float[Array, " m"]
    params_v: Float[Array, " n"]
    a_u: Float[Array, "3 m r"]
    a_v: Float[Array, "3 n s"]
    refit_u: Float[Array, "r m"] | None
    refit_v: Float[Array, "s n"] | None
    weights: Float[Array, "r s"] | None
    knots_u: Float[Array, " ku"] | None
    knots_v: Float[Array, " kv"] | None
    index_u: Int[Array, " m"]
    index_v: Int[Array, " n"]
    degree_u: int = eqx.field(static=True)
    degree_v: int = eqx.field(static=True)
    periodic_u: bool = eqx.field(static=True, default=False)
    periodic_v: bool = eqx.field(static=True, default=False)

    @classmethod
    def from_surface(cls, surface, m: int = 82, n: int = 82, params_u=None, params_v=None) -> "Blending":
        """Build (once) the matrices of `surface`'s basis at an `m × n` grid.

        `params_u`/`params_v` default to `linspace(0, 1, m)`/`(…, n)`, so u = 1 is included.
        """
        dtype = surface.ctrl.dtype
        pu = _params(params_u, m, "params_u", "m", dtype)
        pv = _params(params_v, n, "params_v", "n", dtype)
        r, s = surface.shape
        a_u = _stack(surface.knots_u, surface.degree_u, surface.periodic_u, r, pu)
        a_v = _stack(surface.knots_v, surface.degree_v, surface.periodic_v, s, pv)
        return cls(
            params_u=pu,
            params_v=pv,
            a_u=a_u,
            a_v=a_v,
            refit_u=_pinv(a_u[0]),
            refit_v=_pinv(a_v[0]),
            weights=surface.weights,
            knots_u=surface.knots_u,
            knots_v=surface.knots_v,
            index_u=jnp.arange(len(pu)),
            index_v=jnp.arange(len(pv)),
            degree_u=surface.degree_u,
            degree_v=surface.degree_v,
            periodic_u=surface.periodic_u,
            periodic_v=surface.periodic_v,
        )

    # --- sizes -----------------------------------------------------------------------------
    @property
    def grid_shape(self) -> tuple[int, int]:
        """Sample grid `(m, n)`."""
        return self.a_u.shape[1], self.a_v.shape[1]

    @property
    def ctrl_shape(self) -> tuple[int, int]:
        """Control net `(r, s)`."""
        return self.a_u.shape[2], self.a_v.shape[2]

    # --- evaluation ------------------------------------------------------------------------
    def points(self, ctrl: Float[Array, "r s 3"]) -> Float[Array, "m n 3"]:
        """Sample grid `M = A_u P A_v^T` (thesis eq. 3.6)."""
        return self.derivative(ctrl, 0, 0)

    def derivative(self, ctrl: Float[Array, "r s 3"], nu: int, nv: int) -> Float[Array, "m n 3"]:
        """The (nu, nv) partial derivative on the grid, `A_u^{(nu)} P A_v^{(nv)T}`, nu, nv ≤ 2."""
        self._check_ctrl(ctrl)
        if not (0 <= nu < _ORDERS and 0 <= nv < _ORDERS):
            _checks.fail("nu, nv", f"derivative orders in 0..{_ORDERS - 1}", (nu, nv))
        if self.weights is None:
            return _tensor.grid(self.a_u[nu], ctrl, self.a_v[nv])
        net = _tensor.homogeneous(ctrl, self.weights)
        h = {
            (k, l): _tensor.grid(self.a_u[k], net, self.a_v[l]) for k in range(nu + 1) for l in range(nv + 1)
        }
        return _tensor.rational_derivatives(h, nu, nv)[(nu, nv)]

    def tangents(self, ctrl) -> tuple[Float[Array, "m n 3"], Float[Array, "m n 3"]]:
        """`(T_u, T_v) = (A'_u P A_v^T, A_u P A'_v^T)`."""
        return self.derivative(ctrl, 1, 0), self.derivative(ctrl, 0, 1)

    def normals(self, ctrl: Float[Array, "r s 3"]) -> Float[Array, "m n 3"]:
        """Unit normals `T_u × T_v / |·|` on the grid; the limit normal at poles; never NaN."""
        t_u, t_v = self.tangents(ctrl)
        t_uv = self.derivative(ctrl, 1, 1)
        return _tensor.unit_normal(t_u, t_v, t_uv, self.params_u[:, None], self.params_v[None, :])

    # --- refit -----------------------------------------------------------------------------
    def refit(self, points: Float[Array, "m n 3"]) -> Float[Array, "r s 3"]:
        """Least-squares control net of a point grid (thesis eq. 3.7) with the stored inverses.

        Exact round trip `refit(points(P)) == P` when m ≥ r and n ≥ s. For NURBS the fit is
        linear in homogeneous coordinates with the stored weights.
        """
        m, n = self.grid_shape
        _checks.check_ndim(points, "points", 3, last=3)
        if points.shape[:2] != (m, n):
            _checks.fail("points", f"shape {(m, n, 3)}", points.shape)
        if self.refit_u is None or self.refit_v is None:
            _checks.fail(
                "Blending.refit",
                "a full grid with m >= r and n >= s samples whose blending matrices have full "
                "column rank (a closed direction samples its seam twice)",
                f"grid {self.grid_shape} for control net {self.ctrl_shape}",
            )
        if self.weights is None:
            return _tensor.grid(self.refit_u, points, self.refit_v)
        denom = _tensor.grid(self.a_u[0], self.weights[..., None], self.a_v[0])
        return _tensor.grid(self.refit_u, points * denom, self.refit_v) / self.weights[..., None]

    # --- views -----------------------------------------------------------------------------
    def window(self, u_min: float, u_max: float, v_min: float, v_max: float) -> "Blending":
        """The rows and columns whose parameters lie in `[u_min, u_max] × [v_min, v_max]`."""
        pu, pv = np.asarray(self.params_u), np.asarray(self.params_v)
        rows = np.nonzero((pu >= u_min) & (pu <= u_max))[0]
        cols = np.nonzero((pv >= v_min) & (pv <= v_max))[0]
        if rows.size == 0 or cols.size == 0:
            _checks.fail(
                "window",
                "a window containing at least one sample row and column",
                (u_min, u_max, v_min, v_max),
            )
        return self._take(rows, cols)

    def lod(self, q_u: int, q_v: int | None = None) -> "Blending":
        """Every `q`-th row/column (intermittent rows, a coarse level of detail); the last is kept."""
        q_v = q_u if q_v is None else q_v
        for name, q in (("q_u", q_u), ("q_v", q_v)):
            if not isinstance(q, (int, np.integer)) or q < 1:
                _checks.fail(name, "an int >= 1", q)
        m, n = self.grid_shape
        return self._take(_every(m, q_u), _every(n, q_v))

    def _take(self, rows, cols) -> "Blending":
        return Blending(
            params_u=self.params_u[rows],
            params_v=self.params_v[cols],
            a_u=self.a_u[:, rows],
            a_v=self.a_v[:, cols],
            refit_u=None,
            refit_v=None,
            weights=self.weights,
            knots_u=self.knots_u,
            knots_v=self.knots_v,
            index_u=self.index_u[rows],
            index_v=self.index_v[cols],
            degree_u=self.degree_u,
            degree_v=self.degree_v,
            periodic_u=self.periodic_u,
            periodic_v=self.periodic_v,
        )

    def surface(self, ctrl: Float[Array, "r s 3"]):
        """The `BSplineSurface` of this basis with control net `ctrl`."""
        from bsjax._surface import BSplineSurface

        return BSplineSurface(
            ctrl,
            self.knots_u,
            self.knots_v,
            self.degree_u,
            self.degree_v,
            self.periodic_u,
            self.periodic_v,
            self.weights,
        )

    def _check_ctrl(self, ctrl) -> None:
        if np.shape(ctrl) != self.ctrl_shape + (3,):
            _checks.fail("ctrl", f"shape {self.ctrl_shape + (3,)}", np.shape(ctrl))


def _params(params, count, name, count_name, dtype):
    if params is None:
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 2:
            _checks.fail(count_name, "an int >= 2", count)
        return jnp.linspace(0.0, 1.0, count, dtype=dtype)
    _checks.check_ndim(params, name, 1)
    _checks.check_finite(params, name)
    _checks.check_range(params, name, 0.0, 1.0)
    return jnp.asarray(params, dtype=dtype)


def _stack(knots, degree, periodic, n_ctrl, params):
    return direction_matrices(knots, degree, periodic, n_ctrl, params, tuple(range(_ORDERS)))


def _pinv(a):
    """`(A^T A)^{-1} A^T` via SVD, computed once; `None` when `A` lacks full column rank (fewer
    distinct samples than control points — a closed direction samples its seam twice)."""
    if a.shape[0] < a.shape[1]:
        return None
    if _checks.is_concrete(a) and np.linalg.matrix_rank(np.asarray(a)) < a.shape[1]:
        return None
    return _jit_pinv(a)


_jit_pinv = jax.jit(jnp.linalg.pinv)


def _every(count: int, q: int) -> np.ndarray:
    idx = np.arange(0, count, q)
    return idx if idx[-1] == count - 1 else np.append(idx, count - 1)
