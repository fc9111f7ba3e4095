"""Closest-point projection of points onto a B-spline surface (projected Gauss–Newton).

One implementation serves the merge's deviation report (thesis App. A: points of the originals
projected onto the merged surface), the parameter-correction step of the nonlinear refit, and
anything else that needs foot points (collision, sculpting, file import). For every point x the
foot-point parameters minimise `|S(u, v) − x|²` (the point-inversion problem of "The NURBS Book"
§6.1): Gauss–Newton with 2 unknowns and 3 residuals per point, all points of a call as one
batched iteration (`jax.lax.while_loop` until every point has met the tolerances or `max_steps`).
A step is `δ = (JᵀJ)⁺ Jᵀ r` with `J = [S_u, S_v]` from the derivative rows of the blending
matrices, the 2×2 pseudo-inverse in closed form (`_pinv_step`). Hand-written rather than
`optimistix.least_squares`: the same iteration, without the generic solver's tracing (≈ 3 s per
program, most of the first call of everything that projects).

* A clamped direction keeps its domain [0, 1] by evaluating `S` at the clamped parameter: once a
  parameter lies beyond a bound its column of the Jacobian is zero, and the pseudo-inverse step
  slides the point along that edge (a projected Gauss–Newton step; clipping the whole step would
  stall the other coordinate too). A periodic direction is not clamped: its basis takes the
  parameter modulo 1, so the iteration crosses the seam freely.
* A point has converged (optimistix's Cauchy test) when its step is below `atol + rtol·|uv|`
  (max norms) and its objective `½|r|²` changed by less than `atol + rtol·½|r|²`.
* Without starting parameters the search is global: the surface is sampled on a parameter grid,
  and Gauss–Newton runs from several samples of each point — the nearest, then the nearest
  outside the neighbourhoods of those taken; the best result is kept. One start is not
  enough: on a surface that closes on itself (a cylinder merged from patches, whose edges
  u = 0 and u = 1 coincide) the nearest sample may lie across the seam, where the
  domain-clamped iteration cannot reach the foot point.

The result is not differentiated through (a while loop): the foot points are an input of what
follows (`jax.lax.stop_gradient` them where a gradient flows past).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax.basis import _tensor
from bsjax.basis._surface import BSplineSurface


class ProjectionSolver(eqx.Module):
    """Settings of the closest-point projection.

    **Fields:** `rtol`, `atol`: termination tolerances on the parameter step and the objective
    (optimistix's Cauchy test; raised to `10 eps` / `100 eps` of the working dtype);
    `max_steps`: Gauss–Newton steps per start (a few suffice from a good start: a nearby grid
    sample, or the previous round's parameters in the merge refit).
    """

    rtol: float = eqx.field(static=True, default=1e-10)
    atol: float = eqx.field(static=True, default=1e-12)
    max_steps: int = eqx.field(static=True, default=8)

    def __check_init__(self):
        for name in ("rtol", "atol"):
            _checks.positive(getattr(self, name), name, strict=False)
        _checks.check_count(self.max_steps, "max_steps")

    def tolerances(self, dtype) -> tuple[float, float]:
        """`(rtol, atol)` raised to what `dtype` can resolve."""
        eps = float(jnp.finfo(dtype).eps)
        return max(self.rtol, 10 * eps), max(self.atol, 100 * eps)


class Projection(eqx.Module):
    """Result of `closest_points`.

    **Fields:** `params (N, 2)` foot-point parameters in [0, 1]² (a periodic direction's in
    [0, 1)); `distances (N,)`; `result (N,)`: optimistix `RESULTS` per point (`successful`, or
    `max_steps_reached` where a point did not meet the tolerances within `max_steps` — its
    parameters are still the best found, never worse than the start).
    """

    params: Float[Array, "N 2"]
    distances: Float[Array, " N"]
    result: optx.RESULTS


# --- the iteration --------------------------------------------------------------------------
def _domain(surface: BSplineSurface, uv):
    """`uv` brought into the domain: clamped to [0, 1] along a clamped direction, modulo 1 along
    a periodic one (where the basis wraps anyway)."""
    periodic = jnp.asarray([surface.periodic_u, surface.periodic_v])
    return jnp.where(jnp.broadcast_to(periodic, uv.shape), jnp.mod(uv, 1.0), jnp.clip(uv, 0.0, 1.0))


def _points(surface: BSplineSurface, u, v):
    """`S(u_a, v_a)` for `(k,)` parameters in the domain (the kernel: no value checks)."""
    net = _tensor.homogeneous(surface.ctrl, surface.weights)
    h = _tensor.pointwise(surface.direction_u.matrix(u), net, surface.direction_v.matrix(v))
    return h if surface.weights is None else h[:, :-1] / h[:, -1:]


def _with_tangents(surface: BSplineSurface, uv):
    """`S, S_u, S_v`, each `(M, 3)`, at `uv (M, 2)` brought into the domain (a NURBS through its
    homogeneous map, `_tensor.rational_derivatives`)."""
    uv = _domain(surface, uv)
    a_u = surface.direction_u.matrices(uv[:, 0], (0, 1))
    a_v = surface.direction_v.matrices(uv[:, 1], (0, 1))
    net = _tensor.homogeneous(surface.ctrl, surface.weights)
    h = {(k, l): _tensor.pointwise(a_u[k], net, a_v[l]) for k, l in ((0, 0), (1, 0), (0, 1))}
    if surface.weights is None:
        return [h[(0, 0)], h[(1, 0)], h[(0, 1)]]
    along_u = _tensor.rational_derivatives({kl: h[kl] for kl in ((0, 0), (1, 0))}, 1, 0)
    along_v = _tensor.rational_derivatives({kl: h[kl] for kl in ((0, 0), (0, 1))}, 0, 1)
    return [along_u[(0, 0)], along_u[(1, 0)], along_v[(0, 1)]]


def _pinv_step(su, sv, r):
    """`(JᵀJ)⁺ Jᵀ r` for `J = [su, sv]` (`(M, 3)` columns), `(M, 2)`, in closed form. Rank 2: the
    2×2 normal equations (Cramer); rank 1 (a zero column where a parameter is clamped, or
    parallel tangents at a pole): `(JᵀJ)⁺ = JᵀJ / tr(JᵀJ)²`; rank 0: no step."""
    p, q, t = jnp.sum(su * su, -1), jnp.sum(su * sv, -1), jnp.sum(sv * sv, -1)
    g0, g1 = jnp.sum(su * r, -1), jnp.sum(sv * r, -1)
    det = p * t - q * q
    eps, tiny = jnp.finfo(r.dtype).eps, jnp.finfo(r.dtype).tiny
    full = det > 1e3 * eps * p * t
    safe_det = jnp.where(full, det, 1.0)  # double where: singular systems take the rank-1 branch
    x_full = jnp.stack([t * g0 - q * g1, p * g1 - q * g0], -1) / safe_det[:, None]
    trace = p + t
    some = trace > tiny
    scale = jnp.where(some, 1.0 / jnp.where(some, trace, 1.0) ** 2, 0.0)
    x_rank1 = jnp.stack([p * g0 + q * g1, q * g0 + t * g1], -1) * scale[:, None]
    return jnp.where(full[:, None], x_full, x_rank1)


def _gauss_newton(surface: BSplineSurface, x, uv0, solver: ProjectionSolver):
    """Gauss–Newton from `uv0 (M, 2)` towards the foot points of `x (M, 3)`, all points at once;
    a point stops when it meets the tolerances (module docstring). Each iterate's distance is
    evaluated (the step after the last one too), and the nearest iterate is kept: there is no
    line search, so a step may overshoot, but no point ends farther than its start.

    **Returns:** `(uv (M, 2) in the domain, distances (M,), converged (M,))`."""
    rtol, atol = solver.tolerances(uv0.dtype)
    periodic = jnp.asarray([surface.periodic_u, surface.periodic_v])

    def cond(carry):
        *_, done, i = carry
        return (i <= solver.max_steps) & ~jnp.all(done)

    def body(carry):
        uv, best_uv, best_f, f_prev, done, i = carry
        s, su, sv = _with_tangents(surface, uv)
        r = s - x
        f = 0.5 * jnp.sum(r * r, -1)
        nearer = f < best_f  # False for a non-finite iterate
        best_uv, best_f = jnp.where(nearer[:, None], uv, best_uv), jnp.where(nearer, f, best_f)
        inside = periodic[None, :] | ((uv >= 0.0) & (uv <= 1.0))  # a column beyond a clamped bound is zero
        delta = _pinv_step(jnp.where(inside[:, :1], su, 0.0), jnp.where(inside[:, 1:], sv, 0.0), r)
        small = jnp.max(jnp.abs(delta), -1) < atol + rtol * jnp.max(jnp.abs(uv), -1)
        done = done | (small & (jnp.abs(f - f_prev) < atol + rtol * f))
        step = jnp.where(done[:, None] | (i == solver.max_steps), 0.0, delta)
        return uv - step, best_uv, best_f, f, done, i + 1

    inf = jnp.full(uv0.shape[:1], jnp.inf, uv0.dtype)
    carry = (uv0, uv0, inf, inf, jnp.zeros(uv0.shape[:1], bool), jnp.asarray(0))
    _, uv, f, _, done, _ = jax.lax.while_loop(cond, body, carry)
    return _domain(surface, uv), jnp.sqrt(2.0 * f), done


def _project(surface: BSplineSurface, points, uv_starts, solver: ProjectionSolver):
    """The best foot point of each of `points (N, 3)` from its starts `uv_starts (N, k, 2)`:
    Gauss–Newton from every start, the nearest result kept."""
    n, k, _ = uv_starts.shape
    uv, dist, converged = _gauss_newton(
        surface, jnp.repeat(points, k, axis=0), uv_starts.reshape(n * k, 2), solver
    )
    uv, dist, converged = uv.reshape(n, k, 2), dist.reshape(n, k), converged.reshape(n, k)
    best = jnp.argmin(dist, axis=1)
    pick = jnp.arange(n)
    result = jax.vmap(
        lambda ok: optx.RESULTS.where(ok, optx.RESULTS.successful, optx.RESULTS.max_steps_reached)
    )(converged[pick, best])
    return Projection(params=uv[pick, best], distances=dist[pick, best], result=result)


# --- starting parameters --------------------------------------------------------------------
def candidate_count(surface: BSplineSurface) -> int:
    """Default size of the starting grid: `4·max(r, s) + 1`, between 33 and 129."""
    return int(np.clip(4 * max(surface.shape) + 1, 33, 129))


def _grid(count: int, periodic: bool, dtype):
    # a periodic direction's samples at 0 and 1 are the same point: sample [0, 1) only
    return jnp.linspace(0.0, 1.0, count, endpoint=not periodic, dtype=dtype)


def nearest_samples(surface: BSplineSurface, points, count: int, starts: int, chunk: int = 256):
    """Parameters `(N, starts, 2)` of starting samples on a `count × count` parameter grid: for
    each point the nearest sample, then the nearest outside the ±2-cell neighbourhoods of those
    already taken (a start next to another adds nothing; one across a seam or a fold does). In
    chunks of points, so memory stays `chunk × count²`."""
    gu = _grid(count, surface.periodic_u, points.dtype)
    gv = _grid(count, surface.periodic_v, points.dtype)
    cu, cv = (x.reshape(-1) for x in jnp.meshgrid(gu, gv, indexing="ij"))
    samples = _points(surface, cu, cv)
    c2 = jnp.sum(samples**2, -1)
    iu, iv = jnp.divmod(jnp.arange(count * count), count)
    n = points.shape[0]
    pad = (-n) % chunk
    padded = jnp.concatenate([points, jnp.zeros((pad, 3), points.dtype)]).reshape(-1, chunk, 3)

    def block(p):
        score = 2.0 * p @ samples.T - c2[None, :]  # −|x − c|² up to |x|², common to a row
        found = []
        for _ in range(starts):  # argmax passes: lax.top_k sorts, ~200× slower on CPU
            best = jnp.argmax(score, axis=1)
            found.append(best)
            near = (jnp.abs(iu[None, :] - iu[best][:, None]) <= 2) & (
                jnp.abs(iv[None, :] - iv[best][:, None]) <= 2
            )
            score = jnp.where(near, -jnp.inf, score)
        return jnp.stack(found, axis=1)

    idx = jax.lax.map(block, padded).reshape(-1, starts)[:n]
    return jnp.stack([cu[idx], cv[idx]], -1)


# --- public ---------------------------------------------------------------------------------
def _check_points(points, name: str = "points"):
    _checks.check_real(points, name)
    _checks.check_ndim(points, name, 2, last=3)
    return _checks.finite(points, name)


@compiled
def closest_points(
    surface: BSplineSurface,
    points: Float[Array, "N 3"],
    uv0: Float[Array, "N 2"] | None = None,
    solver: ProjectionSolver = ProjectionSolver(),
    candidates: int | None = None,
    starts: int = 2,
) -> Projection:
    """Closest-point parameters of `points` on `surface` ("The NURBS Book" §6.1, point inversion).

    Minimises `|S(u, v) − x|²` per point (Gauss–Newton, all points as one batched iteration; a
    clamped direction kept in [0, 1], a periodic one wrapping; module docstring). The better of
    the start and the result is kept, so no point gets farther than its start.

    **Arguments:**
    - `surface`: a `BSplineSurface` (clamped or periodic directions, NURBS or not).
    - `points (N, 3)`: finite points, in the surface's dtype.
    - `uv0 (N, 2)` or `None`: starting parameters (in [0, 1]) for a local search; `None` for a
      global one: a `candidates × candidates` parameter grid (default `4·max(r, s) + 1`, 33…129)
      and Gauss–Newton from `starts` samples of each point (the nearest, then the nearest away
      from those taken: `nearest_samples`), the best kept.
    - `solver`: a `ProjectionSolver` (tolerances, steps per start).

    **Returns:** a `Projection` (parameters, distances, per-point status). Compiled once per
    surface shape, point count and options.
    """
    if not isinstance(surface, BSplineSurface):
        raise TypeError(f"surface: expected a BSplineSurface, got {type(surface).__name__}")
    if not isinstance(solver, ProjectionSolver):
        raise TypeError(f"solver: expected a ProjectionSolver, got {type(solver).__name__}")
    points = _check_points(points).astype(surface.ctrl.dtype)
    if uv0 is None:
        count = (
            candidate_count(surface)
            if candidates is None
            else _checks.check_count(candidates, "candidates", 2)
        )
        k = min(_checks.check_count(starts, "starts"), count * count)
        uv_starts = nearest_samples(surface, points, count, k)
    else:
        _checks.check_ndim(uv0, "uv0", 2, last=2)
        if uv0.shape[0] != points.shape[0]:
            _checks.fail("uv0", f"one start per point, shape ({points.shape[0]}, 2)", uv0.shape)
        uv_starts = _checks.in_range(uv0.astype(points.dtype), "uv0", 0.0, 1.0)[:, None]
    return _project(surface, points, uv_starts, solver)


@compiled
def project(
    surface: BSplineSurface,
    points: Float[Array, "N 3"],
    uv0: Float[Array, "N 2"] | None = None,
    steps: int = 8,
) -> Float[Array, "N 2"]:
    """Closest-point parameters of `points` on `surface` from `uv0` (or a global search when
    `None`), with at most `steps` Gauss–Newton steps per start (`closest_points` with
    `ProjectionSolver(max_steps=steps)`).

    **Returns:** `(N, 2)` parameters in [0, 1]².
    """
    steps = _checks.check_count(steps, "steps")
    return closest_points(surface, points, uv0, ProjectionSolver(max_steps=steps)).params
