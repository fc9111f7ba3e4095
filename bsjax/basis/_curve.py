"""`BSplineCurve` (The NURBS Book eqs. 3.1 and 4.1) and `CurveBlending`, its pre-computed sampled form.

A curve is a control polygon `(n, d)` (d = 2 or 3), one `SplineDirection` and optional NURBS
weights: `C(t) = Σ_i B_{i,k}(t) w_i P_i / Σ_i B_{i,k}(t) w_i`. It is the one-direction case of
`BSplineSurface` and shares its basis code (`SplineDirection`, the blending matrices, the
homogeneous form and the rational quotient rule), so an iso-line of a surface is a curve exactly.
`CurveBlending` holds the blending matrices of `m` samples and the least-squares inverse, as
`Blending` does for surfaces (thesis §3.2, eqs. 3.6–3.7 with one direction).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax._typing import ArrayLike, HostArray
from bsjax.basis import _tensor
from bsjax.basis._direction import SplineDirection

_ORDERS = 3  # points, first and second derivatives


class BSplineCurve(eqx.Module):
    """`C(t) = Σ_i B_{i,k}(t) w_i P_i / Σ_i B_{i,k}(t) w_i` on [0, 1] (The NURBS Book eq. 4.1;
    without weights the polynomial B-spline of eq. 3.1; thesis eq. 3.1 in one direction).

    **Arguments:**
    - `ctrl`: control points `(n, d)`, d = 2 (planar) or 3, finite.
    - `knots`: clamped non-decreasing knot vector `(n + degree + 1,)` on [0, 1]; `None` when
      `periodic` (the uniform closed basis of thesis eq. 3.3).
    - `degree`: k ≥ 1, smaller than n.
    - `periodic`: a closed curve on [0, 1) (parameters taken modulo 1).
    - `weights`: `(n,)` positive NURBS weights, or `None` (an exact circle needs them).

    **Fields:** `ctrl`, `direction` (`SplineDirection`), `weights`; `knots`, `degree`,
    `periodic`, `n_ctrl` and `dim` read them. `BSplineCurve.from_direction(ctrl, direction,
    weights)` builds one from a direction.
    """

    ctrl: Float[Array, "n d"]
    direction: SplineDirection
    weights: Float[Array, " n"] | None

    def __init__(
        self,
        ctrl: ArrayLike,
        knots: ArrayLike | None,
        degree: int,
        periodic: bool = False,
        weights: ArrayLike | None = None,
    ):
        dtype = _checks.float_dtype(ctrl, names=("ctrl",))
        ctrl = jnp.asarray(ctrl, dtype=dtype)
        _checks.check_ndim(ctrl, "ctrl", 2)
        if ctrl.shape[1] not in (2, 3):
            _checks.fail(
                "ctrl", "control points of dimension d = 2 or 3, shape (n, d)", f"shape {ctrl.shape}"
            )
        n = ctrl.shape[0]
        self.ctrl = _checks.finite(ctrl, "ctrl")
        self.direction = SplineDirection(knots, degree, n_ctrl=n, periodic=periodic, dtype=dtype)
        self.weights = None if weights is None else _weights(weights, ctrl)

    @classmethod
    def from_direction(cls, ctrl: ArrayLike, direction: SplineDirection, weights=None) -> BSplineCurve:
        """A curve from its control points and a `SplineDirection` (checked like `__init__`)."""
        if not isinstance(direction, SplineDirection):
            _checks.fail("direction", "a SplineDirection", type(direction).__name__)
        return cls(ctrl, direction.knots, direction.degree, direction.periodic, weights)

    @property
    def knots(self) -> Float[Array, " L"] | None:
        """The clamped knot vector, `None` when periodic."""
        return self.direction.knots

    @property
    def degree(self) -> int:
        """The polynomial degree k."""
        return self.direction.degree

    @property
    def periodic(self) -> bool:
        """Whether the curve is closed (uniform periodic basis)."""
        return self.direction.periodic

    @property
    def n_ctrl(self) -> int:
        """Number of control points n."""
        return self.direction.n_ctrl

    @property
    def dim(self) -> int:
        """Dimension d of the space (2 or 3)."""
        return self.ctrl.shape[1]

    def with_ctrl(self, ctrl: ArrayLike) -> BSplineCurve:
        """The same basis (and weights) with other control points: an `eqx.tree_at` replacement
        of `ctrl` (shape checked, values checked finite), so the knots are carried over as they
        are — concrete or traced inside the caller's `jit` — and not checked again."""
        _checks.check_real(ctrl, "ctrl")
        if np.shape(ctrl) != self.ctrl.shape:
            _checks.fail("ctrl", f"shape {self.ctrl.shape}", np.shape(ctrl))
        ctrl = _checks.finite(_checks.array(ctrl, "ctrl", self.ctrl.dtype), "ctrl")
        return eqx.tree_at(lambda curve: curve.ctrl, self, ctrl)

    # --- evaluation --------------------------------------------------------------------------
    @compiled
    def evaluate(self, t: ArrayLike, nu: int = 0) -> Float[Array, "... d"]:
        """Points (nu = 0) or the nu-th derivative `C^{(nu)}(t)` (nu = 1, 2) at parameters `t`.

        Rational curves differentiate `C = H / w` by the quotient rule on the homogeneous map
        `H(t) = Σ B_i(t) [w_i P_i, w_i]` (The NURBS Book eq. 4.8, algorithm A4.2).
        Differentiable in `ctrl`, `weights` and `t`.

        **Arguments:** `t` any shape, in [0, 1] (periodic: any finite value, taken modulo 1);
        `nu` in 0..2.
        **Returns:** `t.shape + (d,)`.
        """
        _check_nu(nu)
        t = self._params(t, "t")
        return _derivatives(self, t.reshape(-1), (nu,))[0].reshape(t.shape + (self.dim,))

    @compiled
    def curvature(self, t: ArrayLike) -> Float[Array, "..."]:
        """Curvature at `t`: signed for planar curves, unsigned in space.

        d = 2: `κ = (x' y'' − y' x'') / |C'|³`, positive where the curve turns left
        (counter-clockwise) along the direction of travel; d = 3: `κ = |C' × C''| / |C'|³`
        (do Carmo, *Differential Geometry of Curves and Surfaces*, §1-5).
        0 where the speed `|C'|` vanishes. **Returns:** `t.shape`.
        """
        t = self._params(t, "t")
        d1, d2 = _derivatives(self, t.reshape(-1), (1, 2))
        return _curvature(d1, d2).reshape(t.shape)

    def blending(self, m: int = 82, params: ArrayLike | None = None) -> CurveBlending:
        """Pre-computed blending matrices at `m` samples (default `linspace(0, 1, m)`) or at the
        given `params (m,)`, and their least-squares inverse (thesis eqs. 3.6–3.7).

        One compiled program per (control count, degree, sample count) — `sampled`, shared with
        every surface direction of the same basis and sample count: a rebuild is one XLA call.
        """
        if params is None:
            _checks.check_count(m, "m", 2)
            params = jnp.linspace(0.0, 1.0, m, dtype=self.ctrl.dtype)
        else:
            params = self._params(params, "params")
            _checks.check_ndim(params, "params", 1)
        return _blending(self.direction, params, self.weights)

    def _params(self, x, name):
        _checks.check_real(x, name)  # complex and booleans refused (tracers too: their dtype)
        return self.direction.check_params(jnp.asarray(x).astype(self.ctrl.dtype), name)


def _check_nu(nu) -> None:
    if isinstance(nu, bool) or not isinstance(nu, (int, np.integer)) or not 0 <= nu < _ORDERS:
        _checks.fail("nu", f"a derivative order in 0..{_ORDERS - 1}", nu)


def _weights(weights, ctrl):
    weights = jnp.asarray(weights, dtype=_checks.float_dtype(weights, ctrl, names=("weights", "ctrl")))
    if weights.shape != ctrl.shape[:1]:
        _checks.fail("weights", f"shape {ctrl.shape[:1]}", weights.shape)
    return _checks.positive(weights, "weights")


def _derivatives(curve: BSplineCurve, t, orders: tuple[int, ...]) -> list:
    """The derivatives `C^{(k)}` for k in `orders` at flat parameters `t (m,)`, each `(m, d)`
    (a rational curve needs every lower order too, for the quotient rule)."""
    if curve.weights is None:
        return [a @ curve.ctrl for a in curve.direction.matrices(t, orders)]
    top = max(orders)
    a = curve.direction.matrices(t, tuple(range(top + 1)))
    every = _contract(a, curve.ctrl, curve.weights, top)
    return [every[k] for k in orders]


def _contract(a, ctrl, weights, nu: int) -> list:
    """`[A^{(k)} P]_{k ≤ nu}` — through the homogeneous form and the quotient rule when rational."""
    if weights is None:
        return [a[k] @ ctrl for k in range(nu + 1)]
    net = _tensor.homogeneous(ctrl, weights)
    h = {(k, 0): a[k] @ net for k in range(nu + 1)}
    s = _tensor.rational_derivatives(h, nu, 0)
    return [s[(k, 0)] for k in range(nu + 1)]


def _curvature(d1, d2):
    speed = _safe.norm(d1)
    if d1.shape[-1] == 2:
        turn = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    else:
        turn = _safe.norm(jnp.cross(d1, d2))
    return _safe.ratio(turn, speed**3)


class CurveBlending(eqx.Module):
    """Blending matrices of `m` samples of a curve basis (thesis §3.2 with one direction).

    **Fields:**
    - `params (m,)`: the sample parameters.
    - `a (3, m, n)`: basis, first- and second-derivative blending matrices (eq. 3.6).
    - `refit_matrix (n, m)`: the pseudo-inverse `A^+ = (A^T A)^{-1} A^T` (eq. 3.7), or `None`
      when there are fewer samples than control points; `full_rank ()`: whether `A` has full
      column rank (else `refit` raises).
    - `weights (n,)` or `None`; `direction`: the `SplineDirection`.
    """

    params: Float[Array, " m"]
    a: Float[Array, "3 m n"]
    refit_matrix: Float[Array, "n m"] | None
    full_rank: Array
    weights: Float[Array, " n"] | None
    direction: SplineDirection

    @property
    def n_samples(self) -> int:
        """Number of samples m."""
        return self.a.shape[1]

    @property
    def n_ctrl(self) -> int:
        """Number of control points n."""
        return self.a.shape[2]

    @compiled
    def points(self, ctrl: Float[Array, "n d"]) -> Float[Array, "m d"]:
        """The samples `A P` (thesis eq. 3.6; rational: `A (w P) / A w`)."""
        return _contract(self.a, self._checked_ctrl(ctrl, "ctrl"), self.weights, 0)[0]

    @compiled
    def derivative(self, ctrl: Float[Array, "n d"], nu: int) -> Float[Array, "m d"]:
        """The nu-th derivative (nu in 0..2) at the samples, `A^{(nu)} P` (quotient rule when rational)."""
        _check_nu(nu)
        ctrl = self._checked_ctrl(ctrl, "ctrl")
        return _contract(self.a, ctrl, self.weights, nu)[nu]

    @compiled
    def refit(self, points: Float[Array, "m d"]) -> Float[Array, "n d"]:
        """Least-squares control points of `m` samples, `P = A^+ M` (thesis eq. 3.7), with the
        stored inverse. Exact round trip `refit(points(P)) == P` when `A` has full column rank.
        For NURBS the fit is linear in homogeneous coordinates with the stored weights."""
        m = self.n_samples
        _checks.check_ndim(points, "points", 2)
        if points.shape[0] != m or points.shape[1] not in (2, 3):
            _checks.fail("points", f"shape ({m}, d) with d = 2 or 3", points.shape)
        inverse = self.refit_matrix
        if inverse is None:
            _checks.fail("CurveBlending.refit", _REFIT_NEEDS, f"{m} samples for {self.n_ctrl} control points")
            raise AssertionError  # (fail raises)
        points = _checks.finite(points, "points")
        points = _checks.check(
            points, ~self.full_rank, "CurveBlending.refit", _REFIT_NEEDS, "a rank-deficient matrix"
        )
        if self.weights is None:
            return inverse @ points
        denom = self.a[0] @ self.weights
        return (inverse @ (points * denom[:, None])) / self.weights[:, None]

    def curve(self, ctrl: Float[Array, "n d"]) -> BSplineCurve:
        """The `BSplineCurve` of this basis with control points `ctrl`."""
        return BSplineCurve.from_direction(ctrl, self.direction, self.weights)

    def _checked_ctrl(self, ctrl, name):
        _checks.check_ndim(ctrl, name, 2)
        if ctrl.shape[0] != self.n_ctrl or ctrl.shape[1] not in (2, 3):
            _checks.fail(name, f"shape ({self.n_ctrl}, d) with d = 2 or 3", ctrl.shape)
        return _checks.finite(ctrl, name)


_REFIT_NEEDS = "at least as many samples as control points, with a full-column-rank blending matrix"


def _blending(direction: SplineDirection, params, weights) -> CurveBlending:
    a, refit, ok, _, _ = sampled(direction, params)
    return CurveBlending(
        params=params, a=a, refit_matrix=refit, full_rank=ok, weights=weights, direction=direction
    )


def sampled(direction: SplineDirection, params: Float[HostArray, " m"]) -> tuple:
    """The blending of one direction at checked `params (m,)` (thesis eqs. 3.6–3.7): the kernel of
    curve and surface blendings. Concrete `params` (and knots) are sampled on the host in numpy
    (`basis._functions`: the same code, no program to compile, so building a blending costs
    milliseconds in a new process); traced ones inside the caller's program.

    **Returns:** `(a (3, m, n), refit (n, m) or None, full_rank (), support (m, k+1),
    band (3, m, k+1))` as JAX arrays: the basis, first- and second-derivative matrices, the
    pseudo-inverse of `a[0]` and whether `a[0]` has full column rank, and the band of `a` — the
    `k + 1` columns that can be non-zero in each row (`SplineDirection.support`) and their
    entries.
    """
    xp = _checks.xp(direction, params)
    params = xp.asarray(params)
    a = xp.asarray(direction.matrices(params, tuple(range(_ORDERS))))
    refit, ok = _tensor.pseudo_inverse(a[0])
    support = xp.asarray(direction.support(params))
    out = (a, refit, ok, support, xp.take_along_axis(a, support[None], axis=2))
    return _checks.on_device(out)
