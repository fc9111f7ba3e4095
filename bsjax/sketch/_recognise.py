"""Single-stroke recognition and regularisation (thesis §3.1.1, Table 3-1 STEP 2, Fig. 3-3).

A stroke `G(L, S, P, V)` (length, speed, point set, vertex set) is classified as one of
`KINDS` and regularised into the primitive it stands for, with a score. Host-side numpy: a
stroke's length depends on the data. D is the diagonal of the stroke's bounding box along its
principal axes; every test compares ratios to it, angles or ratios of sides and axes, so the
class does not depend on the stroke's position, size or rotation. The chain:

1. **clean** — samples within `_STEP · D` of the previous kept one dropped (a slow pen's tremor
   would add path length, and so speed, where the pen is slow); a closed stroke's over-traced
   tail (it runs on past its start) cut at its closest return to the start.
2. **resample** — `_SAMPLES` samples evenly spaced in arc length, times interpolated (closed:
   around the loop). A lightly smoothed copy (two passes of [¼, ½, ¼]) gives the vertex set
   `V`: `bsjax.sketch.corners` (high curvature of eq. 4-1, and low speed when timed), one
   compiled shape for every stroke; a loop is read from its start and from half-way round.
3. **fit** (`_fits`; in the stroke's plane, PCA for 3-D strokes) — a total-least-squares line, a
   geometric circle (Kåsa's algebraic fit refined by Gauss–Newton), a direct least-squares
   ellipse (Fitzgibbon, Pilu & Fisher 1999, in Halíř & Flusser's stable form) for closed
   strokes, and a polygon: the corners of step 2 as candidate vertices, merged while two
   neighbouring edges turn by less than `_MERGE_TURN`, each edge a total-least-squares line,
   the regularised corners their intersections.
4. **decide** — by the models' residuals `e = rms distance / D`: an open stroke is a line
   (`e ≤ _LINE_TOL`), else a polyline (`e ≤ _POLYLINE_TOL`, below the arc's, and its vertices
   sharp: `_fits.sharp_vertices`), else an arc (`e ≤ _ARC_TOL`), else a spline; a closed stroke is a polygon
   when its `e ≤ _TOL` is below the ellipse's, else a conic (`e ≤ _TOL`; axis ratio below
   `_ROUND`: a circle), else a spline. Polygons: 3 vertices a triangle; 4 with right angles
   (within `_RIGHT`) a square (opposite-side sums within `_SQUARE`) or a rectangle; 4 with equal
   sides (within `_RHOMBUS`) and no right angle a diamond; anything else a polyline (`_fits`
   holds the polygon thresholds).

The regularised curve is exact where bsjax's rational curves allow: a circle is the 9-point
rational quadratic (The NURBS Book §7.5, Ex. 7.2), an ellipse its affine image, an arc the
rational quadratic arc of A7.1 (at most 90° a segment), polygons and lines degree-1 curves
through the regularised vertices (chord-length knots); a free stroke is `fit_stroke`'s cubic.
The thresholds were set on the synthetic strokes of the tests (tests/strokes.py).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from bsjax import _checks
from bsjax._typing import ArrayLike
from bsjax.basis import BSplineCurve
from bsjax.sketch._fits import (
    Polygon,
    fit_circle,
    fit_ellipse,
    fit_line,
    fit_polygon,
    polygon_kind,
    sharp_vertices,
)
from bsjax.sketch._strokes import corners, fit_stroke

KINDS = (
    "line",
    "circle",
    "ellipse",
    "arc",
    "triangle",
    "square",
    "rectangle",
    "diamond",
    "polyline",
    "spline",
)
POLYGONS = ("triangle", "square", "rectangle", "diamond")

_SAMPLES = 64  # samples of the resampled stroke (one compiled `corners` per dimension and timing)
_CURVATURE = 1.5  # `corners`' curvature_factor (open strokes; the merge step drops false candidates)
_CURVATURE_CLOSED = 1.0  # closed strokes: a diamond's obtuse corners turn a third of its acute ones
_STEP = 0.01  # samples nearer than this fraction of D to the previous one are dropped
_CLOSE = 0.15  # a stroke is closed when it returns within this fraction of D of its start
_TOL = 0.025  # largest rms residual / D of an accepted closed primitive
_LINE_TOL = 0.015  # … of a line
_ARC_TOL = 0.015  # … of an arc
_POLYLINE_TOL = 0.01  # … of an open polyline (a free curve's crests make a polyline of ~0.015)
_ROUND = 1.22  # ellipses of axis ratio below are circles
_OUTLINE = 128  # samples of a regularised shape's outline


@dataclasses.dataclass(frozen=True, eq=False)  # arrays inside: identity, not element-wise, equality
class Recognised:
    """A recognised stroke.

    **Fields:**
    - `kind`: one of `KINDS`.
    - `params`: the regularised primitive's parameters (points in the stroke's space, d = 2 or 3;
      angles in radians in the stroke's plane frame `frame`):
      line `endpoints (2, d)`; circle `centre (d,)`, `radius`; ellipse `centre (d,)`,
      `axes (2,)` (a ≥ b), `angle` (of the major axis), `major (d,)` (its unit vector); arc
      `centre`, `radius`, `start`, `end` (`end − start` the signed sweep, counter-clockwise
      positive); triangle/square/rectangle/diamond `corners (k, d)` in drawing order;
      polyline `vertices (k, d)`, `closed`; spline: `{}`.
    - `score`: in [0, 1], `exp(−(e/_TOL)²)` of the chosen model's residual e (rms / D).
    - `curve`: the regularised `BSplineCurve` (see the module docstring).
    - `points (M, d)`: the cleaned, resampled stroke the decision was made on.
    - `outline (K, d)`: samples of the regularised shape (`curve` at K parameters; a free
      stroke: `points`), what `relations` measures.
    - `closed`: whether the stroke returned to its start.
    - `frame (3, d)`: the plane's origin and two orthonormal axes (d = 2: the identity frame).
    - `span`: `(first, last)` time stamps, or `None` for an untimed stroke.
    """

    kind: str
    params: dict[str, Any]
    score: float
    curve: BSplineCurve
    points: np.ndarray
    outline: np.ndarray
    closed: bool
    frame: np.ndarray
    span: tuple[float, float] | None

    @property
    def normal(self) -> np.ndarray:
        """The unit normal of the stroke's plane `(3,)` (d = 2: the drawing plane's +z)."""
        if self.frame.shape[1] == 2:
            return np.array([0.0, 0.0, 1.0])
        n = np.cross(self.frame[1], self.frame[2])
        return n / np.linalg.norm(n)

    @property
    def size(self) -> float:
        """D, the diagonal of the stroke's bounding box along its principal axes."""
        return _extent(self.points)


def _extent(points: np.ndarray) -> float:
    """D: the diagonal of the bounding box of `points (M, d)` along their principal axes (a
    size that does not change under rotation, unlike the axis-aligned box's)."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return float(np.linalg.norm(np.ptp(centred @ vt.T, axis=0)))


# --- input ------------------------------------------------------------------------------------
def _array(x, name: str) -> np.ndarray:
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name}: expected an array of real numbers, got {type(x).__name__}")
    _checks.check_real(x, name)
    kind = np.asarray(x).dtype.kind
    if kind not in "iuf":
        raise TypeError(f"{name}: expected an array of real numbers, got dtype {np.asarray(x).dtype}")
    return np.asarray(x, np.float64)


def _inputs(points, times):
    pts = _array(points, "points")
    _checks.check_ndim(pts, "points", 2)
    if pts.shape[1] not in (2, 3):
        _checks.fail("points", "stroke samples of dimension 2 or 3, shape (N, d)", f"shape {pts.shape}")
    if pts.shape[0] < 3:
        _checks.fail("points", "at least 3 samples", pts.shape[0])
    if not np.isfinite(pts).all():
        _checks.fail("points", "finite values", "NaN or inf")
    if times is None:
        return pts, None
    t = _array(times, "times")
    if t.shape != pts.shape[:1]:
        _checks.fail("times", f"shape ({pts.shape[0]},) like points", t.shape)
    if not np.isfinite(t).all():
        _checks.fail("times", "finite values", "NaN or inf")
    if np.any(np.diff(t) <= 0):
        _checks.fail("times", "strictly increasing time stamps", "a step <= 0")
    return pts, t


# --- step 1–2: clean and resample ----------------------------------------------------------------
def _arc(pts: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])


def _clean(pts, times):
    """Samples closer than `_STEP · D` to the last kept one dropped (the last sample kept): a
    slow pen's tremor would otherwise add path length — and so speed — where the pen is slow."""
    size = _extent(pts)
    if not size > 0:
        _checks.fail("points", "a stroke of nonzero length", "all points equal")
    keep, last = [0], pts[0]
    for i in range(1, len(pts)):
        if np.linalg.norm(pts[i] - last) >= _STEP * size:
            keep.append(i)
            last = pts[i]
    if keep[-1] != len(pts) - 1 and np.linalg.norm(pts[-1] - pts[keep[-1]]) > 0:
        keep.append(len(pts) - 1)
    if len(keep) < 3:
        _checks.fail("points", "a stroke of nonzero length (3 distinct samples)", f"{len(keep)}")
    return pts[keep], None if times is None else times[keep]


def _closure(pts: np.ndarray) -> int | None:
    """The index where a stroke first comes back to its start (within `_CLOSE · D`, at its
    closest there), searched in its second half; `None` for an open stroke."""
    arc = _arc(pts)
    size = _extent(pts)
    dist = np.linalg.norm(pts - pts[0], axis=1)
    late = np.flatnonzero((arc >= 0.5 * arc[-1]) & (dist < _CLOSE * size))
    if late.size == 0:
        return None
    i = int(late[0])
    while i + 1 < len(dist) and dist[i + 1] <= dist[i]:
        i += 1
    return i


def _resample(pts, times, count: int, closed: bool):
    """`count` samples evenly spaced in arc length (a closed stroke: around the loop closed by
    its start, the start not repeated), times interpolated; and a smoothed copy (two passes of
    [¼, ½, ¼], cyclic when closed, else with the ends kept) for the corner detector — the fits
    use the unsmoothed samples, which the filter would pull towards the centre of curvature."""
    if closed:  # the closing segment is drawn at the stroke's last speed
        if times is not None:
            gap = np.linalg.norm(pts[0] - pts[-1]) / np.linalg.norm(pts[-1] - pts[-2])
            times = np.append(times, times[-1] + gap * (times[-1] - times[-2]))
        pts = np.concatenate([pts, pts[:1]])
    arc = _arc(pts)
    at = np.linspace(0.0, arc[-1], count + 1 if closed else count)[:count]
    out = np.stack([np.interp(at, arc, pts[:, i]) for i in range(pts.shape[1])], 1)
    smooth = out.copy()
    for _ in range(2):
        if closed:
            smooth = 0.25 * np.roll(smooth, 1, axis=0) + 0.5 * smooth + 0.25 * np.roll(smooth, -1, axis=0)
        else:
            smooth[1:-1] = 0.25 * smooth[:-2] + 0.5 * smooth[1:-1] + 0.25 * smooth[2:]
    if times is not None and closed:  # the loop's period, for reading it from half-way round
        times = np.append(np.interp(at, arc, times), times[-1])
        return out, smooth, times
    return out, smooth, None if times is None else np.interp(at, arc, times)


def _corner_mask(smooth: np.ndarray, times, closed: bool) -> np.ndarray:
    """`corners` of the smoothed samples; a closed loop is read twice, from its start and from
    half-way round, and each reading kept on the half of the loop away from its ends (where
    `corners` never looks and eq. 4-1's window is cut), so a corner at the seam is found once."""
    if not closed:
        return np.asarray(corners(smooth, times, curvature_factor=_CURVATURE, speed_factor=1.0))
    half = len(smooth) // 2
    loop = None if times is None else times[:-1]  # times (M + 1,): the last closes the loop
    mask = np.asarray(corners(smooth, loop, curvature_factor=_CURVATURE_CLOSED, speed_factor=1.0))
    if times is not None:  # times must increase: the rolled copy is re-timed past its seam
        times = np.concatenate([times[half:-1], times[:half] + (times[-1] - times[0])])
    rolled = corners(
        np.roll(smooth, -half, axis=0), times, curvature_factor=_CURVATURE_CLOSED, speed_factor=1.0
    )
    index = np.arange(len(smooth))
    far_from_seam = (index >= len(smooth) // 4) & (index < len(smooth) - len(smooth) // 4)
    return np.where(far_from_seam, mask, np.roll(np.asarray(rolled), half))  # each reads its middle


def _frame(pts: np.ndarray):
    """The stroke's plane: origin and axes `(3, d)`, its 2-D coordinates `(M, 2)`."""
    if pts.shape[1] == 2:
        return np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), pts.copy()
    origin = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - origin, full_matrices=False)
    frame = np.stack([origin, vt[0], vt[1]])
    return frame, (pts - origin) @ vt[:2].T


def _lift(frame: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Plane coordinates `(..., 2)` → the stroke's space `(..., d)`."""
    return frame[0] + q[..., :1] * frame[1] + q[..., 1:2] * frame[2]


# --- regularised curves (2-D, then lifted) ----------------------------------------------------
def _polyline_curve(v: np.ndarray):
    """Degree 1 through `v (k, 2)`, chord-length knots: `(ctrl, knots, 1, None)`."""
    at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(v, axis=0), axis=1))])
    return v, np.concatenate([[0.0], at / at[-1], [1.0]]), 1, None


def _arc_curve(centre, radius: float, start: float, sweep: float, u=(1.0, 0.0), v=(0.0, 1.0), b=None):
    """The rational quadratic arc of The NURBS Book A7.1: `ceil(|sweep| / 90°)` segments, end
    control points on the arc, middle ones at `radius / cos(Δ/2)` with weight `cos(Δ/2)`. With
    axes `u`, `v` and semi-axis `b` (≠ radius) the affine image: an elliptic arc, exact."""
    segments = max(1, math.ceil(abs(sweep) / (math.pi / 2) - 1e-9))
    half = sweep / (2 * segments)
    theta = start + half * np.arange(2 * segments + 1)
    middle = np.arange(2 * segments + 1) % 2 == 1
    gain = np.where(middle, 1 / math.cos(half), 1.0)
    ax, by = radius * gain * np.cos(theta), (radius if b is None else b) * gain * np.sin(theta)
    ctrl = np.asarray(centre) + ax[:, None] * np.asarray(u)[None] + by[:, None] * np.asarray(v)[None]
    steps = np.repeat(np.arange(1, segments) / segments, 2)
    knots = np.concatenate([np.zeros(3), steps, np.ones(3)])
    return ctrl, knots, 2, np.where(middle, math.cos(half), 1.0)


def _basis(knots: np.ndarray, degree: int, t: np.ndarray) -> np.ndarray:
    """Cox–de Boor (The NURBS Book eq. 2.5) for a clamped knot vector, `(len(t), n)`; the last
    span is closed at t = 1."""
    n = len(knots) - degree - 1
    span = np.clip(np.searchsorted(knots, t, side="right") - 1, degree, n - 1)
    out = (np.arange(len(knots) - 1)[None] == span[:, None]).astype(float)
    for p in range(1, degree + 1):
        left = knots[: len(knots) - p - 1]
        right = knots[p + 1 :]
        a = np.where(
            knots[p:-1] > left, (t[:, None] - left) / np.where(knots[p:-1] > left, knots[p:-1] - left, 1), 0
        )
        b = np.where(right > knots[1 : len(knots) - p], (right - t[:, None]) / np.where(
            right > knots[1 : len(knots) - p], right - knots[1 : len(knots) - p], 1), 0)  # fmt: skip
        out = a * out[:, :-1] + b * out[:, 1:]
    return out


def _outline(parts, count: int = _OUTLINE) -> np.ndarray:
    """The regularised curve's points `(count, 2)` at evenly spaced parameters (numpy)."""
    ctrl, knots, degree, weights = parts
    if degree == 1:  # every vertex a sample, so corners stay sharp
        at = np.asarray(knots, float)[1:-1]
        t = np.union1d(at, np.linspace(0.0, 1.0, count))
        return np.stack([np.interp(t, at, np.asarray(ctrl, float)[:, i]) for i in range(2)], 1)
    basis = _basis(np.asarray(knots, float), degree, np.linspace(0.0, 1.0, count))
    w = np.ones(len(ctrl)) if weights is None else np.asarray(weights, float)
    return (basis * w) @ np.asarray(ctrl, float) / (basis @ w)[:, None]


def _curve(parts, frame: np.ndarray, dtype) -> BSplineCurve:
    ctrl, knots, degree, weights = parts
    return BSplineCurve(np.asarray(_lift(frame, np.asarray(ctrl)), dtype), np.asarray(knots, dtype), degree,
                        weights=None if weights is None else np.asarray(weights, dtype))  # fmt: skip


def _orientation(q: np.ndarray) -> float:
    """+1 for a counter-clockwise stroke (positive signed area), −1 otherwise."""
    x, y = q[:, 0], q[:, 1]
    return 1.0 if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) >= 0 else -1.0


def _angle_of(q, centre) -> np.ndarray:
    return np.unwrap(np.arctan2(q[:, 1] - centre[1], q[:, 0] - centre[0]))


def _score(e: float) -> float:
    return float(math.exp(-((e / _TOL) ** 2)))


# --- step 4: decide ---------------------------------------------------------------------------
def _decide(q: np.ndarray, smooth: np.ndarray, mask: np.ndarray, closed: bool, size: float):
    """(kind, params in plane coordinates, curve parts or None for a free spline, residual e)."""
    if not closed:
        c, d, rms = fit_line(q)
        if rms / size <= _LINE_TOL:
            ends = c + np.outer([(q[0] - c) @ d, (q[-1] - c) @ d], d)
            return "line", {"endpoints": ends}, _polyline_curve(ends), rms / size
    centre, radius, circle_rms = fit_circle(q)
    poly = fit_polygon(q, mask, closed)
    e_poly = poly.rms / size if poly is not None and (closed or len(poly.vertices) > 2) else math.inf
    if closed:
        fit = fit_ellipse(q)
        e_conic = math.inf if fit is None else fit[3] / size
        if e_poly <= min(e_conic, _TOL) and poly is not None:
            return _closed_polygon(q, poly, e_poly)
        if e_conic <= _TOL and fit is not None:
            return _conic(q, fit, (centre, radius, circle_rms / size), e_conic)
        return "spline", {}, None, min(e_poly, e_conic)
    e_arc = circle_rms / size
    if e_poly <= min(e_arc, _POLYLINE_TOL) and poly is not None and sharp_vertices(smooth, poly.vertices):
        params = {"vertices": poly.vertices, "closed": False}
        return "polyline", params, _polyline_curve(poly.vertices), e_poly
    if e_arc <= _ARC_TOL:
        angles = _angle_of(q, centre)
        params = {"centre": centre, "radius": radius, "start": float(angles[0]), "end": float(angles[-1])}
        return "arc", params, _arc_curve(centre, radius, angles[0], angles[-1] - angles[0]), e_arc
    return "spline", {}, None, min(e_poly, e_arc)


def _closed_polygon(q, poly: Polygon, e: float):
    v = poly.vertices
    kind = polygon_kind(v)
    ring = np.concatenate([v, v[:1]])
    params = {"vertices": v, "closed": True} if kind == "polyline" else {"corners": v}
    return kind, params, _polyline_curve(ring), e


def _conic(q, fit, circle, e_ellipse: float):
    centre, axes, major, _ = fit
    sign = _orientation(q)
    if axes[0] / axes[1] < _ROUND:
        c, r, e = circle
        start = math.atan2(q[0, 1] - c[1], q[0, 0] - c[0])
        return "circle", {"centre": c, "radius": r}, _arc_curve(c, r, start, sign * 2 * math.pi), e
    minor = np.array([-major[1], major[0]])
    local = (q[0] - centre) @ np.stack([major, minor], 1) / axes
    start = math.atan2(local[1], local[0])
    angle = math.atan2(major[1], major[0])
    if angle > math.pi / 2 or angle <= -math.pi / 2:  # the major axis's angle in (−π/2, π/2]
        angle, major, minor, start = angle - math.copysign(math.pi, angle), -major, -minor, start + math.pi
    params = {"centre": centre, "axes": axes, "angle": angle, "major": major}
    parts = _arc_curve(centre, float(axes[0]), start, sign * 2 * math.pi, major, minor, float(axes[1]))
    return "ellipse", params, parts, e_ellipse


_POINT_KEYS = ("endpoints", "centre", "corners", "vertices")


def recognise(points: ArrayLike, times: ArrayLike | None = None) -> Recognised:
    """Recognise and regularise one stroke (thesis §3.1.1, Table 3-1 STEP 2, Fig. 3-3).

    See the module docstring for the chain (clean, resample, fit, decide) and the thresholds.
    The class does not depend on the stroke's position, size or rotation: every test compares
    ratios (residual / bounding-box diagonal, axis and side ratios, angles).

    **Arguments:**
    - `points (N, d)`: the stroke's samples in drawing order, N ≥ 3, d = 2 or 3 (3-D strokes,
      e.g. from `unproject`, are recognised in their best-fitting plane), finite reals.
    - `times (N,)`: strictly increasing time stamps, or `None`; with times a corner must also be
      slow (`corners`' speed test).

    **Returns:** a `Recognised` (kind, params, score, curve, …). Host-side numpy; one compiled
    `corners` call of fixed shape `(_SAMPLES, d)`, and `fit_stroke` for a free stroke.
    """
    pts, t = _inputs(points, times)
    dtype = _checks.float_dtype(np.asarray(points), names=("points",))
    span = None if t is None else (float(t[0]), float(t[-1]))
    pts, t = _clean(pts, t)
    cut = _closure(pts)
    if cut is not None:
        pts, t = pts[: cut + 1], None if t is None else t[: cut + 1]
    res, smooth, res_t = _resample(pts, t, _SAMPLES, cut is not None)  # closed: res_t (M + 1,)
    frame, q = _frame(res)
    size = _extent(q)
    mask = _corner_mask(smooth, res_t, cut is not None)
    smooth_q = (smooth - frame[0]) @ frame[1:].T if smooth.shape[1] == 3 else smooth
    kind, params, parts, e = _decide(q, smooth_q, mask, cut is not None, size)
    if parts is None:
        (curve,) = fit_stroke(np.asarray(res, dtype), None, tol=0.005 * size, split=False)
        outline = res
    else:
        curve, outline = _curve(parts, frame, dtype), _lift(frame, _outline(parts))
    for key in _POINT_KEYS:
        if key in params:
            params[key] = _lift(frame, np.asarray(params[key]))
    if "major" in params:
        params["major"] = params["major"][0] * frame[1] + params["major"][1] * frame[2]
    return Recognised(kind, params, _score(e), curve, res, outline, cut is not None, frame, span)
