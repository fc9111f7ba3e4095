"""`BSplineSurface`: a tensor-product B-spline (or NURBS) surface (thesis eq. 3.1)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, _tensor
from bsjax.basis import _check_nu, _float_dtype, direction_matrix


def _as_float(x, dtype=None):
    return None if x is None else jnp.asarray(x, dtype=dtype or _float_dtype(x))


class BSplineSurface(eqx.Module):
    """`S(u, v) = Σ_i Σ_j B_{i,k}(u) B_{j,l}(v) P_ij` on [0, 1]² (thesis eq. 3.1).

    **Fields:**
    - `ctrl`: control net `(r, s, 3)`.
    - `knots_u`, `knots_v`: clamped knot vectors `(r + k + 1,)`, `(s + l + 1,)`; `None` for a
      periodic direction, which uses the uniform closed basis (thesis eq. 3.3).
    - `degree_u`, `degree_v` (static): k, l ≥ 1.
    - `periodic_u`, `periodic_v` (static): closed directions.
    - `weights`: `(r, s)` positive NURBS weights, or `None` for a polynomial surface.
    """

    ctrl: Float[Array, "r s 3"]
    knots_u: Float[Array, " ku"] | None
    knots_v: Float[Array, " kv"] | None
    degree_u: int = eqx.field(static=True)
    degree_v: int = eqx.field(static=True)
    periodic_u: bool = eqx.field(static=True, default=False)
    periodic_v: bool = eqx.field(static=True, default=False)
    weights: Float[Array, "r s"] | None = None

    def __init__(
        self,
        ctrl: ArrayLike,
        knots_u: ArrayLike | None,
        knots_v: ArrayLike | None,
        degree_u: int,
        degree_v: int,
        periodic_u: bool = False,
        periodic_v: bool = False,
        weights: ArrayLike | None = None,
    ):
        _checks.check_ndim(ctrl, "ctrl", 3, last=3)
        r, s, _ = np.shape(ctrl)
        _checks.check_finite(ctrl, "ctrl")
        _check_direction("u", knots_u, degree_u, periodic_u, r)
        _check_direction("v", knots_v, degree_v, periodic_v, s)
        if weights is not None:
            if np.shape(weights) != (r, s):
                _checks.fail("weights", f"shape {(r, s)}", np.shape(weights))
            _checks.check_positive(weights, "weights")
        dtype = _float_dtype(ctrl)
        self.ctrl = jnp.asarray(ctrl, dtype=dtype)
        self.knots_u = None if periodic_u else _as_float(knots_u, dtype)
        self.knots_v = None if periodic_v else _as_float(knots_v, dtype)
        self.degree_u, self.degree_v = int(degree_u), int(degree_v)
        self.periodic_u, self.periodic_v = bool(periodic_u), bool(periodic_v)
        self.weights = _as_float(weights, dtype)

    @property
    def shape(self) -> tuple[int, int]:
        """Control-net size `(r, s)`."""
        return self.ctrl.shape[:2]

    def rows(self, direction: str, params, nu: int = 0):
        """Blending matrix of one direction (`"u"` or `"v"`) at `params`, derivative order `nu`."""
        if direction == "u":
            return direction_matrix(self.knots_u, self.degree_u, self.periodic_u, self.shape[0], params, nu)
        if direction == "v":
            return direction_matrix(self.knots_v, self.degree_v, self.periodic_v, self.shape[1], params, nu)
        _checks.fail("direction", "'u' or 'v'", repr(direction))

    def evaluate(self, u: ArrayLike, v: ArrayLike, nu: int = 0, nv: int = 0) -> Float[Array, "... 3"]:
        """Points (or the (nu, nv) partial derivative) at equal-shape parameter arrays `u`, `v`.

        Differentiable in the control net, the weights and in `u`, `v`.
        **Returns:** `u.shape + (3,)`.
        """
        _check_nu(nu, "nu")
        _check_nu(nv, "nv")
        u, v = jnp.asarray(u, self.ctrl.dtype), jnp.asarray(v, self.ctrl.dtype)
        if u.shape != v.shape:
            _checks.fail("v", f"the shape of u {u.shape}", v.shape)
        flat_u, flat_v = u.reshape(-1), v.reshape(-1)
        net = _tensor.homogeneous(self.ctrl, self.weights)
        if self.weights is None:
            out = _tensor.pointwise(self.rows("u", flat_u, nu), net, self.rows("v", flat_v, nv))
        else:
            h = {
                (k, l): _tensor.pointwise(self.rows("u", flat_u, k), net, self.rows("v", flat_v, l))
                for k in range(nu + 1)
                for l in range(nv + 1)
            }
            out = _tensor.rational_derivatives(h, nu, nv)[(nu, nv)]
        return out.reshape(u.shape + (3,))

    def normal(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... 3"]:
        """Unit normal `T_u × T_v / |T_u × T_v|` at `u`, `v` (limit normal at poles, never NaN)."""
        u, v = jnp.asarray(u, self.ctrl.dtype), jnp.asarray(v, self.ctrl.dtype)
        t_u, t_v, t_uv = (self.evaluate(u, v, a, b) for a, b in ((1, 0), (0, 1), (1, 1)))
        return _tensor.unit_normal(t_u, t_v, t_uv, u, v)

    def blending(self, m: int = 82, n: int = 82, params_u=None, params_v=None):
        """Pre-computed blending matrices for an `m × n` sample grid (default `linspace(0, 1, ·)`)."""
        from bsjax._blending import Blending

        return Blending.from_surface(self, m, n, params_u, params_v)

    def with_ctrl(self, ctrl: ArrayLike) -> "BSplineSurface":
        """The same basis with another control net (shape checked)."""
        if np.shape(ctrl) != self.ctrl.shape:
            _checks.fail("ctrl", f"shape {self.ctrl.shape}", np.shape(ctrl))
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


def _check_direction(name, knots, degree, periodic, n_ctrl):
    _checks.check_degree(degree, f"degree_{name}", n_ctrl, f"{name} ({n_ctrl})")
    if periodic:
        if knots is not None:
            _checks.fail(f"knots_{name}", "None for a periodic direction (uniform closed basis)", "an array")
        return
    if knots is None:
        _checks.fail(f"knots_{name}", "a knot vector for a non-periodic direction", None)
    _checks.check_knots(knots, degree, n_ctrl, f"knots_{name}")
