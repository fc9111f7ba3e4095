"""STEP and IGES through OCCT (OCP, the `cad` extra): B-spline and analytic faces with their
trims and orientation, free curves, units.

* Reading: every face of the file's shapes (shells and solids included). A B-spline face keeps its
  surface exactly (a periodic or unclamped direction clamped by knot insertion, `_knots.clamp`);
  an analytic one (plane, cylinder, cone, sphere, torus, revolution, extrusion, offset) is turned
  into its exact NURBS over the face's parameter bounds by `GeomConvert`. Trim loops are the
  faces' pcurves sampled (`EDGE_SAMPLES` per edge) and mapped into the NURBS's [0, 1]²: linearly
  for a B-spline face, by closest-point projection (a local Gauss–Newton from the linear guess,
  `bsjax.basis.closest_points`) where `GeomConvert` changed the parametrisation (circles become
  rational arcs). A face whose orientation is `TopAbs_REVERSED` is flagged `reversed`. Free edges
  load as `BSplineCurve`s; free vertices and anything else are reported.
* Units: OCCT converts lengths into its session unit while reading; the session unit is set to the
  file's own (`FileUnits`) for the transfer, so the numbers are the file's and `units` names them.
* Writing: clamped B-spline surfaces over the stored domain (a periodic direction clamped first),
  a `Trim` written as degree-1 pcurves (outer loop counter-clockwise, holes clockwise), a reversed
  face reversed, curves as edges; the file's unit is bsjax's.
* Names and layers: written and read through OCCT's XCAF document (`STEPCAFControl`,
  `IGESCAFControl`, `XCAFDoc_DocumentTool`, `TDataStd_Name`, `XCAFDoc_LayerTool`). STEP: each
  object is a product named after the object, on its layer (`PRESENTATION_LAYER_ASSIGNMENT`).
  IGES: the name is the entity's label and its name property (entity 406 form 15), ASCII only;
  the layer is the entity's level, an integer — a layer named by an integer ("12") travels, any
  other layer name is written as a level number OCCT chooses and reads back as that number.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from bsjax import _checks
from bsjax.basis import BSplineCurve, BSplineSurface, closest_points, periodic_knots
from bsjax.io import _knots
from bsjax.io._cad import CadList, CadObject, Trim, closed_directions, counted, seam_moved, unit_scale

EDGE_SAMPLES = 33
IGES_BREP_MODE = "BRep"
_OCCT_UNITS = {"mm": "MM", "cm": "CM", "m": "M", "km": "KM", "in": "INCH", "ft": "FT", "mi": "MI", "um": "UM"}
_STEP_NAMES = {  # unit names FileUnits reports → ours
    "millimetre": "mm",
    "millimeter": "mm",
    "centimetre": "cm",
    "centimeter": "cm",
    "metre": "m",
    "meter": "m",
    "kilometre": "km",
    "kilometer": "km",
    "inch": "in",
    "foot": "ft",
    "mile": "mi",
    "micrometre": "um",
    "micrometer": "um",
}


# --- reading ------------------------------------------------------------------------------
def _array1(arr) -> np.ndarray:
    return np.array([arr.Value(i) for i in range(arr.Lower(), arr.Upper() + 1)], dtype=np.float64)


def bspline_surface(bs):
    """A `Geom_BSplineSurface` → `(BSplineSurface, ((u0, u1), (v0, v1)))`, clamped."""
    bs = bs.Copy()
    if bs.IsUPeriodic() or bs.IsVPeriodic():
        bs.Segment(*bs.Bounds())  # one period, no longer periodic (the knot sequence is then a plain one)
    r, s = bs.NbUPoles(), bs.NbVPoles()
    hom = np.empty((r, s, 4))
    for i in range(r):
        for j in range(s):
            p, w = bs.Pole(i + 1, j + 1), bs.Weight(i + 1, j + 1)
            hom[i, j] = (p.X() * w, p.Y() * w, p.Z() * w, w)
    degrees = (bs.UDegree(), bs.VDegree())
    knots, domain = {}, {}
    for axis, seq in enumerate((bs.UKnotSequence(), bs.VKnotSequence())):
        full = _array1(seq)
        hom, knots[axis], domain[axis] = _knots.clamp(hom, full, degrees[axis], axis)
    w = hom[..., 3]
    weights = None if bool(np.all(w == 1.0)) else w
    surface = BSplineSurface(hom[..., :3] / w[..., None], knots[0], knots[1], *degrees, weights=weights)
    return surface, (domain[0], domain[1])


def bspline_curve(bc):
    """A `Geom_BSplineCurve` → `(BSplineCurve, ((t0, t1),))`, clamped."""
    bc = bc.Copy()
    if bc.IsPeriodic():
        bc.SetNotPeriodic()
    n = bc.NbPoles()
    hom = np.array([(*_xyz(bc.Pole(i + 1)), 1.0) for i in range(n)], dtype=np.float64)
    w = np.array([bc.Weight(i + 1) for i in range(n)])
    hom[:, :3] *= w[:, None]
    hom[:, 3] = w
    hom, knots, domain = _knots.clamp(hom, _array1(bc.KnotSequence()), bc.Degree())
    w = hom[:, 3]
    weights = None if bool(np.all(w == 1.0)) else w
    return BSplineCurve(hom[:, :3] / w[:, None], knots, bc.Degree(), False, weights), (domain,)


def _xyz(p):
    return (p.X(), p.Y(), p.Z())


def _face(face, trims: bool):
    """One `TopoDS_Face` → `(CadObject fields, trimmed)`."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepTools import BRepTools
    from OCP.Geom import Geom_BSplineSurface, Geom_RectangularTrimmedSurface
    from OCP.GeomConvert import GeomConvert
    from OCP.TopAbs import TopAbs_REVERSED

    geom = BRep_Tool.Surface_s(face)
    u0, u1, v0, v1 = BRepTools.UVBounds_s(face)
    exact = isinstance(geom, Geom_BSplineSurface)
    if not exact:
        # a closed face's bounds may exceed the period by the file's rounding (6.28318530718)
        # (and OCCT's periodic conversion fails on a start of -4e-13): snap a full period
        if geom.IsUPeriodic() and u1 - u0 > geom.UPeriod() * (1 - 1e-9):
            u0 = round(u0, 9) + 0.0
            u1 = u0 + geom.UPeriod()
        if geom.IsVPeriodic() and v1 - v0 > geom.VPeriod() * (1 - 1e-9):
            v0 = round(v0, 9) + 0.0
            v1 = v0 + geom.VPeriod()
        geom = GeomConvert.SurfaceToBSplineSurface_s(Geom_RectangularTrimmedSurface(geom, u0, u1, v0, v1))
    surface, domain = bspline_surface(geom)
    if not exact:  # the converted NURBS spans the face's bounds: that is its domain in the file
        domain = ((u0, u1), (v0, v1))
    loops, outer = _face_loops(face)
    lo, hi = np.array([domain[0][0], domain[1][0]]), np.array([domain[0][1], domain[1][1]])
    loops01 = [(uv - lo) / (hi - lo) for uv in loops]
    trimmed = len(loops) > 1 or any(bool(np.any(np.all(_interior(x), axis=1))) for x in loops01)
    trim = None
    if trims and trimmed:
        if not exact:
            loops01 = [
                _project_loop(surface, BRep_Tool.Surface_s(face), uv, x) for uv, x in zip(loops, loops01)
            ]
        trim = Trim.from_loops(loops01, outer, closed_directions(surface))
    return surface, domain, face.Orientation() == TopAbs_REVERSED, trim, trimmed


def _interior(x):
    return (x > 1e-9) & (x < 1 - 1e-9)


def _face_loops(face):
    """Each wire of `face` as a polyline in the surface's own (u, v), and whether it is outer."""
    from OCP.BRepAdaptor import BRepAdaptor_Curve2d
    from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
    from OCP.TopAbs import TopAbs_REVERSED, TopAbs_WIRE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    outer_wire = BRepTools.OuterWire_s(face)
    loops, outer = [], []
    explorer = TopExp_Explorer(face, TopAbs_WIRE)
    while explorer.More():
        wire = TopoDS.Wire(explorer.Current())
        pieces, edges = [], BRepTools_WireExplorer(wire, face)
        while edges.More():
            edge = edges.Current()
            curve = BRepAdaptor_Curve2d(edge, face)
            ts = _edge_parameters(curve)
            ts = ts[::-1] if edge.Orientation() == TopAbs_REVERSED else ts
            pieces.append(np.array([(lambda p: (p.X(), p.Y()))(curve.Value(float(t))) for t in ts]))
            edges.Next()
        loops.append(np.concatenate(pieces))
        outer.append(wire.IsSame(outer_wire))
        explorer.Next()
    return loops, outer


def _edge_parameters(curve) -> np.ndarray:
    """`EDGE_SAMPLES` parameters over the pcurve, plus its knots (a polyline's corners) inside."""
    from OCP.GeomAbs import GeomAbs_BSplineCurve

    t0, t1 = curve.FirstParameter(), curve.LastParameter()
    ts = np.linspace(t0, t1, EDGE_SAMPLES)
    if curve.GetType() == GeomAbs_BSplineCurve:
        knots = _array1(curve.BSpline().Knots())
        ts = np.union1d(ts, knots[(knots > t0) & (knots < t1)])
    return ts


def _project_loop(surface: BSplineSurface, geom, uv, guess):
    """Loop points of the original surface's (u, v) → parameters on its NURBS conversion."""
    points = np.array([_xyz(geom.Value(float(a), float(b))) for a, b in uv])
    found = closest_points(surface, points, np.clip(guess, 0.0, 1.0))
    return np.asarray(found.params, dtype=np.float64)


def _read_parts(path: Path):
    """The file's shapes as `[(shape, describe)]` (transferred with OCCT's session unit set to
    the file's) and its unit; `describe(face_or_edge) -> (name, layer)`.

    STEP goes through XCAF (`STEPCAFControl_Reader`): each free shape of the document (a
    product) is a part named by its `TDataStd_Name`, with its layers from the `XCAFDoc_LayerTool`
    (a face's own sub-shape label, when the file names or layers that face, wins). An assembly's
    components are parts of their own, located. IGES goes through XCAF too
    (`IGESCAFControl_Reader`): entity names and levels. OCCT's auto-naming is off while
    transferring, so an unnamed entity stays unnamed (not 'FACE').
    """
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.XCAFDoc import XCAFDoc_ShapeTool

    _quiet()
    step = path.suffix.lower() in (".step", ".stp")
    if step:
        from OCP.STEPCAFControl import STEPCAFControl_Reader

        xcaf = STEPCAFControl_Reader()
        xcaf.SetNameMode(True)
        xcaf.SetLayerMode(True)
        reader = xcaf.ChangeReader()
    else:
        from OCP.IGESCAFControl import IGESCAFControl_Reader

        reader = xcaf = IGESCAFControl_Reader()
        xcaf.SetNameMode(True)
        xcaf.SetLayerMode(True)
    if xcaf.ReadFile(str(path)) != IFSelect_RetDone:
        _checks.fail(str(path), f"a readable {'STEP' if step else 'IGES'} file", "a file OCCT cannot parse")
    units = _file_units(reader, step)
    settings = {
        "xstep.cascade.unit": _OCCT_UNITS.get(units or "mm", "MM"),
        "read.surfacecurve.mode": 2,  # the file's pcurves, not re-projections
    }
    if not step:  # curves as the file has them (OCCT splits B-splines at C1 knots by default)
        settings["read.iges.bspline.continuity"] = 0
    previous = _set_static(settings)
    try:
        doc = _xcaf_document()
        naming = XCAFDoc_ShapeTool.AutoNaming_s()
        XCAFDoc_ShapeTool.SetAutoNaming_s(False)  # else an unnamed IGES entity is named 'FACE'
        try:
            transferred = xcaf.Transfer(doc)
        finally:
            XCAFDoc_ShapeTool.SetAutoNaming_s(naming)
        if not transferred:
            _checks.fail(
                str(path), f"a {'STEP' if step else 'IGES'} file OCCT can transfer", "a transfer failure"
            )
        parts = _xcaf_parts(doc)
    finally:
        _set_static(previous)
    return parts, units


def _set_static(settings: dict) -> dict:
    """Set OCCT's `Interface_Static` parameters (ints by `SetIVal`, strings by `SetCVal`);
    return their previous values, to restore them."""
    from OCP.Interface import Interface_Static

    previous = {}
    for k, v in settings.items():
        integer = isinstance(v, int)
        previous[k] = Interface_Static.IVal_s(k) if integer else Interface_Static.CVal_s(k)
        (Interface_Static.SetIVal_s if integer else Interface_Static.SetCVal_s)(k, v)
    return previous


def _xcaf_document():
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFApp import XCAFApp_Application

    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    XCAFApp_Application.GetApplication_s().InitDocument(doc)
    return doc


def _xcaf_parts(doc):
    """`[(shape, describe)]` of the document's free shapes (assemblies: their components)."""
    from OCP.collections import Sequence_TDF_Label
    from OCP.TDF import TDF_Label
    from OCP.XCAFDoc import XCAFDoc_DocumentTool, XCAFDoc_ShapeTool

    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    layers = XCAFDoc_DocumentTool.LayerTool_s(doc.Main())
    free = Sequence_TDF_Label()
    shapes.GetFreeShapes(free)
    parts = []
    for label in free:
        if not XCAFDoc_ShapeTool.IsAssembly_s(label):
            parts.append((XCAFDoc_ShapeTool.GetShape_s(label), _describer(layers, label, label)))
            continue
        components = Sequence_TDF_Label()
        XCAFDoc_ShapeTool.GetComponents_s(label, components, True)  # flattened, located
        for component in components:
            referred = TDF_Label()
            if not XCAFDoc_ShapeTool.GetReferredShape_s(component, referred):
                referred = component
            describe = _describer(layers, component, referred, _describer(layers, label, label)(None))
            parts.append((XCAFDoc_ShapeTool.GetShape_s(component), describe))
    return parts


def _describer(layers, label, referred, parent=("", "")):
    """`describe(sub) -> (name, layer)` for the faces and edges of the part at `label`: the
    sub-shape's own label first (a file that names or layers single faces), then the component's,
    then the product's, then the assembly's (`parent`: `(name, layer)`). Everything is read
    now: labels die with their document."""
    from OCP.collections import Sequence_TDF_Label
    from OCP.XCAFDoc import XCAFDoc_ShapeTool

    instance = _label_name(label) if not label.IsEqual(referred) else ""
    own = (  # a component's own name only when not OCCT's fallback to the occurrence's numeric id
        (instance if not instance.isdigit() else "") or _label_name(referred) or parent[0],
        _label_layer(layers, label) or _label_layer(layers, referred) or parent[1],
    )
    subs: dict[int, list] = {}  # hash → [(shape, (name, layer))]; OCP's shapes compare by identity
    if label.IsEqual(referred):  # a located component's sub-shapes sit elsewhere: its own name only
        labels = Sequence_TDF_Label()
        XCAFDoc_ShapeTool.GetSubShapes_s(referred, labels)
        for sub in labels:
            shape = XCAFDoc_ShapeTool.GetShape_s(sub)
            value = (_label_name(sub) or own[0], _label_layer(layers, sub) or own[1])
            subs.setdefault(hash(shape), []).append((shape, value))

    def describe(sub):
        return next((value for shape, value in subs.get(hash(sub), ()) if shape.IsSame(sub)), own)

    return describe


# OCCT's writers name an unnamed product after themselves and an unnamed component after its
# label ("=>[0:1:1:1]"): not names the user gave
_OCCT_DEFAULT_NAMES = ("Open CASCADE STEP translator", "=>[")


def _label_name(label) -> str:
    from OCP.TDataStd import TDataStd_Name

    if not label.IsAttribute(TDataStd_Name.GetID_s()):  # OCP's FindAttribute crashes on a miss
        return ""
    name = TDataStd_Name()
    label.FindAttribute(TDataStd_Name.GetID_s(), name)
    text = name.Get().ToExtString()
    return "" if text.startswith(_OCCT_DEFAULT_NAMES) else text


def _label_layer(layers, label) -> str:
    """The first layer of `label` ("" when none)."""
    from OCP.collections import Sequence_TDF_Label
    from OCP.TCollection import TCollection_ExtendedString

    found = Sequence_TDF_Label()
    if not layers.GetLayers(label, found) or found.Length() == 0:
        return ""
    name = TCollection_ExtendedString()
    layers.GetLayer(found.Value(1), name)
    return name.ToExtString()


def _file_units(reader, step: bool) -> str | None:
    if step:
        from OCP.collections import Sequence_TCollection_AsciiString as Strings

        lengths = Strings()
        reader.FileUnits(lengths, Strings(), Strings())
        names = [name.ToCString().lower() for name in lengths]
        return next((_STEP_NAMES[n] for n in names if n in _STEP_NAMES), None)
    flag = reader.Model().GlobalSection().UnitFlag()  # IGES global section, field 14
    return {1: "in", 2: "mm", 4: "ft", 5: "mi", 6: "m", 7: "km", 9: "um", 10: "cm"}.get(flag)


def _edge_curve(edge, scale: float):
    """A free edge's 3-D curve as `(BSplineCurve, ((t0, t1),))`, in the edge's direction (a
    reversed edge of a wire: its curve reversed, `t → t0 + t1 − t`)."""
    from OCP.BRep import BRep_Tool
    from OCP.Geom import Geom_TrimmedCurve
    from OCP.GeomConvert import GeomConvert
    from OCP.TopAbs import TopAbs_REVERSED

    geom, first, last = BRep_Tool.Curve_s(edge, 0.0, 0.0), *BRep_Tool.Range_s(edge)
    bc = GeomConvert.CurveToBSplineCurve_s(Geom_TrimmedCurve(geom, first, last))
    if edge.Orientation() == TopAbs_REVERSED:
        bc.Reverse()
    curve, domain = bspline_curve(bc)
    return curve.with_ctrl(curve.ctrl * scale), domain


def _chained(curves, rtol: float = 1e-9) -> bool:
    """Whether each curve starts where the previous one ends (relative to their extent)."""
    ends = np.array([np.asarray(c.evaluate(np.array([0.0, 1.0]))) for c in curves], dtype=np.float64)
    tol = rtol * max(1.0, float(np.ptp(ends.reshape(-1, ends.shape[-1]), axis=0).max()))
    return bool(np.all(np.linalg.norm(ends[1:, 0] - ends[:-1, 1], axis=-1) <= tol))


def _wire_edges(wire) -> list:
    """A wire's edges in order along it (`BRepTools_WireExplorer`), each with its orientation."""
    from OCP.BRepTools import BRepTools_WireExplorer

    edges, explorer = [], BRepTools_WireExplorer(wire)
    while explorer.More():
        edges.append(explorer.Current())
        explorer.Next()
    return edges


def load_occt(path: Path, units: str | None, on_unsupported: str, trims: bool) -> CadList:
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE, TopAbs_VERTEX, TopAbs_WIRE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from bsjax.io._rhino import report

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    parts, file_units = _read_parts(path)
    scale = unit_scale(file_units, units, str(path))
    objects, held, unsupported, untrimmed = [], Counter(), [], 0
    for shape, describe in parts:
        explorer = TopExp_Explorer(shape, TopAbs_FACE)
        while explorer.More():
            face = TopoDS.Face(explorer.Current())
            surface, domain, reverse, trim, trimmed = _face(face, trims)
            untrimmed += trimmed and trim is None
            held["face"] += 1
            surface = surface.with_ctrl(surface.ctrl * scale)
            objects.append(CadObject(surface, *describe(face), domain, reverse, trim))
            explorer.Next()
        explorer = TopExp_Explorer(shape, TopAbs_WIRE, TopAbs_FACE)  # free wires: polycurves
        while explorer.More():
            wire = TopoDS.Wire(explorer.Current())
            read = [_edge_curve(edge, scale) for edge in _wire_edges(wire)]
            held["wire"] += 1
            if len(read) == 1:
                objects.append(CadObject(*read[0][:1], *describe(wire), read[0][1]))
            elif read:
                curves, domains = tuple(c for c, _ in read), tuple(d for _, (d,) in read)
                objects.append(CadObject(curves, *describe(wire), domains))
            explorer.Next()
        explorer, free = TopExp_Explorer(shape, TopAbs_EDGE, TopAbs_WIRE), []  # free edges: curves
        while explorer.More():
            edge = TopoDS.Edge(explorer.Current())
            held["edge"] += 1
            free.append((edge, *_edge_curve(edge, scale)))
            explorer.Next()
        if shape.ShapeType() != TopAbs_EDGE and len(free) > 1 and _chained([c for _, c, _ in free]):
            # a part of edges only, meeting end to start: a STEP writer's polycurve (OCCT writes a
            # wire as a GEOMETRIC_CURVE_SET of its edges)
            domains = tuple(d for _, _, (d,) in free)
            objects.append(CadObject(tuple(c for _, c, _ in free), *describe(shape), domains))
            held["wire"] += 1
        else:
            objects.extend(CadObject(c, *describe(e), d) for e, c, d in free)
        explorer = TopExp_Explorer(shape, TopAbs_VERTEX, TopAbs_EDGE)
        while explorer.More():
            held["vertex"] += 1
            unsupported.append(f"free vertex {held['vertex'] - 1}")
            explorer.Next()
    report(path, unsupported, on_unsupported)
    if untrimmed:
        import warnings

        warnings.warn(
            f"{path}: {untrimmed} trimmed faces loaded as their untrimmed surfaces (trims=True keeps trims)",
            stacklevel=4,
        )
    return CadList([o.item for o in objects], units or file_units, objects, held)


# --- writing ------------------------------------------------------------------------------
def _clamped_net(geometry, axes: int):
    """Homogeneous control net and clamped [0, 1] knots of a surface or curve (periodic
    directions clamped exactly through Rhino's wrapped layout)."""
    ctrl = np.asarray(geometry.ctrl, dtype=np.float64)
    w = (
        np.ones(ctrl.shape[:-1])
        if geometry.weights is None
        else np.asarray(geometry.weights, dtype=np.float64)
    )
    if ctrl.shape[-1] == 2:
        ctrl = np.concatenate([ctrl, np.zeros((*ctrl.shape[:-1], 1))], axis=-1)
    hom = np.concatenate([ctrl * w[..., None], w[..., None]], axis=-1)
    names = ("u", "v") if axes == 2 else ("",)
    out = []
    for axis, d in enumerate(names):
        degree = getattr(geometry, f"degree_{d}" if d else "degree")
        periodic = getattr(geometry, f"periodic_{d}" if d else "periodic")
        knots = (
            np.asarray(getattr(geometry, f"knots_{d}" if d else "knots"), dtype=np.float64)
            if not periodic
            else None
        )
        if periodic:
            n = hom.shape[axis]
            hom = np.take(hom, np.arange(n + degree) % n, axis=axis)
            hom, knots, _ = _knots.clamp(
                hom, np.asarray(periodic_knots(n, degree), dtype=np.float64), degree, axis
            )
        out.append((knots, degree))
    return hom, out


def _knot_arrays(knots, domain):
    from OCP.collections import Array1_double as TColStd_Array1OfReal
    from OCP.collections import Array1_int as TColStd_Array1OfInteger

    if domain is not None:
        knots = domain[0] + (domain[1] - domain[0]) * knots
    values, counts = np.unique(knots, return_counts=True)
    a, m = TColStd_Array1OfReal(1, len(values)), TColStd_Array1OfInteger(1, len(values))
    for i, (x, c) in enumerate(zip(values, counts)):
        a.SetValue(i + 1, float(x))
        m.SetValue(i + 1, int(c))
    return a, m


def to_geom_surface(surface: BSplineSurface, domain=None):
    from OCP.collections import Array2_double as TColStd_Array2OfReal
    from OCP.collections import Array2_gp_Pnt as TColgp_Array2OfPnt
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt

    hom, ((ku, p), (kv, q)) = _clamped_net(surface, 2)
    r, s = hom.shape[:2]
    poles, weights = TColgp_Array2OfPnt(1, r, 1, s), TColStd_Array2OfReal(1, r, 1, s)
    for i in range(r):
        for j in range(s):
            x, y, z, w = hom[i, j]
            poles.SetValue(i + 1, j + 1, gp_Pnt(x / w, y / w, z / w))
            weights.SetValue(i + 1, j + 1, float(w))
    (uk, um), (vk, vm) = (
        _knot_arrays(k, None if domain is None else domain[a]) for a, k in enumerate((ku, kv))
    )
    return Geom_BSplineSurface(poles, weights, uk, vk, um, vm, p, q, False, False)


def to_geom_curve(curve: BSplineCurve, domain=None):
    from OCP.collections import Array1_double as TColStd_Array1OfReal
    from OCP.collections import Array1_gp_Pnt as TColgp_Array1OfPnt
    from OCP.Geom import Geom_BSplineCurve
    from OCP.gp import gp_Pnt

    hom, ((k, p),) = _clamped_net(curve, 1)
    poles, weights = TColgp_Array1OfPnt(1, len(hom)), TColStd_Array1OfReal(1, len(hom))
    for i, (x, y, z, w) in enumerate(hom):
        poles.SetValue(i + 1, gp_Pnt(x / w, y / w, z / w))
        weights.SetValue(i + 1, float(w))
    knots, mults = _knot_arrays(k, None if domain is None else domain[0])
    return Geom_BSplineCurve(poles, weights, knots, mults, p)


def _wire(loop01, surface_geom, domain, hole: bool):
    """A closed degree-1 pcurve through `loop01` (in [0, 1]²) on `surface_geom`, as a wire."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire
    from OCP.collections import Array1_double as TColStd_Array1OfReal
    from OCP.collections import Array1_gp_Pnt2d as TColgp_Array1OfPnt2d
    from OCP.collections import Array1_int as TColStd_Array1OfInteger
    from OCP.Geom2d import Geom2d_BSplineCurve
    from OCP.gp import gp_Pnt2d

    lo = np.array([domain[0][0], domain[1][0]]) if domain else np.zeros(2)
    hi = np.array([domain[0][1], domain[1][1]]) if domain else np.ones(2)
    uv = lo + (hi - lo) * np.asarray(loop01)
    x, y = uv[:, 0], uv[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    if (area > 0) == hole:  # outer loops counter-clockwise, holes clockwise
        uv = uv[::-1]
    n = len(uv)
    poles = TColgp_Array1OfPnt2d(1, n)
    for i, (a, b) in enumerate(uv):
        poles.SetValue(i + 1, gp_Pnt2d(float(a), float(b)))
    knots, mults = TColStd_Array1OfReal(1, n), TColStd_Array1OfInteger(1, n)
    for i in range(n):
        knots.SetValue(i + 1, float(i))
        mults.SetValue(i + 1, 2 if i in (0, n - 1) else 1)
    edge = BRepBuilderAPI_MakeEdge(Geom2d_BSplineCurve(poles, knots, mults, 1), surface_geom).Edge()
    return BRepBuilderAPI_MakeWire(edge).Wire()


def _face_shape(obj: CadObject):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.BRepLib import BRepLib

    if obj.trim is not None:  # loops past the seam of a closed direction: move the seam off them
        obj = seam_moved(obj)
    geom = to_geom_surface(obj.geometry, obj.domain)  # pyright: ignore[reportArgumentType]
    if obj.trim is None:
        face = BRepBuilderAPI_MakeFace(geom, 1e-9).Face()
    else:
        loops = obj.trim.loops()
        order = sorted(range(len(loops)), key=lambda k: not obj.trim.outer[k])  # pyright: ignore
        maker = _band_face(obj, loops[order[0]], geom)
        if maker is not None:
            order = order[1:]
        for k in order:
            wire = _wire(loops[k], geom, obj.domain, hole=not obj.trim.outer[k])
            if maker is None:
                maker = BRepBuilderAPI_MakeFace(geom, wire, True)
            else:
                maker.Add(wire)
        face = maker.Face()  # pyright: ignore[reportOptionalMemberAccess]
        BRepLib.BuildCurves3d_s(face)
    return face.Reversed() if obj.reversed else face


def _band_face(obj: CadObject, loop01, geom):
    """A face maker over the rectangle of `loop01` when it is the outer loop of a closed surface
    running around its whole period (`(0, 0) → (1, 0) → (1, 1) → (0, 1)` on a u-closed cylinder):
    OCCT's own rectangle face (`BRepBuilderAPI_MakeFace(surface, u0, u1, v0, v1)`), whose sides
    along the seam are one seam edge, as OCCT expects; `None` for any other loop."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace

    trim, tol = obj.trim, 1e-9
    loop01 = np.asarray(loop01)
    lo, hi = loop01.min(axis=0), loop01.max(axis=0)
    on_sides = np.all(
        (np.abs(loop01 - lo) <= tol) | (np.abs(loop01 - hi) <= tol), axis=1
    )  # every point a corner or on a side
    steps = np.abs(np.diff(loop01, axis=0))
    rectangle = bool(on_sides.all() and np.all((steps[:, 0] <= tol) | (steps[:, 1] <= tol)))
    full = [bool(trim.closed[a]) and lo[a] <= tol and hi[a] >= 1 - tol for a in (0, 1)]  # pyright: ignore
    if not (rectangle and any(full)):
        return None
    dom = obj.domain or ((0.0, 1.0), (0.0, 1.0))
    bounds = [dom[a][0] + (dom[a][1] - dom[a][0]) * x for a in (0, 1) for x in (lo[a], hi[a])]
    face = BRepBuilderAPI_MakeFace(geom, *(float(b) for b in bounds), 1e-9).Face()
    return BRepBuilderAPI_MakeFace(face)


def _quiet() -> None:
    """OCCT's readers and writers print progress to stdout: drop its printers. Also register the
    STEP and IGES settings (`write.step.unit`, …), which do not exist before their controllers
    are initialised (setting them earlier silently does nothing)."""
    from OCP.IGESControl import IGESControl_Controller
    from OCP.Message import Message
    from OCP.STEPControl import STEPControl_Controller

    Message.DefaultMessenger_s().ChangePrinters().Clear()
    STEPControl_Controller.Init_s()
    IGESControl_Controller.Init_s()


def save_occt(objects: list[CadObject], path: Path, units: str, progress=None) -> None:
    """Write `objects` as STEP or IGES through an XCAF document (`_named_document`: each object
    a free shape carrying its name and layer); IGES in B-Rep mode (`IGES_BREP_MODE`)."""
    from OCP.IFSelect import IFSelect_RetDone

    _quiet()
    unit = _OCCT_UNITS.get(units)
    if unit is None:
        _checks.fail("units", f"one of {', '.join(_OCCT_UNITS)} for STEP/IGES", repr(units))
    step = path.suffix.lower() in (".step", ".stp")
    shapes = [_object_shape(obj) for obj in counted(objects, progress)]
    # IGES: B-Rep mode (faces with their loops and orientation in a 514 shell), not mode 0's 144
    settings = {"xstep.cascade.unit": unit, "write.step.unit" if step else "write.iges.unit": unit}
    if not step:
        settings["write.iges.brep.mode"] = IGES_BREP_MODE
    previous = _set_static(settings)
    try:
        if step:
            from OCP.STEPCAFControl import STEPCAFControl_Writer
            from OCP.STEPControl import STEPControl_AsIs

            writer = STEPCAFControl_Writer()
            writer.SetNameMode(True)
            writer.SetLayerMode(True)
            ok = writer.Transfer(_named_document(objects, shapes), STEPControl_AsIs)
            ok = ok and writer.Write(str(path)) == IFSelect_RetDone
        else:
            from OCP.IGESCAFControl import IGESCAFControl_Writer

            writer = IGESCAFControl_Writer()
            writer.SetNameMode(True)
            writer.SetLayerMode(True)
            ok = writer.Transfer(_named_document(objects, shapes)) and writer.Write(str(path))
    finally:
        _set_static(previous)
    if not ok:
        raise OSError(f"{path}: OCCT could not write the file")


def _object_shape(obj: CadObject):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge

    if isinstance(obj.geometry, tuple):
        return _polycurve_wire(obj)
    if isinstance(obj.geometry, BSplineCurve):
        return BRepBuilderAPI_MakeEdge(to_geom_curve(obj.geometry, obj.domain)).Edge()
    return _face_shape(obj)


def _polycurve_wire(obj: CadObject):
    """A polycurve as a wire of its segments' edges (STEP/IGES: a composite curve); segments
    must meet end to start (OCCT's `BRepBuilderAPI_MakeWire`, within 1e-7)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeWire

    maker = BRepBuilderAPI_MakeWire()
    domains = obj.domain or (None,) * len(obj.geometry)  # pyright: ignore[reportArgumentType]
    for k, (curve, domain) in enumerate(zip(obj.geometry, domains)):  # pyright: ignore
        edge = BRepBuilderAPI_MakeEdge(to_geom_curve(curve, None if domain is None else (domain,))).Edge()
        maker.Add(edge)
        if not maker.IsDone():
            where = f"polycurve {obj.name!r} segment {k}"
            _checks.fail(where, "a segment starting where the previous one ends", "a gap")
    return maker.Wire()


def _named_document(objects: list[CadObject], shapes):
    """An XCAF document with one free shape per object, named and layered as the object."""
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.XCAFDoc import XCAFDoc_DocumentTool, XCAFDoc_ShapeTool

    doc = _xcaf_document()
    shape_tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    layer_tool = XCAFDoc_DocumentTool.LayerTool_s(doc.Main())
    naming = XCAFDoc_ShapeTool.AutoNaming_s()
    XCAFDoc_ShapeTool.SetAutoNaming_s(False)  # else an unnamed object is named 'FACE' or 'EDGE'
    try:
        labels = [shape_tool.AddShape(shape, False) for shape in shapes]
    finally:
        XCAFDoc_ShapeTool.SetAutoNaming_s(naming)
    for obj, label in zip(objects, labels):
        if obj.name:
            TDataStd_Name.Set_s(label, TCollection_ExtendedString(obj.name, True))  # True: UTF-8
        if obj.layer:
            layer_tool.SetLayer(label, TCollection_ExtendedString(obj.layer, True))
    return doc
