"""The minimum-norm displacement of control points under linear constraints (Fowler & Bartels,
*Constraint-based curve manipulation*; thesis *Interactive shape modeling and dynamic deformation
based on spline sculpting*, §6.1–6.2, eqs. 6-6…6-18).

With the constraint rows `F (K, N)` on the N control points and the right-hand sides
`b (K, d)`, the edit is the displacement of least (weighted) norm that meets `F d = b`:

    d = W⁻¹ Fᵀ (F W⁻¹ Fᵀ)⁻¹ b          (eqs. 6-8/6-9, with the diagonal metric W)

restricted to the free control points (blocked ones have d = 0). It is computed as
`d = W^{-1/2} (F W^{-1/2})⁺ b` with the SVD pseudo-inverse (blocked columns zeroed), which is the
same matrix when the rows are independent and is the minimum-norm least-squares solution when
they are not (over-constrained or rank-deficient sets): never an exception, never NaN. Singular
values below `10 · max(K, N) · eps · σ_max` count as zero (numpy's `matrix_rank` rule, ×10).
The matrix `C = W^{-1/2} (F W^{-1/2})⁺` depends on the shape and the parameters only, so an
interaction computes it once (`prefactor`) and each drag event is `d = C b` (thesis §6.1).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.sculpt._constraints import (
    AbstractConstraint,
    AlongNormal,
    Derivative,
    Displacement,
    Position,
    Shape,
    checked_params,
    checked_value,
)

SCHEMES = ("tensor", "separable")
_VALUE_NAME = {Position: "target", Displacement: "delta", AlongNormal: "amount"}


class Edit(eqx.Module):
    """Result of `min_norm`.

    **Fields:**
    - `shape`: the edited curve or surface (control points `P + d`).
    - `displacement`: `d`, shaped like the control points (`(n, d)` or `(r, s, 3)`).
    - `residual ()`: `‖F d − b‖₂` over all rows and coordinates.
    - `rank ()`: the number of independent scalar equations over all coordinates (the rank of
      the free columns of F times the dimension d).
    - `status ()`: 0 when every constraint is met (residual ≤ √eps · ‖b‖), 1 otherwise — an
      over-constrained or rank-deficient set with inconsistent targets, whose least-squares
      solution is returned.
    """

    shape: Shape
    displacement: Array
    residual: Float[Array, ""]
    rank: Int[Array, ""]
    status: Int[Array, ""]


class Factor(eqx.Module):
    """The solve of one interaction, computed once (`prefactor`): each drag event is `d = C b`.

    **Fields:** `shape` (the shape before the interaction), `constraints`, `solve_matrix (N, K)`
    (`C`), `rows (K, N)` (`F`), `aux` (per constraint, what its right-hand side needs: current
    points, derivatives or normals), `rank ()`.
    """

    shape: Shape
    constraints: tuple[AbstractConstraint, ...]
    solve_matrix: Float[Array, "N K"]
    rows: Float[Array, "K N"]
    aux: tuple[Array, ...]
    rank: Int[Array, ""]

    @compiled
    def drag(self, targets) -> Shape:
        """The shape after moving the constraints to new values, `P + C b` (one product).

        **Arguments:** `targets`: one new value per constraint in the constraints' order (a
        list/tuple, or an array whose leading axis runs over the constraints): a target point
        (`Position`), displacement (`Displacement`), derivative (`Derivative`) or amount
        (`AlongNormal`); `None` keeps the constraint's own value; ignored for `Fixed`.
        **Returns:** the new curve or surface.
        """
        b = self._rhs(targets)
        return _moved(self.shape, self.solve_matrix @ b)

    @compiled
    def edit(self, targets) -> Edit:
        """`drag` with the full report (`Edit`: displacement, residual, rank, status)."""
        b = self._rhs(targets)
        return _edit(self.shape, self.rows, self.solve_matrix, b, self.rank)

    def _rhs(self, targets):
        if targets is None:  # the constraints' own values (min_norm)
            targets = [None] * len(self.constraints)
            names = [
                f"constraints[{i}].{_VALUE_NAME.get(type(c), 'value')}"
                for i, c in enumerate(self.constraints)
            ]
        else:
            names = [f"targets[{i}]" for i in range(len(self.constraints))]
        if len(targets) != len(self.constraints):
            _checks.fail("targets", f"one value per constraint ({len(self.constraints)})", len(targets))
        parts = []
        for i, (c, aux) in enumerate(zip(self.constraints, self.aux)):
            value = targets[i]
            value = c.goal() if value is None else value
            value = checked_value(self.shape, c, value, aux.shape[0], names[i])
            parts.append(c.rhs(aux, value))
        return jnp.concatenate(parts)


# --- public -----------------------------------------------------------------------------------
@compiled
def min_norm(
    shape: Shape,
    constraints: Sequence[AbstractConstraint],
    free: ArrayLike | None = None,
    metric: ArrayLike | None = None,
    *,
    scheme: str = "tensor",
) -> Edit:
    """The minimum-norm edit of a curve or surface that meets linear constraints.

    `d = W⁻¹Fᵀ(FW⁻¹Fᵀ)⁻¹b` over the free control points (Fowler & Bartels, *Constraint-based
    curve manipulation*; thesis *Interactive shape modeling and dynamic deformation based on
    spline sculpting* eqs. 6-6…6-15; the least-squares solution for over-constrained or
    rank-deficient sets: module docstring).

    **Arguments:**
    - `shape`: a `BSplineCurve` (`(n, d)` control points) or `BSplineSurface` (`(r, s, 3)`),
      NURBS weights allowed (held fixed).
    - `constraints`: a list of `Position`, `Displacement`, `Fixed`, `Derivative`, `AlongNormal`
      (parameters in [0, 1], values finite).
    - `free`: boolean mask `(n,)` / `(r, s)` of the control points that may move (default all).
    - `metric`: positive diagonal metric W `(n,)` / `(r, s)` (default 1): `Σ W_i ‖d_i‖²` is
      minimised, so a larger W makes a control point stiffer.
    - `scheme` (surfaces): `"tensor"`, the full solve over the tensor rows `B_i(u) B_j(v)`, or
      `"separable"`, the thesis's iso-curve scheme (§6.2.1, eqs. 6-17/6-18; `prefactor`).

    **Returns:** an `Edit(shape, displacement, residual, rank, status)`.
    """
    factor = _prefactor(shape, constraints, free, metric, scheme)
    b = factor._rhs(None)
    return _edit(factor.shape, factor.rows, factor.solve_matrix, b, factor.rank)


@compiled
def prefactor(
    shape: Shape,
    constraints: Sequence[AbstractConstraint],
    free: ArrayLike | None = None,
    *,
    metric: ArrayLike | None = None,
    scheme: str = "tensor",
) -> Factor:
    """The solve matrix `C` of an interaction, computed once (thesis §6.1: preprocessing
    `C = Fᵀ adj(F̂)/f̂`, then `d = C b` per drag event). Arguments as `min_norm`.

    Surfaces, `scheme="separable"` (thesis §6.2.1, eqs. 6-17/6-18): pass 1 solves each
    constraint on the iso-curve `v ↦ S(u_k, v)` (with every constraint at the same `u_k`; its
    control points are the column curves at `u_k`), pass 2 moves each column curve
    `u ↦ C_j(u)` so that it takes the new iso-curve values at all `u_k` (a curve solve per
    column, where `free` and `metric` apply). One constraint: exactly the tensor solve,
    `d_ij = a_i b_j δ / (‖a‖² ‖b‖²)`. Several constraints on distinct iso-curves are met; the
    displacement is not the tensor minimum. Polynomial surfaces, position rows and derivatives
    along v only.

    **Returns:** a `Factor`; `factor.drag(targets)` gives the new shape per event.
    """
    return _prefactor(shape, constraints, free, metric, scheme)


# --- kernels ----------------------------------------------------------------------------------
def _prefactor(shape, constraints, free, metric, scheme) -> Factor:
    if not isinstance(shape, (BSplineCurve, BSplineSurface)):
        raise TypeError(f"shape: expected a BSplineCurve or BSplineSurface, got {type(shape).__name__}")
    constraints = _checked_constraints(constraints)
    if scheme not in SCHEMES:
        _checks.fail("scheme", "'tensor' or 'separable'", repr(scheme))
    grid = shape.ctrl.shape[:-1]
    scale = _column_scale(shape, free, metric, grid)
    rows, aux, params = [], [], []
    for i, c in enumerate(constraints):
        u, v = checked_params(shape, c, f"constraints[{i}]")
        r = c.rows(shape, u, v)
        rows.append(r)
        aux.append(c.aux(shape, r, u, v))
        params.append((u, v))
    f = jnp.concatenate(rows)
    if scheme == "separable" and isinstance(shape, BSplineSurface):
        c_mat = _separable(shape, constraints, params, scale)
    else:
        c_mat = _tensor_solve(f, scale)
    rank = _rank(f * scale[None, :]) * shape.ctrl.shape[-1]
    return Factor(shape=shape, constraints=constraints, solve_matrix=c_mat, rows=f, aux=tuple(aux), rank=rank)


def _describe(constraints) -> str:
    """What came instead of a constraint list (an empty list reaches a compiled function as a
    traced array of shape (0,))."""
    if getattr(constraints, "shape", None) == (0,) or (
        isinstance(constraints, (list, tuple)) and not constraints
    ):
        return "an empty list"
    return type(constraints).__name__


def _checked_constraints(constraints) -> tuple[AbstractConstraint, ...]:
    if isinstance(constraints, AbstractConstraint):
        constraints = (constraints,)
    if not isinstance(constraints, (list, tuple)) or not constraints:
        _checks.fail("constraints", "a non-empty list of constraints", _describe(constraints))
    for i, c in enumerate(constraints):
        if not isinstance(c, AbstractConstraint):
            raise TypeError(
                f"constraints[{i}]: expected Position, Displacement, Fixed, Derivative or AlongNormal, "
                f"got {type(c).__name__}"
            )
    return tuple(constraints)


def _column_scale(shape, free, metric, grid) -> Float[Array, " N"]:
    """`mask · W^{-1/2}` per control point (0 for a blocked one)."""
    dtype = shape.ctrl.dtype
    scale = jnp.ones(grid, dtype)
    if metric is not None:
        _checks.check_real(metric, "metric")
        metric = jnp.asarray(metric, dtype)
        if metric.shape != grid:
            _checks.fail("metric", f"shape {grid}", metric.shape)
        scale = 1.0 / jnp.sqrt(_checks.positive(metric, "metric"))
    if free is not None:
        free = jnp.asarray(free)
        if free.shape != grid or free.dtype != jnp.bool_:
            _checks.fail("free", f"a boolean mask of shape {grid}", f"{free.dtype} {free.shape}")
        scale = jnp.where(free, scale, 0.0)
    return scale.reshape(-1)


def _tolerance(a) -> float:
    return 10.0 * max(a.shape) * float(jnp.finfo(a.dtype).eps)


def _pinv(a):
    """The SVD pseudo-inverse with the module's rank tolerance (differentiable: jnp's custom JVP)."""
    return jnp.linalg.pinv(a, rtol=_tolerance(a))


def _rank(a) -> Int[Array, ""]:
    """The number of singular values above the module's tolerance. The thin SVD is the one
    `jnp.linalg.pinv` computes, so XLA merges the two (one LAPACK call where `compute_uv=False`
    made a second one: −25 % on a 12 × 210 prefactor)."""
    s = jnp.linalg.svd(jax.lax.stop_gradient(a), full_matrices=False)[1]
    return jnp.sum(s > _tolerance(a) * s[0]).astype(jnp.int32)


def _tensor_solve(f, scale):
    """`C = S (F S)⁺` with `S = diag(mask · W^{-1/2})`: `(N, K)`."""
    return scale[:, None] * _pinv(f * scale[None, :])


def _separable(shape: BSplineSurface, constraints, params, scale):
    """The solve matrix `(N, K)` of the iso-curve scheme (see `prefactor`)."""
    if shape.weights is not None:
        _checks.fail(
            "scheme", "'tensor' for a rational surface ('separable' needs tensor rows)", "'separable'"
        )
    a_rows, b_rows = [], []
    for i, (c, (u, v)) in enumerate(zip(constraints, params)):
        order = 0
        if isinstance(c, Derivative):
            if c.direction == "u":
                _checks.fail(
                    f"constraints[{i}].direction", "'v' under scheme='separable' (or scheme='tensor')", "'u'"
                )
            order = c.order
        a_rows.append(shape.direction_u.matrix(u))
        b_rows.append(shape.direction_v.matrix(v, order))
    a, b = jnp.concatenate(a_rows), jnp.concatenate(b_rows)  # (K, r), (K, s)
    u_all = jnp.concatenate([p[0] for p in params])
    same = u_all[:, None] == u_all[None, :]  # constraints on one iso-curve solve together

    # pass 1: iso-curve k's control-point displacement e_k = pinv(b masked to its group) β: (K, s, K)
    e_map = jax.vmap(lambda mask: _pinv(jnp.where(mask[:, None], b, 0.0)))(same)
    # pass 2: column j meets e_{k, j} at every u_k: δP_{·j} = S_j pinv(a S_j) e_{·j}
    r, s = shape.shape
    col_scale = scale.reshape(r, s).T  # (s, r)
    g = jax.vmap(lambda sc: sc[:, None] * _pinv(a * sc[None, :]))(col_scale)  # (s, r, K)
    c_mat = jnp.einsum("jik,kjl->ijl", g, e_map)  # (r, s, K)
    return c_mat.reshape(r * s, -1)


def _moved(shape: Shape, d_flat) -> Shape:
    return shape.with_ctrl(shape.ctrl + d_flat.reshape(shape.ctrl.shape))


def _edit(shape: Shape, f, c_mat, b, rank) -> Edit:
    d = c_mat @ b
    residual = _safe.norm((f @ d - b).reshape(-1))
    size = _safe.norm(b.reshape(-1))
    status = (residual > np.sqrt(float(jnp.finfo(b.dtype).eps)) * size).astype(jnp.int32)
    return Edit(
        shape=_moved(shape, d),
        displacement=d.reshape(shape.ctrl.shape),
        residual=residual,
        rank=rank,
        status=status,
    )
