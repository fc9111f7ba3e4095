"""Spatial relations between two recognised strokes (thesis §3.1.3, constraints C7–C11; Fig. 3-3).

`relations(a, b)` says how the stroke `b` stands to the stroke `a` (drawn before it), as a set of
names from `RELATIONS`:

* `"intersect"`: the strokes cross (away from an end of an open stroke) — C7 "overlap";
* `"touch"`: they meet without crossing (closest approach below `_CONTACT · D_min`) — C10;
* `"disjoint"`: neither intersect nor touch (Fig. 3-3);
* `"tangent"`: they touch and their directions at the contact agree within `_ANGLE`;
* `"parallel"`, `"perpendicular"`: both are lines, at an angle within `_ANGLE` of 0° / 90° (C8);
* `"vertical"`: `b` is a line standing on `a`'s plane, within `_ANGLE` of its normal (3-D); in
  a 2-D sketch, within `_ANGLE` of the page's up axis `+y` (C9, Fig. 3-4b, c);
* `"inside"`: `a` is closed and every sample of `b`, projected on `a`'s plane, is inside it (C11);
* `"outside"`: `a` is closed, no sample of `b` is inside it and they do not intersect (Fig. 3-4b);
* `"contains"`: `b` is closed and `a` is inside `b`;
* `"within"`: every sample of `b` lies in `a`'s circumscribed circle (centre: `a`'s centre, radius:
  its farthest sample) — the "circle constraint" of Fig. 3-4a;
* `"concentric"`: both have a centre (conics, arcs, polygons) and they agree within
  `_CONTACT · D_max`;
* `"precedes"`: both are timed and `a` ends no later than `b` starts (C7–C10 "X precede Y").

`D_min`, `D_max`: the smaller and larger bounding-box diagonal of the two strokes, so every test
is independent of position, size and rotation. Host-side numpy on the strokes' regularised outlines.
"""

from __future__ import annotations

import math

import numpy as np

from bsjax.sketch._recognise import POLYGONS, Recognised

RELATIONS = (
    "intersect",
    "touch",
    "disjoint",
    "tangent",
    "parallel",
    "perpendicular",
    "vertical",
    "inside",
    "outside",
    "contains",
    "within",
    "concentric",
    "precedes",
)

_CONTACT = 0.05  # contact distance, a fraction of the smaller stroke's size
_ANGLE = math.radians(12)  # angular tolerance of parallel, perpendicular, vertical, tangent
_END = 0.06  # a crossing within this fraction of an open stroke's length of its end is a touch


def _pad(p: np.ndarray) -> np.ndarray:
    """Points `(..., d)` in 3-D (2-D points at z = 0)."""
    return p if p.shape[-1] == 3 else np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], axis=-1)


def _space(r: Recognised) -> np.ndarray:
    """The stroke's regularised outline in 3-D `(K, 3)`."""
    return _pad(r.outline)


def _plane(r: Recognised):
    """Origin and two axes `(3, 3)` of the stroke's plane in 3-D."""
    return _pad(r.frame)


def _on(frame: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Points `(M, 3)` → coordinates `(M, 2)` in the plane `frame`."""
    return (x - frame[0]) @ frame[1:].T


def _arc_fraction(p: np.ndarray) -> np.ndarray:
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    return arc / arc[-1]


def _segment_distances(p: np.ndarray, q: np.ndarray):
    """Closest distance between every segment of `p` and of `q` `(m−1, n−1)`, with the
    closest points' fractions along each segment (sampled at 9 positions: dense enough for
    64-sample strokes, exact on crossings since both sets include the segment ends)."""
    s = np.linspace(0.0, 1.0, 9)
    pa = p[:-1, None] + s[None, :, None] * (p[1:] - p[:-1])[:, None]  # (m−1, 9, 3)
    qa = q[:-1, None] + s[None, :, None] * (q[1:] - q[:-1])[:, None]
    d = np.linalg.norm(pa.reshape(-1, 1, 3) - qa.reshape(1, -1, 3), axis=2)
    return d.reshape(len(p) - 1, 9, len(q) - 1, 9)


def _crossings(p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Proper crossings of two 2-D polylines: the (i, j) pairs of crossing segments."""
    a, b = p2[:-1, None], p2[1:, None]
    c, d = q2[None, :-1], q2[None, 1:]
    cross = lambda u, v: u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    d1, d2 = cross(b - a, c - a), cross(b - a, d - a)
    d3, d4 = cross(d - c, a - c), cross(d - c, b - c)
    return np.argwhere((d1 * d2 < 0) & (d3 * d4 < 0))


def _inside(loop: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Even–odd rule: which points `x (n, 2)` lie inside the closed polygon `loop (m, 2)`."""
    a, b = loop, np.roll(loop, -1, axis=0)
    ya, yb = a[None, :, 1], b[None, :, 1]
    y = x[:, None, 1]
    spans = (ya > y) != (yb > y)
    t = (y - ya) / np.where(yb != ya, yb - ya, 1.0)
    at = a[None, :, 0] + t * (b[None, :, 0] - a[None, :, 0])
    return np.sum(spans & (x[:, None, 0] < at), axis=1) % 2 == 1


def _direction(r: Recognised) -> np.ndarray | None:
    """A line's unit direction in 3-D, `None` for other kinds."""
    if r.kind != "line":
        return None
    e = _pad(np.asarray(r.params["endpoints"], float))
    v = e[1] - e[0]
    return v / np.linalg.norm(v)


def _centre(r: Recognised) -> np.ndarray | None:
    if "centre" in r.params:
        c = np.asarray(r.params["centre"], float)
    elif r.kind in POLYGONS:
        c = np.mean(r.params["corners"], axis=0)
    else:
        return None
    return _pad(c)


def _contact(a: Recognised, b: Recognised, tol: float) -> set[str]:
    p, q = _space(a), _space(b)
    d = _segment_distances(p, q)
    if d.min() > tol:
        return {"disjoint"}
    frame = _plane(a)
    sa, sb = _arc_fraction(p), _arc_fraction(q)
    near_end = lambda s, closed: (not closed) & ((s < _END) | (s > 1 - _END))
    crossing = False
    for i, j in _crossings(_on(frame, p), _on(frame, q)):
        if d[i, :, j].min() <= tol and not (near_end(sa[i], a.closed) or near_end(sb[j], b.closed)):
            crossing = True
            break
    if crossing:
        return {"intersect"}
    out = {"touch"}
    i, _, j, _ = np.unravel_index(np.argmin(d), d.shape)
    u, v = p[i + 1] - p[i], q[j + 1] - q[j]
    cos = abs(u @ v) / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-300)
    if cos > math.cos(_ANGLE):
        out.add("tangent")
    return out


def relations(a: Recognised, b: Recognised) -> frozenset[str]:
    """How stroke `b` stands to stroke `a` (drawn before it): a set of `RELATIONS` names.

    See the module docstring for each relation's test (thesis §3.1.3, C7–C11; Fig. 3-4's
    "vertical", "inside", "outside" and the circle constraint, here `"within"`).

    **Arguments:** `a`, `b`: `Recognised` strokes (`recognise`), of dimension 2 or 3 (mixed: the
    2-D one is read at z = 0).
    **Returns:** a `frozenset[str]`.
    """
    for value, name in ((a, "a"), (b, "b")):
        if not isinstance(value, Recognised):
            raise TypeError(f"{name}: expected a bsjax.sketch.Recognised, got {type(value).__name__}")
    small, large = sorted((a.size, b.size))
    out = _contact(a, b, _CONTACT * small)
    out |= _lines(a, b)
    out |= _containment(a, b, "intersect" in out)
    ca, cb = _centre(a), _centre(b)
    if ca is not None and cb is not None and np.linalg.norm(ca - cb) <= _CONTACT * large:
        out.add("concentric")
    if a.span is not None and b.span is not None and a.span[1] <= b.span[0]:
        out.add("precedes")
    return frozenset(out)


def _lines(a: Recognised, b: Recognised) -> set[str]:
    out = set()
    da, db = _direction(a), _direction(b)
    if da is not None and db is not None:
        cos = abs(da @ db)
        if cos > math.cos(_ANGLE):
            out.add("parallel")
        if cos < math.sin(_ANGLE):
            out.add("perpendicular")
    if db is not None:
        up = np.array([0.0, 1.0, 0.0]) if a.points.shape[1] == 2 and b.points.shape[1] == 2 else a.normal
        if abs(db @ up) > math.cos(_ANGLE):
            out.add("vertical")
    return out


def _containment(a: Recognised, b: Recognised, crossing: bool) -> set[str]:
    out = set()
    pa, pb = _on(_plane(a), _space(a)), _on(_plane(a), _space(b))
    if a.closed:
        inside = _inside(pa, pb)
        if inside.all():
            out.add("inside")
        elif not inside.any() and not crossing:
            out.add("outside")
    if b.closed:
        frame = _plane(b)
        if _inside(_on(frame, _space(b)), _on(frame, _space(a))).all():
            out.add("contains")
    centre = _centre(a)
    c = _on(_plane(a), centre[None])[0] if centre is not None else pa.mean(axis=0)
    if np.linalg.norm(pb - c, axis=1).max() <= np.linalg.norm(pa - c, axis=1).max():
        out.add("within")
    return out
