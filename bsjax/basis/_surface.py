"""`BSplineSurface` (thesis eq. 3.1) and `Blending`, its pre-computed sampled form (thesis §3.2).

A surface is a control net and one `SplineDirection` per parameter direction (plus optional
NURBS weights). Its `Blending` holds the blending matrices of an `m × n` sample grid and their
least-squares inverses, built once; every later operation is a pair of small matrix products:
points `M = A_u P A_v^T` (eq. 3.6), tangents with `A'_u`, `A'_v`, and the refit
`P = A_u^+ M (A_v^+)^T` (eq. 3.7, `A^+ = (A^T A)^{-1} A^T`). The two classes live together
because each builds the other (`surface.blending(m, n)`, `blending.surface(ctrl)`).
"""

from __future__ import annotations

from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax._typing import ArrayLike
from bsjax.basis import _tensor
from bsjax.basis._curve import BSplineCurve, sampled
from bsjax.basis._direction import SplineDirection
from bsjax.basis._functions import check_order

_ORDERS = 3  # basis, first and second derivative matrices are stored


def _direction_properties() -> tuple[property, ...]:
    """`knots_u, knots_v, degree_u, degree_v, periodic_u, periodic_v`: read from the object's
    `direction_u` / `direction_v` (shared by `BSplineSurface` and `Blending`)."""

    def read(field: str, side: str) -> property:
        return property(
            lambda self: getattr(getattr(self, f"direction_{side}"), field), doc=f"{field} along {side}"
        )

    return tuple(read(field, side) for field in ("knots", "degree", "periodic") for side in ("u", "v"))


def _direction_of(name, knots, degree, periodic, n_ctrl, dtype) -> SplineDirection:
    return SplineDirection(knots, degree, n_ctrl=n_ctrl, periodic=periodic, name=f"knots_{name}", dtype=dtype)


class BSplineSurface(eqx.Module):
    """`S(u, v) = Σ_i Σ_j B_{i,k}(u) B_{j,l}(v) P_ij` on [0, 1]² (thesis eq. 3.1).

    **Arguments / fields:**
    - `ctrl`: control net `(r, s, 3)`, finite.
    - `knots_u`, `knots_v`: clamped knot vectors `(r + k + 1,)`, `(s + l + 1,)`; `None` for a
      periodic direction, which uses the uniform closed basis (thesis eq. 3.3).
    - `degree_u`, `degree_v`: k, l ≥ 1; `periodic_u`, `periodic_v`: closed directions.
    - `weights`: `(r, s)` positive NURBS weights, or `None` for a polynomial surface.

    Stored as `direction_u`, `direction_v` (`SplineDirection`); `knots_u`, `degree_u`,
    `periodic_u` (and `_v`) read them. `BSplineSurface.from_directions(ctrl, du, dv, weights)`
    builds one from directions.
    """

    ctrl: Float[Array, "r s 3"]
    direction_u: SplineDirection
    direction_v: SplineDirection
    weights: Float[Array, "r s"] | None

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
        dtype = _checks.float_dtype(ctrl, names=("ctrl",))
        ctrl = jnp.asarray(ctrl, dtype=dtype)
        _checks.check_ndim(ctrl, "ctrl", 3, last=3)
        r, s, _ = ctrl.shape
        self.ctrl = _checks.finite(ctrl, "ctrl")
        self.direction_u = _direction_of("u", knots_u, degree_u, periodic_u, r, dtype)
        self.direction_v = _direction_of("v", knots_v, degree_v, periodic_v, s, dtype)
        self.weights = None if weights is None else _weights(weights, ctrl, r, s)

    @classmethod
    def from_directions(
        cls, ctrl, direction_u: SplineDirection, direction_v: SplineDirection, weights=None
    ) -> BSplineSurface:
        """A surface from its control net and two `SplineDirection`s (checked like `__init__`)."""
        du, dv = direction_u, direction_v
        return cls(ctrl, du.knots, dv.knots, du.degree, dv.degree, du.periodic, dv.periodic, weights)

    # --- the directions ----------------------------------------------------------------------
    def direction(self, name: str) -> SplineDirection:
        """The `SplineDirection` of `"u"` or `"v"`."""
        if name == "u":
            return self.direction_u
        if name == "v":
            return self.direction_v
        _checks.fail("direction", "'u' or 'v'", repr(name))
        raise AssertionError

    knots_u, knots_v, degree_u, degree_v, periodic_u, periodic_v = _direction_properties()

    @property
    def shape(self) -> tuple[int, int]:
        """Control-net size `(r, s)`."""
        return self.ctrl.shape[0], self.ctrl.shape[1]

    @compiled
    def rows(self, direction: str, params, nu: int = 0):
        """Blending matrix of one direction (`"u"` or `"v"`) at `params`, derivative order `nu`."""
        return self.direction(direction).matrix(jnp.asarray(params, self.ctrl.dtype), nu)

    # --- evaluation --------------------------------------------------------------------------
    @compiled
    def evaluate(self, u: ArrayLike, v: ArrayLike, nu: int = 0, nv: int = 0) -> Float[Array, "... 3"]:
        """Points (or the (nu, nv) partial derivative) at equal-shape parameter arrays `u`, `v`.

        Parameters of a clamped direction must lie in [0, 1] (periodic ones are taken modulo 1).
        Differentiable in the control net, the weights and in `u`, `v`.
        **Returns:** `u.shape + (3,)`.
        """
        check_order(nu, "nu")
        check_order(nv, "nv")
        return _evaluate(self, self._params(u, "u"), self._params(v, "v"), nu, nv)

    @compiled
    def normal(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... 3"]:
        """Unit normal `T_u × T_v / |T_u × T_v|` at `u`, `v` (limit normal at poles, never NaN)."""
        u, v = self._params(u, "u"), self._params(v, "v")
        t_u, t_v, t_uv = (_evaluate(self, u, v, a, b) for a, b in ((1, 0), (0, 1), (1, 1)))
        return _tensor.unit_normal(t_u, t_v, t_uv, u, v)

    def _params(self, x, name):
        _checks.check_real(x, name)
        return jnp.asarray(x, self.ctrl.dtype)

    def blending(self, m: int = 82, n: int = 82, params_u=None, params_v=None) -> Blending:
        """Pre-computed blending matrices for an `m × n` sample grid (default `linspace(0, 1, ·)`).

        One compiled program per direction (`basis._curve.sampled`, per control count, degree and
        sample count: a square net sampled on a square grid compiles one): a rebuild is two
        XLA calls.
        """
        pu = _grid_params(params_u, m, "params_u", "m", self.ctrl.dtype)
        pv = _grid_params(params_v, n, "params_v", "n", self.ctrl.dtype)
        return _blending(self.direction_u, self.direction_v, pu, pv, self.weights)

    def with_ctrl(self, ctrl: ArrayLike) -> BSplineSurface:
        """The same basis (and weights) with another control net: an `eqx.tree_at` replacement
        of `ctrl` (shape checked, values checked finite), so the knots are carried over as they
        are — concrete or traced inside the caller's `jit` — and not checked again."""
        _checks.check_real(ctrl, "ctrl")
        if np.shape(ctrl) != self.ctrl.shape:
            _checks.fail("ctrl", f"shape {self.ctrl.shape}", np.shape(ctrl))
        ctrl = _checks.finite(_checks.array(ctrl, "ctrl", self.ctrl.dtype), "ctrl")
        return eqx.tree_at(lambda surface: surface.ctrl, self, ctrl)

    @compiled
    def iso_curve(self, direction: str, value: ArrayLike) -> BSplineCurve:
        """The exact `BSplineCurve` of an iso-line (the iso-curve network of eq. 5-3 in *Interactive
        shape modeling and dynamic deformation based on spline sculpting*; The NURBS Book §4.5).

        `direction="u"`: the curve `v ↦ S(value, v)`, in the basis of `direction_v`, with control
        points `Q_j = Σ_i B_i(value) w_ij P_ij / Σ_i B_i(value) w_ij` and weights
        `Σ_i B_i(value) w_ij` (rational when the surface is); `"v"`: `u ↦ S(u, value)`.
        **Arguments:** `value` a scalar in [0, 1] (periodic: taken modulo 1).
        """
        fixed = self.direction(direction)
        other = self.direction_v if direction == "u" else self.direction_u
        value = self._params(value, "value")
        _checks.check_ndim(value, "value", 0)
        value = fixed.check_params(value, "value")
        net = jnp.moveaxis(_tensor.homogeneous(self.ctrl, self.weights), 0 if direction == "u" else 1, 0)
        h = jnp.tensordot(fixed.matrix(value[None])[0], net, axes=1)
        if self.weights is None:
            return BSplineCurve.from_direction(h, other)
        return BSplineCurve.from_direction(h[:, :3] / h[:, 3:], other, h[:, 3])


def _evaluate(surface: BSplineSurface, u, v, nu: int, nv: int):
    if u.shape != v.shape:
        _checks.fail("v", f"the shape of u {u.shape}", v.shape)
    u = surface.direction_u.check_params(u, "u")
    v = surface.direction_v.check_params(v, "v")
    flat_u, flat_v = u.reshape(-1), v.reshape(-1)
    du, dv = surface.direction_u, surface.direction_v
    net = _tensor.homogeneous(surface.ctrl, surface.weights)
    if surface.weights is None:
        out = _tensor.pointwise(du.matrix(flat_u, nu), net, dv.matrix(flat_v, nv))
    else:
        a_u = du.matrices(flat_u, tuple(range(nu + 1)))
        a_v = dv.matrices(flat_v, tuple(range(nv + 1)))
        h = {(k, l): _tensor.pointwise(a_u[k], net, a_v[l]) for k in range(nu + 1) for l in range(nv + 1)}
        out = _tensor.rational_derivatives(h, nu, nv)[(nu, nv)]
    return out.reshape(u.shape + (3,))


def _weights(weights, ctrl, r: int, s: int):
    weights = jnp.asarray(weights, dtype=_checks.float_dtype(weights, ctrl, names=("weights", "ctrl")))
    if weights.shape != (r, s):
        _checks.fail("weights", f"shape {(r, s)}", weights.shape)
    return _checks.positive(weights, "weights")


class Blending(eqx.Module):
    """Blending matrices of an `m × n` sample grid of a surface basis.

    **Fields:**
    - `params_u (m,)`, `params_v (n,)`: the sample parameters.
    - `a_u (3, m, r)`, `a_v (3, n, s)`: basis, first- and second-derivative blending matrices.
    - `refit_u (r, m)`, `refit_v (s, n)`: the pseudo-inverses `A^+`, or `None` when the grid has
      fewer samples than control points in that direction (or for a window/LOD view);
      `full_rank ()`: whether both matrices have full column rank (a closed direction sampled with
      its seam twice and too few distinct samples has not; `refit` then raises).
    - `weights (r, s)` or `None`; `direction_u`, `direction_v`: the `SplineDirection`s.
    - `index_u (m,)`, `index_v (n,)`: rows of the full grid this view holds.
    - `support_u (m, k+1)`, `band_u (3, m, k+1)`: the band of `a_u` — the columns of the `k+1`
      basis functions non-zero at each sample (`SplineDirection.support`) and their values (and
      derivatives): `a_u[nu, i, support_u[i, c]] == band_u[nu, i, c]`, every other entry zero.
    - `banded` (static): evaluate through the band (`_tensor.banded_grid`) rather than the dense
      product; chosen from the shapes when the matrices are built (`_tensor.prefer_banded`).
    """

    params_u: Float[Array, " m"]
    params_v: Float[Array, " n"]
    a_u: Float[Array, "3 m r"]
    a_v: Float[Array, "3 n s"]
    refit_u: Float[Array, "r m"] | None
    refit_v: Float[Array, "s n"] | None
    full_rank: Array
    weights: Float[Array, "r s"] | None
    direction_u: SplineDirection
    direction_v: SplineDirection
    index_u: Int[Array, " m"]
    index_v: Int[Array, " n"]
    support_u: Int[Array, "m k1"]
    band_u: Float[Array, "3 m k1"]
    banded: bool = eqx.field(static=True)

    @classmethod
    def from_surface(cls, surface: BSplineSurface, m: int = 82, n: int = 82, params_u=None, params_v=None):
        """Build (once) the matrices of `surface`'s basis at an `m × n` grid (`surface.blending`)."""
        return surface.blending(m, n, params_u, params_v)

    @staticmethod
    def from_directions(
        direction_u: SplineDirection, direction_v: SplineDirection, params_u, params_v, weights=None
    ) -> Blending:
        """The matrices of the basis `direction_u ⊗ direction_v` (NURBS `weights` optional) at the
        grid `params_u (m,)` × `params_v (n,)` (any sorted parameters in the domain — e.g. the
        stacked sample parameters of a merge): basis and derivative matrices (eq. 3.6) and the
        refit factors `A^+` (eq. 3.7), in one compiled call."""
        dtype = _checks.float_dtype(params_u, params_v, names=("params_u", "params_v"))
        pu, pv = jnp.asarray(params_u, dtype), jnp.asarray(params_v, dtype)
        _checks.check_ndim(pu, "params_u", 1)
        _checks.check_ndim(pv, "params_v", 1)
        return _blending(direction_u, direction_v, pu, pv, weights)

    knots_u, knots_v, degree_u, degree_v, periodic_u, periodic_v = _direction_properties()

    @property
    def grid_shape(self) -> tuple[int, int]:
        """Sample grid `(m, n)`."""
        return self.a_u.shape[1], self.a_v.shape[1]

    @property
    def ctrl_shape(self) -> tuple[int, int]:
        """Control net `(r, s)`."""
        return self.a_u.shape[2], self.a_v.shape[2]

    # --- samples counted once ----------------------------------------------------------------
    @property
    def first_samples(self) -> Int[Array, "m n"]:
        """Flat index (row-major into the `(m, n)` grid) of the first sample at each sample's
        parameters: the sample itself, except on a seam sampled twice — a periodic direction's
        default grid holds both 0 and 1, the same row of points — or at a repeated parameter."""
        xp = _checks.xp(self.params_u, self.params_v)
        first_u = _first_copies(self.params_u, self.periodic_u, xp)
        first_v = _first_copies(self.params_v, self.periodic_v, xp)
        return first_u[:, None] * self.grid_shape[1] + first_v[None, :]

    @property
    def counted(self) -> Bool[Array, "m n"]:
        """`(m, n)` booleans: the samples that count in a sum over the surface (contact depths and
        forces, penetrations, statistics) — every sample but the second copy of a point
        (`first_samples`), so a closed surface's seam counts once."""
        xp = _checks.xp(self.params_u, self.params_v)
        m, n = self.grid_shape
        return self.first_samples == xp.arange(m * n, dtype=np.int32).reshape(m, n)

    # --- evaluation --------------------------------------------------------------------------
    @compiled
    def points(self, ctrl: Float[Array, "r s 3"]) -> Float[Array, "m n 3"]:
        """Sample grid `M = A_u P A_v^T` (thesis eq. 3.6)."""
        return self.derivative(ctrl, 0, 0)

    @compiled
    def derivative(self, ctrl: Float[Array, "r s 3"], nu: int, nv: int) -> Float[Array, "m n 3"]:
        """The (nu, nv) partial derivative on the grid, `A_u^{(nu)} P A_v^{(nv)T}`, nu, nv ≤ 2."""
        self._check_ctrl(ctrl)
        if not (0 <= nu < _ORDERS and 0 <= nv < _ORDERS):
            _checks.fail("nu, nv", f"derivative orders in 0..{_ORDERS - 1}", (nu, nv))
        ctrl = _checks.finite(ctrl, "ctrl")
        if self.weights is None:
            return self._grid(nu, ctrl, nv)
        net = _tensor.homogeneous(ctrl, self.weights)
        h = {(k, l): self._grid(k, net, l) for k in range(nu + 1) for l in range(nv + 1)}
        return _tensor.rational_derivatives(h, nu, nv)[(nu, nv)]

    def _grid(self, nu: int, net, nv: int) -> Array:
        """`A_u^{(nu)} P A_v^{(nv)T}` through the band or the dense product (`banded`)."""
        if self.banded:
            assert self.support_u is not None and self.band_u is not None
            return cast(Array, _tensor.banded_grid(self.support_u, self.band_u[nu], net, self.a_v[nv]))
        return cast(Array, _tensor.grid(self.a_u[nu], net, self.a_v[nv]))

    @compiled
    def tangents(self, ctrl) -> tuple[Float[Array, "m n 3"], Float[Array, "m n 3"]]:
        """`(T_u, T_v) = (A'_u P A_v^T, A_u P A'_v^T)`."""
        return self.derivative(ctrl, 1, 0), self.derivative(ctrl, 0, 1)

    @compiled
    def normals(self, ctrl: Float[Array, "r s 3"]) -> Float[Array, "m n 3"]:
        """Unit normals `T_u × T_v / |·|` on the grid; the limit normal at poles; never NaN."""
        t_u, t_v = self.tangents(ctrl)
        t_uv = self.derivative(ctrl, 1, 1)
        return _tensor.unit_normal(t_u, t_v, t_uv, self.params_u[:, None], self.params_v[None, :])

    # --- refit -------------------------------------------------------------------------------
    @compiled
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
                "Blending.refit", _REFIT_NEEDS, f"grid {self.grid_shape} for control net {self.ctrl_shape}"
            )
        points = _checks.finite(points, "points")
        points = _checks.check(
            points, ~self.full_rank, "Blending.refit", _REFIT_NEEDS, "rank-deficient matrices"
        )
        if self.weights is None:
            return _tensor.grid(self.refit_u, points, self.refit_v)
        denom = self._grid(0, self.weights[..., None], 0)
        return _tensor.grid(self.refit_u, points * denom, self.refit_v) / self.weights[..., None]

    # --- views -------------------------------------------------------------------------------
    def window(self, u_min: float, u_max: float, v_min: float, v_max: float) -> Blending:
        """The rows and columns whose parameters lie in `[u_min, u_max] × [v_min, v_max]`
        (host-side: the view's size depends on the values, so it cannot be built under `jit`)."""
        if not _checks.is_concrete((self.params_u, self.params_v)):
            raise TypeError(
                "window: expected a concrete Blending (a host-side view whose size depends on the "
                "parameter values), got a traced one inside jit/vmap/grad; build the window outside"
            )
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

    def lod(self, q_u: int, q_v: int | None = None) -> Blending:
        """Every `q`-th row/column (intermittent rows, a coarse level of detail); the last is kept."""
        q_v = q_u if q_v is None else q_v
        _checks.check_count(q_u, "q_u")
        _checks.check_count(q_v, "q_v")
        m, n = self.grid_shape
        return self._take(_every(m, q_u), _every(n, q_v))

    def _take(self, rows, cols) -> Blending:
        return eqx.tree_at(
            lambda b: (
                b.params_u,
                b.params_v,
                b.a_u,
                b.a_v,
                b.refit_u,
                b.refit_v,
                b.index_u,
                b.index_v,
                b.support_u,
                b.band_u,
            ),
            self,
            (
                self.params_u[rows],
                self.params_v[cols],
                self.a_u[:, rows],
                self.a_v[:, cols],
                None,
                None,
                self.index_u[rows],
                self.index_v[cols],
                self.support_u[rows],
                self.band_u[:, rows],
            ),
            is_leaf=lambda x: x is None,
        )

    def surface(self, ctrl: Float[Array, "r s 3"]) -> BSplineSurface:
        """The `BSplineSurface` of this basis with control net `ctrl`."""
        return BSplineSurface.from_directions(ctrl, self.direction_u, self.direction_v, self.weights)

    def _check_ctrl(self, ctrl) -> None:
        if np.shape(ctrl) != (*self.ctrl_shape, 3):
            _checks.fail("ctrl", f"shape {(*self.ctrl_shape, 3)}", np.shape(ctrl))


_REFIT_NEEDS = (
    "a full grid with m >= r and n >= s samples whose blending matrices have full column rank "
    "(a closed direction samples its seam twice)"
)


def _blending(du: SplineDirection, dv: SplineDirection, pu, pv, weights) -> Blending:
    pu, pv = du.check_params(pu, "params_u"), dv.check_params(pv, "params_v")
    a_u, refit_u, ok_u, support_u, band_u = sampled(du, pu)
    a_v, refit_v, ok_v, _, _ = sampled(dv, pv)
    (m, r), (n, s) = a_u.shape[1:], a_v.shape[1:]
    full_rank = _checks.on_device(_checks.xp(ok_u, ok_v).logical_and(ok_u, ok_v))
    return Blending(
        params_u=pu, params_v=pv, a_u=a_u, a_v=a_v, refit_u=refit_u, refit_v=refit_v,
        full_rank=full_rank, weights=weights, direction_u=du, direction_v=dv,
        index_u=_index(m), index_v=_index(n),
        support_u=support_u, band_u=band_u, banded=_tensor.prefer_banded(m, n, r, s, du.degree),
    )  # fmt: skip


def _first_copies(params, periodic: bool, xp):
    """`(m,)` int32: for each of `params (m,)` the index of the first equal one (modulo 1 in a
    periodic direction, whose 0 and 1 are the same seam)."""
    p = xp.mod(params, 1.0) if periodic else params
    return xp.argmax(p[:, None] == p[None, :], axis=1).astype(np.int32)


def _index(count: int):
    """`arange(count)` in JAX's default int dtype, from the host (no program to compile)."""
    return _checks.on_device(np.arange(count, dtype=jax.dtypes.canonicalize_dtype(int)))


def _grid_params(params, count, name, count_name, dtype):
    if params is None:
        _checks.check_count(count, count_name, 2)
        dtype = jnp.dtype(dtype) if dtype is not None else jnp.result_type(float)
        return _checks.on_device(np.linspace(0.0, 1.0, count).astype(dtype))  # no program to compile
    _checks.check_real(params, name)
    params = jnp.asarray(params, dtype=dtype)
    _checks.check_ndim(params, name, 1)
    return params


def _every(count: int, q: int) -> np.ndarray:
    idx = np.arange(0, count, q)
    return idx if idx[-1] == count - 1 else np.append(idx, count - 1)
