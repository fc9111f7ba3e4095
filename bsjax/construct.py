"""Surfaces from curves (thesis ch. 5, "surface interpreters"): ruled, extruded, revolved,
Coons-filled and lofted `BSplineSurface`s, exact where the construction is polynomial or rational;
swept, rail- and boundary-rotated ones (sections or one term fitted, returned with their error as
`SurfaceFit`); and the global interpolation of a point grid.

Every constructor first makes its curves *compatible* — one degree (raised by `elevate_degree`)
and one knot vector (the merged knots, inserted by `insert_knots`), the geometry unchanged
(The NURBS Book §10.3) — then builds the control net in closed form. The curve parameter is `u`
throughout; the constructed direction (across the curves, along the extrusion, around the axis)
is `v`. Planar curves (d = 2) lie in the plane z = 0 (except `revolve`, which reads them as
(radius, height) in the axial half-plane).

Knot vectors are planned on the host: the merged knots and the change-of-basis matrices are
cached by the curves' (degree, knots) and re-used (256 plans are kept;
`bsjax._boundary.clear_caches()` forgets them), so a direct call is one compiled XLA call. The plan
enters that call as an input, so curves with new knot values but the same degrees and counts (and
the same merged knot count) re-use the compilation.
Control points (and weights) may be traced: every constructor works under `jit`, `vmap` and
`grad` in the control points. Curves whose *knots* are traced (curves passed as arguments of
the caller's own `jit`) must already be compatible — same degree and control count, equal knots
(checked at run time); call `compatible` outside `jit` first otherwise. `sweep` and
`rail_rotation` read their curves by evaluation only (any knots, traced or not: one compilation
per degree, control count and section count); `interpolate_grid` compiles once per grid shape
and degree pair.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled, host_cache
from bsjax._declared import declared
from bsjax._typing import ArrayLike
from bsjax.basis import BSplineCurve, BSplineSurface, SplineDirection, change_of_basis

__all__ = [
    "SurfaceFit",
    "boundary_rotation",
    "compatible",
    "coons",
    "extrude",
    "interpolate_grid",
    "loft",
    "rail_rotation",
    "revolve",
    "ruled",
    "sweep",
]

_TWO_PI = 2.0 * math.pi
_LINEAR = (0.0, 0.0, 1.0, 1.0)  # the clamped degree-1 knot vector of two control points


# --- compatibility: host-side plan --------------------------------------------------------------
class _Plan(NamedTuple):
    """How to bring curves to one basis: the common `direction`, one change-of-basis matrix per
    curve (`None`: already in it), and whether the curves' (traced) knots must be checked equal."""

    direction: SplineDirection
    transforms: tuple
    check_equal: bool


class _FixedPlan(eqx.Module):
    """A cached plan of concrete knots: the merged direction and each curve's change-of-basis
    matrix (`None`: already in the merged basis). A pytree whose knots and matrices are *inputs*
    of the compiled kernels, so a new knot configuration with the same counts (a new
    chord-parametrised stroke, say) re-uses the compilation; only the host-side planning (numpy,
    cached by the knot values) runs again."""

    direction: SplineDirection
    transforms: tuple
    check_equal: bool = eqx.field(static=True, default=False)


_AnyPlan = _Plan | _FixedPlan


def _check_curves(curves, names: Sequence[str]) -> None:
    for curve, name in zip(curves, names):
        if not isinstance(curve, BSplineCurve):
            raise TypeError(f"{name}: expected a BSplineCurve, got {type(curve).__name__}")


def _plan(curves: Sequence[BSplineCurve], names: Sequence[str]) -> _AnyPlan:
    """The compatibility plan of `curves` (structure checked; cached by degrees and knots)."""
    _check_curves(curves, names)
    directions = [c.direction for c in curves]  # (equinox attribute reads are slow: read once)
    if any(d.periodic for d in directions):
        _same_structure(curves, names, "periodic curves of one degree and control count (the uniform "
                        "closed basis cannot be refined)")  # fmt: skip
        return _Plan(directions[0], (None,) * len(curves), False)
    knots = [d.knots for d in directions]
    if not _checks.is_concrete(knots):
        _same_structure(curves, names, "curves of one degree and control count when their knots are "
                        "traced inside jit (call bsjax.construct.compatible outside jit first)")  # fmt: skip
        return _Plan(directions[0], (None,) * len(curves), True)
    key = tuple((d.degree, np.asarray(k, np.float64).tobytes()) for d, k in zip(directions, knots))
    return _cached_plan(knots[0].dtype.name, key)


def _same_structure(curves, names, expected: str) -> None:
    first = curves[0]
    for curve, name in zip(curves[1:], names[1:]):
        same = (curve.periodic, curve.degree, curve.n_ctrl) == (first.periodic, first.degree, first.n_ctrl)
        if not same:
            got = f"{'periodic' if curve.periodic else 'clamped'} degree {curve.degree}, {curve.n_ctrl} "
            _checks.fail(name, f"{expected}, like {names[0]}", got + "control points")


@host_cache(maxsize=256)
def _cached_plan(dtype: str, key: tuple) -> _FixedPlan:
    """Merged knots (every knot value at its largest multiplicity after raising all curves to the
    highest degree) and each curve's change-of-basis matrix `T` (`P_new = T P_old`), computed on
    concrete values also inside a caller's `jit` (`ensure_compile_time_eval`)."""
    with jax.ensure_compile_time_eval():
        return _merged_plan(dtype, key)


def _merged_plan(dtype: str, key: tuple) -> _FixedPlan:
    degrees = [degree for degree, _ in key]
    knot_vectors = [np.frombuffer(raw, np.float64) for _, raw in key]
    degree = max(degrees)
    values = np.unique(np.concatenate(knot_vectors))
    multiplicity = np.zeros(values.shape, int)
    for knots, own in zip(knot_vectors, degrees):
        found, counts = np.unique(knots, return_counts=True)
        where = np.searchsorted(values, found)
        multiplicity[where] = np.maximum(multiplicity[where], counts + degree - own)
    target = np.repeat(values, multiplicity)
    transforms = tuple(
        _transform(knots, own, degree, target, dtype) for knots, own in zip(knot_vectors, degrees)
    )
    return _FixedPlan(SplineDirection(jnp.asarray(target, dtype), degree), transforms)


def _transform(knots, degree: int, target_degree: int, target, dtype):
    """`T (n_new, n_old)` taking control points in the basis (knots, degree) to the target basis
    (`bsjax.basis.change_of_basis`, exact here: the target space contains the old one), or
    `None` when the bases are equal."""
    if degree == target_degree and knots.shape == target.shape and np.array_equal(knots, target):
        return None
    old, new = SplineDirection(knots, degree), SplineDirection(target, target_degree)
    return jnp.asarray(change_of_basis(old, new), dtype)


# --- compatibility: traced part -----------------------------------------------------------------
class _Part(NamedTuple):
    """What the compiled kernels need of a curve (fewer leaves to pass than the whole module):
    its control points and weights, and its knots only when they must be checked equal."""

    ctrl: Array
    weights: Array | None
    knots: Array | None


def _parts(curves, plan: _AnyPlan) -> tuple[_Part, ...]:
    return tuple(_Part(c.ctrl, c.weights, c.knots if plan.check_equal else None) for c in curves)


def _homogeneous(part: _Part, transform, plan: _AnyPlan, name: str) -> Float[Array, "n 4"]:
    """The curve's control points in the common basis as a homogeneous 3-D net `[w P, w]`
    (planar curves at z = 0; weight 1 for polynomial curves)."""
    ctrl = part.ctrl
    if part.knots is not None:
        expected = "the knot vector of the first curve (compatible curves under jit)"
        ctrl = _checks.check(ctrl, part.knots != plan.direction.knots, name, expected, "other knots")
    if ctrl.shape[1] == 2:
        ctrl = jnp.concatenate([ctrl, jnp.zeros_like(ctrl[:, :1])], axis=1)
    w = jnp.ones_like(ctrl[:, 0]) if part.weights is None else part.weights
    net = jnp.concatenate([ctrl * w[:, None], w[:, None]], axis=1)
    return net if transform is None else transform.astype(net.dtype) @ net


def _nets(parts, plan: _AnyPlan, names) -> list:
    return [_homogeneous(p, t, plan, n) for p, t, n in zip(parts, plan.transforms, names)]


def _rational(parts) -> bool:
    return any(p.weights is not None for p in parts)


def _surface(net, direction_u, direction_v, rational: bool) -> BSplineSurface:
    """A surface from a homogeneous net `(r, s, 4)` (weights kept only when `rational`)."""
    if not rational:
        return BSplineSurface.from_directions(net[..., :3], direction_u, direction_v)
    w = net[..., 3]
    return BSplineSurface.from_directions(net[..., :3] / w[..., None], direction_u, direction_v, w)


def _linear(dtype) -> SplineDirection:
    return SplineDirection(jnp.asarray(_LINEAR, dtype), 1)


def _greville(direction: SplineDirection):
    """Greville abscissae (The NURBS Book eq. 9.8) of a clamped direction, traceable: the
    control points of the identity function, `Σ_i ξ_i B_i(t) = t`."""
    knots, p = direction.knots, direction.degree
    assert knots is not None
    return jnp.stack([knots[i + 1 : i + p + 1] for i in range(direction.n_ctrl)]).mean(axis=1)


# --- public constructors ------------------------------------------------------------------------
def compatible(curves: Sequence[BSplineCurve]) -> list[BSplineCurve]:
    """The curves re-expressed with one degree and one knot vector, geometry unchanged.

    Each curve is raised to the highest degree (NURBS Book §5.5, `elevate_degree`) and refined by
    the knots it lacks (§5.2, `insert_knots`) so that every curve has the merged knot vector:
    each distinct knot value at its largest multiplicity (The NURBS Book §10.3, making sections
    compatible for skinning). Rational curves are refined in homogeneous coordinates. Periodic
    curves must already share degree and control count.

    **Arguments:** `curves`: a sequence of at least one `BSplineCurve` (d = 2 or 3, all the same d).
    **Returns:** a list of `BSplineCurve`s with equal `degree` and `knots` (polynomial curves stay
    polynomial). Differentiable in the control points and weights (the plan is fixed by the knots).
    """
    curves = _curve_list(curves, "curves", 1)
    names = [f"curves[{i}]" for i in range(len(curves))]
    _same_dim(curves, names)
    plan = _plan(curves, names)
    return list(_compatible(_parts(curves, plan), plan, tuple(names)))


@compiled
def _compatible(parts, plan: _AnyPlan, names):
    out = []
    for part, transform, name in zip(parts, plan.transforms, names):
        net = _homogeneous(part, transform, plan, name)
        d, w = part.ctrl.shape[1], net[:, 3]
        if part.weights is None:
            out.append(BSplineCurve.from_direction(net[:, :d], plan.direction))
        else:
            out.append(BSplineCurve.from_direction(net[:, :d] / w[:, None], plan.direction, w))
    return tuple(out)


@declared
def ruled(c0: BSplineCurve, c1: BSplineCurve) -> BSplineSurface:
    """The ruled surface `S(u, v) = (1 − v) C0(u) + v C1(u)` between two curves.

    Linear (degree 1) in v; the curves are made compatible first (`compatible`). Rational curves
    are joined in homogeneous coordinates, so every iso-line `u = const` is the straight segment
    from `C0(u)` to `C1(u)` (The NURBS Book §10.3; thesis §5.1, two-curve filling).

    **Arguments:** `c0`, `c1`: `BSplineCurve`s (d = 2 curves lie at z = 0).
    **Returns:** a `BSplineSurface` with control net `(n, 2, 3)`: column 0 is `c0`, column 1 `c1`
    in the common basis. Differentiable in both curves' control points.
    """
    plan = _plan([c0, c1], ("c0", "c1"))
    return _ruled(_parts((c0, c1), plan), plan)


@compiled
def _ruled(parts, plan: _AnyPlan) -> BSplineSurface:
    h0, h1 = _nets(parts, plan, ("c0", "c1"))
    net = jnp.stack([h0, h1], axis=1)
    return _surface(net, plan.direction, _linear(net.dtype), _rational(parts))


@compiled
def extrude(curve: BSplineCurve, vector: ArrayLike) -> BSplineSurface:
    """The extrusion `S(u, v) = C(u) + v · vector` (a general cylinder, The NURBS Book §8.3).

    **Arguments:** `curve`: a `BSplineCurve` (d = 2 lies at z = 0); `vector (3,)`: the extrusion
    direction and length, finite and nonzero.
    **Returns:** a `BSplineSurface` `(n, 2, 3)`, linear in v, in the curve's basis (rational when
    the curve is). Differentiable in the control points and in `vector`.
    """
    _check_curves([curve], ["curve"])
    vector = _checks.vector3(vector, "vector", curve.ctrl.dtype)
    vector = _nonzero(vector, "vector", "a finite nonzero extrusion vector")
    plan = _Plan(curve.direction, (None,), False)
    (h,) = _nets(_parts((curve,), plan), plan, ("curve",))
    moved = h.at[:, :3].add(h[:, 3:] * vector[None])
    net = jnp.stack([h, moved], axis=1)
    return _surface(net, curve.direction, _linear(net.dtype), curve.weights is not None)


@declared
def revolve(
    profile: BSplineCurve, axis_point: ArrayLike, axis_dir: ArrayLike, angle: float = _TWO_PI
) -> BSplineSurface:
    """The surface of revolution of `profile` about an axis, exact (rational quadratic in v).

    Each control point `P_i` sweeps a circular arc about the axis: with `O_i` its foot on the
    axis, `X_i = P_i − O_i` and `Y_i = a × X_i`, the arc's control points are
    `O_i + (cos θ_j X_i + sin θ_j Y_i) / c_j` with weights `w_i c_j`, where the `2 n_arcs + 1`
    angles step by half an arc, `c_j = 1` at arc ends and `cos(Δθ/2)` at arc middles
    (The NURBS Book §8.5, algorithm A8.1, and §7.5 for the arcs). `n_arcs` is the fewest arcs of
    at most 90° (1…4; the full turn is the 9-point circle with knots
    `[0, 0, 0, ¼, ¼, ½, ½, ¾, ¾, 1, 1, 1]`, closed: `S(u, 0) = S(u, 1)`); a traced `angle` uses 4.

    **Arguments:**
    - `profile`: a `BSplineCurve`. d = 3: points in space; d = 2: `(x, y)` = (radius, height
      along the axis) in the half-plane spanned by the axis and `e`, the coordinate axis least
      aligned with `axis_dir` made orthogonal to it (the surface's v = 0 side).
    - `axis_point (3,)`, `axis_dir (3,)`: the axis (direction finite, nonzero, any length).
    - `angle`: the swept angle in (0, 2π] (radians, counter-clockwise about `axis_dir`).

    **Returns:** a rational `BSplineSurface` `(n, 2 n_arcs + 1, 3)`, u along the profile.
    Differentiable in the profile's control points and weights, the axis and the angle.
    """
    _check_curves([profile], ["profile"])
    return _revolve(profile, axis_point, axis_dir, angle, _arc_count(angle))


def _arc_count(angle) -> int:
    if not _checks.is_concrete(angle) or np.ndim(angle) != 0:
        return 4
    value = float(angle)
    if not math.isfinite(value):
        return 4
    return int(min(4, max(1, math.ceil(value / (0.5 * math.pi) - 1e-12))))


@compiled
def _revolve(profile: BSplineCurve, axis_point, axis_dir, angle, n_arcs: int) -> BSplineSurface:
    dtype = profile.ctrl.dtype
    origin = _checks.finite(_checks.vector3(axis_point, "axis_point", dtype), "axis_point")
    axis = _checks.vector3(axis_dir, "axis_dir", dtype)
    axis = _nonzero(axis, "axis_dir", "a finite nonzero axis direction")
    _checks.check_real(angle, "angle")
    angle = jnp.asarray(angle, dtype)
    _checks.check_ndim(angle, "angle", 0)
    bad = ~((angle > 0) & (angle <= _TWO_PI * (1 + 1e-12)))
    angle = _checks.check(angle, bad, "angle", "an angle in (0, 2π]", "a value outside (or NaN)")
    a = _safe.unit(axis)
    points = profile.ctrl
    if profile.dim == 2:
        points = origin[None] + points[:, :1] * _perpendicular(a)[None] + points[:, 1:] * a[None]
    foot = origin[None] + ((points - origin[None]) @ a)[:, None] * a[None]
    x = points - foot
    y = jnp.cross(jnp.broadcast_to(a, x.shape), x)
    half = np.arange(2 * n_arcs + 1)
    theta = jnp.asarray(half, dtype) * (angle / (2 * n_arcs))
    middle = jnp.asarray(half % 2 == 1)
    c = jnp.where(middle, jnp.cos(angle / (2 * n_arcs)), jnp.ones_like(theta))
    arc = jnp.cos(theta)[None, :, None] * x[:, None] + jnp.sin(theta)[None, :, None] * y[:, None]
    ctrl = foot[:, None] + arc / c[None, :, None]
    w = jnp.ones_like(points[:, 0]) if profile.weights is None else profile.weights
    steps = np.arange(1, n_arcs) / n_arcs
    knots_v = np.concatenate([np.zeros(3), np.repeat(steps, 2), np.ones(3)])
    direction_v = SplineDirection(jnp.asarray(knots_v, dtype), 2)
    return BSplineSurface.from_directions(ctrl, profile.direction, direction_v, w[:, None] * c[None, :])


def _perpendicular(a):
    """A unit vector ⟂ `a`: the coordinate axis least aligned with `a`, made orthogonal to it."""
    eye = jnp.eye(3, dtype=a.dtype)
    ref = eye[jnp.argmin(jnp.abs(a))]
    return _safe.unit(ref - (ref @ a) * a)


@declared
def coons(
    c_bottom: BSplineCurve,
    c_top: BSplineCurve,
    c_left: BSplineCurve,
    c_right: BSplineCurve,
    tol: float = 1e-9,
) -> BSplineSurface:
    """The bilinearly blended Coons patch of four boundary curves, exact as a B-spline.

    `S(u, v) = (1−v) B(u) + v T(u) + (1−u) L(v) + u R(v)
    − [(1−u)(1−v) P00 + u(1−v) P10 + (1−u) v P01 + u v P11]`, so `S(u, 0) = B(u)`,
    `S(u, 1) = T(u)`, `S(0, v) = L(v)`, `S(1, v) = R(v)` (The NURBS Book §10.5, Coons patch as the
    sum of two ruled surfaces minus a bilinear one; thesis §5.1, "geom-filling", Coons style).
    Bottom/top are made compatible in u, left/right in v; the linear factors are written in those
    bases with the Greville abscissae (`Σ ξ_i B_i(u) = u`), so no further refinement is needed.

    **Arguments:** four polynomial (unweighted), clamped `BSplineCurve`s (d = 2 at z = 0) whose
    ends meet: `B(0) = L(0)`, `B(1) = R(0)`, `T(0) = L(1)`, `T(1) = R(1)` within
    `tol · max(1, largest |coordinate|)`; `tol` a float ≥ 0.
    **Returns:** a `BSplineSurface` `(n_u, n_v, 3)`. Differentiable in the control points.
    """
    names = ("c_bottom", "c_top", "c_left", "c_right")
    curves = (c_bottom, c_top, c_left, c_right)
    _check_curves(curves, names)
    for curve, name in zip(curves, names):
        if curve.weights is not None:
            _checks.fail(name, "a polynomial curve (weights None) for an exact Coons patch", "weights")
        if curve.periodic:
            _checks.fail(name, "a clamped curve (its end points are corners)", "a periodic curve")
    plan_u = _plan(curves[:2], names[:2])
    plan_v = _plan(curves[2:], names[2:])
    return _coons(_parts(curves[:2], plan_u), _parts(curves[2:], plan_v), plan_u, plan_v, tol)


@compiled
def _coons(parts_u, parts_v, plan_u: _AnyPlan, plan_v: _AnyPlan, tol) -> BSplineSurface:
    b, t = (h[:, :3] for h in _nets(parts_u, plan_u, ("c_bottom", "c_top")))
    l, r = (h[:, :3] for h in _nets(parts_v, plan_v, ("c_left", "c_right")))
    gaps = jnp.stack([b[0] - l[0], b[-1] - r[0], t[0] - l[-1], t[-1] - r[-1]])
    scale = jnp.maximum(1.0, jnp.max(jnp.abs(jnp.concatenate([b, t, l, r]))))
    tol = jnp.asarray(tol, b.dtype)
    tol = _checks.check(tol, ~(tol >= 0), "tol", "a tolerance >= 0", "a negative value (or NaN)")
    bad = _safe.norm(gaps) > tol * scale
    expected = "curves meeting at the four corners (B(0)=L(0), B(1)=R(0), T(0)=L(1), T(1)=R(1))"
    b = _checks.check(b, bad, "coons corners", expected, "a gap larger than tol")
    xi = _greville(plan_u.direction)[:, None, None]
    eta = _greville(plan_v.direction)[None, :, None]
    across = (1 - eta) * b[:, None] + eta * t[:, None]
    along = (1 - xi) * l[None] + xi * r[None]
    p00, p10, p01, p11 = (p[None, None] for p in (b[0], b[-1], t[0], t[-1]))
    bilinear = (1 - xi) * (1 - eta) * p00 + xi * (1 - eta) * p10 + (1 - xi) * eta * p01 + xi * eta * p11
    return BSplineSurface.from_directions(across + along - bilinear, plan_u.direction, plan_v.direction)


@declared
def loft(curves: Sequence[BSplineCurve], degree: int = 3, ruled: bool = False) -> BSplineSurface:
    """Skinning: the surface interpolating section curves `C_0 … C_{K−1}` across v.

    The sections are made compatible (`compatible`); the v parameter of section k is the
    averaged chord length `v_k = (1/n) Σ_i |Q_k^i − Q_{k−1}^i|`-cumulated over the control-point
    columns i (columns of zero length left out), the v knots are the averages of `degree`
    consecutive `v_k` (The NURBS Book §10.3, eqs. 9.8 and 10.8), and each column of homogeneous
    control points is interpolated at the `v_k` (a K × K solve): `S(u, v_k) = C_k(u)` exactly.

    **Arguments:**
    - `curves`: K ≥ 2 `BSplineCurve`s (d = 2 at z = 0), consecutive sections distinct.
    - `degree`: the degree in v, an int ≥ 1, lowered to K − 1 when there are fewer sections.
    - `ruled`: degree 1 in v (piecewise ruled between consecutive sections).

    **Returns:** a `BSplineSurface` `(n, K, 3)` (rational when a section is). Differentiable in
    the control points (the parameters and knots follow them).
    """
    curves = _curve_list(curves, "curves", 2)
    degree = _checks.check_count(degree, "degree", 1)
    if not isinstance(ruled, (bool, np.bool_)):
        raise TypeError(f"ruled: expected a bool, got {type(ruled).__name__}")
    names = tuple(f"curves[{i}]" for i in range(len(curves)))
    plan = _plan(curves, names)
    degree_v = 1 if ruled else min(degree, len(curves) - 1)
    return _loft(_parts(curves, plan), plan, names, degree_v)


@compiled
def _loft(parts, plan: _AnyPlan, names, degree_v: int) -> BSplineSurface:
    net = jnp.stack(_nets(parts, plan, names), axis=1)  # (n, K, 4)
    expected = "distinct consecutive sections (increasing chord-length parameters)"
    params = _chord_params(net[..., :3] / net[..., 3:], "curves", expected, "coincident sections")
    direction_v = SplineDirection(_averaged_knots(params, degree_v), degree_v)
    return _surface(
        _interpolate(net, direction_v, params, axis=1), plan.direction, direction_v, _rational(parts)
    )


def _averaged_knots(params, degree: int):
    """Clamped knots by averaging `degree` consecutive parameters (The NURBS Book eq. 9.8)."""
    count = params.shape[0]
    interior = [params[j : j + degree].mean() for j in range(1, count - degree)]
    ends = jnp.zeros(degree + 1, params.dtype)
    return jnp.concatenate([ends, jnp.stack(interior), ends + 1] if interior else [ends, ends + 1])


def _interpolate(net, direction: SplineDirection, params, axis: int):
    """The control points along `axis` of `net` whose spline in `direction` passes through the
    data at `params` (one square collocation solve, The NURBS Book eq. 9.9)."""
    a = direction.matrix(params)
    moved = jnp.moveaxis(net, axis, 0)
    solved = jnp.linalg.solve(a, moved.reshape(moved.shape[0], -1)).reshape(moved.shape)
    return jnp.moveaxis(solved, 0, axis)


def _chord_params(points, name: str, expected: str, got: str):
    """Averaged chord-length parameters `(K,)` along axis 1 of `points (n, K, 3)` (The NURBS
    Book eqs. 9.5 and 10.8: each of the n lines' cumulated chord lengths, normalised, averaged;
    lines of zero length left out); consecutive parameters must increase."""
    steps = _safe.norm(points[:, 1:] - points[:, :-1])  # (n, K-1)
    cumulative = jnp.concatenate([jnp.zeros_like(steps[:, :1]), jnp.cumsum(steps, axis=1)], axis=1)
    total = cumulative[:, -1:]
    used = total > 0
    per_column = _safe.ratio(cumulative, total)
    params = _safe.ratio(jnp.sum(jnp.where(used, per_column, 0), axis=0), jnp.sum(used, dtype=points.dtype))
    bad = jnp.diff(params) <= 64 * jnp.finfo(params.dtype).eps  # equal up to rounding
    params = _checks.check(params, bad, name, expected, got)
    # keep the rest finite when the check fails, so that this is the error reported
    return jnp.where(jnp.any(bad), jnp.linspace(0.0, 1.0, params.shape[0], dtype=params.dtype), params)


# --- global interpolation of a point grid -------------------------------------------------------
@compiled
def interpolate_grid(points: Float[Array, "m n 3"], degree: tuple[int, int] = (3, 3)) -> BSplineSurface:
    """The B-spline surface through an `(m, n)` grid of points (global interpolation).

    Parameters per direction by averaged chord length (each row's, or column's, cumulated chord
    lengths normalised to [0, 1], then averaged: The NURBS Book eq. 9.5 and §9.2.5), knots by
    averaging `degree` consecutive parameters (eq. 9.8), and the control net by curve
    interpolation twice — first every column along u, then every row of that result along v
    (The NURBS Book §9.2.5; thesis eq. 5-8, "applying the technique of B-spline curve
    interpolation twice"): `S(u_k, v_l) = Q_kl` exactly.

    **Arguments:**
    - `points (m, n, 3)`: the grid, finite; `m ≥ degree[0] + 1`, `n ≥ degree[1] + 1`; no two
      consecutive rows (or columns) may coincide everywhere.
    - `degree`: `(p, q)`, ints ≥ 1 (static).

    **Returns:** a `BSplineSurface` with control net `(m, n, 3)`, clamped knots. Differentiable
    in `points` (the parameters and knots follow them).
    """
    p, q = _degree_pair(degree)
    _checks.check_real(points, "points")
    points = jnp.asarray(points, _float(points))
    _checks.check_ndim(points, "points", 3, last=3)
    m, n = points.shape[:2]
    if m < p + 1 or n < q + 1:
        expected = f"at least degree + 1 = ({p + 1}, {q + 1}) points per direction, shape (m, n, 3)"
        _checks.fail("points", expected, f"shape {points.shape}")
    points = _checks.finite(points, "points")
    expected = "distinct consecutive rows and columns (increasing chord-length parameters)"
    params_u = _chord_params(jnp.swapaxes(points, 0, 1), "points", expected, "coincident rows")
    params_v = _chord_params(points, "points", expected, "coincident columns")
    direction_u = SplineDirection(_averaged_knots(params_u, p), p)
    direction_v = SplineDirection(_averaged_knots(params_v, q), q)
    net = _interpolate(_interpolate(points, direction_u, params_u, 0), direction_v, params_v, 1)
    return BSplineSurface.from_directions(net, direction_u, direction_v)


def _degree_pair(degree) -> tuple[int, int]:
    if not isinstance(degree, tuple) or len(degree) != 2:
        raise TypeError(f"degree: expected a pair of ints (p, q), got {degree!r}")
    return _checks.check_count(degree[0], "degree[0]", 1), _checks.check_count(degree[1], "degree[1]", 1)


def _float(x):
    dtype = jnp.result_type(x)
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


# --- surfaces through moving sections (sweep, rail rotation) ------------------------------------
class SurfaceFit(eqx.Module):
    """A constructed surface and how far it is from the construction it approximates.

    **Fields:** `surface` (`BSplineSurface`); `max_error` (scalar): the largest distance between
    the surface and the exact construction over the sample grid the constructor names (the
    surface interpolates its sections exactly; the error is between them).
    """

    surface: BSplineSurface
    max_error: Float[Array, ""]


_FRAMES = ("rmf", "frenet", "fixed")
_SUBSTEPS = 8  # frames and error samples per section interval


def _section_grid(count: int, dtype):
    """`(t_fine, every)`: `(count − 1) · _SUBSTEPS + 1` uniform parameters on [0, 1], of which
    every `_SUBSTEPS`-th is a section parameter."""
    return jnp.linspace(0.0, 1.0, (count - 1) * _SUBSTEPS + 1, dtype=dtype), _SUBSTEPS


def _moving_sections(profile: BSplineCurve, local, origins, maps, t_fine, every: int) -> SurfaceFit:
    """Sections `origins_k + maps_k @ local_i` at `t_fine[::every]`, interpolated across v at
    those parameters (cubic, knots by averaging), and the largest distance to the exact moving
    section `origins(t) + maps(t) @ profile(u)` over `t_fine` × 4 n profile parameters."""
    t = t_fine[::every]
    sections = origins[None, ::every] + jnp.einsum("kab,ib->ika", maps[::every], local)  # (n, K, 3)
    degree_v = min(3, t.shape[0] - 1)
    direction_v = SplineDirection(_averaged_knots(t, degree_v), degree_v)
    net = _interpolate(sections, direction_v, t, axis=1)
    weights = None if profile.weights is None else jnp.broadcast_to(profile.weights[:, None], net.shape[:2])
    surface = BSplineSurface.from_directions(net, profile.direction, direction_v, weights)
    u = jnp.linspace(0.0, 1.0, 4 * profile.n_ctrl, dtype=t.dtype)
    exact = origins[None] + jnp.einsum("fab,ub->ufa", maps, _local_points(profile, u))
    # the fitted surface on the grid by its blending matrices (M = A_u P A_v^T, thesis eq. 3.6)
    w = jnp.ones_like(net[:, 0, 0]) if profile.weights is None else profile.weights
    homogeneous = jnp.concatenate(
        [net * w[:, None, None], jnp.broadcast_to(w[:, None, None], net.shape[:2] + (1,))], -1
    )
    a_u, a_v = profile.direction.matrix(u), direction_v.matrix(t_fine)
    fitted = jnp.einsum("ui,ikc,fk->ufc", a_u, homogeneous, a_v)
    error = jnp.max(_safe.norm(fitted[..., :3] / fitted[..., 3:] - exact))
    return SurfaceFit(surface, error)


def _local_points(curve: BSplineCurve, t):
    points = curve.evaluate(t)
    return _planar_to_3d(points)


def _planar_to_3d(points):
    if points.shape[-1] == 3:
        return points
    return jnp.concatenate([points, jnp.zeros_like(points[..., :1])], axis=-1)


@declared
def sweep(
    profile: BSplineCurve,
    path: BSplineCurve,
    frame: str = "rmf",
    n_sections: int | None = None,
    *,
    normal: ArrayLike | None = None,
) -> SurfaceFit:
    """The surface swept by a profile carried along a path in a moving frame (thesis §5.1,
    sweeping mode; The NURBS Book §10.4, swept surfaces by skinning sections).

    The profile is given in the frame's local coordinates — x → the frame's normal `N(t)`,
    y → binormal `B(t)`, z → tangent `T(t)`, origin → the path point `C(t)` — so the exact sweep
    is `S*(u, t) = C(t) + [N B T](t) P(u)`. `n_sections` copies of the profile (exact: a frame is
    affine, so the copy's control points are the moved control points, weights kept) are placed
    at uniform path parameters `t_k` and interpolated across v at `v = t_k` (cubic, knots by
    averaging, The NURBS Book eq. 9.8): `S(u, t_k) = S*(u, t_k)` exactly and `S(u, t) ≈ S*(u, t)`
    between sections.

    Frames (`frame`):
    - `"rmf"`: rotation-minimising, by the double reflection method (Wang, Jüttler, Zheng & Liu,
      *Computation of rotation minimizing frames*, 2008, algorithm of §4) on 8 steps per section
      interval; no twist about the tangent (on a planar path the binormal stays the plane normal).
    - `"frenet"`: `T = C'/|C'|`, `N` along the part of `C''` normal to `T`, `B = T × N`; the
      path must have nonzero curvature at every sampled parameter.
    - `"fixed"`: the start frame kept (the profile translated along the path, not turned).
    The start normal (rmf and fixed) is `normal` made orthogonal to `T(0)`; by default the z axis
    made orthogonal to `T(0)` (the x axis when `T(0)` is along ±z): for a path in the xy plane
    the profile's x axis points up (+z) and its y axis along `T × z`.

    **Arguments:**
    - `profile`: a `BSplineCurve` (d = 2: z = 0 in the local frame), clamped or periodic.
    - `path`: a `BSplineCurve` (d = 2 lies at z = 0), regular (nonzero tangent) on [0, 1]; read
      on [0, 1] (a closed path gives a surface open in v).
    - `frame`: `"rmf"`, `"frenet"` or `"fixed"`.
    - `n_sections`: the number K ≥ 2 of sections (default `4 · path.n_ctrl + 4`).
    - `normal (3,)`: the start normal, finite, not parallel to `T(0)` (keyword only).

    **Returns:** `SurfaceFit(surface, max_error)`: `surface` has control net `(n, K, 3)`, u along
    the profile (its basis and weights), v the path parameter; `max_error` is the largest
    distance `|S(u, t) − S*(u, t)|` over `4 n` uniform `u` × `8 (K − 1) + 1` uniform `t`.
    Differentiable in both curves' control points (and `normal`).
    """
    _check_curves([profile, path], ["profile", "path"])
    if frame not in _FRAMES:
        _checks.fail("frame", "'rmf', 'frenet' or 'fixed'", repr(frame))
    count = 4 * path.n_ctrl + 4 if n_sections is None else _checks.check_count(n_sections, "n_sections", 2)
    return _sweep(profile, path, frame, count, normal)


@compiled
def _sweep(profile: BSplineCurve, path: BSplineCurve, frame: str, count: int, normal) -> SurfaceFit:
    dtype = path.ctrl.dtype
    t_fine, every = _section_grid(count, dtype)
    points = _planar_to_3d(path.evaluate(t_fine))
    d1 = _planar_to_3d(path.evaluate(t_fine, 1))
    speed = _safe.norm(d1)
    scale = jnp.maximum(1.0, jnp.max(jnp.abs(points)))
    d1 = _checks.check(d1, speed <= 1e-12 * scale, "path", "a regular path (nonzero tangent)", "zero")
    tangents = _safe.unit(d1)
    if frame == "frenet":
        d2 = _planar_to_3d(path.evaluate(t_fine, 2))
        bent = d2 - jnp.sum(d2 * tangents, axis=-1, keepdims=True) * tangents
        flat = _safe.norm(bent) <= 1e-9 * speed**2 / scale
        expected = "nonzero curvature at every section for frame='frenet' (use 'rmf')"
        normals = _safe.unit(_checks.check(bent, flat, "path", expected, "a straight stretch"))
    else:
        start = _start_normal(tangents[0], normal, dtype)
        if frame == "rmf":
            normals = _rotation_minimising(points, tangents, start)
        else:
            normals = jnp.broadcast_to(start, points.shape)
            tangents = jnp.broadcast_to(tangents[0], points.shape)
    binormals = jnp.cross(tangents, normals)
    maps = jnp.stack([normals, binormals, tangents], axis=-1)  # columns: local x, y, z
    local = _planar_to_3d(profile.ctrl)
    return _moving_sections(profile, local, points, maps, t_fine, every)


def _start_normal(tangent, normal, dtype):
    """The start normal ⟂ `tangent`: `normal` (checked), or the z axis made orthogonal to the
    tangent (the x axis when the tangent is within ~0.06° of ±z): smooth in the path except there,
    and the up direction of a path drawn in the xy plane."""
    if normal is None:
        up = jnp.asarray([0.0, 0.0, 1.0], dtype) - tangent[2] * tangent
        side = jnp.asarray([1.0, 0.0, 0.0], dtype) - tangent[0] * tangent
        return _safe.unit(jnp.where(_safe.norm(up) > 1e-3, up, side))
    normal = _checks.finite(_checks.vector3(normal, "normal", dtype), "normal")
    along = normal - (normal @ tangent) * tangent
    bad = _safe.norm(along) <= 1e-9 * _safe.norm(normal)
    along = _checks.check(along, bad, "normal", "a vector not parallel to the path's start tangent", "one")
    return _safe.unit(along)


def _rotation_minimising(points, tangents, start):
    """Normals of the rotation-minimising frame by double reflection (Wang, Jüttler, Zheng &
    Liu, *Computation of rotation minimizing frames*, §4): reflect the frame in the bisector
    plane of `x_i x_{i+1}`, then in the one that maps the reflected tangent to `t_{i+1}`."""

    def reflect(x, v, c):
        return x - _safe.ratio(2.0 * (v @ x), c) * v

    def step(r, inputs):
        x0, x1, t0, t1 = inputs
        v1 = x1 - x0
        c1 = v1 @ v1
        r_l, t_l = reflect(r, v1, c1), reflect(t0, v1, c1)
        v2 = t1 - t_l
        r_next = reflect(r_l, v2, v2 @ v2)
        r_next = _safe.unit(r_next - (r_next @ t1) * t1)  # keep it unit and ⟂ against rounding
        return r_next, r_next

    _, rest = jax.lax.scan(step, start, (points[:-1], points[1:], tangents[:-1], tangents[1:]))
    return jnp.concatenate([start[None], rest], axis=0)


@declared
def rail_rotation(
    rail_a: BSplineCurve, rail_b: BSplineCurve, profile: BSplineCurve, n_sections: int | None = None
) -> SurfaceFit:
    """The surface of a profile moved along two rails, its ends riding on them (thesis §5.2.2,
    rail-based rotation, eq. 5-9: `C_i(u) = M_i · C3(u)` with `M_i p_0 = p_i`, `M_i p'_0 = p'_i`).

    Design choices where the thesis is terse: the section at rail parameter `t` is the image of
    the profile under the similarity `M(t)` that maps the profile's end points `C3(0), C3(1)` to
    `P(t) = rail_a(t)`, `P'(t) = rail_b(t)` and turns the profile's reference frame into the
    section's: each frame is (chord direction `e1 = (P' − P)/|P' − P|`, the direction of travel
    — the mean of the rails' unit tangents — made orthogonal to `e1` as `e3`, and
    `e2 = e3 × e1`); the profile's reference frame uses its own chord `C3(1) − C3(0)` and the
    direction of travel at `t = 0`; the scale is the chord-length ratio. The rails are read at
    equal parameters (the thesis takes equal angles about the axis through the rails'
    bounding-box centres; for coaxial circles parametrised alike the two agree, and the frame
    then turns about that axis, so a planar profile in an axial half-plane gives its surface of
    revolution). `n_sections` sections at uniform `t_k` are interpolated across v at `v = t_k`
    (cubic, knots by averaging), as in `sweep`: `S(0, t_k) = rail_a(t_k)`,
    `S(1, t_k) = rail_b(t_k)` exactly, and exactly for every t when the rails are polynomials of
    degree ≤ 3 in t and the frames are constant (e.g. straight parallel rails: a translation).

    **Arguments:**
    - `rail_a`, `rail_b`: `BSplineCurve`s (d = 2 at z = 0; closed or open), regular, parametrised
      alike, apart at every section, not travelling along the chord between them.
    - `profile`: a clamped `BSplineCurve` in world coordinates with distinct end points (its
      first point rides on `rail_a`, its last on `rail_b`).
    - `n_sections`: the number K ≥ 2 of sections (default `2 · max(n_a, n_b) + 4`).

    **Returns:** `SurfaceFit(surface, max_error)`: `surface` `(n, K, 3)` with u along the profile,
    v the rails' parameter; `max_error` the largest distance to the exact moving section
    `M(t) C3(u)` over `4 n` uniform `u` × `8 (K − 1) + 1` uniform `t`. Differentiable in the
    three curves' control points.
    """
    _check_curves([rail_a, rail_b, profile], ["rail_a", "rail_b", "profile"])
    if profile.periodic:
        _checks.fail("profile", "a clamped curve (its ends ride on the rails)", "a periodic curve")
    n = max(rail_a.n_ctrl, rail_b.n_ctrl)
    count = 2 * n + 4 if n_sections is None else _checks.check_count(n_sections, "n_sections", 2)
    return _rail_rotation(rail_a, rail_b, profile, count)


@compiled
def _rail_rotation(rail_a: BSplineCurve, rail_b: BSplineCurve, profile: BSplineCurve, count: int):
    t_fine, every = _section_grid(count, rail_a.ctrl.dtype)
    p, p_prime = (_planar_to_3d(rail.evaluate(t_fine)) for rail in (rail_a, rail_b))
    travel = sum(_safe.unit(_planar_to_3d(rail.evaluate(t_fine, 1))) for rail in (rail_a, rail_b))
    chord = p_prime - p
    length = _safe.norm(chord)
    scale = jnp.maximum(1.0, jnp.max(jnp.abs(jnp.concatenate([p, p_prime]))))
    chord = _checks.check(
        chord, length <= 1e-12 * scale, "rail_b", "rails apart at every section", "a meeting"
    )
    frames = _chord_frames(chord, travel, "rail_a, rail_b")
    ends = _planar_to_3d(profile.evaluate(jnp.asarray([0.0, 1.0], t_fine.dtype)))
    own = ends[1] - ends[0]
    own_length = _safe.norm(own)
    bad = own_length <= 1e-12 * jnp.maximum(1.0, jnp.max(jnp.abs(ends)))
    own = _checks.check(own, bad, "profile", "distinct end points", "coincident ends")
    reference = _chord_frames(own[None], travel[:1], "profile")[0]
    maps = _safe.ratio(length, own_length)[:, None, None] * (frames @ reference.T)
    origins = p - jnp.einsum("fab,b->fa", maps, ends[0])
    return _moving_sections(profile, _planar_to_3d(profile.ctrl), origins, maps, t_fine, every)


def _chord_frames(chord, travel, name: str):
    """Orthonormal frames `(F, 3, 3)` with columns (chord direction, e3 × e1, travel ⟂ chord)."""
    e1 = _safe.unit(chord)
    across = travel - jnp.sum(travel * e1, axis=-1, keepdims=True) * e1
    bad = _safe.norm(across) <= 1e-9 * _safe.norm(travel)
    expected = "a direction of travel not along the chord between the rails"
    e3 = _safe.unit(_checks.check(across, bad, name, expected, "parallel"))
    return jnp.stack([e1, jnp.cross(e3, e1), e3], axis=-1)


# --- boundary-based rotation ---------------------------------------------------------------------
_CIRCLE_KNOTS = (0.0, 0.0, 0.0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1.0, 1.0, 1.0)


@declared
def boundary_rotation(left: BSplineCurve, right: BSplineCurve, plane_normal: ArrayLike) -> SurfaceFit:
    """The rotational blending surface of two outline curves (thesis §5.2.1, eqs. 5-4, 5-5;
    Cherlin, Samavati, Sousa & Jorge, *Sketch-based modeling with few strokes*, 2005).

    For each u, a circle perpendicular to the outlines' plane A, centred on the mid-curve
    `Q(u) = ½ (C_l(u) + C_r(u))` and through both outlines, `O(0) = C_l(u)`, `O(π) = C_r(u)`:
    `S*(u, θ) = Q(u) + cos θ D(u) + sin θ E*(u)`, with `D = ½ (C_l − C_r)` and
    `E* = |D| n_⟂`, `n_⟂` the unit plane normal made orthogonal to `D` (`= n_A` when both
    outlines lie in A). Built here, rather than by sampling and interpolating a point grid as
    the thesis does, exactly in θ: the v direction is the 9-point rational quadratic circle
    (knots `[0, 0, 0, ¼, ¼, ½, ½, ¾, ¾, 1, 1, 1]`, The NURBS Book §7.5), and `Q`, `D` are exact
    in the outlines' common basis (`compatible`); only `E*(u)` (a square root) is fitted in that
    basis, by least squares at `4 n + 1` uniform u. So `S(u, 0) = S(u, 1) = C_l(u)` and
    `S(u, ½) = C_r(u)` exactly for every u, every v-section is an exact ellipse through both
    outlines, and it is a circle wherever the fitted `E` equals `E*` — everywhere to rounding
    when `|D|` is itself a spline of that basis (mirror-symmetric outlines: a surface of
    revolution about the mirror line). Corners of the outlines stay creases.

    **Arguments:**
    - `left`, `right`: polynomial (unweighted) `BSplineCurve`s (d = 2 at z = 0, then
      `plane_normal` is usually (0, 0, 1)), parametrised alike (corresponding points at equal u);
      made compatible first.
    - `plane_normal (3,)`: the normal of the outlines' plane A, finite and nonzero (any length);
      the circles bulge towards `+plane_normal` at `v = ¼`.

    **Returns:** `SurfaceFit(surface, max_error)`: a rational `surface` `(n, 9, 3)` (u along the
    outlines, v around, closed in v) and `max_error = max_u |E(u) − E*(u)|`, the largest distance
    to `S*` over `8 n + 1` uniform u (at any θ). Differentiable in both outlines' control points
    and in `plane_normal`.
    """
    names = ("left", "right")
    curves = (left, right)
    _check_curves(curves, names)
    for curve, name in zip(curves, names):
        if curve.weights is not None:
            _checks.fail(name, "a polynomial curve (weights None)", "weights")
    plan = _plan(curves, names)
    return _boundary_rotation(_parts(curves, plan), plan, plane_normal)


@compiled
def _boundary_rotation(parts, plan: _AnyPlan, plane_normal) -> SurfaceFit:
    left, right = (h[:, :3] for h in _nets(parts, plan, ("left", "right")))
    dtype = left.dtype
    normal = _checks.vector3(plane_normal, "plane_normal", dtype)
    normal = _nonzero(normal, "plane_normal", "a finite nonzero normal")
    normal = _safe.unit(normal)
    centre, half = 0.5 * (left + right), 0.5 * (left - right)
    direction = plan.direction
    n = direction.n_ctrl
    fit_u = jnp.linspace(0.0, 1.0, 4 * n + 1, dtype=dtype)
    a_fit = direction.matrix(fit_u)
    radial = jnp.linalg.solve(a_fit.T @ a_fit, a_fit.T @ _radial(a_fit @ half, normal))
    check_u = jnp.linspace(0.0, 1.0, 8 * n + 1, dtype=dtype)
    a_check = direction.matrix(check_u)
    error = jnp.max(_safe.norm(a_check @ radial - _radial(a_check @ half, normal)))
    theta = jnp.arange(9, dtype=dtype) * (math.pi / 4)
    c = jnp.asarray([1.0, math.sqrt(0.5)] * 4 + [1.0], dtype)
    ring = (jnp.cos(theta) / c)[None, :, None] * half[:, None] + (jnp.sin(theta) / c)[None, :, None] * radial[
        :, None
    ]
    net = centre[:, None] + ring
    direction_v = SplineDirection(jnp.asarray(_CIRCLE_KNOTS, dtype), 2)
    weights = jnp.broadcast_to(c[None], net.shape[:2])
    return SurfaceFit(BSplineSurface.from_directions(net, direction, direction_v, weights), error)


def _radial(half, normal):
    """`E* = |D| n_⟂`: the circle's second semi-axis, `n_⟂` the unit normal made ⟂ `D`."""
    along = _safe.unit(half)
    across = _safe.unit(normal[None] - (along @ normal)[:, None] * along)
    return _safe.norm(half)[:, None] * across


# --- argument helpers ---------------------------------------------------------------------------
def _curve_list(curves, name: str, minimum: int) -> list[BSplineCurve]:
    if isinstance(curves, BSplineCurve) or not isinstance(curves, Sequence):
        raise TypeError(f"{name}: expected a sequence of BSplineCurves, got {type(curves).__name__}")
    curves = list(curves)
    if len(curves) < minimum:
        _checks.fail(name, f"at least {minimum} curves", len(curves))
    _check_curves(curves, [f"{name}[{i}]" for i in range(len(curves))])
    return curves


def _same_dim(curves, names) -> None:
    for curve, name in zip(curves[1:], names[1:]):
        if curve.dim != curves[0].dim:
            _checks.fail(name, f"dimension {curves[0].dim} like {names[0]}", curve.dim)


def _nonzero(x, name: str, expected: str):
    bad = ~jnp.all(jnp.isfinite(x)) | jnp.all(x == 0)
    return _checks.check(x, bad, name, expected, "zero, NaN or inf")
