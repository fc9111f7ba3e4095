"""Surfaces from curves (thesis ch. 5, "surface interpreters"): ruled, extruded, revolved,
Coons-filled and lofted `BSplineSurface`s, exact where the construction is polynomial or rational.

Every constructor first makes its curves *compatible* — one degree (raised by `elevate_degree`)
and one knot vector (the merged knots, inserted by `insert_knots`), the geometry unchanged
(The NURBS Book §10.3) — then builds the control net in closed form. The curve parameter is `u`
throughout; the constructed direction (across the curves, along the extrusion, around the axis)
is `v`. Planar curves (d = 2) lie in the plane z = 0 (except `revolve`, which reads them as
(radius, height) in the axial half-plane).

Knot vectors are planned on the host: the merged knots and the change-of-basis matrices are
cached by the curves' (degree, knots) and re-used, so a direct call is one compiled XLA call.
The plan is a constant of that call, so each new knot configuration compiles once (256 plans are
kept; `bsjax._boundary.clear_caches()` forgets them and their compilations).
Control points (and weights) may be traced: every constructor works under `jit`, `vmap` and
`grad` in the control points. Curves whose *knots* are traced (curves passed as arguments of
the caller's own `jit`) must already be compatible — same degree and control count, equal knots
(checked at run time); call `compatible` outside `jit` first otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled, host_cache
from bsjax._typing import ArrayLike
from bsjax.basis import BSplineCurve, BSplineSurface, SplineDirection, basis_functions, greville

__all__ = ["compatible", "coons", "extrude", "loft", "revolve", "ruled"]

_TWO_PI = 2.0 * math.pi
_LINEAR = (0.0, 0.0, 1.0, 1.0)  # the clamped degree-1 knot vector of two control points


# --- compatibility: host-side plan --------------------------------------------------------------
class _Plan(NamedTuple):
    """How to bring curves to one basis: the common `direction`, one change-of-basis matrix per
    curve (`None`: already in it), and whether the curves' (traced) knots must be checked equal."""

    direction: SplineDirection
    transforms: tuple
    check_equal: bool


class _FixedPlan:
    """A cached plan of concrete knots, passed to the compiled kernels as a *static* argument
    (hashed by identity: the cache hands out one object per knot configuration), so its knots
    and matrices are constants of the compiled program and the knot checks of the surface built
    inside fold away (as inputs they would cost run-time checks on every call)."""

    def __init__(self, direction: SplineDirection, transforms: tuple):
        self.direction, self.transforms, self.check_equal = direction, transforms, False


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
    """`T (n_new, n_old)` taking control points in the basis (knots, degree) to the target basis:
    `B_old = B_new T`, found by least-squares collocation at more parameters than basis
    functions — exact, since the target space contains the old one (the change of basis behind
    `elevate_degree` and `insert_knots`)."""
    if degree == target_degree and knots.shape == target.shape and np.array_equal(knots, target):
        return None
    n_new = target.shape[0] - target_degree - 1
    t = np.linspace(0.0, 1.0, 4 * (n_new + 1))
    t = np.unique(np.concatenate([t, greville(target, target_degree)]))
    a_old, a_new = (np.asarray(a, np.float64) for a in _collocation(knots, degree, target, target_degree, t))
    return jnp.asarray(np.linalg.lstsq(a_new, a_old, rcond=None)[0], dtype)


@compiled
def _collocation(knots, degree: int, target, target_degree: int, t):
    """Both bases at the collocation parameters, in one compiled call (not op by op; the knots
    were checked by the curves, and `basis_functions` is the unchecked kernel, which also keeps
    this call free of run-time checks inside `ensure_compile_time_eval`)."""
    old = jax.vmap(lambda x: basis_functions(knots, degree, x))(t)
    new = jax.vmap(lambda x: basis_functions(target, target_degree, x))(t)
    return old, new


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
    vector = _vector(vector, "vector", curve.ctrl.dtype)
    vector = _nonzero(vector, "vector", "a finite nonzero extrusion vector")
    plan = _Plan(curve.direction, (None,), False)
    (h,) = _nets(_parts((curve,), plan), plan, ("curve",))
    moved = h.at[:, :3].add(h[:, 3:] * vector[None])
    net = jnp.stack([h, moved], axis=1)
    return _surface(net, curve.direction, _linear(net.dtype), curve.weights is not None)


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
    origin = _checks.finite(_vector(axis_point, "axis_point", dtype), "axis_point")
    axis = _nonzero(_vector(axis_dir, "axis_dir", dtype), "axis_dir", "a finite nonzero axis direction")
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
    params = _section_params(net[..., :3] / net[..., 3:])
    count = params.shape[0]
    interior = [params[j : j + degree_v].mean() for j in range(1, count - degree_v)]
    ends = jnp.zeros(degree_v + 1, params.dtype)
    knots = jnp.concatenate([ends, jnp.stack(interior), ends + 1] if interior else [ends, ends + 1])
    direction_v = SplineDirection(knots, degree_v)
    a = direction_v.matrix(params)
    flat = jnp.moveaxis(net, 1, 0).reshape(count, -1)
    solved = jnp.moveaxis(jnp.linalg.solve(a, flat).reshape(count, net.shape[0], 4), 0, 1)
    return _surface(solved, plan.direction, direction_v, _rational(parts))


def _section_params(points):
    """Averaged chord-length parameters `(K,)` of the sections, from control points `(n, K, 3)`
    (The NURBS Book eq. 10.8); consecutive sections must differ."""
    steps = _safe.norm(points[:, 1:] - points[:, :-1])  # (n, K-1)
    cumulative = jnp.concatenate([jnp.zeros_like(steps[:, :1]), jnp.cumsum(steps, axis=1)], axis=1)
    total = cumulative[:, -1:]
    used = total > 0
    per_column = _safe.ratio(cumulative, total)
    params = _safe.ratio(jnp.sum(jnp.where(used, per_column, 0), axis=0), jnp.sum(used, dtype=points.dtype))
    bad = jnp.diff(params) <= 64 * jnp.finfo(params.dtype).eps  # equal up to rounding
    expected = "distinct consecutive sections (increasing chord-length parameters)"
    params = _checks.check(params, bad, "curves", expected, "coincident sections")
    # keep the rest finite when the check fails, so that this is the error reported
    return jnp.where(jnp.any(bad), jnp.linspace(0.0, 1.0, params.shape[0], dtype=params.dtype), params)


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


def _vector(x, name: str, dtype) -> jax.Array:
    _checks.check_real(x, name)
    x = jnp.asarray(x, dtype)
    _checks.check_ndim(x, name, 1, last=3)
    return x


def _nonzero(x, name: str, expected: str):
    bad = ~jnp.all(jnp.isfinite(x)) | jnp.all(x == 0)
    return _checks.check(x, bad, name, expected, "zero, NaN or inf")
