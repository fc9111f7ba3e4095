"""Nonlinear refit with parameter correction — beyond the thesis.

The linear merge (eq. 3.7) gives every sample x_a a fixed parameter: patch i's grid scaled into
its segment of the merged domain. With unequal edge lengths or dissimilar curvature those
parameters are poor and the least-squares surface is pulled along the seam. The refit minimises
the squared point-to-surface distance of the samples — what the deviation report measures —
over the control net P *and* the sample parameters,

    min_{P, (u_a, v_a) ∈ [0,1]²}  Σ_a |S(u_a, v_a; P) − x_a|²,

by alternating the two exact sub-problems (Hoschek's parameter correction, a block coordinate
descent):

1. parameters: every sample's foot point on the current surface, from its previous parameters
   (Gauss–Newton, 2 unknowns per sample, clamped to the domain; `bsjax.basis.closest_points`,
   the projection the deviation report uses);
2. net: the linear least-squares problem `K P ≈ X`, `K[a, (i, j)] = B_i(u_a) B_j(v_a)`, solved
   through its normal equations (Cholesky, a relative ridge of `1e3 eps` towards the previous
   net keeps a basis function without samples from going singular).

Neither half step can raise the objective, so the RMS distance falls monotonically; the loop
stops when a round lowers it by less than `rtol` (relative) or after `rounds` rounds. Seam knots
are kept, so the continuity asked for is kept. `refit` and `refine` are compiled at the public
boundary: one XLA call, compiled once per (layout shape, rounds, projection settings); `rtol` is
traced, so a new tolerance does not compile again. The linear layout's fit is the start.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

from bsjax import _checks, batch
from bsjax._boundary import compiled
from bsjax._declared import check_fields
from bsjax.basis import BSplineSurface, ProjectionSolver, closest_points


class RefitSolver(eqx.Module):
    """Settings of the nonlinear refit.

    **Fields:**
    - `rounds`: at most this many (projection, net) rounds.
    - `rtol`: stop when a round lowers the RMS sample distance by less than this fraction.
    - `projection`: the `ProjectionSolver` of the parameter step (a few Gauss–Newton steps per
      round: each round starts from the previous parameters).
    """

    rounds: int = eqx.field(static=True, default=8)
    rtol: float = 1e-2  # a leaf: traced by the compiled boundary, a new value does not recompile
    projection: ProjectionSolver = eqx.field(static=True, default=ProjectionSolver(max_steps=3))

    def __check_init__(self):
        check_fields(self)
        _checks.check_count(self.rounds, "rounds")
        _checks.positive(self.rtol, "rtol", strict=False)


class RefitSolution(eqx.Module):
    """Result of `refit`.

    **Fields:**
    - `ctrl (r, s, 3)`: the merged control net on the layout's basis.
    - `params (N, 2)`: the corrected sample parameters (row-major over the combined grid).
    - `rms (rounds + 1,)`: RMS sample distance of the linear fit and after each round (NaN for
      rounds not run); non-increasing.
    - `rounds`: rounds run.
    - `result`: `optx.RESULTS.successful` when the RMS settled within `rtol`,
      `optx.RESULTS.max_steps_reached` when `rounds` ran out first.
    - `projection_result (N,)`: per-sample status of the last projection.
    """

    ctrl: Float[Array, "r s 3"]
    params: Float[Array, "N 2"]
    rms: Float[Array, " R"]
    rounds: Int[Array, ""]
    result: optx.RESULTS
    projection_result: optx.RESULTS


def collocation(surface: BSplineSurface, uv: Float[Array, "N 2"]) -> Float[Array, "N rs"]:
    """Rows `B_i(u_a) B_j(v_a)` of the scattered-data least-squares system, `(N, r·s)`."""
    bu = surface.rows("u", uv[:, 0])
    bv = surface.rows("v", uv[:, 1])
    return (bu[:, :, None] * bv[:, None, :]).reshape(uv.shape[0], -1)


def _band_indices(r: int, k: int, s: int, l: int):
    """Static index pairs of the normal matrix entries `((i, j), (i + d, j + e))`, `0 ≤ d ≤ k`,
    `|e| ≤ l`, held by the band products of `normal_matrix`, and where they sit in them."""
    i, d, j, e = np.meshgrid(
        np.arange(r), np.arange(k + 1), np.arange(s), np.arange(-l, l + 1), indexing="ij"
    )
    keep = (i + d < r) & (j + e >= 0) & (j + e < s)
    rows, cols = (i * s + j)[keep], ((i + d) * s + j + e)[keep]
    flat = np.ravel_multi_index((i[keep], d[keep], j[keep], e[keep] + l), (r, k + 1, s, 2 * l + 1))
    return rows, cols, flat


def normal_matrix(bu: Float[Array, "N r"], bv: Float[Array, "N s"], k: int, l: int) -> Float[Array, "rs rs"]:
    """`KᵀK` of the collocation matrix `K[a, (i, j)] = bu[a, i] bv[a, j]` of degrees `(k, l)`.

    `KᵀK[(i, j), (i', j')] = Σ_a bu_ai bu_ai' bv_aj bv_aj'` is zero unless `|i − i'| ≤ k` and
    `|j − j'| ≤ l`: one matrix product of the band products `bu_ai bu_a(i+d)` (`0 ≤ d ≤ k`) and
    `bv_aj bv_a(j+e)` (`|e| ≤ l`), `N·r(k+1)·s(2l+1)` flops instead of `N·(rs)²`, then placed.
    """
    n, r = bu.shape
    s = bv.shape[1]
    pu = jnp.pad(bu, ((0, 0), (0, k)))
    pv = jnp.pad(bv, ((0, 0), (l, l)))
    u2 = jnp.stack([bu * pu[:, d : d + r] for d in range(k + 1)], -1)  # (N, r, k+1)
    v2 = jnp.stack([bv * pv[:, e : e + s] for e in range(2 * l + 1)], -1)  # (N, s, 2l+1)
    g = (u2.reshape(n, -1).T @ v2.reshape(n, -1)).reshape(r, k + 1, s, 2 * l + 1)
    rows, cols, flat = _band_indices(r, k, s, l)
    vals = g.reshape(-1)[flat]
    return jnp.zeros((r * s, r * s), bu.dtype).at[rows, cols].set(vals).at[cols, rows].set(vals)


def fit_scattered(
    surface: BSplineSurface, uv: Float[Array, "N 2"], points: Float[Array, "N 3"], ridge: float | None = None
) -> tuple[Float[Array, "r s 3"], Float[Array, " N"]]:
    """Least-squares control net of `surface`'s basis through `points` at parameters `uv`.

    Normal equations `(KᵀK + μI) P = KᵀX + μ P₀` (Cholesky) with `K` the collocation matrix,
    `P₀ = surface.ctrl` and `μ = ridge` times the mean diagonal of `KᵀK` (default `1e3 eps`):
    the plain least-squares net wherever the samples determine it, the old net where they do
    not. `KᵀK` is built from its bands (`normal_matrix`).

    **Returns:** `(net (r, s, 3), distances (N,))`: the net and `|S(u_a, v_a) − x_a|` with it.
    """
    bu = surface.rows("u", uv[:, 0])
    bv = surface.rows("v", uv[:, 1])
    a = normal_matrix(bu, bv, surface.degree_u, surface.degree_v)
    n = a.shape[0]
    mu = (1e3 * jnp.finfo(a.dtype).eps if ridge is None else ridge) * jnp.trace(a) / n
    rhs = jnp.einsum("ai,aj,ac->ijc", bu, bv, points).reshape(n, 3)
    factor = jax.scipy.linalg.cho_factor(a + mu * jnp.eye(n, dtype=a.dtype))
    ctrl = jax.scipy.linalg.cho_solve(factor, rhs + mu * surface.ctrl.reshape(n, 3)).reshape(
        surface.shape + (3,)
    )
    fitted = jnp.einsum("ai,ijc,aj->ac", bu, ctrl, bv)
    return ctrl, jnp.linalg.norm(fitted - points, axis=-1)


def _rms(distances):
    return jnp.sqrt(jnp.mean(distances**2))


def _settled(hist, i, rtol):
    """The last round lowered the RMS distance by at most `rtol` of its value."""
    prev, now = hist[jnp.maximum(i - 1, 0)], hist[i]
    return (i > 0) & (prev - now <= rtol * prev)


def _refit(
    surface: BSplineSurface,
    points: Float[Array, "N 3"],
    uv0: Float[Array, "N 2"],
    rms0: Float[Array, ""],
    rtol: Float[Array, ""],
    rounds: int,
    projection: ProjectionSolver,
    progress: Callable[[int, int], object] | None = None,
) -> RefitSolution:
    # rtol is traced (changing it does not recompile); rounds fixes the history's length
    history = jnp.full((rounds + 1,), jnp.nan, points.dtype).at[0].set(rms0)
    status0 = jax.vmap(lambda _: optx.RESULTS.successful)(uv0)

    def cond(carry):
        _, _, hist, i, _ = carry
        return (i < rounds) & ~_settled(hist, i, rtol)

    def body(carry):
        ctrl, uv, hist, i, _ = carry
        # no value checks in the loop body (`_checks.trusted`: the entry checked the values, and
        # a check in a loop body is a host callback, which keeps the program off the disk cache)
        current = eqx.tree_at(lambda s: s.ctrl, surface, ctrl)
        with _checks.trusted():
            proj = closest_points(current, points, uv, projection)
        ctrl, d = fit_scattered(current, proj.params, points)
        batch.report_progress(progress, i + 1, rounds, after=ctrl)
        return ctrl, proj.params, hist.at[i + 1].set(_rms(d)), i + 1, proj.result

    carry = (surface.ctrl, uv0, history, jnp.asarray(0), status0)
    ctrl, uv, hist, i, status = jax.lax.while_loop(cond, body, carry)
    result = optx.RESULTS.where(
        _settled(hist, i, rtol), optx.RESULTS.successful, optx.RESULTS.max_steps_reached
    )
    return RefitSolution(ctrl=ctrl, params=uv, rms=hist, rounds=i, result=result, projection_result=status)


def _check_layout(layout) -> None:
    # a MergeLayout, known by what this module uses of it (its module imports this one)
    if not all(hasattr(layout, a) for a in ("points", "merged", "grid_shape")):
        _checks.fail("layout", "a MergeLayout from merge.plan or merge.plan_grid", type(layout).__name__)


@compiled
def refit(
    layout, ctrls, solver: RefitSolver = RefitSolver(), progress: Callable[[int, int], object] | None = None
) -> RefitSolution:
    """Merged control net with parameter correction, starting from the linear merge.

    **Arguments:**
    - `layout`: a `MergeLayout` from `plan`/`plan_grid`.
    - `ctrls`: the input control nets, as for `layout.apply` (finite).
    - `solver`: a `RefitSolver` (rounds ≥ 1, tolerance `rtol` ≥ 0, projection settings).
    - `progress`: an optional callback `progress(done, solver.rounds)` called on the host after
      each round as the refit runs (`bsjax.batch.report_progress`, an ordered `jax.debug.callback`; a
      refit that settles early stops reporting before `solver.rounds`); the result is the same.
      A callable is static (the same callback reuses the compilation); None adds nothing.

    **Returns:** a `RefitSolution` (net, corrected parameters, RMS history, status). Compiled at
    the boundary (one XLA call per direct call).
    """
    if not isinstance(solver, RefitSolver):
        raise TypeError(f"solver: expected a RefitSolver, got {type(solver).__name__}")
    _checks.check_progress(progress)
    _checks.check_count(solver.rounds, "solver.rounds")
    _check_layout(layout)
    points = layout.points(ctrls)
    pu, pv = layout.merged.params_u, layout.merged.params_v
    uv = jnp.stack(jnp.meshgrid(pu, pv, indexing="ij"), -1).reshape(-1, 2)
    ctrl = layout.merged.refit(points)
    # the linear fit's RMS at the grid parameters, with the stored blending matrices
    rms0 = _rms(jnp.linalg.norm(layout.merged.points(ctrl) - points, axis=-1))
    rtol = _checks.positive(
        _checks.array(solver.rtol, "solver.rtol", points.dtype), "solver.rtol", strict=False
    )
    return _refit(
        layout.surface(ctrl),
        points.reshape(-1, 3),
        uv,
        rms0,
        rtol,
        solver.rounds,
        solver.projection,
        progress,
    )


@compiled
def refine(
    layout,
    ctrls,
    iterations: int = 8,
    steps: int = 3,
    progress: Callable[[int, int], object] | None = None,
) -> Float[Array, "r s 3"]:
    """Control net of `refit(layout, ctrls, RefitSolver(rounds=iterations,
    projection=ProjectionSolver(max_steps=steps)), progress)` — the net alone
    (`merge(..., refine=True)`).

    **Returns:** `(r, s, 3)` control net on the layout's merged basis.
    """
    _check_layout(layout)
    iterations = _checks.check_count(iterations, "iterations")
    steps = _checks.check_count(steps, "steps")
    solver = RefitSolver(rounds=iterations, projection=ProjectionSolver(max_steps=steps))
    return refit(layout, ctrls, solver, progress).ctrl
