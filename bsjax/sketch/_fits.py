"""The primitive fits of `recognise` (step 3), on a stroke's plane coordinates `(M, 2)`, numpy.

`fit_line` (total least squares), `fit_circle` (Kåsa's algebraic fit refined by Gauss–Newton),
`fit_ellipse` (Fitzgibbon, Pilu & Fisher, *Direct least square fitting of ellipses*, IEEE PAMI
1999, in Halíř & Flusser's numerically stable form), `fit_polygon` (corner candidates merged
while their edges turn by less than `_MERGE_TURN`; edges by total least squares, corners their
intersections), `sharp_vertices` (corners, not the crests of a smooth curve) and `polygon_kind`
(triangle, square, rectangle, diamond from the corners' sides and angles).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

_GAP = 5  # candidates nearer than this many samples are one corner (`corners` may report two)
_MERGE_TURN = math.radians(30)  # candidate vertices between edges turning less are dropped
_WINDOW = 3  # samples either side of a vertex whose chords' turn must be …
_SHARP = 0.6  # … at least this fraction of the turn between the vertex's edges
_RIGHT = math.radians(12)  # largest deviation from 90° of a rectangle's angles
_SQUARE = 1.2  # largest long/short side ratio of a square
_RHOMBUS = 1.3  # largest long/short side ratio of a diamond


def fit_line(q: np.ndarray):
    """Total least squares: (centroid, unit direction along the samples' order, rms distance)."""
    c = q.mean(axis=0)
    _, _, vt = np.linalg.svd(q - c, full_matrices=False)
    d = vt[0] if (q[-1] - q[0]) @ vt[0] >= 0 else -vt[0]
    normal = np.array([-d[1], d[0]])
    return c, d, float(np.sqrt(np.mean(((q - c) @ normal) ** 2)))


def fit_circle(q: np.ndarray):
    """Geometric circle fit: Kåsa's linear fit `x² + y² = a x + b y + c`, then Gauss–Newton on
    `Σ (|q − c| − r)²`. Returns (centre, radius, rms)."""
    a = np.column_stack([q, np.ones(len(q))])
    sol = np.linalg.lstsq(a, np.sum(q * q, axis=1), rcond=None)[0]
    centre = 0.5 * sol[:2]
    radius = math.sqrt(max(sol[2] + centre @ centre, 1e-300))
    for _ in range(8):
        diff = q - centre
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(q))])
        step = np.linalg.lstsq(jac, -(dist - radius), rcond=None)[0]
        centre, radius = centre + step[:2], radius + step[2]
    dist = np.linalg.norm(q - centre, axis=1)
    return centre, abs(radius), float(np.sqrt(np.mean((dist - abs(radius)) ** 2)))


def fit_ellipse(q: np.ndarray):
    """Direct least-squares ellipse (Fitzgibbon et al.; Halíř & Flusser's partition of the
    scatter matrix), on centred, scaled samples. Returns (centre, (a, b), major unit vector,
    rms Sampson distance) or `None` when no ellipse fits."""
    shift, scale = q.mean(axis=0), float(np.abs(q - q.mean(axis=0)).max())
    x, y = ((q - shift) / scale).T
    d1 = np.column_stack([x * x, x * y, y * y])
    d2 = np.column_stack([x, y, np.ones_like(x)])
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    m = np.stack([m[2] / 2, -m[1], m[0] / 2])
    _, v = np.linalg.eig(m)
    v = np.real(v)
    ok = 4 * v[0] * v[2] - v[1] ** 2 > 0
    if not ok.any():
        return None
    a1 = v[:, np.flatnonzero(ok)[0]]
    conic = np.concatenate([a1, t @ a1])  # A x² + B xy + C y² + D x + E y + F
    quad = np.array([[conic[0], conic[1] / 2], [conic[1] / 2, conic[2]]])
    centre = np.linalg.solve(2 * quad, -conic[3:5])
    value = conic[5] + 0.5 * conic[3:5] @ centre
    lam, vec = np.linalg.eigh(quad)
    if not (np.all(lam * -value > 0)):
        return None
    axes = np.sqrt(-value / lam)
    order = np.argsort(-axes)  # a ≥ b (the conic's sign decides which λ is the larger axis)
    axes, vec = axes[order], vec[:, order]
    grad = 2 * np.column_stack([x, y]) @ quad + conic[3:5]
    f = np.einsum("ni,ij,nj->n", np.column_stack([x, y]), quad, np.column_stack([x, y]))
    f = f + np.column_stack([x, y]) @ conic[3:5] + conic[5]
    rms = float(np.sqrt(np.mean((f / np.maximum(np.linalg.norm(grad, axis=1), 1e-300)) ** 2)))
    return shift + scale * centre, scale * axes, vec[:, 0], scale * rms


class Polygon(NamedTuple):
    """A polygon fit: regularised vertices `(k, 2)` (closed: the corners; open: ends included)
    and the rms distance of the samples to their edges' lines."""

    vertices: np.ndarray
    rms: float


def _edge(q, a: int, b: int, closed: bool) -> np.ndarray:
    n = len(q)
    return q[np.arange(a, b + n + 1) % n] if closed and b <= a else q[a : b + 1]


def _edge_fits(q, vs: list[int], closed: bool):
    n = len(q)
    pairs = zip(vs, vs[1:] + vs[:1]) if closed else zip([0, *vs], [*vs, n - 1])
    return [fit_line(_edge(q, a, b, closed)) for a, b in pairs]


def _turns(fits, closed: bool) -> np.ndarray:
    """The turn between the edges meeting at each vertex (closed: vertex j joins edges j − 1
    and j; open: edges j and j + 1)."""
    d = np.stack([f[1] for f in fits])
    ahead = d if closed else d[1:]
    behind = np.roll(d, 1, axis=0) if closed else d[:-1]
    return np.arccos(np.clip(np.sum(ahead * behind, axis=1), -1.0, 1.0))


def _meet(f0, f1, fallback) -> np.ndarray:
    """The intersection of two fitted lines (the sample `fallback` when nearly parallel)."""
    (c0, d0, _), (c1, d1, _) = f0, f1
    cross = d0[0] * d1[1] - d0[1] * d1[0]
    if abs(cross) < math.sin(math.radians(10)):
        return fallback
    diff = c1 - c0
    return c0 + d0 * (diff[0] * d1[1] - diff[1] * d1[0]) / cross


def fit_polygon(q: np.ndarray, mask: np.ndarray, closed: bool) -> Polygon | None:
    """Candidate vertices (the corner samples), merged while the
    two edges at a vertex turn by less than `_MERGE_TURN` (the flattest first); edges are
    total-least-squares lines, the corners their intersections."""
    n = len(q)
    vs: list[int] = []
    for i in np.flatnonzero(mask).tolist():
        if (not vs or i - vs[-1] >= _GAP) and (closed or n - 1 - i >= 3) and i >= (0 if closed else 3):
            vs.append(i)
    if closed and len(vs) > 1 and n - vs[-1] + vs[0] < _GAP:
        vs.pop()
    while vs:
        fits = _edge_fits(q, vs, closed)
        turns = _turns(fits, closed)
        j = int(np.argmin(turns))
        if turns[j] >= _MERGE_TURN:
            break
        vs.pop(j)
    if closed and len(vs) < 3:
        return None
    fits = _edge_fits(q, vs, closed)
    sq = [f[2] ** 2 * len(_edge(q, a, b, closed)) for f, (a, b) in zip(fits, _pairs(vs, n, closed))]
    rms = math.sqrt(sum(sq) / sum(len(_edge(q, a, b, closed)) for a, b in _pairs(vs, n, closed)))
    if closed:
        corners_ = [_meet(fits[j - 1], fits[j], q[vs[j]]) for j in range(len(vs))]
    else:
        ends = [fits[0][0] + fits[0][1] * ((q[0] - fits[0][0]) @ fits[0][1])]
        inner = [_meet(fits[j], fits[j + 1], q[vs[j]]) for j in range(len(vs))]
        last = fits[-1][0] + fits[-1][1] * ((q[-1] - fits[-1][0]) @ fits[-1][1])
        corners_ = [*ends, *inner, last]
    return Polygon(np.asarray(corners_), rms)


def sharp_vertices(smooth: np.ndarray, vertices: np.ndarray) -> bool:
    """Whether an open polyline's vertices are corners rather than the crests of a smooth curve:
    at each interior vertex, the chords of the smoothed samples `(M, 2)` reaching `_WINDOW`
    samples either side turn by at least `_SHARP` of the turn between its two edges (a crest
    spreads its turn along the curve, a corner makes it at one place)."""
    n = len(smooth)
    for a, v, b in zip(vertices[:-2], vertices[1:-1], vertices[2:]):
        i = int(np.clip(np.argmin(np.linalg.norm(smooth - v, axis=1)), 1, n - 2))
        into, out = smooth[i] - smooth[max(i - _WINDOW, 0)], smooth[min(i + _WINDOW, n - 1)] - smooth[i]
        if _angle(into, out) < _SHARP * _angle(v - a, b - v):
            return False
    return True


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    cos = a @ b / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-300)
    return math.acos(float(np.clip(cos, -1.0, 1.0)))


def _pairs(vs: list[int], n: int, closed: bool):
    return list(zip(vs, vs[1:] + vs[:1])) if closed else list(zip([0, *vs], [*vs, n - 1]))


def polygon_kind(v: np.ndarray) -> str:
    """Triangle, square, rectangle, diamond or polyline from a closed polygon's corners `(k, 2)`."""
    if len(v) == 3:
        return "triangle"
    if len(v) != 4:
        return "polyline"
    sides = np.linalg.norm(np.roll(v, -1, axis=0) - v, axis=1)
    into, out = np.roll(v, 1, axis=0) - v, np.roll(v, -1, axis=0) - v
    cos = np.sum(into * out, axis=1) / np.maximum(
        np.linalg.norm(into, axis=1) * np.linalg.norm(out, axis=1), 1e-300
    )
    angles = np.arccos(np.clip(cos, -1.0, 1.0))
    if np.max(np.abs(angles - math.pi / 2)) < _RIGHT:
        ratio = (sides[0] + sides[2]) / (sides[1] + sides[3])
        return "square" if max(ratio, 1 / ratio) < _SQUARE else "rectangle"
    return "diamond" if sides.max() / sides.min() < _RHOMBUS else "polyline"
