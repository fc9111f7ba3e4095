"""Linear constraints on control-point displacements (Fowler & Bartels, *Constraint-based curve
manipulation*; thesis *Interactive shape modeling and dynamic deformation based on spline
sculpting*, §6.1, eqs. 6-6…6-15 and Table 6-1).

Every constraint acts at `m` parameters (a scalar `u` is one point) and gives `m` scalar rows
`F (m, N)` on the flattened control points (N = n for a curve, r·s for a surface) and a
right-hand side `b (m, d)`, one column per coordinate: `F d = b`. The rows are the (rational)
basis functions, or their derivatives, at the constraint's parameters (thesis eq. 6-10: "the row
is the basis values or their derivatives at u"). A constraint is prepared once per shape
(`prepare`: its rows and what its right-hand side needs) and its right-hand side is then a cheap
function of its value (`rhs`), which is what `Factor.drag` evaluates per event.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, _safe
from bsjax._declared import check_fields
from bsjax.basis import BSplineCurve, BSplineSurface, SplineDirection

Shape = BSplineCurve | BSplineSurface


class AbstractConstraint(eqx.Module):
    """A linear constraint `F d = b` on the displacement d of a curve's or a surface's control
    points, at parameters `u` (and `v` for a surface)."""

    u: ArrayLike
    v: ArrayLike | None

    def __check_init__(self):
        check_fields(self)  # types at construction; values where the constraint is solved

    def goal(self):
        """The constraint's value (target point, displacement, derivative or amount); None if none."""
        return None

    def rows(self, shape: Shape, u, v) -> Array:
        """Position rows `(m, N)` at the checked parameters."""
        return point_rows(shape, u, v, 0, "u")

    def aux(self, shape: Shape, rows, u, v) -> Array:
        """What the right-hand side needs besides the value (by default the current points)."""
        return rows @ flat_ctrl(shape)

    def rhs(self, aux, value) -> Array:
        """`b (m, d)` from the prepared `aux (m, d)` and a value (default: move to the value)."""
        return jnp.broadcast_to(jnp.asarray(value, aux.dtype), aux.shape) - aux


class Position(AbstractConstraint):
    """`P(u) = target` (surfaces: `S(u, v) = target`) — the point-position row of Table 6-1.

    **Fields:** `u`, `v`: scalars or `(m,)` parameters in [0, 1] (`v` only for surfaces);
    `target`: `(d,)` or `(m, d)` finite points.
    """

    target: ArrayLike

    def __init__(self, u: ArrayLike, target: ArrayLike, v: ArrayLike | None = None):
        self.u, self.target, self.v = u, target, v

    def goal(self):
        return self.target


class Displacement(AbstractConstraint):
    """`ΔP(u) = delta`: the point at `u` (, `v`) moves by `delta` (`(d,)` or `(m, d)`)."""

    delta: ArrayLike

    def __init__(self, u: ArrayLike, delta: ArrayLike, v: ArrayLike | None = None):
        self.u, self.delta, self.v = u, delta, v

    def goal(self):
        return self.delta

    def aux(self, shape, rows, u, v):
        return jnp.zeros((rows.shape[0], shape.ctrl.shape[-1]), rows.dtype)

    def rhs(self, aux, value):
        return jnp.broadcast_to(jnp.asarray(value, aux.dtype), aux.shape)


class Fixed(AbstractConstraint):
    """`ΔP(u) = 0`: the point at `u` (, `v`) does not move (a blocked point, §7.2)."""

    def __init__(self, u: ArrayLike, v: ArrayLike | None = None):
        self.u, self.v = u, v

    def goal(self):
        return None

    def aux(self, shape, rows, u, v):
        return jnp.zeros((rows.shape[0], shape.ctrl.shape[-1]), rows.dtype)

    def rhs(self, aux, value):
        del value
        return aux


class Derivative(AbstractConstraint):
    """`∂^k P/∂u^k (u) = value` (surfaces: along `direction` "u" or "v") — tangent (k = 1) or
    second-derivative (k = 2) rows from the derivative blending rows (thesis eqs. 6-12…6-14).

    **Fields:** `u`, `v` parameters as in `Position`; `value (d,)` or `(m, d)`; `order` (static)
    1 or 2; `direction` (static) "u" or "v" (surfaces).
    """

    value: ArrayLike
    order: int = eqx.field(static=True)
    direction: str = eqx.field(static=True)

    def __init__(
        self, u: ArrayLike, value: ArrayLike, order: int = 1, v: ArrayLike | None = None, direction: str = "u"
    ):
        self.u, self.value, self.v = u, value, v
        self.order, self.direction = order, direction

    def __check_init__(self):
        if isinstance(self.order, bool) or self.order not in (1, 2):
            _checks.fail("order", "a derivative order 1 or 2", repr(self.order))
        if self.direction not in ("u", "v"):
            _checks.fail("direction", "'u' or 'v'", repr(self.direction))

    def goal(self):
        return self.value

    def rows(self, shape, u, v):
        return point_rows(shape, u, v, self.order, self.direction)


class AlongNormal(AbstractConstraint):
    """`ΔP(u) = amount · n(u)`: the point moves along its unit normal.

    Surfaces: `n = S_u × S_v / |S_u × S_v|`. Planar curves: the left normal (the tangent turned
    by +90°, the side of positive signed curvature). Space curves: the Frenet principal normal
    (thesis §7.2, `ΔP(u1) = λ b(u1)`); where the curve is straight it is undefined and the
    point is held (`n = 0`).

    **Fields:** `u`, `v` parameters as in `Position`; `amount`: scalar or `(m,)`.
    """

    amount: ArrayLike

    def __init__(self, u: ArrayLike, amount: ArrayLike, v: ArrayLike | None = None):
        self.u, self.amount, self.v = u, amount, v

    def goal(self):
        return self.amount

    def aux(self, shape, rows, u, v):
        return unit_normals(shape, u, v)

    def rhs(self, aux, value):
        amount = jnp.broadcast_to(jnp.asarray(value, aux.dtype), aux.shape[:1])
        return amount[:, None] * aux


# --- rows -------------------------------------------------------------------------------------
def flat_ctrl(shape: Shape) -> Float[Array, "N d"]:
    """The control points as `(N, d)` (a surface's net row-major, index `i·s + j`)."""
    return shape.ctrl.reshape(-1, shape.ctrl.shape[-1])


def flat_weights(shape: Shape):
    return None if shape.weights is None else shape.weights.reshape(-1)


def _rational(a, w, order: int):
    """Rows of the rational basis `R = N w / (N·w)` and its derivatives up to `order` in one
    variable from the polynomial rows `a (order + 1, m, N)` (quotient rule, The NURBS Book eq. 4.8)."""
    big_w = [a[k] @ w for k in range(order + 1)]
    num = [a[k] * w[None, :] for k in range(order + 1)]
    r0 = num[0] / big_w[0][:, None]
    if order == 0:
        return r0
    r1 = (num[1] - r0 * big_w[1][:, None]) / big_w[0][:, None]
    if order == 1:
        return r1
    return (num[2] - 2 * r1 * big_w[1][:, None] - r0 * big_w[2][:, None]) / big_w[0][:, None]


def point_rows(shape: Shape, u, v, order: int, direction: str) -> Float[Array, "m N"]:
    """Rows `(m, N)` of the (rational) basis, or its `order`-th derivative along `direction`, at
    the parameters: `C^{(k)}(u_a) = rows[a] @ ctrl` (surfaces: the tensor rows `B_i(u) B_j(v)`)."""
    orders = tuple(range(order + 1))
    if isinstance(shape, BSplineCurve):
        a = shape.direction.matrices(u, orders)
    else:
        du = shape.direction_u.matrices(u, orders if direction == "u" else (0,))
        dv = shape.direction_v.matrices(v, orders if direction == "v" else (0,))
        if direction == "u":
            a = jnp.einsum("kmi,mj->kmij", du, dv[0])
        else:
            a = jnp.einsum("mi,kmj->kmij", du[0], dv)
        a = a.reshape(a.shape[0], a.shape[1], -1)
    w = flat_weights(shape)
    return a[order] if w is None else _rational(a, w, order)


def unit_normals(shape: Shape, u, v) -> Float[Array, "m d"]:
    """Unit normals at the parameters (see `AlongNormal`)."""
    ctrl = flat_ctrl(shape)
    if isinstance(shape, BSplineSurface):
        t_u = point_rows(shape, u, v, 1, "u") @ ctrl
        t_v = point_rows(shape, u, v, 1, "v") @ ctrl
        return _safe.unit(jnp.cross(t_u, t_v))
    d1 = point_rows(shape, u, v, 1, "u") @ ctrl
    if shape.dim == 2:
        return _safe.unit(jnp.stack([-d1[:, 1], d1[:, 0]], -1))
    d2 = point_rows(shape, u, v, 2, "u") @ ctrl
    t = _safe.unit(d1)
    return _safe.unit(d2 - jnp.sum(d2 * t, -1, keepdims=True) * t)


def checked_params(shape: Shape, constraint: AbstractConstraint, name: str):
    """The constraint's parameters as `(m,)` arrays in the shape's dtype, checked: structure
    (scalars or 1-D, `v` exactly for surfaces) now, values ([0, 1], finite) also under jit."""
    dtype = shape.ctrl.dtype
    surface = isinstance(shape, BSplineSurface)
    if surface and constraint.v is None:
        _checks.fail(f"{name}.v", "a parameter v for a surface constraint", None)
    if not surface and constraint.v is not None:
        _checks.fail(f"{name}.v", "None for a curve constraint", "a value")
    u = _as_array(constraint.u, f"{name}.u", dtype)
    if u.ndim > 1:
        _checks.fail(f"{name}.u", "a scalar or a 1-D array of parameters", f"shape {u.shape}")
    u = u.reshape(-1)
    directions = (shape.direction_u, shape.direction_v) if surface else (shape.direction, None)
    u = _param_check(directions[0], u, f"{name}.u")
    if not surface:
        return u, None
    v = _as_array(constraint.v, f"{name}.v", dtype)
    if v.ndim > 1 or v.reshape(-1).shape != u.shape:
        _checks.fail(f"{name}.v", f"the shape of u {tuple(u.shape)} (or a scalar)", f"shape {v.shape}")
    return u, _param_check(directions[1], v.reshape(-1), f"{name}.v")


def _as_array(x, name: str, dtype):
    """`x` (an array, a number or a nested list of numbers/tracers) as a real array of `dtype`."""
    if isinstance(x, (list, tuple)):
        x = jnp.asarray(x)
    _checks.check_real(x, name)
    return jnp.asarray(x, dtype)


def _param_check(direction: SplineDirection | None, x, name: str):
    assert direction is not None
    return direction.check_params(x, name)


def checked_value(shape: Shape, constraint: AbstractConstraint, value, m: int, name: str):
    """`value` checked against the constraint's kind: points `(d,)`/`(m, d)`, amounts `()`/`(m,)`,
    finite (also under jit); None for `Fixed`."""
    if isinstance(constraint, Fixed):
        return None
    value = _as_array(value, name, shape.ctrl.dtype)
    if isinstance(constraint, AlongNormal):
        if value.shape not in ((), (m,)):
            _checks.fail(name, f"a scalar or shape ({m},)", f"shape {value.shape}")
    else:
        d = shape.ctrl.shape[-1]
        if value.shape not in ((d,), (m, d)):
            _checks.fail(name, f"shape ({d},) or ({m}, {d})", f"shape {value.shape}")
    return _checks.finite(value, name)
