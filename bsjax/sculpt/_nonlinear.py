"""Nonlinear constraints (thesis *Interactive shape modeling and dynamic deformation based on
spline sculpting*, Table 6-1) and their minimum-norm Gauss–Newton solve on optimistix.

Each constraint is a residual `c(P + d) = 0` of the moved control points. The solve linearises
at the current displacement and takes the minimum-(weighted-)norm displacement that meets the
linearised constraints, `d ← S (J S)⁺ (J d − c(d))` with `S = mask · W^{-1/2}` (the Gauss–Newton
iteration for `min ‖d‖_W` s.t. `c(d) = 0`): one step for linear constraints (the `min_norm`
solution); its fixed points meet the constraints with `d` in the row space of `J` (the KKT
condition). The iteration runs as `optimistix.fixed_point` (`throw=False`; the status is
reported), so `jax.grad` through `solve` uses the implicit function theorem at the solution.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax._declared import check_fields
from bsjax.basis import BSplineCurve, BSplineSurface, closest_points
from bsjax.sculpt._constraints import (
    AbstractConstraint,
    Shape,
    checked_params,
    checked_value,
    flat_ctrl,
    point_rows,
)
from bsjax.sculpt._min_norm import Edit, _column_scale, _describe, _pinv, _rank


class AbstractNonlinear(eqx.Module):
    """A nonlinear constraint `c(P + d) = 0` on a curve's or surface's control points."""

    def __check_init__(self):
        check_fields(self)  # types at construction; values where the constraint is solved

    def prepare(self, shape: Shape, name: str):
        """Checked values and constant basis rows (a pytree) for `residual`."""
        raise NotImplementedError

    def residual(self, plan, ctrl) -> Array:
        """The residual vector at the moved control points `ctrl (N, d)`."""
        raise NotImplementedError


class _Vec(AbstractConstraint):
    """A stand-in constraint, so nonlinear values are checked like linear ones (`checked_value`)."""

    def __init__(self, u, v):
        self.u, self.v = u, v


def _point(shape, u, v, name):
    u, v = checked_params(shape, _Vec(u, v), name)
    if u.shape != (1,):
        _checks.fail(f"{name}.u", "a scalar parameter", f"shape {u.shape}")
    return u, v


def _normal_rows(shape, u, v):
    rows = {"du": point_rows(shape, u, v, 1, "u")}
    if isinstance(shape, BSplineSurface):
        rows["dv"] = point_rows(shape, u, v, 1, "v")
    elif shape.dim == 3:
        rows["d2"] = point_rows(shape, u, v, 2, "u")
    return rows


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0] if a.shape[-1] == 2 else jnp.cross(a, b)


class Distance(AbstractNonlinear):
    """`‖P(u1) − P(u2)‖ = d` (Table 6-1; quadratic, so nonlinear; Fig. 6-3).

    **Fields:** `u1`, `u2` scalar parameters (`v1`, `v2` for surfaces); `d ≥ 0`.
    """

    u1: ArrayLike
    u2: ArrayLike
    d: ArrayLike
    v1: ArrayLike | None = None
    v2: ArrayLike | None = None

    def prepare(self, shape, name):
        u1, v1 = _point(shape, self.u1, self.v1, name + "[1]")
        u2, v2 = _point(shape, self.u2, self.v2, name + "[2]")
        d = _checks.positive(_checks.array(self.d, f"{name}.d", shape.ctrl.dtype), f"{name}.d", strict=False)
        _checks.check_ndim(d, f"{name}.d", 0)
        return {"rows": point_rows(shape, u1, v1, 0, "u") - point_rows(shape, u2, v2, 0, "u"), "d": d}

    def residual(self, plan, ctrl):
        return (_safe.norm((plan["rows"] @ ctrl)[0]) - plan["d"])[None]


class TangentParallel(AbstractNonlinear):
    """The tangent at `u` is parallel to `direction`: `t ∧ direction = 0` (Table 6-1; unit
    vectors, so the residual is the sine of the angle between them).

    **Fields:** `u` (and `v` for surfaces) a scalar parameter; `direction (d,)`, non-zero;
    `along` (static) "u" or "v": which surface tangent.
    """

    u: ArrayLike
    direction: ArrayLike
    v: ArrayLike | None = None
    along: str = eqx.field(static=True, default="u")

    def prepare(self, shape, name):
        if self.along not in ("u", "v"):
            _checks.fail(f"{name}.along", "'u' or 'v'", repr(self.along))
        u, v = _point(shape, self.u, self.v, name)
        direction = checked_value(shape, _Vec(0.0, None), self.direction, 1, f"{name}.direction")
        bad = _safe.norm(direction) == 0
        direction = _checks.check(direction, bad, f"{name}.direction", "a non-zero vector", "zero")
        return {"rows": point_rows(shape, u, v, 1, self.along), "direction": _safe.unit(direction)}

    def residual(self, plan, ctrl):
        return jnp.atleast_1d(_cross(_safe.unit((plan["rows"] @ ctrl)[0]), plan["direction"]))


class NormalAngle(AbstractNonlinear):
    """The unit normal at `u` makes `angle` (radians) with `normal`: `n · n̂ = cos α` (Table 6-1;
    `angle = 0`: coincident normals). Normals as `AlongNormal`.

    **Fields:** `u` (and `v`) a scalar parameter; `normal (d,)` non-zero; `angle` in [0, π].
    """

    u: ArrayLike
    normal: ArrayLike
    angle: ArrayLike = 0.0
    v: ArrayLike | None = None

    def prepare(self, shape, name):
        u, v = _point(shape, self.u, self.v, name)
        normal = checked_value(shape, _Vec(0.0, None), self.normal, 1, f"{name}.normal")
        normal = _checks.check(normal, _safe.norm(normal) == 0, f"{name}.normal", "a non-zero vector", "zero")
        angle = _checks.in_range(
            _checks.array(self.angle, f"{name}.angle", shape.ctrl.dtype), f"{name}.angle", 0.0, np.pi
        )
        return {**_normal_rows(shape, u, v), "normal": _safe.unit(normal), "cos": jnp.cos(angle)}

    def residual(self, plan, ctrl):
        return (_normal_from(plan, ctrl) @ plan["normal"] - plan["cos"])[None]


class OnSurface(AbstractNonlinear):
    """Point-to-surface contact: the point at `u` (, `v`) lies on `surface` (Table 6-1, the
    curve-on-surface constraint of §6.2.2). The residual is the signed distance along the
    surface normal at the foot point (projected afresh each iteration; by the envelope theorem
    its derivative is the foot normal, the foot point itself held).

    **Fields:** `u` (and `v`) a scalar parameter; `surface`: a `BSplineSurface` (3-D shapes).
    """

    u: ArrayLike
    surface: BSplineSurface
    v: ArrayLike | None = None

    def prepare(self, shape, name):
        if not isinstance(self.surface, BSplineSurface):
            raise TypeError(f"{name}.surface: expected a BSplineSurface, got {type(self.surface).__name__}")
        if shape.ctrl.shape[-1] != 3:
            _checks.fail(
                f"{name}", "a 3-D shape for a point-to-surface contact", f"dimension {shape.ctrl.shape[-1]}"
            )
        u, v = _point(shape, self.u, self.v, name)
        return {"rows": point_rows(shape, u, v, 0, "u"), "surface": self.surface}

    def residual(self, plan, ctrl):
        surface = plan["surface"]
        p = (plan["rows"] @ ctrl)[0]
        uv = jax.lax.stop_gradient(closest_points(surface, jax.lax.stop_gradient(p)[None]).params[0])
        foot = surface.evaluate(uv[0], uv[1])
        n = surface.normal(uv[0], uv[1])
        return jax.lax.stop_gradient(n) @ (p - jax.lax.stop_gradient(foot))[..., None]


def _normal_from(plan, ctrl):
    """Unit normal from the planned derivative rows (as `AlongNormal`)."""
    if "dv" in plan:
        return _safe.unit(jnp.cross((plan["du"] @ ctrl)[0], (plan["dv"] @ ctrl)[0]))
    d1 = (plan["du"] @ ctrl)[0]
    if "d2" not in plan:
        return _safe.unit(jnp.stack([-d1[1], d1[0]]))
    d2 = (plan["d2"] @ ctrl)[0]
    t = _safe.unit(d1)
    return _safe.unit(d2 - jnp.sum(d2 * t) * t)


# --- the solve --------------------------------------------------------------------------------
@compiled
def solve(
    shape: Shape,
    constraints: Sequence[AbstractConstraint | AbstractNonlinear],
    free: ArrayLike | None = None,
    metric: ArrayLike | None = None,
    *,
    max_steps: int = 32,
    rtol: float = 1e-10,
    atol: float = 1e-12,
) -> Edit:
    """The minimum-norm edit under linear and nonlinear constraints (Table 6-1 of *Interactive
    shape modeling and dynamic deformation based on spline sculpting*), by minimum-norm
    Gauss–Newton `d ← S (J S)⁺ (J d − c(d))` on `optimistix.fixed_point` (module docstring).

    **Arguments:**
    - `shape`: a `BSplineCurve` or `BSplineSurface`.
    - `constraints`: linear ones (`Position`, `Displacement`, `Fixed`, `Derivative`,
      `AlongNormal`) and nonlinear ones (`Distance`, `TangentParallel`, `NormalAngle`,
      `OnSurface`).
    - `free`, `metric`: as `min_norm`.
    - `max_steps`: Gauss–Newton steps at most; `rtol`, `atol`: optimistix's tolerances on the
      step (floored at 10 eps / 100 eps of the dtype).

    **Returns:** an `Edit`: `residual = ‖c(P + d)‖₂`, `rank` of `J S` at the solution (scalar
    equations), `status` 0 when the constraints are met (residual ≤ √eps · (1 + ‖c(P)‖)), else 1
    when the iteration converged (inconsistent or over-constrained: the least-squares point) and
    2 when it did not within `max_steps`. Differentiable (implicit function theorem at the solution).
    """
    if not isinstance(shape, (BSplineCurve, BSplineSurface)):
        raise TypeError(f"shape: expected a BSplineCurve or BSplineSurface, got {type(shape).__name__}")
    max_steps = _checks.check_count(max_steps, "max_steps")
    if isinstance(constraints, (AbstractConstraint, AbstractNonlinear)):
        constraints = (constraints,)
    if not isinstance(constraints, (list, tuple)) or not constraints:
        _checks.fail("constraints", "a non-empty list of constraints", _describe(constraints))
    plans = []
    for i, c in enumerate(constraints):
        name = f"constraints[{i}]"
        if isinstance(c, AbstractNonlinear):
            plans.append(c.prepare(shape, name))
        elif isinstance(c, AbstractConstraint):
            u, v = checked_params(shape, c, name)
            rows = c.rows(shape, u, v)
            value = None if c.goal() is None else checked_value(shape, c, c.goal(), rows.shape[0], name)
            plans.append({"rows": rows, "b": c.rhs(c.aux(shape, rows, u, v), value)})
        else:
            raise TypeError(f"{name}: expected a sculpt constraint, got {type(c).__name__}")
    constraints = tuple(constraints)
    ctrl0 = flat_ctrl(shape)
    dim = ctrl0.shape[-1]
    scale = jnp.repeat(_column_scale(shape, free, metric, shape.ctrl.shape[:-1]), dim)

    def residuals(d, args):
        plans, ctrl0 = args
        ctrl = ctrl0 + d.reshape(ctrl0.shape)
        parts = []
        for c, plan in zip(constraints, plans):
            if isinstance(c, AbstractNonlinear):
                parts.append(c.residual(plan, ctrl))
            else:
                parts.append((plan["rows"] @ (ctrl - ctrl0) - plan["b"]).reshape(-1))
        return jnp.concatenate(parts)

    def jacobian_and_residuals(d, args):
        """`(J, c)` at `d` from one trace of `residuals` (its value is jacfwd's primal): a
        nonlinear constraint's foot-point search (`OnSurface`) is compiled once per use, not twice."""
        return jax.jacfwd(lambda x: (residuals(x, args),) * 2, has_aux=True)(d)

    def step(d, args):
        j, c = jacobian_and_residuals(d, args)
        return scale * (_pinv(j * scale[None, :]) @ (j @ d - c))

    eps = float(jnp.finfo(ctrl0.dtype).eps)
    solver = optx.FixedPointIteration(rtol=max(rtol, 10 * eps), atol=max(atol, 100 * eps))
    d0 = jnp.zeros(ctrl0.size, ctrl0.dtype)
    args = (plans, ctrl0)
    sol = optx.fixed_point(step, solver, d0, args, max_steps=max_steps, throw=False)
    d = sol.value
    j, c_end = jacobian_and_residuals(d, args)
    j, c_start = jax.lax.stop_gradient(j), residuals(d0, args)
    residual = _safe.norm(c_end)
    met = residual <= np.sqrt(eps) * (1.0 + _safe.norm(c_start))
    converged = sol.result == optx.RESULTS.successful
    status = jnp.where(met, 0, jnp.where(converged, 1, 2)).astype(jnp.int32)
    return Edit(
        shape=shape.with_ctrl(shape.ctrl + d.reshape(shape.ctrl.shape)),
        displacement=d.reshape(shape.ctrl.shape),
        residual=residual,
        rank=_rank(j * scale[None, :]),
        status=status,
    )
