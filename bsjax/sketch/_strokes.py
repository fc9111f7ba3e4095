"""Strokes to curves and curve editing by over-sketching (thesis ch. 4, §5.1.2).

A stroke is the ordered samples `points (N, d)` (d = 2 or 3) between pen-down and pen-up, with
optional time stamps `times (N,)`. The chain is: `features` (length, speed, direction and the
curvature measure of eq. 4-1) → `corners` (high curvature and low speed) → `resample`
(speed-adaptive thinning, eqs. 4-2/4-3) → `fit_curve` (least squares with the ends interpolated,
eqs. 4-4…4-22) or `fit_stroke` (split at corners, fewest control points meeting a tolerance).
`oversketch` replaces the span of a curve under a new stroke (§4.2), and `unproject` lifts
window points onto a drawing plane (§5.1.2, ray–plane).

Compiled at the boundary (one XLA call per shape): `features`, `corners`, `fit_curve`,
`unproject`. Host-side (their output length depends on the data): `resample`, `fit_stroke`,
`oversketch` — each calls the compiled pieces.

Without `times`, a stroke is taken as sampled at unit time steps: the "speed" of a sample is
then the path length per sample (so `corners` uses the curvature measure alone).
"""

from __future__ import annotations

import itertools
import math
from typing import Literal, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax._typing import ArrayLike
from bsjax.basis import (
    BSplineCurve,
    SplineDirection,
    basis_functions,
    blending_matrix,
    greville,
    insert_knots,
)
from bsjax.collide import Plane

__all__ = [
    "Camera",
    "CurveFit",
    "Features",
    "Oversketch",
    "Resampled",
    "corners",
    "features",
    "fit_curve",
    "fit_stroke",
    "oversketch",
    "resample",
    "unproject",
]


# --- stroke features ----------------------------------------------------------------------------
class Features(eqx.Module):
    """Per-stroke and per-sample features `G(L, S, P, V)` of thesis §3.1.1 / §4.1.1.

    **Fields:**
    - `length ()`: the polyline length L.
    - `arc (N,)`: cumulative path length from the first sample.
    - `speed (N,)`: `S_i = |p_{i+1} − p_{i−1}| / (t_{i+1} − t_{i−1})` (one-sided at the ends); with
      no times, path length per sample (unit time steps).
    - `mean_speed ()`: `S_avg = L / (t_{N−1} − t_0)` (no times: `L / (N − 1)`).
    - `direction (N, d)`: unit direction of the segment leaving each sample (the last sample
      repeats the last segment's); zero for a zero-length segment.
    - `turning (N,)`: the unsigned turning angle at each sample, in [0, π] (0 at the ends).
    - `curvature (N,)`: the curvature measure `C_n` of eq. 4-1.
    """

    length: Float[Array, ""]
    arc: Float[Array, " N"]
    speed: Float[Array, " N"]
    mean_speed: Float[Array, ""]
    direction: Float[Array, "N d"]
    turning: Float[Array, " N"]
    curvature: Float[Array, " N"]


def _stroke(points, name: str = "points", minimum: int = 3):
    points = jnp.asarray(points, _checks.float_dtype(points, names=(name,)))
    _checks.check_ndim(points, name, 2)
    if points.shape[1] not in (2, 3):
        _checks.fail(name, "stroke samples of dimension 2 or 3, shape (N, d)", f"shape {points.shape}")
    if points.shape[0] < minimum:
        _checks.fail(name, f"at least {minimum} samples", points.shape[0])
    return _checks.finite(points, name)


def _times(times, points, name: str = "times"):
    _checks.check_real(times, name)
    times = jnp.asarray(times, points.dtype)
    if times.shape != points.shape[:1]:
        _checks.fail(name, f"shape ({points.shape[0]},) like points", times.shape)
    times = _checks.finite(times, name)
    return _checks.check(times, jnp.diff(times) <= 0, name, "strictly increasing time stamps", "a step <= 0")


def _turning(a, b):
    """Unsigned angle between vectors `a` and `b` (`atan2(|a × b|, a·b)`, the 3-D form of
    `|φ(d_{i+1} − d_i)|`); 0 where either is zero, gradient finite there."""
    if a.shape[-1] == 2:
        cross = jnp.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
    else:
        cross = _safe.norm(jnp.cross(a, b))
    dot = jnp.sum(a * b, axis=-1)
    ok = (cross != 0) | (dot != 0)
    return jnp.where(ok, jnp.arctan2(cross, jnp.where(ok, dot, 1)), 0)


def _features(points, times, k: int) -> Features:
    seg = points[1:] - points[:-1]
    seg_len = _safe.norm(seg)
    arc = jnp.concatenate([jnp.zeros_like(seg_len[:1]), jnp.cumsum(seg_len)])
    length = arc[-1]
    t = jnp.arange(points.shape[0], dtype=points.dtype) if times is None else times
    ahead = jnp.concatenate([points[1:], points[-1:]])
    behind = jnp.concatenate([points[:1], points[:-1]])
    t_ahead = jnp.concatenate([t[1:], t[-1:]])
    t_behind = jnp.concatenate([t[:1], t[:-1]])
    speed = _safe.ratio(_safe.norm(ahead - behind), t_ahead - t_behind)
    mean_speed = _safe.ratio(length, t[-1] - t[0])
    direction = _safe.unit(jnp.concatenate([seg, seg[-1:]]))
    inner = _turning(seg[:-1], seg[1:])
    turning = jnp.concatenate([jnp.zeros_like(inner[:1]), inner, jnp.zeros_like(inner[:1])])
    return Features(length, arc, speed, mean_speed, direction, turning, _curvature_measure(turning, arc, k))


def _curvature_measure(turning, arc, k: int):
    """Eq. 4-1: `C_n = Σ_{i=n−k}^{n+k−1} |φ(d_{i+1} − d_i)| / D(n−k, n+k)`; the turn between
    segments i and i+1 is at sample i+1, so the sum runs over samples n−k+1 … n+k (indices
    clipped to the stroke)."""
    count = turning.shape[0]
    n = np.arange(count)
    cumulative = jnp.concatenate([jnp.zeros_like(turning[:1]), jnp.cumsum(turning)])
    lo_turn, hi_turn = np.clip(n - k + 1, 0, count), np.clip(n + k + 1, 0, count)
    total = cumulative[hi_turn] - cumulative[lo_turn]
    lo, hi = np.clip(n - k, 0, count - 1), np.clip(n + k, 0, count - 1)
    return _safe.ratio(total, arc[hi] - arc[lo])


@compiled
def features(points: Float[Array, "N d"], times: Float[Array, " N"] | None = None, k: int = 2) -> Features:
    """The features of a stroke: length, speed, direction and the curvature measure of eq. 4-1.

    `d_n` is the direction of segment n (2-D: `atan2(Δy, Δx)`); the curvature measure is
    `C_n = Σ_{i=n−k}^{n+k−1} |φ(d_{i+1} − d_i)| / D(n−k, n+k)`, φ wrapping an angle to (−π, π]
    and `D(a, b)` the path length from sample a to b (thesis eq. 4-1, after Yu & Cai, *A
    domain-independent system for sketch recognition*); 3-D strokes use the unsigned angle
    between consecutive segments for `|φ(Δd)|`. Speeds as in thesis §3.1.1.

    **Arguments:**
    - `points (N, d)`: stroke samples, N ≥ 3, d = 2 or 3, finite.
    - `times (N,)`: strictly increasing time stamps, or `None` (unit time steps).
    - `k`: the neighbourhood half-width (thesis default 2), an int ≥ 1.

    **Returns:** `Features` (see its fields).
    """
    points = _stroke(points)
    k = _checks.check_count(k, "k", 1)
    times = None if times is None else _times(times, points)
    return _features(points, times, k)


@compiled
def corners(
    points: Float[Array, "N d"],
    times: Float[Array, " N"] | None = None,
    k: int = 2,
    curvature_factor: float = 2.0,
    speed_factor: float = 0.5,
) -> Bool[Array, " N"]:
    """The corner samples of a stroke: high curvature measure and (with times) low speed.

    A sample is in a corner region when `C_n > curvature_factor · mean(C)` and, when `times` are
    given, `S_n < speed_factor · S_avg` (thesis §4.1.1: "regions of high curvature and low
    speed"; thresholds after Sezgin et al., *Sketch based interfaces: early processing for sketch
    understanding*). Each region is reported by one sample, its largest `C_n` (the first of
    equal ones) within ±k samples; the end samples are never corners.

    **Arguments:** `points (N, d)`, `times (N,)` or `None` as in `features`; `k` an int ≥ 1;
    `curvature_factor` > 0, `speed_factor` > 0 (floats).
    **Returns:** a boolean mask `(N,)`.
    """
    points = _stroke(points)
    k = _checks.check_count(k, "k", 1)
    times = None if times is None else _times(times, points)
    f = _features(points, times, k)
    curvature_factor = _checks.positive(
        _checks.array(curvature_factor, "curvature_factor", points.dtype), "curvature_factor"
    )
    speed_factor = _checks.positive(_checks.array(speed_factor, "speed_factor", points.dtype), "speed_factor")
    return _corner_mask(f, curvature_factor, speed_factor, times is not None, k)


def _corner_region(f: Features, curvature_factor, speed_factor, timed: bool):
    region = f.curvature > curvature_factor * jnp.mean(f.curvature)
    if timed:
        region &= f.speed < speed_factor * f.mean_speed
    return region.at[0].set(False).at[-1].set(False)


def _corner_mask(f: Features, curvature_factor, speed_factor, timed: bool, k: int):
    """One sample per corner region: the region's peak of `C_n` (largest within ±k, the first of
    equal ones), moved to the sharpest turn (largest turning angle) within ±k of it — eq. 4-1's
    window is k samples wide, so its peak can sit up to k samples off the turn itself."""
    region = _corner_region(f, curvature_factor, speed_factor, timed)
    c = jnp.where(region, f.curvature, -jnp.inf)
    count = c.shape[0]
    padded = jnp.concatenate([jnp.full((k,), -jnp.inf, c.dtype), c, jnp.full((k,), -jnp.inf, c.dtype)])
    peak = region
    for s in range(1, k + 1):
        peak &= c > padded[k - s : k - s + count]  # strictly above the samples before
        peak &= c >= padded[k + s : k + s + count]  # at least the samples after
    window = np.clip(np.arange(count)[:, None] + np.arange(-k, k + 1)[None], 1, count - 2)
    sharpest = jnp.asarray(window)[jnp.arange(count), jnp.argmax(f.turning[window], axis=1)]
    at = jnp.where(peak, sharpest, count)
    return jnp.zeros(count, bool).at[at].set(True, mode="drop")


# --- resampling (host-side) ---------------------------------------------------------------------
class Resampled(NamedTuple):
    """The kept samples of `resample`: `points (M, d)`, `times (M,)` or `None`, and their
    indices `index (M,)` into the input stroke."""

    points: np.ndarray
    times: np.ndarray | None
    index: np.ndarray


@declared
def resample(
    points: ArrayLike,
    times: ArrayLike | None = None,
    *,
    step_factor: float = 2.0,
    step_offset: float = 0.5,
    spacing_factor: float = 7.0,
    unit: float = 1.0,
    slow_factor: float = 1.0,
    keep: ArrayLike | None = None,
) -> Resampled:
    """Speed-adaptive ("dynamic threshold") resampling of a stroke (thesis eqs. 4-2, 4-3).

    Walking along the stroke from the first sample: in a slow region (`S_i < slow_factor · S_avg`,
    where corners are) the next kept sample is `m = max(1, floor(step_factor · S_i/S_avg +
    step_offset + ½))` samples on (eq. 4-2, `round(2 S_i/S_avg + 0.5)`); in a fast region the
    next kept sample is the first one at least `m_i = spacing_factor · unit · S_i/S_avg` away
    from the last kept one (eq. 4-3, `7 S_i/S_avg` screen pixels). The thesis constants 2, 0.5
    and 7 are the defaults; `unit` is the size of the thesis's pixel in the caller's units. The
    first and last samples and the samples of `keep` (default: `corners(points, times)`) are
    always kept.

    Host-side (the number of kept samples depends on the data; not compiled) — it calls the
    compiled `features` and `corners`.

    **Arguments:** `points (N, d)`, `times (N,)` or `None` (then the speed is the path length per
    sample); positive floats `step_factor`, `spacing_factor`, `unit`, `slow_factor`,
    `step_offset ≥ 0`; `keep`: a boolean mask `(N,)` or `None`.
    **Returns:** `Resampled(points, times, index)` (numpy arrays).
    """
    for value, name in ((step_factor, "step_factor"), (spacing_factor, "spacing_factor"), (unit, "unit"),
                        (slow_factor, "slow_factor")):  # fmt: skip
        _checks.positive(np.asarray(value, float), name)
    _checks.positive(np.asarray(step_offset, float), "step_offset", strict=False)
    f = features(points, times)
    pts = np.asarray(points, dtype=np.asarray(f.arc).dtype)
    count = pts.shape[0]
    if keep is None:
        keep = corners(points, times)
    keep = np.asarray(keep)
    if keep.shape != (count,) or keep.dtype != np.bool_:
        _checks.fail("keep", f"a boolean mask of shape ({count},)", f"{keep.dtype} {keep.shape}")
    relative = np.asarray(f.speed) / max(float(f.mean_speed), np.finfo(pts.dtype).tiny)
    index = _walk(pts, relative, keep, step_factor, step_offset, spacing_factor * unit, slow_factor)
    kept_times = None if times is None else np.asarray(times, pts.dtype)[index]
    return Resampled(pts[index], kept_times, index)


def _walk(pts, relative, keep, step_factor, step_offset, spacing, slow_factor) -> np.ndarray:
    count = pts.shape[0]
    kept, last, i = [0], 0, 0
    forced = set(np.flatnonzero(keep).tolist()) | {count - 1}
    while i < count - 1:
        if relative[i] < slow_factor:  # eq. 4-2: an index step
            step = max(1, math.floor(step_factor * relative[i] + step_offset + 0.5))
            nxt = min(i + step, count - 1)
        else:  # eq. 4-3: a minimum distance from the last kept sample
            nxt = i + 1
            while nxt < count - 1 and np.linalg.norm(pts[nxt] - pts[last]) < spacing * relative[i]:
                if nxt in forced:
                    break
                nxt += 1
        skipped = [j for j in forced if i < j < nxt]
        nxt = min(skipped) if skipped else nxt
        kept.append(nxt)
        last = i = nxt
    return np.asarray(kept)


# --- least-squares fit ----------------------------------------------------------------------------
class CurveFit(eqx.Module):
    """The result of `fit_curve`: `curve` (a clamped `BSplineCurve`), the data parameters
    `params (N,)`, the distances `residuals (N,)` `|C(t_k) − D_k|` and `max_error ()`."""

    curve: BSplineCurve
    params: Float[Array, " N"]
    residuals: Float[Array, " N"]
    max_error: Float[Array, ""]


Parameters = Literal["chord", "centripetal", "uniform"]  # the rules of `_data_params`


def _data_params(points, method: str):
    """Data parameters on [0, 1]: chord length, centripetal (square roots of the chords) or
    uniform (The NURBS Book eqs. 9.4–9.6)."""
    count = points.shape[0]
    if method == "uniform":
        return jnp.linspace(0.0, 1.0, count, dtype=points.dtype)
    step = _safe.norm(points[1:] - points[:-1])
    if method == "centripetal":
        step = _safe.sqrt(step)
    cumulative = jnp.concatenate([jnp.zeros_like(step[:1]), jnp.cumsum(step)])
    total = _checks.check(
        cumulative[-1], ~(cumulative[-1] > 0), "points", "a stroke of nonzero length", "all points equal"
    )
    return _safe.ratio(cumulative, total).at[-1].set(1.0)


def _averaged_knots(params, n_ctrl, n_max: int, degree: int):
    """Knots for least-squares approximation (The NURBS Book eqs. 9.68–9.69): with m + 1 data
    points and n + 1 control points, `d = (m + 1)/(n − p + 1)` and for j = 1 … n − p,
    `u_{p+j} = (1 − α) t_{i−1} + α t_i` with `i = int(j d)`, `α = j d − i` — every knot span
    then holds a parameter (Schoenberg–Whitney), so the normal equations are regular.

    `n_ctrl` may be traced (≤ the static `n_max`): the vector then has length `n_max + p + 1`,
    its first `n_ctrl + p + 1` knots are those of `n_ctrl` control points and the rest are 1
    (basis functions of zero width, identically 0 — one compilation serves every count)."""
    count = params.shape[0]
    j = jnp.arange(1, n_max - degree)
    jd = j.astype(params.dtype) * (count / (n_ctrl - degree).astype(params.dtype))
    i = jnp.floor(jd)
    alpha = jd - i
    i = jnp.clip(i.astype(j.dtype), 1, count - 1)
    interior = (1 - alpha) * params[i - 1] + alpha * params[i]
    interior = jnp.where(j <= n_ctrl - degree - 1, interior, 1.0)
    ends = jnp.zeros(degree + 1, params.dtype)
    return jnp.concatenate([ends, interior, ends + 1])


def _fit_arrays(points, n_ctrl, n_max: int, degree: int, params_method: str, fix_ends: bool):
    """The fit of `n_ctrl` (possibly traced, ≤ `n_max`) control points as arrays: parameters,
    knots `(n_max + p + 1,)`, control points `(n_max, d)` (zero past `n_ctrl`), residuals.

    eq. 4-8: `Q_k = D_k − N_0(t_k) D_0 − N_n(t_k) D_m`; eq. 4-22: `(NᵀN) P = NᵀQ` over the free
    control points (the unused columns get a unit diagonal, so their solution is 0)."""
    column = jnp.arange(n_max)
    n_ctrl = jnp.asarray(n_ctrl).astype(column.dtype)
    params = _data_params(points, params_method)
    knots = _averaged_knots(params, n_ctrl, n_max, degree)
    a = basis_functions(knots, degree, params)  # (samples, n_max): one row per parameter
    last = n_ctrl - 1
    if fix_ends:
        ends = jnp.where((column == 0)[:, None], points[:1], 0) + jnp.where(
            (column == last)[:, None], points[-1:], 0
        )
        free = (column >= 1) & (column < last)
    else:
        ends = jnp.zeros((n_max, points.shape[1]), points.dtype)
        free = column <= last
    rhs = points - a @ ends
    rows = slice(1, -1) if fix_ends else slice(None)
    a_free = jnp.where(free[None], a[rows], 0)
    normal = a_free.T @ a_free + jnp.diag(jnp.where(free, 0.0, 1.0).astype(a.dtype))
    ctrl = jnp.linalg.solve(normal, a_free.T @ rhs[rows]) + ends
    residuals = _safe.norm(a @ ctrl - points)
    return params, knots, ctrl, residuals


def _fit(points, n_ctrl: int, degree: int, params_method: str, fix_ends: bool) -> CurveFit:
    params, knots, ctrl, residuals = _fit_arrays(points, n_ctrl, n_ctrl, degree, params_method, fix_ends)
    curve = BSplineCurve(ctrl, knots, degree)
    return CurveFit(curve, params, residuals, jnp.max(residuals))


@compiled
def fit_curve(
    points: Float[Array, "N d"],
    n_ctrl: int,
    degree: int = 3,
    *,
    params: Parameters = "chord",
    fix_ends: bool = True,
) -> CurveFit:
    """The least-squares B-spline of `n_ctrl` control points through a stroke, ends interpolated.

    With data `D_0 … D_m` at parameters `t_k` and `P_0 = D_0`, `P_n = D_m` fixed, the inner control
    points minimise `Σ_{k=1}^{m−1} |Q_k − Σ_{i=1}^{n−1} N_{i,p}(t_k) P_i|²` with
    `Q_k = D_k − N_{0,p}(t_k) D_0 − N_{n,p}(t_k) D_m`, i.e. the normal equations `(NᵀN) P = NᵀQ`
    (thesis eqs. 4-4…4-22; The NURBS Book §9.4.1, eqs. 9.63–9.67), solved by QR. Knots by
    averaging (The NURBS Book eqs. 9.68–9.69); parameters by chord length (eq. 9.5), centripetal
    (eq. 9.6) or uniform.

    **Arguments:**
    - `points (N, d)`: stroke samples, d = 2 or 3, finite, N ≥ `n_ctrl`.
    - `n_ctrl`: number of control points, an int with `degree < n_ctrl ≤ N`.
    - `degree`: an int ≥ 1 (thesis: 3).
    - `params`: "chord", "centripetal" or "uniform".
    - `fix_ends`: interpolate the end points exactly (else plain least squares over all).

    **Returns:** `CurveFit(curve, params, residuals, max_error)`. Differentiable in `points`
    (through the parameters and knots too).
    """
    points = _stroke(points, minimum=2)
    n_ctrl = _checks.check_count(n_ctrl, "n_ctrl", 2)
    _checks.check_degree(degree, "degree", n_ctrl, "the fitted curve")
    if n_ctrl > points.shape[0]:
        _checks.fail("n_ctrl", f"at most the {points.shape[0]} stroke samples", n_ctrl)
    if not isinstance(fix_ends, (bool, np.bool_)):
        raise TypeError(f"fix_ends: expected a bool, got {type(fix_ends).__name__}")
    return _fit(points, n_ctrl, degree, params, bool(fix_ends))


@declared
def fit_stroke(
    points: ArrayLike,
    times: ArrayLike | None = None,
    tol: float = 1e-2,
    *,
    degree: int = 3,
    split: bool = True,
    params: Parameters = "chord",
) -> list[BSplineCurve]:
    """A stroke as B-spline curves split at its corners, each with the fewest control points whose
    fit meets `tol` (thesis §4.1: corners split the stroke, each part is fitted with fixed ends,
    so consecutive curves join C0 at the corners).

    The control count of each part is found by bisection between `degree + 1` and the part's
    sample count (a host-side loop over the compiled `fit_curve`; the largest count interpolates).

    **Arguments:** `points (N, d)`, `times (N,)` or `None` (as in `corners`); `tol` > 0: the
    largest allowed distance between a sample and the curve, in the stroke's units; `degree` an
    int ≥ 1; `split`: split at `corners` (else one curve); `params` as in `fit_curve`.
    **Returns:** a list of clamped `BSplineCurve`s, in stroke order.
    """
    _checks.positive(np.asarray(tol, float), "tol")
    degree = _checks.check_count(degree, "degree", 1)
    pts = np.asarray(_stroke(points))
    cuts = np.flatnonzero(np.asarray(corners(points, times))) if split else np.zeros(0, int)
    bounds = [0, *cuts.tolist(), pts.shape[0] - 1]
    return [_fewest(pts[a : b + 1], tol, degree, params) for a, b in itertools.pairwise(bounds)]


def _fewest(piece, tol: float, degree: int, params: str) -> BSplineCurve:
    """Bisection on the control count with one compiled kernel per piece length (the count is
    traced, `_fit_arrays` pads to the sample count)."""
    count = piece.shape[0]
    deg = min(degree, count - 1)
    lo, hi = deg + 1, count
    while lo < hi:
        mid = (lo + hi) // 2
        if float(np.max(_padded_fit(piece, np.asarray(mid), count, deg, params)[3])) <= tol:
            hi = mid
        else:
            lo = mid + 1
    _, knots, ctrl, _ = _padded_fit(piece, np.asarray(lo), count, deg, params)
    return BSplineCurve(np.asarray(ctrl)[:lo], np.asarray(knots)[: lo + deg + 1], deg)


@compiled
def _padded_fit(points, n_ctrl, n_max: int, degree: int, params: str):
    return _fit_arrays(points, n_ctrl, n_max, degree, params, True)


# --- over-sketching (host-side) -------------------------------------------------------------------
class Oversketch(NamedTuple):
    """The result of `oversketch`: the edited `curve`, and the parameters `start < end` (of the
    edited curve) bounding the span that changed; outside `[start, end]` the curve is the
    original one exactly."""

    curve: BSplineCurve
    start: float
    end: float


_SAMPLES = 1024  # dense samples of the original curve for the projections


@declared
def oversketch(curve: BSplineCurve, stroke_curve: BSplineCurve, scale: float = 1.0) -> Oversketch:
    """Replace the span of `curve` under a new stroke by the stroke (thesis §4.2, Figs. 4-4…4-7).

    1. The stroke's ends `Ps`, `Pe` are projected onto the curve (`P's`, `P'e`, parameters
       `ts < te`; a stroke drawn against the curve's direction is reversed).
    2. Transitions (eqs. 4-24…4-26): `M` is the mean distance between neighbouring control
       points of the curve; the transition control point `CTs` before `P's` is, among those at a
       distance `M ≤ Δd = |Ps CTs| ≤ 1.5 M`, the one with the least tangent-angle difference
       `0 < Δφ < π/2` between `CTs→Ps` and `CT_{s−1}→CTs` (eq. 4-26, as a 3-D angle); else the
       nearest with `Δd ≥ M` (or the curve's start). `CTe` likewise after `P'e`. The edited span
       is `[start, end]` = the Greville parameters of `CTs` and `CTe`.
    3. Knots are inserted in the span (exact refinement, The NURBS Book §5.2) so that its control
       points can follow the stroke; the control points `y_i` whose support lies in the span
       are fitted by least squares to the target: the stroke on `[ts, te]` (linear in the
       parameter), the curve plus a smooth ramp to the stroke's end gaps on the transitions.
    4. Eq. 4-23 with `d_i = y_i − c_i`, the displacement from the curve's own (refined) control
       point `c_i`: `y'_i = y_i − (1 − scale) d_i`. So `scale = 0` gives the original curve
       exactly, `scale = 1` follows the stroke, and the curve is unchanged outside the span
       (the new control points' basis functions vanish there; the joins stay C^{p−1}).

    A closed (periodic) curve is first written exactly as a clamped curve (its uniform knots
    `j/n`, the seam moved by whole control points to lie opposite the stroke), so the result is
    a clamped curve that closes at its seam.

    Host-side (the control count of the result depends on the data; not compiled).

    **Arguments:** `curve`: a polynomial `BSplineCurve`; `stroke_curve`: a clamped polynomial
    `BSplineCurve` of the same dimension (e.g. from `fit_stroke`); `scale` in [0, 1].
    **Returns:** `Oversketch(curve, start, end)`.
    """
    for c, name in ((curve, "curve"), (stroke_curve, "stroke_curve")):
        if not isinstance(c, BSplineCurve):
            raise TypeError(f"{name}: expected a BSplineCurve, got {type(c).__name__}")
        if c.weights is not None:
            _checks.fail(name, "a polynomial curve (weights None)", "a rational curve")
    if stroke_curve.periodic:
        _checks.fail("stroke_curve", "a clamped (open) curve", "a periodic curve")
    if stroke_curve.dim != curve.dim:
        _checks.fail("stroke_curve", f"dimension {curve.dim} like curve", stroke_curve.dim)
    _checks.in_range(np.asarray(scale, float), "scale", 0.0, 1.0)
    stroke = np.asarray(stroke_curve.evaluate(jnp.linspace(0.0, 1.0, _SAMPLES)))
    if curve.periodic:
        curve = _open_at(curve, stroke)
    return _replace(curve, stroke_curve, stroke, float(scale))


def _dense(curve: BSplineCurve):
    t = np.linspace(0.0, 1.0, _SAMPLES)
    return t, np.asarray(curve.evaluate(jnp.asarray(t, curve.ctrl.dtype)))


def _foot(t, samples, x) -> float:
    return float(t[np.argmin(np.linalg.norm(samples - x[None], axis=1))])


def _open_at(curve: BSplineCurve, stroke) -> BSplineCurve:
    """A periodic curve as the exactly equal clamped curve, its seam rolled by whole control
    points to the parameter opposite the stroke's middle."""
    n, p = curve.n_ctrl, curve.degree
    t, samples = _dense(curve)
    middle = _foot(t, samples, stroke[len(stroke) // 2])
    shift = int(round((middle - 0.5) * n)) % n
    rolled = np.roll(np.asarray(curve.ctrl), -shift, axis=0)
    periodic = BSplineCurve(rolled, None, p, periodic=True)
    knots = np.concatenate([np.zeros(p + 1), np.arange(1, n) / n, np.ones(p + 1)])
    clamped = SplineDirection(jnp.asarray(knots, curve.ctrl.dtype), p)
    probe = jnp.asarray(np.linspace(0.0, 1.0, 4 * (n + p)), curve.ctrl.dtype)
    ctrl = np.linalg.lstsq(
        np.asarray(clamped.matrix(probe)), np.asarray(periodic.evaluate(probe)), rcond=None
    )[0]
    return BSplineCurve.from_direction(jnp.asarray(ctrl, curve.ctrl.dtype), clamped)


def _transition(ctrl, xi, end_point, side: int, spacing: float) -> float:
    """The Greville parameter of the transition control point (eqs. 4-25, 4-26) on one side
    (`side = −1`: before the stroke's start; `+1`: after its end)."""
    n = ctrl.shape[0]
    dist = np.linalg.norm(ctrl - end_point[None], axis=1)
    foot = int(np.argmin(dist))
    order = range(foot, -1, -1) if side < 0 else range(foot, n)
    best, best_angle, fallback = None, np.inf, None
    for j in order:
        if dist[j] >= spacing and fallback is None:
            fallback = j
        if not 0 <= j + side < n:
            continue
        if spacing <= dist[j] <= 1.5 * spacing:
            toward = end_point - ctrl[j]
            along = ctrl[j] - ctrl[j - 1] if side < 0 else ctrl[j] - ctrl[j + 1]
            angle = _angle(toward, along)
            if 0 < angle < math.pi / 2 and angle < best_angle:
                best, best_angle = j, angle
    chosen = best if best is not None else fallback
    if chosen is None:
        return 0.0 if side < 0 else 1.0
    return float(xi[chosen])


def _angle(a, b) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 0.0
    return float(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0)))


def _replace(curve: BSplineCurve, stroke_curve: BSplineCurve, stroke, scale: float) -> Oversketch:
    t, samples = _dense(curve)
    ts, te = _foot(t, samples, stroke[0]), _foot(t, samples, stroke[-1])
    if te < ts:
        stroke, ts, te = stroke[::-1], te, ts
    if te <= ts:
        _checks.fail("stroke_curve", "a stroke whose ends project to two different points of curve", "one")
    ctrl = np.asarray(curve.ctrl, np.float64)
    p = curve.degree
    xi = greville(np.asarray(curve.knots), p)
    spacing = float(np.mean(np.linalg.norm(np.diff(ctrl, axis=0), axis=1)))  # M (eq. 4-25, prose)
    start = min(_transition(ctrl, xi, stroke[0], -1, spacing), ts)
    end = max(_transition(ctrl, xi, stroke[-1], +1, spacing), te)
    refined = _refine(curve, start, end, stroke_curve.n_ctrl * (end - start) / (te - ts))
    knots = np.asarray(refined.knots, np.float64)
    n = refined.n_ctrl
    free = np.flatnonzero((knots[:n] >= start) & (knots[p + 1 : n + p + 1] <= end))
    if start == 0.0:
        free = np.union1d(free, [0])
    if end == 1.0:
        free = np.union1d(free, [n - 1])
    params = np.linspace(start, end, 8 * (n + p))
    a = np.asarray(blending_matrix(refined.knots, p, jnp.asarray(params, refined.ctrl.dtype)))
    base = a @ np.asarray(refined.ctrl, np.float64)  # the original curve at `params`
    gaps = (stroke[0] - samples[np.searchsorted(t, ts)], stroke[-1] - samples[np.searchsorted(t, te)])
    target = _target(base, stroke, params, (ts, te), (start, end), gaps)
    delta = np.linalg.lstsq(a[:, free], target - base, rcond=None)[0]
    new = np.asarray(refined.ctrl, np.float64).copy()
    new[free] += scale * delta  # eq. 4-23: y' = y − (1 − scale) d, d = y − c
    edited = refined.with_ctrl(jnp.asarray(new, refined.ctrl.dtype))
    return Oversketch(edited, float(start), float(end))


def _refine(curve: BSplineCurve, start: float, end: float, density: float) -> BSplineCurve:
    """The curve with knots inserted uniformly in `[start, end]` (and at its ends): about as many
    spans per parameter length on the stroke's part as the stroke has control points, and
    `p + 1` more for each transition."""
    p = curve.degree
    intervals = math.ceil(density) + 3 * p + 2
    values = np.linspace(start, end, intervals + 1)
    knots = np.asarray(curve.knots, np.float64)
    values = values[(values > 0) & (values < 1)]
    new = [v for v in values if not np.any(np.isclose(knots, v, rtol=0, atol=1e-12))]
    if not new:
        return curve
    refined = insert_knots(curve, np.asarray(new))
    assert isinstance(refined, BSplineCurve)
    return refined


def _target(base, stroke, params, stroke_span, span, gaps):
    """Target points on the span: the stroke on `[ts, te]` (linear in the parameter), and on the
    transitions the curve (`base`) plus a smoothstep ramp to the gap between the stroke's end and
    its projection."""
    (ts, te), (start, end) = stroke_span, span
    on_stroke = _along(stroke, np.clip((params - ts) / (te - ts), 0.0, 1.0))
    before = np.clip(_ratio(params - start, ts - start), 0.0, 1.0)
    after = np.clip(_ratio(end - params, end - te), 0.0, 1.0)
    ramp = lambda x: x * x * (3 - 2 * x)
    out = np.where(((params >= ts) & (params <= te))[:, None], on_stroke, base)
    out = out + np.where((params < ts)[:, None], ramp(before)[:, None] * gaps[0][None], 0)
    return out + np.where((params > te)[:, None], ramp(after)[:, None] * gaps[1][None], 0)


def _ratio(a, b):
    return a / b if b > 0 else np.ones_like(a)


def _along(samples, s):
    """Points at fractions `s` of a densely sampled polyline's index range (linear)."""
    x = s * (samples.shape[0] - 1)
    i = np.clip(np.floor(x).astype(int), 0, samples.shape[0] - 2)
    f = (x - i)[:, None]
    return (1 - f) * samples[i] + f * samples[i + 1]


# --- 2-D → 3-D ------------------------------------------------------------------------------------
class Camera(eqx.Module):
    """A perspective camera (thesis §5.1.2): `eye (3,)`, `target (3,)`, `up (3,)` (not parallel
    to the view direction), vertical field of view `fov` in radians (0, π), `aspect` = width /
    height > 0. The window is normalised: (0, 0) lower-left, (1, 1) upper-right."""

    eye: Float[Array, "3"]
    target: Float[Array, "3"]
    up: Float[Array, "3"]
    fov: Float[Array, ""]
    aspect: Float[Array, ""]

    def __init__(self, eye, target, up=(0.0, 0.0, 1.0), fov: float = math.pi / 3, aspect: float = 1.0):
        dtype = _checks.float_dtype(eye, target, names=("eye", "target"))
        self.eye, self.target, self.up = (
            _checks.finite(_checks.vector3(v, name, dtype), name)
            for v, name in ((eye, "eye"), (target, "target"), (up, "up"))
        )
        angle = _checks.array(fov, "fov", dtype)
        bad = ~((angle > 0) & (angle < math.pi))
        self.fov = _checks.check(angle, bad, "fov", "an angle in (0, π)", "a value outside (or NaN)")
        self.aspect = _checks.positive(_checks.array(aspect, "aspect", dtype), "aspect")

    def frame(self):
        """`(forward, right, up)` unit vectors of the view."""
        forward = _safe.unit(self.target - self.eye)
        right = _safe.unit(jnp.cross(forward, self.up))
        return forward, right, jnp.cross(right, forward)

    def ray(self, window_xy: Float[Array, "... 2"]) -> Float[Array, "... 3"]:
        """Unit ray directions from the eye through window points `(..., 2)` (a kernel)."""
        forward, right, up = self.frame()
        flat = window_xy.reshape(-1, 2)
        h = jnp.tan(self.fov / 2)
        x = (2 * flat[:, :1] - 1) * (h * self.aspect)
        y = (2 * flat[:, 1:] - 1) * h
        ray = _safe.unit(forward[None] + x * right[None] + y * up[None])
        return ray.reshape(window_xy.shape[:-1] + (3,))


@compiled
def unproject(window_xy: Float[Array, "... 2"], camera: Camera, plane: Plane) -> Float[Array, "... 3"]:
    """Window points lifted onto a drawing plane: the intersection of the camera ray through
    each point with the plane (thesis §5.1.2, eq. 5-1 as ray–plane intersection:
    `x = e + s r`, `s = n·(p − e) / n·r`).

    **Arguments:** `window_xy (..., 2)` normalised window coordinates (finite); `camera`: a
    `Camera`; `plane`: a `bsjax.collide.Plane` (point, normal).
    **Returns:** `(..., 3)` points on the plane. Rays parallel to the plane or meeting it behind
    the eye are an error. Differentiable in every input.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera: expected a bsjax.sketch.Camera, got {type(camera).__name__}")
    if not isinstance(plane, Plane):
        raise TypeError(f"plane: expected a bsjax.collide.Plane, got {type(plane).__name__}")
    _checks.check_real(window_xy, "window_xy")
    xy = jnp.asarray(window_xy, camera.eye.dtype)
    if xy.ndim < 1 or xy.shape[-1] != 2:
        _checks.fail("window_xy", "window points of shape (..., 2)", f"shape {xy.shape}")
    xy = _checks.finite(xy, "window_xy")
    ray = camera.ray(xy)
    n = plane.normal.astype(ray.dtype)
    facing = ray @ n
    reach = (plane.point.astype(ray.dtype) - camera.eye) @ n
    s = _safe.ratio(jnp.broadcast_to(reach, facing.shape), facing)
    bad = ~(jnp.abs(facing) > 64 * jnp.finfo(ray.dtype).eps) | ~(s > 0)
    s = _checks.check(s, bad, "window_xy", "points whose rays meet the plane in front of the camera", "a ray "
                      "parallel to the plane or meeting it behind the eye")  # fmt: skip
    return jnp.expand_dims(camera.eye, tuple(range(ray.ndim - 1))) + s[..., None] * ray
