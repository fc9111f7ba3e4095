"""The geometry of `bsjax studio`: the drawing plane, drawn curves, built surfaces.

Everything here is plain calls of the public API — `sketch.unproject` (thesis §5.1.2,
eqs. 5-1/5-2), `sketch.recognise`, `sketch.oversketch`, `sketch.compose`, `bsjax.construct`,
`bsjax.sculpt` — so a script that makes the same calls gets the same surfaces, bit for bit.

A stroke is unprojected onto the drawing plane and recognised in the plane's 2-D coordinates
`q = ((x − o)·e₁, (x − o)·e₂)`; its regularised curve is lifted back, `o + q₁ e₁ + q₂ e₂`. A
2-D composite of `sketch.compose` (its third axis the page's normal, ẑ) is lifted the same way
with `z n`. On the default plane (o = 0, e₁ = x̂, e₂ = ŷ, n = ẑ) both maps are the identity.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from bsjax import construct, sketch
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.collide import Plane


class CommandError(ValueError):
    """A command the session cannot carry out; the message names the field at fault."""


class DrawingPlane(NamedTuple):
    """The plane strokes are drawn on: `origin (3,)`, orthonormal in-plane axes `e1`, `e2` and
    `normal = e1 × e2`."""

    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray

    @classmethod
    def through(cls, point, normal) -> DrawingPlane:
        """The plane through `point` with `normal`; e₁ is x̂ made orthogonal to the normal (ŷ when
        the normal is along x̂), e₂ = n × e₁."""
        n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
        seed = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = seed - (seed @ n) * n
        e1 = e1 / np.linalg.norm(e1)
        return cls(np.asarray(point, np.float64), e1, np.cross(n, e1), n)

    def tool(self, dtype) -> Plane:
        return Plane(self.origin.astype(dtype), self.normal.astype(dtype))

    def coords(self, points: np.ndarray) -> np.ndarray:
        """Plane coordinates `(N, 2)` of points `(N, 3)`."""
        d = np.asarray(points) - self.origin
        return np.stack([d @ self.e1, d @ self.e2], axis=1)

    def lift(self, q: np.ndarray) -> np.ndarray:
        """Plane coordinates `(..., 2)` or plane-and-normal coordinates `(..., 3)` → space."""
        q = np.asarray(q)
        out = self.origin + q[..., :1] * self.e1 + q[..., 1:2] * self.e2
        return out + q[..., 2:3] * self.normal if q.shape[-1] == 3 else out

    def lift_curve(self, curve: BSplineCurve) -> BSplineCurve:
        if curve.dim == 3:
            return curve
        ctrl = np.asarray(curve.ctrl)
        return BSplineCurve(self.lift(ctrl).astype(ctrl.dtype), curve.knots, curve.degree, curve.periodic,
                            curve.weights)  # fmt: skip

    def lift_surface(self, surface: BSplineSurface) -> BSplineSurface:
        ctrl = np.asarray(surface.ctrl)
        return surface.with_ctrl(self.lift(ctrl).astype(ctrl.dtype))

    def message(self) -> dict:
        return {k: getattr(self, k).tolist() for k in self._fields}


DEFAULT_PLANE = DrawingPlane.through((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))


@dataclasses.dataclass(frozen=True, eq=False)
class Item:
    """A curve of the session: `id`, `kind` (a `sketch.KINDS` name, `"oversketched"` or
    `"loaded"`), `curve` (3-D), `plane` it was drawn on, `flat` (its 2-D curve in the plane's
    coordinates, or None), `recognised` (`sketch.Recognised`, or None once edited or loaded),
    `stroke (N, 3)` the unprojected samples (or None)."""

    id: int
    kind: str
    curve: BSplineCurve
    plane: DrawingPlane
    flat: BSplineCurve | None = None
    recognised: sketch.Recognised | None = None
    stroke: np.ndarray | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class Body:
    """A surface of the session: `id`, `op` (how it was made), `surface`, `sources` (item ids)."""

    id: int
    op: str
    surface: BSplineSurface
    sources: tuple[int, ...] = ()


# --- strokes ---------------------------------------------------------------------------------------
def camera(data: dict, dtype) -> sketch.Camera:
    """A `sketch.Camera` from the page's `{eye, target, up, fov, aspect}`."""
    return sketch.Camera(
        np.asarray(data["eye"], dtype),
        np.asarray(data["target"], dtype),
        np.asarray(data.get("up", (0.0, 0.0, 1.0)), dtype),
        fov=float(data["fov"]),
        aspect=float(data["aspect"]),
    )


def unproject(window: np.ndarray, cam: sketch.Camera, plane: DrawingPlane) -> np.ndarray:
    """Window points `(N, 2)` on the drawing plane `(N, 3)` (eqs. 5-1/5-2). The points are
    padded (the last one repeated) to a power of two ≥ 64, so strokes of every length share a
    few compiled programs (each point's ray is its own: the padding changes no value)."""
    dtype = np.asarray(cam.eye).dtype
    count = len(window)
    padded = np.concatenate([window, np.repeat(window[-1:], _bucket(count) - count, axis=0)])
    return np.asarray(sketch.unproject(np.asarray(padded, dtype), cam, plane.tool(dtype)))[:count]


def _bucket(count: int) -> int:
    return max(64, 1 << (count - 1).bit_length())


_FIT_SAMPLES = 64  # an over-sketch stroke is fitted on this many arc-length samples (one program)


def _even(points: np.ndarray, count: int = _FIT_SAMPLES) -> np.ndarray:
    """`count` samples evenly spaced in arc length along the polyline `points (N, d)`."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    at = np.linspace(0.0, arc[-1], count)
    return np.stack([np.interp(at, arc, points[:, i]) for i in range(points.shape[1])], 1).astype(
        points.dtype
    )


def drawn(item_id: int, points: np.ndarray, times, plane: DrawingPlane) -> Item:
    """A stroke's samples on the plane → the recognised, regularised `Item`."""
    rec = sketch.recognise(plane.coords(points).astype(points.dtype), times)
    return Item(item_id, rec.kind, plane.lift_curve(rec.curve), plane, rec.curve, rec, points)


def oversketched(item: Item, points: np.ndarray, plane: DrawingPlane) -> Item:
    """`item` with the span under a new stroke replaced (`sketch.oversketch`, thesis §4.2), in
    the plane's coordinates when the curve was drawn on this plane, else in space. The stroke is
    `fit_stroke`'s cubic through `_FIT_SAMPLES` arc-length samples of it."""
    same = item.flat is not None and _same_plane(item.plane, plane)
    base = item.flat if same else item.curve
    stroke = _even(plane.coords(points).astype(points.dtype) if same else points)
    (fitted,) = sketch.fit_stroke(stroke, None, tol=5e-3 * _size(stroke), split=False)
    new = sketch.oversketch(base, fitted).curve
    if same:
        return Item(item.id, "oversketched", plane.lift_curve(new), plane, new, None, points)
    return Item(item.id, "oversketched", new, item.plane, None, None, points)


def _same_plane(a: DrawingPlane, b: DrawingPlane) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b))


def _size(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.ptp(points, axis=0)))


# --- surfaces ---------------------------------------------------------------------------------------
def _ends(curve: BSplineCurve) -> np.ndarray:
    return np.asarray(curve.evaluate(np.asarray([0.0, 1.0], curve.ctrl.dtype)))


def revolve(items: Sequence[Item], options: dict) -> BSplineSurface:
    """The first curve revolved about the second, a line from its first to its last point."""
    ends = _ends(items[1].curve)
    return construct.revolve(items[0].curve, ends[0], ends[1] - ends[0])


def loft(items: Sequence[Item], options: dict) -> BSplineSurface:
    """Skinning through the curves in the order given (`construct.loft`, cubic across)."""
    return construct.loft([i.curve for i in items])


def ruled(items: Sequence[Item], options: dict) -> BSplineSurface:
    return construct.ruled(items[0].curve, items[1].curve)


def extrude(items: Sequence[Item], options: dict) -> BSplineSurface:
    """The first curve along `options["vector"]`, else along the second curve's chord, else along
    its plane's normal by the curve's size."""
    curve = items[0].curve
    dtype = curve.ctrl.dtype
    if options.get("vector") is not None:
        vector = np.asarray(options["vector"], dtype)
    elif len(items) > 1:
        ends = _ends(items[1].curve)
        vector = ends[1] - ends[0]
    else:
        vector = (items[0].plane.normal * _size(np.asarray(curve.ctrl))).astype(dtype)
    return construct.extrude(curve, vector)


def sweep(items: Sequence[Item], options: dict) -> BSplineSurface:
    """The first curve (the profile) along the second (the path), rotation-minimising frame. A
    profile drawn on a plane is read in that plane's coordinates relative to the path's start
    (x → the frame's normal, y → its binormal: `construct.sweep`)."""
    profile, path = items
    local = profile.flat
    if local is None:
        local = profile.curve
    else:
        start = profile.plane.coords(_ends(path.curve)[:1])[0].astype(local.ctrl.dtype)
        local = local.with_ctrl(np.asarray(local.ctrl) - start)
    return construct.sweep(local, path.curve).surface


def coons(items: Sequence[Item], options: dict) -> BSplineSurface:
    """The Coons patch of bottom, top, left, right; each curve turned so that its ends meet the
    others' (left and right start at the bottom, top starts on the left), the meeting end
    points moved to their mean when within 10 % of the largest curve's size."""
    b, t, l, r = (i.curve for i in items)
    l = _from(l, _ends(b)[0])
    r = _from(r, _ends(b)[1])
    t = _from(t, _ends(l)[1])
    size = max(_size(np.asarray(c.ctrl)) for c in (b, t, l, r))
    ends = [np.asarray(c.ctrl)[[0, -1]].copy() for c in (b, t, l, r)]
    for (a, ia), (c, ic) in (((0, 0), (2, 0)), ((0, 1), (3, 0)), ((1, 0), (2, 1)), ((1, 1), (3, 1))):
        gap = float(np.linalg.norm(ends[a][ia] - ends[c][ic]))
        if gap > 0.1 * size:
            raise CommandError(
                f"curves: the coons curves {a} and {c} do not meet at a corner (gap {gap:.3g})"
            )
        ends[a][ia] = ends[c][ic] = 0.5 * (ends[a][ia] + ends[c][ic])
    curves = []
    for c, e in zip((b, t, l, r), ends):
        ctrl = np.asarray(c.ctrl).copy()
        ctrl[[0, -1]] = e
        curves.append(c.with_ctrl(ctrl))
    return construct.coons(*curves)


def _from(curve: BSplineCurve, point: np.ndarray) -> BSplineCurve:
    """`curve`, reversed when its end is nearer `point` than its start."""
    ends = _ends(curve)
    if np.linalg.norm(ends[1] - point) >= np.linalg.norm(ends[0] - point):
        return curve
    knots = None if curve.knots is None else 1.0 - np.asarray(curve.knots)[::-1]
    weights = None if curve.weights is None else np.asarray(curve.weights)[::-1]
    return BSplineCurve(np.asarray(curve.ctrl)[::-1], knots, curve.degree, curve.periodic, weights)


def compose(items: Sequence[Item], tree: sketch.DecisionTree) -> tuple[str, BSplineSurface]:
    """A composite of thesis ch. 3 (`sketch.compose` over the session's tree), lifted from the
    drawing plane's coordinates."""
    for i, item in enumerate(items):
        if item.recognised is None:
            raise CommandError(
                f"curves[{i}]: expected a recognised stroke, got curve {item.id} ({item.kind})"
            )
        if not _same_plane(item.plane, items[0].plane):
            raise CommandError(f"curves[{i}]: expected strokes drawn on one plane, got curve {item.id}")
    built = sketch.compose([i.recognised for i in items], tree)
    if built.surface is None:
        found = "; ".join(", ".join(sorted(r)) or "none" for r in built.relations)
        raise CommandError(
            f"curves: expected strokes that match a composite of the tree, got kinds "
            f"{[i.kind for i in items]} with relations [{found}]"
        )
    return built.name or "composite", items[0].plane.lift_surface(built.surface)


BUILDS = {
    "revolve": (revolve, 2, 2),
    "loft": (loft, 2, 32),
    "ruled": (ruled, 2, 2),
    "extrude": (extrude, 1, 2),
    "sweep": (sweep, 2, 2),
    "coons": (coons, 4, 4),
}
"""op → (constructor, fewest curves, most curves); `compose` is the session's own."""
