"""Rhino `.3dm` files through rhino3dm (OpenNURBS): surfaces, Brep faces (trims, orientation),
extrusions with caps, block instances, curves, units, names and layers.

* Knots: Rhino stores `n + p - 1` knots (no superfluous end knots) on any domain. A clamped
  direction maps its domain onto [0, 1]; a uniform periodic one (as bsjax writes) loads as a
  periodic direction; any other unclamped direction — Rhino's closed lofts, revolves, sweeps —
  is clamped exactly by knot insertion at the domain ends (`_knots.clamp`). The domain is kept
  in `CadObject.domain`, so a save maps [0, 1] back onto it.
* Trims: rhino3dm exposes a Brep trim's loop, edge and direction but not its 2-D curve; the
  loops are recovered by projecting the 3-D edge curves onto the face's surface
  (`bsjax.basis.closest_points`, point inversion, "The NURBS Book" §6.1) as polylines in [0, 1]².
  On a closed surface a seam point projects to 0 or 1 at random: the loops are unwrapped across
  the seam and the `Trim` knows the surface is closed (`Trim.closed`).
* Writing trims: rhino3dm (8.35) has no API that builds loops and trims, but
  `CommonObject.Decode` reads an OpenNURBS binary archive of one object. bsjax encodes that
  archive itself (`_3dm_archive.trimmed_brep`: chunked, CRC-32-checked `ON_Brep` records — 2-D
  and 3-D degree-1 curves, vertices, edges, boundary/seam/singular trims with iso flags, outer
  and inner loops, the face), checks it with OpenNURBS's `IsValid`, and adds the decoded Brep.
  A closed direction's seam is first moved off the loops (`seam_moved`), since a trim must lie in
  the surface's domain. The exact loops also go in the user string `bsjax.trim` (bsjax reads them
  back exactly); when the loops cannot be written as trims (a loop around every seam position)
  the face is its untrimmed surface with that user string, as before.
* Polycurves: a `PolyCurve` loads as a tuple of `BSplineCurve`s (`CadObject.geometry`; a list in
  `load_all`'s result), one per segment in order (nested polycurves flattened), each on its own
  domain; `save` writes a tuple or list of curves back as a `PolyCurve` (`AppendSegment`).
"""

from __future__ import annotations

import json
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from bsjax import _checks
from bsjax._optional import require
from bsjax.basis import BSplineCurve, BSplineSurface, closest_points, periodic_knots
from bsjax.io import _knots
from bsjax.io._3dm_archive import trimmed_brep
from bsjax.io._cad import CadList, CadObject, Trim, closed_directions, counted, seam_moved, unit_scale

_RHINO_UNITS = {  # bsjax unit name → rhino3dm.UnitSystem member
    "nm": "Nanometers",
    "um": "Microns",
    "mm": "Millimeters",
    "cm": "Centimeters",
    "dm": "Decimeters",
    "m": "Meters",
    "km": "Kilometers",
    "in": "Inches",
    "ft": "Feet",
    "yd": "Yards",
    "mi": "Miles",
}
_TRIM_KEY = "bsjax.trim"
_INSIDE = 1e-9  # how far past [0, 1] a loop written as a trim may reach (rounding)
EDGE_SAMPLES = 33  # points per trim edge projected onto the face's surface


# --- knots and control nets ---------------------------------------------------------------
def _direction(hom, inner, degree: int, axis: int):
    """Rhino's knots along `axis` → `(hom, knots01 or None, periodic, domain)`."""
    p, n = degree, hom.shape[axis]
    domain = (float(inner[p - 1]), float(inner[n - 1]))
    full = np.concatenate([[inner[0]], inner, [inner[-1]]])
    if _knots.is_clamped(full, p):
        return hom, (full - full[0]) / (full[-1] - full[0]), False, domain
    m = n - p
    head, tail = np.take(hom, range(p), axis=axis), np.take(hom, range(m, n), axis=axis)
    steps = np.diff(inner)
    uniform = np.allclose(steps, steps[0], rtol=1e-9, atol=0) and steps[0] > 0
    if uniform and m > p and np.allclose(head, tail, rtol=0, atol=1e-12 * max(1.0, np.abs(hom).max())):
        return np.take(hom, range(m), axis=axis), None, True, domain
    hom, knots01, domain = _knots.clamp(hom, full, p, axis)
    return hom, knots01, False, domain


def _split(hom):
    w = hom[..., 3]
    return hom[..., :3] / w[..., None], (None if np.all(w == 1.0) else w)


def surface_from_rhino(srf, scale: float = 1.0):
    """A rhino3dm `NurbsSurface` → `(BSplineSurface, ((u0, u1), (v0, v1)))`."""
    r, s = srf.Points.CountU, srf.Points.CountV
    hom = np.array([[_point4(srf.Points[i, j]) for j in range(s)] for i in range(r)], dtype=np.float64)
    degrees = (srf.OrderU - 1, srf.OrderV - 1)
    knots, periodic, domain = {}, {}, {}
    for axis, rhino_knots in enumerate((srf.KnotsU, srf.KnotsV)):
        inner = np.array(list(rhino_knots), dtype=np.float64)
        hom, knots[axis], periodic[axis], domain[axis] = _direction(hom, inner, degrees[axis], axis)
    ctrl, weights = _split(hom)
    surface = BSplineSurface(ctrl * scale, knots[0], knots[1], *degrees, periodic[0], periodic[1], weights)
    return surface, (domain[0], domain[1])


def curve_from_rhino(crv, scale: float = 1.0):
    """A rhino3dm `NurbsCurve` → `(BSplineCurve, ((t0, t1),))`."""
    hom = np.array([_point4(crv.Points[i]) for i in range(len(crv.Points))], dtype=np.float64)
    inner = np.array(list(crv.Knots), dtype=np.float64)
    hom, knots, periodic, domain = _direction(hom, inner, crv.Order - 1, 0)
    ctrl, weights = _split(hom)
    return BSplineCurve(ctrl[:, : crv.Dimension] * scale, knots, crv.Order - 1, periodic, weights), (domain,)


def _point4(p):
    return (p.X, p.Y, p.Z, p.W)


def _rhino_knots(knots, degree: int, periodic: bool, n: int, domain) -> np.ndarray:
    """Rhino's knots: ours (or the unclamped uniform ones of a periodic direction) mapped onto
    `domain`, without the two superfluous end knots."""
    full = np.asarray(periodic_knots(n, degree) if periodic else knots, dtype=np.float64)
    if domain is not None:
        full = domain[0] + (domain[1] - domain[0]) * full
    return full[1:-1]


def surface_to_rhino(surface: BSplineSurface, domain=None):
    rhino3dm = _rhino()

    ctrl = np.asarray(surface.ctrl, dtype=np.float64)
    w = np.ones(ctrl.shape[:2]) if surface.weights is None else np.asarray(surface.weights, dtype=np.float64)
    knots = []
    for axis, d in enumerate("uv"):
        degree, periodic = getattr(surface, f"degree_{d}"), getattr(surface, f"periodic_{d}")
        if periodic:  # wrap: n + p control points over the unclamped uniform knots
            wrap = np.arange(ctrl.shape[axis] + degree) % ctrl.shape[axis]
            ctrl, w = np.take(ctrl, wrap, axis=axis), np.take(w, wrap, axis=axis)
        dom = None if domain is None else domain[axis]
        knots.append(_rhino_knots(getattr(surface, f"knots_{d}"), degree, periodic, surface.shape[axis], dom))
    r, s = ctrl.shape[:2]
    srf = rhino3dm.NurbsSurface.Create(
        3, surface.weights is not None, surface.degree_u + 1, surface.degree_v + 1, r, s
    )
    for i, k in enumerate(knots[0]):
        srf.KnotsU[i] = float(k)
    for j, k in enumerate(knots[1]):
        srf.KnotsV[j] = float(k)
    for i in range(r):
        for j in range(s):
            x, y, z = ctrl[i, j] * w[i, j]
            srf.Points[i, j] = rhino3dm.Point4d(float(x), float(y), float(z), float(w[i, j]))
    return srf


def curve_to_rhino(curve: BSplineCurve, domain=None):
    rhino3dm = _rhino()

    ctrl = np.asarray(curve.ctrl, dtype=np.float64)
    n, dim = ctrl.shape
    w = np.ones(n) if curve.weights is None else np.asarray(curve.weights, dtype=np.float64)
    if curve.periodic:  # n + p control points over the unclamped uniform knots, as Rhino's own
        wrap = np.arange(n + curve.degree) % n
        ctrl, w = ctrl[wrap], w[wrap]
    out = rhino3dm.NurbsCurve(dim, curve.weights is not None, curve.degree + 1, ctrl.shape[0])
    dom = None if domain is None else domain[0]
    for i, k in enumerate(_rhino_knots(curve.knots, curve.degree, curve.periodic, n, dom)):
        out.Knots[i] = float(k)
    hom = np.concatenate([ctrl * w[:, None], np.zeros((ctrl.shape[0], 3 - dim)), w[:, None]], axis=1)
    for i, (x, y, z, wi) in enumerate(hom):
        out.Points[i] = rhino3dm.Point4d(float(x), float(y), float(z), float(wi))
    return out


# --- reading ------------------------------------------------------------------------------
class _Reader:
    """One pass over a model's objects, collecting `CadObject`s and what was not loaded."""

    def __init__(self, model, path: Path, scale: float, trims: bool):
        self.model, self.path, self.scale, self.trims = model, path, scale, trims
        self.objects: list[CadObject] = []
        self.unsupported: list[str] = []
        self.annotations: list[str] = []  # text, dots, dimensions, leaders: not geometry
        self.carried: list = []  # (geometry in the loaded units, attributes): for a .3dm save
        self.held: Counter = Counter()
        self.untrimmed = self.reversed = 0
        self.layers = [layer.FullPath for layer in model.Layers]
        self.members = {}  # block definition id → [(geometry, attributes)]
        by_id = {obj.Attributes.Id: obj for obj in model.Objects}
        for idef in model.InstanceDefinitions:
            self.members[idef.Id] = [by_id[i] for i in idef.GetObjectIds() if i in by_id]

    def read(self) -> None:
        for index, obj in enumerate(self.model.Objects):
            if not obj.Attributes.IsInstanceDefinitionObject:  # block members load where placed
                self.add(obj.Geometry, obj.Attributes, f"object {index}")

    def add(self, geometry, attributes, where: str) -> None:
        rhino3dm = _rhino()

        kind = type(geometry).__name__
        self.held[kind] += 1
        name, layer = attributes.Name or "", self._layer(attributes.LayerIndex)
        label = f"{where} ({kind}{f' {name!r}' if name else ''})"
        if isinstance(geometry, (rhino3dm.TextDot, rhino3dm.AnnotationBase)):
            self.annotations.append(label)
            self.carried.append(self._carry(geometry, name, layer))
        elif isinstance(geometry, rhino3dm.InstanceReference):
            for k, member in enumerate(self.members.get(geometry.ParentIdefId, [])):
                placed = member.Geometry.Duplicate()
                placed.Transform(geometry.Xform)
                self.add(placed, member.Attributes, f"{where} block member {k}")
        elif isinstance(geometry, rhino3dm.PolyCurve):
            read = [curve_from_rhino(c.ToNurbsCurve(), self.scale) for c in _segments(geometry)]
            domains = tuple(domain for _, (domain,) in read)
            self.objects.append(CadObject(tuple(c for c, _ in read), name, layer, domains))
        elif isinstance(geometry, rhino3dm.Curve):
            curve, domain = curve_from_rhino(geometry.ToNurbsCurve(), self.scale)
            self.objects.append(CadObject(curve, name, layer, domain))
        elif isinstance(geometry, rhino3dm.Extrusion):
            self.add_brep(geometry.ToBrep(False), name, layer, label)
        elif isinstance(geometry, rhino3dm.Brep):
            self.add_brep(geometry, name, layer, label)
        elif isinstance(geometry, rhino3dm.Surface) and geometry.ToNurbsSurface() is not None:
            surface, domain = surface_from_rhino(geometry.ToNurbsSurface(), self.scale)
            self.objects.append(CadObject(surface, name, layer, domain))
        else:
            self.unsupported.append(label)

    def _carry(self, geometry, name: str, layer: str):
        """`(geometry, name, layer)` of an annotation, scaled to the loaded units."""
        rhino3dm = _rhino()

        copy = geometry.Duplicate()
        if self.scale != 1.0:
            copy.Transform(rhino3dm.Transform.Scale(rhino3dm.Point3d(0.0, 0.0, 0.0), self.scale))
        return copy, name, layer

    def add_brep(self, brep, name: str, layer: str, label: str) -> None:
        stored = brep.GetUserString(_TRIM_KEY)
        stored = json.loads(stored) if stored else None
        for k in range(len(brep.Faces)):
            face = brep.Faces[k]
            nurbs = face.ToNurbsSurface()
            if nurbs is None:
                self.unsupported.append(f"{label} face {k}")
                continue
            surface, domain = surface_from_rhino(nurbs, self.scale)
            trimmed = not face.DuplicateFace(False).IsSurface
            reverse = bool(face.OrientationIsReversed)
            trim = None
            if stored is not None and len(brep.Faces) == 1:
                trim = Trim.from_dict(stored)
            elif trimmed and self.trims:
                trim = _face_trim(brep, face, surface)
            self.untrimmed += trimmed and trim is None
            self.reversed += reverse and not self.trims
            self.objects.append(CadObject(surface, name, layer, domain, reverse, trim))

    def _layer(self, index: int) -> str:
        return self.layers[index] if 0 <= index < len(self.layers) else ""


def _segments(polycurve) -> list:
    """A `PolyCurve`'s segments in order, nested polycurves flattened (OpenNURBS keeps each
    segment's own domain: `SegmentCurve(i).PointAt(t)` is the curve on it)."""
    out = []
    for i in range(polycurve.SegmentCount):
        segment = polycurve.SegmentCurve(i)
        out.extend(_segments(segment) if isinstance(segment, _rhino().PolyCurve) else [segment])
    return out


def _rhino():
    return require("rhino3dm", "cad", ".3dm files")


def _face_trim(brep, face, surface: BSplineSurface) -> Trim:
    """The face's loops as polylines in [0, 1]²: each trim's 3-D edge sampled and projected.

    On a closed direction a point on the seam projects to 0 or to 1 at random, so each trim's
    piece is placed on its own (`_place`): a seam trim (its edge used twice by the face) goes to
    the side its direction says (the face lies left of its trims, "The NURBS Book" §12 and
    OpenNURBS's loop rule: going up the u-seam is u = 1, down is u = 0), any other piece is
    unwrapped and moved by a whole period into [0, 1] (Rhino splits trims at the seam). A
    singular trim (a pole) has no edge: its uv segment is the gap the polyline closes."""
    closed = closed_directions(surface)
    uses = Counter(trim.EdgeIndex for loop in face.Loops for trim in loop.Trims)
    loops, outer = [], []
    for loop in face.Loops:
        pieces, seams = [], []
        for trim in loop.Trims:
            if trim.EdgeIndex < 0:
                continue
            edge = brep.Edges[trim.EdgeIndex]
            ts = np.linspace(edge.Domain.T0, edge.Domain.T1, EDGE_SAMPLES)
            ts = ts[::-1] if trim.IsReversed else ts
            pieces.append(np.array([_xyz(edge.PointAt(float(t))) for t in ts]))
            seams.append(uses[trim.EdgeIndex] > 1)  # an edge the face meets twice: its seam
        points = np.concatenate(pieces).astype(surface.ctrl.dtype)
        size = 1 << max(6, (len(points) - 1).bit_length())  # padded: one compile per size class
        padded = np.concatenate([points, np.repeat(points[-1:], size - len(points), axis=0)])
        uv = np.asarray(closest_points(surface, padded).params, dtype=np.float64)[: len(points)]
        split = np.split(uv, np.cumsum([len(piece) for piece in pieces])[:-1])
        loops.append(np.concatenate([_place(piece, closed, seam) for piece, seam in zip(split, seams)]))
        outer.append(str(loop.LoopType).endswith("Outer"))
    return Trim.from_loops(loops, outer, closed)


def _place(uv: np.ndarray, closed, seam: bool) -> np.ndarray:
    """One trim's projected points placed across the seam of the closed directions."""
    out = uv.copy()
    for axis in (0, 1):
        if not closed[axis]:
            continue
        x = np.unwrap(uv[:, axis], period=1.0)
        if seam and np.ptp(x) < np.ptp(uv[:, 1 - axis]):  # along this direction's seam
            rising = uv[-1, 1 - axis] > uv[0, 1 - axis]
            out[:, axis] = float(rising) if axis == 0 else float(not rising)
        else:
            out[:, axis] = x - np.floor(x.mean())
    return out


def load_3dm(path: Path, units: str | None, on_unsupported: str, trims: bool) -> CadList:
    rhino3dm = _rhino()

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    model = rhino3dm.File3dm.Read(str(path))
    if model is None:
        _checks.fail(str(path), "a readable Rhino .3dm file", "a file rhino3dm cannot parse")
    file_units = _units_of(model.Settings.ModelUnitSystem)
    reader = _Reader(model, path, unit_scale(file_units, units, str(path)), trims)
    reader.read()
    report(path, reader.unsupported, on_unsupported)
    notes = []
    if reader.annotations:
        listed = ", ".join(reader.annotations[:5]) + (" …" if len(reader.annotations) > 5 else "")
        notes.append(
            f"{len(reader.annotations)} annotations (text, dots, dimensions) not loaded as geometry "
            f"(kept in CadList.annotations, written back to a .3dm): {listed}"
        )
    if reader.untrimmed:
        notes.append(
            f"{reader.untrimmed} trimmed faces loaded as their untrimmed surfaces (trims=True keeps trims)"
        )
    if reader.reversed:
        notes.append(f"{reader.reversed} faces have reversed orientation (CadList.objects[i].reversed)")
    if notes:
        warnings.warn(f"{path}: " + "; ".join(notes), stacklevel=4)
    held = reader.held
    return CadList(
        [o.item for o in reader.objects], units or file_units, reader.objects, held, reader.carried
    )


def report(path: Path, unsupported: list[str], on_unsupported: str) -> None:
    """Raise (or, with `on_unsupported="skip"`, warn) listing the objects not loaded."""
    if not unsupported:
        return
    listed = ", ".join(unsupported[:20]) + (
        f" and {len(unsupported) - 20} more" if len(unsupported) > 20 else ""
    )
    if on_unsupported == "raise":
        raise ValueError(
            f"{path}: {len(unsupported)} objects bsjax cannot load: {listed} "
            "(pass on_unsupported='skip' to load the rest)"
        )
    warnings.warn(f"{path}: not loaded: {listed}", stacklevel=4)


def _units_of(system) -> str | None:
    name = str(system).rsplit(".", 1)[-1]
    return next((k for k, v in _RHINO_UNITS.items() if v == name), None)


# --- writing ------------------------------------------------------------------------------
def save_3dm(objects: list[CadObject], path: Path, units: str | None, annotations=(), progress=None) -> None:
    """Write `objects` and the carried `annotations` (`CadList.annotations`) to a `.3dm`."""
    rhino3dm = _rhino()

    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = getattr(rhino3dm.UnitSystem, _RHINO_UNITS[units] if units else "None")
    layers = {}

    def attributes_of(name: str, layer: str):
        attributes = rhino3dm.ObjectAttributes()
        attributes.Name = name
        if layer:
            if layer not in layers:
                layers[layer] = model.Layers.AddLayer(layer, (0, 0, 0, 255))
            attributes.LayerIndex = layers[layer]
        return attributes

    for geometry, name, layer in annotations:
        model.Objects.Add(geometry, attributes_of(name, layer))
    for obj in counted(objects, progress):
        attributes = attributes_of(obj.name, obj.layer)
        if isinstance(obj.geometry, tuple):
            model.Objects.AddCurve(_polycurve_to_rhino(obj), attributes)
        elif isinstance(obj.geometry, BSplineCurve):
            model.Objects.AddCurve(curve_to_rhino(obj.geometry, obj.domain), attributes)
        elif obj.trim is None and not obj.reversed:
            model.Objects.AddSurface(surface_to_rhino(obj.geometry, obj.domain), attributes)
        else:
            model.Objects.AddBrep(_brep(obj), attributes)
    if not model.Write(str(path), 7):
        raise OSError(f"{path}: rhino3dm could not write the file")


def _brep(obj: CadObject):
    """A face `CadObject` → a one-face rhino3dm `Brep`: trimmed by its loops (an OpenNURBS archive
    encoded by `_3dm_archive.trimmed_brep`, the seam of a closed direction moved off the loops
    first, `seam_moved`), with the exact loops also in the user string `bsjax.trim`; the
    untrimmed surface with that user string when the loops cannot be written (a loop crossing
    every seam position) or OpenNURBS finds the Brep invalid."""
    rhino3dm = _rhino()

    if obj.trim is not None:
        obj = seam_moved(obj)
    srf = surface_to_rhino(obj.geometry, obj.domain)  # pyright: ignore[reportArgumentType]
    brep = None
    if obj.trim is not None:
        loops = obj.trim.loops()
        if all(loop.min() >= -_INSIDE and loop.max() <= 1 + _INSIDE for loop in loops):
            loops = [np.clip(loop, 0.0, 1.0) for loop in loops]
            brep = trimmed_brep(srf, loops, obj.trim.outer, obj.reversed, obj.trim.closed)
            brep = brep if brep is not None and brep.IsValid else None
    if brep is None:
        brep = rhino3dm.Brep.CreateFromSurface(srf)
        if obj.reversed:
            brep.Flip()
    if obj.trim is not None:
        brep.SetUserString(_TRIM_KEY, json.dumps(obj.trim.to_dict()))
    return brep


def _polycurve_to_rhino(obj: CadObject):
    """A polycurve `CadObject` → a rhino3dm `PolyCurve`, each segment on its own domain
    (`AppendSegment` keeps the segment's geometry; OpenNURBS refuses a segment after a closed run)."""
    rhino3dm = _rhino()

    out = rhino3dm.PolyCurve()
    domains = obj.domain or (None,) * len(obj.geometry)  # pyright: ignore[reportArgumentType]
    for k, (curve, domain) in enumerate(zip(obj.geometry, domains)):  # pyright: ignore
        if not out.AppendSegment(curve_to_rhino(curve, None if domain is None else (domain,))):
            _checks.fail(f"polycurve {obj.name!r} segment {k}", "a segment OpenNURBS can append", "refused")
    return out


def _xyz(p):
    return (p.X, p.Y, p.Z)
