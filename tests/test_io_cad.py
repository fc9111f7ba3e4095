"""CAD exchange (issue #17): Rhino's unclamped and periodic knots, units, names, layers, domains,
trims and orientation, extrusions, blocks, STEP/IGES through OCCT. Every file is generated here
with rhino3dm or OCCT, and every loaded surface is compared with the file's own evaluator
(OpenNURBS `PointAt`, OCCT `Value`)."""

import numpy as np
import pytest
import rhino3dm

from bsjax import io
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.io import _knots

GRID = np.linspace(0.0, 1.0, 13)


def _xyz(p):
    return (p.X, p.Y, p.Z)


def _rhino_grid(srf, count: int = 13):
    """OpenNURBS's points at a count × count grid over the surface's own domain."""
    (u0, u1), (v0, v1) = [(srf.Domain(d).T0, srf.Domain(d).T1) for d in (0, 1)]
    t = np.linspace(0.0, 1.0, count)
    return np.array([[_xyz(srf.PointAt(u0 + (u1 - u0) * a, v0 + (v1 - v0) * b)) for b in t] for a in t])


def _assert_same_surface(surface: BSplineSurface, srf, rtol: float = 1e-10):
    theirs = _rhino_grid(srf)
    u, v = np.meshgrid(GRID, GRID, indexing="ij")
    ours = np.asarray(surface.evaluate(u, v))
    scale = np.abs(theirs).max()
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=rtol * scale)


def _unclamped_surface(rng, p: int, q: int, r: int, s: int, rational: bool, wrap_u: bool):
    """A rhino3dm NurbsSurface with random nondecreasing unclamped knots on an odd domain;
    with `wrap_u` the first `p` control rows repeat at the end (a closed, non-uniform periodic
    surface as Rhino's lofts and revolves hold)."""
    srf = rhino3dm.NurbsSurface.Create(3, rational, p + 1, q + 1, r, s)
    for count, knots, offset in ((r + p - 1, srf.KnotsU, -3.0), (s + q - 1, srf.KnotsV, 10.0)):
        values = offset + np.cumsum(rng.uniform(0.2, 1.5, count))
        for i, k in enumerate(values):
            knots[i] = float(k)
    ctrl = rng.normal(size=(r, s, 3)) * 10
    if wrap_u:
        ctrl[r - p :] = ctrl[:p]
    w = rng.uniform(0.5, 2.0, (r, s)) if rational else np.ones((r, s))
    if wrap_u:
        w[r - p :] = w[:p]
    for i in range(r):
        for j in range(s):
            x, y, z = ctrl[i, j] * w[i, j]
            srf.Points[i, j] = rhino3dm.Point4d(float(x), float(y), float(z), float(w[i, j]))
    return srf


def _write(tmp_path, name, *geometry, units=None):
    model = rhino3dm.File3dm()
    if units is not None:
        model.Settings.ModelUnitSystem = units
    for g in geometry:
        if isinstance(g, rhino3dm.Curve):
            model.Objects.AddCurve(g)
        elif isinstance(g, rhino3dm.Brep):
            model.Objects.AddBrep(g)
        elif isinstance(g, rhino3dm.Extrusion):
            model.Objects.AddExtrusion(g)
        else:
            model.Objects.AddSurface(g)
    path = tmp_path / name
    assert model.Write(str(path), 7)
    return path


# --- 1. every NURBS surface Rhino can hold ----------------------------------------------------
def test_clamp_matches_the_unclamped_spline_by_collocation():
    """`_knots.clamp` against scipy's B-spline evaluation of the original unclamped curve."""
    from scipy.interpolate import BSpline

    rng = np.random.default_rng(0)
    for p in (1, 2, 3, 5):
        n = p + 4
        knots = np.cumsum(rng.uniform(0.1, 1.0, n + p + 1))
        ctrl = rng.normal(size=(n, 2))
        hom, k01, (a, b) = _knots.clamp(ctrl, knots, p)
        assert (a, b) == (knots[p], knots[n]) and _knots.is_clamped(k01, p)
        t = np.linspace(0, 1, 41)
        ref = BSpline(knots, ctrl, p)(a + (b - a) * t)
        np.testing.assert_allclose(BSpline(k01, hom, p)(t), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "p, q, r, s, rational, wrap_u",
    [
        (3, 3, 9, 7, False, True),
        (2, 3, 8, 6, True, True),
        (1, 2, 5, 4, False, False),
        (11, 4, 14, 6, True, True),
    ],
)
def test_unclamped_rhino_surfaces_load_exactly(tmp_path, p, q, r, s, rational, wrap_u):
    srf = _unclamped_surface(np.random.default_rng(p * 10 + q), p, q, r, s, rational, wrap_u)
    loaded = io.load_all(_write(tmp_path, "u.3dm", srf))
    surface = loaded[0]
    assert not surface.periodic_u and (surface.degree_u, surface.degree_v) == (p, q)
    assert (surface.weights is not None) == rational
    _assert_same_surface(surface, srf)
    (u0, u1), (v0, v1) = loaded.objects[0].domain
    assert (u0, u1, v0, v1) == (srf.Domain(0).T0, srf.Domain(0).T1, srf.Domain(1).T0, srf.Domain(1).T1)


def _rhino_primitives():
    origin = rhino3dm.Point3d(1.0, -2.0, 0.5)
    circle = rhino3dm.Circle(origin, 3.0)
    return {
        "sphere (collapsed poles)": rhino3dm.NurbsSurface.CreateFromSphere(rhino3dm.Sphere(origin, 2.5)),
        "cylinder": rhino3dm.NurbsSurface.CreateFromCylinder(rhino3dm.Cylinder(circle, 4.0)),
        "ruled": rhino3dm.NurbsSurface.CreateRuledSurface(
            rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(5, 1, 0)).ToNurbsCurve(),
            circle.ToNurbsCurve(),
        ),
    }


@pytest.mark.parametrize("name", list(_rhino_primitives()))
def test_rhino_primitives_load_exactly_and_round_trip(tmp_path, name):
    srf = _rhino_primitives()[name]
    loaded = io.load_all(_write(tmp_path, "p.3dm", srf))
    _assert_same_surface(loaded[0], srf)
    back = io.load_all(io.save(loaded, tmp_path / "back.3dm"))
    assert back.objects[0].domain == loaded.objects[0].domain
    written = rhino3dm.File3dm.Read(str(tmp_path / "back.3dm")).Objects[0].Geometry
    _assert_same_surface(loaded[0], written)
    assert [(written.Domain(d).T0, written.Domain(d).T1) for d in (0, 1)] == list(loaded.objects[0].domain)


def test_non_uniform_periodic_curve_loads_exactly(tmp_path):
    rng = np.random.default_rng(5)
    p, n = 3, 9
    crv = rhino3dm.NurbsCurve(3, True, p + 1, n)
    for i, k in enumerate(np.cumsum(rng.uniform(0.3, 1.2, n + p - 1))):
        crv.Knots[i] = float(k)
    pts = rng.normal(size=(n, 3))
    pts[n - p :] = pts[:p]
    w = rng.uniform(0.5, 2, n)
    w[n - p :] = w[:p]
    for i in range(n):
        crv.Points[i] = rhino3dm.Point4d(*(pts[i] * w[i]).tolist(), float(w[i]))
    circle = rhino3dm.NurbsCurve.CreateFromCircle(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 2.0))
    loaded = io.load_all(_write(tmp_path, "c.3dm", crv, circle))
    for curve, ref, obj in zip(loaded, (crv, circle), loaded.objects):
        assert isinstance(curve, BSplineCurve)
        t0, t1 = obj.domain[0]
        t = np.linspace(0, 1, 57)
        theirs = np.array([_xyz(ref.PointAt(t0 + (t1 - t0) * x)) for x in t])
        np.testing.assert_allclose(
            np.asarray(curve.evaluate(t)), theirs, rtol=0, atol=1e-10 * np.abs(theirs).max()
        )


# --- 2. units and names -----------------------------------------------------------------------
def test_units_are_read_converted_and_written_back(tmp_path):
    srf = _rhino_primitives()["sphere (collapsed poles)"]
    path = _write(tmp_path, "mm.3dm", srf, units=rhino3dm.UnitSystem.Millimeters)
    loaded = io.load_all(path)
    assert loaded.units == "mm"
    metres = io.load_all(path, units="m")
    assert metres.units == "m"
    np.testing.assert_allclose(np.asarray(metres[0].ctrl), np.asarray(loaded[0].ctrl) / 1000, rtol=1e-15)
    for ext in (".3dm", ".json"):
        again = io.load_all(io.save(loaded, tmp_path / f"back{ext}"))
        assert again.units == "mm"
        np.testing.assert_array_equal(np.asarray(again[0].ctrl), np.asarray(loaded[0].ctrl))
    model = rhino3dm.File3dm.Read(str(tmp_path / "back.3dm"))
    assert model.Settings.ModelUnitSystem == rhino3dm.UnitSystem.Millimeters
    with pytest.raises(ValueError, match="units: expected None or one of"):
        io.load_all(path, units="furlong")


def test_names_and_layers_travel(tmp_path):
    model = rhino3dm.File3dm()
    layer = model.Layers.AddLayer("Hull", (255, 0, 0, 255))
    attributes = rhino3dm.ObjectAttributes()
    attributes.Name, attributes.LayerIndex = "port side", layer
    model.Objects.AddSurface(_rhino_primitives()["cylinder"], attributes)
    path = tmp_path / "named.3dm"
    assert model.Write(str(path), 7)
    loaded = io.load_all(path)
    assert (loaded.objects[0].name, loaded.objects[0].layer) == ("port side", "Hull")
    for ext in (".3dm", ".json"):
        again = io.load_all(io.save(loaded, tmp_path / f"back{ext}"))
        assert (again.objects[0].name, again.objects[0].layer) == ("port side", "Hull")


def test_load_of_a_file_without_surfaces_says_what_it_held(tmp_path):
    model = rhino3dm.File3dm()
    model.Objects.AddPoint(rhino3dm.Point3d(1, 2, 3))
    model.Objects.AddCurve(
        rhino3dm.NurbsCurve.CreateFromCircle(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 1))
    )
    path = tmp_path / "curve.3dm"
    assert model.Write(str(path), 7)
    with pytest.raises(
        ValueError, match=r"exactly one surface.*0 items \(the file holds 1 NurbsCurve, 1 Point\)"
    ):
        with pytest.warns(UserWarning, match=r"not loaded: object 0 \(Point\)"):
            io.load(path, "surface", on_unsupported="skip")


def test_bad_options_are_named():
    with pytest.raises(ValueError, match="on_unsupported: expected 'raise' or 'skip', got 'ignore'"):
        io.load_all("x.3dm", on_unsupported="ignore")
    with pytest.raises(TypeError, match="trims: expected True or False"):
        io.load_all("x.3dm", trims="yes")
    with pytest.raises(FileNotFoundError, match="absent.step"):
        io.load_all("absent.step")


# --- 3. STEP and IGES through OCCT ------------------------------------------------------------
def _occt_solids():
    """A box with a through hole (planes with a trimmed hole, a reversed cylinder), a sphere, a
    cone and a torus: every analytic surface STEP holds."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepPrimAPI import (
        BRepPrimAPI_MakeBox,
        BRepPrimAPI_MakeCone,
        BRepPrimAPI_MakeCylinder,
        BRepPrimAPI_MakeSphere,
        BRepPrimAPI_MakeTorus,
    )
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.TopoDS import TopoDS_Compound

    box = BRepPrimAPI_MakeBox(4.0, 3.0, 2.0).Shape()
    hole = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(2, 1.5, -1), gp_Dir(0, 0, 1)), 0.7, 4.0).Shape()
    compound, builder = TopoDS_Compound(), BRep_Builder()
    builder.MakeCompound(compound)
    for shape in (
        BRepAlgoAPI_Cut(box, hole).Shape(),
        BRepPrimAPI_MakeSphere(gp_Pnt(10, 0, 0), 1.5).Shape(),
        BRepPrimAPI_MakeCone(gp_Ax2(gp_Pnt(0, 10, 0), gp_Dir(0, 0, 1)), 2.0, 0.5, 3.0).Shape(),
        BRepPrimAPI_MakeTorus(gp_Ax2(gp_Pnt(0, -10, 0), gp_Dir(0, 1, 0)), 3.0, 0.8).Shape(),
    ):
        builder.Add(compound, shape)
    return compound


def _occt_write(shape, path):
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    writer.Transfer(shape, STEPControl_AsIs)
    writer.Write(str(path))
    return path


def _occt_faces(path):
    """The faces of a STEP or IGES file as OCCT reads them (`STEPControl_Reader`/`IGESControl_Reader`)."""
    from OCP.IGESControl import IGESControl_Reader
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    reader = IGESControl_Reader() if path.suffix.lower() in (".iges", ".igs") else STEPControl_Reader()
    reader.ReadFile(str(path))
    reader.TransferRoots()
    explorer, faces = TopExp_Explorer(reader.OneShape(), TopAbs_FACE), []
    while explorer.More():
        faces.append(TopoDS.Face(explorer.Current()))
        explorer.Next()
    return faces


def _distance_to_face_surface(face, points):
    """OCCT's own point inversion (`GeomAPI_ProjectPointOnSurf`) onto the face's surface."""
    from OCP.BRep import BRep_Tool
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    geom = BRep_Tool.Surface_s(face)
    return max(GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, p)), geom).LowerDistance() for p in points)


def test_step_analytic_faces_load_as_exact_nurbs_with_trims_and_orientation(tmp_path):
    from OCP.TopAbs import TopAbs_REVERSED

    path = _occt_write(_occt_solids(), tmp_path / "solids.step")
    faces = _occt_faces(path)
    loaded = io.load_all(path, trims=True)
    assert loaded.units == "mm" and len(loaded) == len(faces) == 7 + 1 + 3 + 1
    u, v = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 7), indexing="ij")
    for face, obj in zip(faces, loaded):
        points = np.asarray(obj.geometry.evaluate(u, v)).reshape(-1, 3)
        assert _distance_to_face_surface(face, points) < 1e-9
        assert obj.reversed == (face.Orientation() == TopAbs_REVERSED)
    trimmed = [o for o in loaded if o.trim is not None]  # the box's top and bottom, the cone's caps
    assert sorted(o.trim.outer for o in trimmed) == [(True,), (True,), (True, False), (True, False)]
    holed = [o for o in trimmed if len(o.trim.outer) == 2]
    for obj in holed:  # the hole of radius 0.7 about (2, 1.5) on the 4 × 3 faces
        (u0, u1), (v0, v1) = obj.domain
        x, y = np.meshgrid(np.linspace(0.05, 3.95, 40), np.linspace(0.05, 2.95, 30), indexing="ij")
        s, t = (x - u0) / (u1 - u0), (y - v0) / (v1 - v0)
        if u1 - u0 < 3.5:  # the face's u runs along y
            s, t = (y - u0) / (u1 - u0), (x - v0) / (v1 - v0)
        outside_hole = np.hypot(x - 2, y - 1.5) > 0.7
        clear = np.abs(np.hypot(x - 2, y - 1.5) - 0.7) > 0.01  # polyline chords: 1e-3 deep
        np.testing.assert_array_equal(np.asarray(obj.mask(s, t))[clear], outside_hole[clear])


@pytest.mark.parametrize("ext", [".step", ".igs", ".3dm", ".json"])
def test_step_model_round_trips(tmp_path, ext):
    """STEP → bsjax → `ext` → bsjax: the same surfaces, orientation and trimmed regions."""
    loaded = io.load_all(_occt_write(_occt_solids(), tmp_path / "solids.step"), trims=True)
    back = io.load_all(io.save(loaded, tmp_path / f"back{ext}"), trims=True)
    assert back.units == "mm" and len(back) == len(loaded)
    u, v = np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 9), indexing="ij")
    for a, b in zip(loaded, back):
        ours, theirs = np.asarray(a.geometry.evaluate(u, v)), np.asarray(b.geometry.evaluate(u, v))
        np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.domain, a.domain, rtol=0, atol=1e-9)
        if ext != ".igs":  # OCCT's IGES reader does not keep a face's orientation
            assert a.reversed == b.reversed
        assert (a.trim is None) == (b.trim is None)
        if a.trim is not None:
            s, t = np.meshgrid(np.linspace(0.01, 0.99, 50), np.linspace(0.01, 0.99, 50), indexing="ij")
            assert np.mean(np.asarray(a.mask(s, t)) != np.asarray(b.mask(s, t))) < 0.01


def test_step_written_from_rhino_matches_opennurbs_and_occt(tmp_path):
    """A closed non-uniform periodic Rhino surface through .3dm → STEP: OCCT's evaluator of the
    written file (`BRepAdaptor_Surface.Value`) agrees with OpenNURBS's `PointAt` on the original."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface

    srf = _unclamped_surface(np.random.default_rng(7), 3, 2, 9, 5, True, True)
    loaded = io.load_all(_write(tmp_path, "u.3dm", srf))
    step = io.save(loaded, tmp_path / "u.step")
    (face,) = _occt_faces(step)
    adaptor = BRepAdaptor_Surface(face)
    (u0, u1), (v0, v1) = loaded.objects[0].domain
    t = np.linspace(0, 1, 13)
    occt = np.array(
        [[_xyz_occt(adaptor.Value(u0 + (u1 - u0) * a, v0 + (v1 - v0) * b)) for b in t] for a in t]
    )
    theirs = _rhino_grid(srf)
    np.testing.assert_allclose(occt, theirs, rtol=0, atol=1e-10 * np.abs(theirs).max())
    again = io.load_all(step)
    _assert_same_surface(again[0], srf)
    np.testing.assert_allclose(again.objects[0].domain, loaded.objects[0].domain, rtol=0, atol=1e-12)


def test_step_names_and_layers_round_trip(tmp_path):
    """Names (UTF-8 too) and layers written by `save` as STEP products and layer assignments
    (OCCT's XCAF) come back from `load_all`, for surfaces and curves; an unnamed object stays
    unnamed (not OCCT's default product name); the geometry is unchanged."""
    rng = np.random.default_rng(3)
    surface = BSplineSurface(rng.normal(size=(4, 5, 3)), _knots_01(4, 2), _knots_01(5, 3), 2, 3)
    curve = BSplineCurve(rng.normal(size=(5, 3)), _knots_01(5, 3), 3)
    objects = [
        io.CadObject(surface, "port plate é", "Hull::port"),
        io.CadObject(curve, "keel line", "Deck"),
        io.CadObject(surface),
        io.CadObject(surface, "", "Deck"),
        io.CadObject(surface, "lid", ""),
    ]
    path = io.save(objects, tmp_path / "named.step", units="mm")
    text = path.read_text(encoding="utf-8")
    assert "PRODUCT('port plate é'" in text and "PRESENTATION_LAYER_ASSIGNMENT('Hull::port'" in text
    back = io.load_all(path)
    assert [(o.name, o.layer) for o in back.objects] == [(o.name, o.layer) for o in objects]
    assert [type(o.geometry) for o in back.objects] == [type(o.geometry) for o in objects]
    u, v = np.meshgrid(GRID, GRID, indexing="ij")
    np.testing.assert_allclose(back[0].evaluate(u, v), surface.evaluate(u, v), rtol=0, atol=1e-12)
    # the file itself holds them as any STEP reader sees them: products and layer assignments
    assert text.count("PRESENTATION_LAYER_ASSIGNMENT(") == 2
    assert all(f"PRODUCT('{name}'" in text for name in ("keel line", "lid"))
    # and a .3dm's names and layers reach STEP and come back
    model = rhino3dm.File3dm()
    layer = model.Layers.AddLayer("Hull", (255, 0, 0, 255))
    attributes = rhino3dm.ObjectAttributes()
    attributes.Name, attributes.LayerIndex = "starboard", layer
    model.Objects.AddSurface(_rhino_primitives()["cylinder"], attributes)
    assert model.Write(str(tmp_path / "named.3dm"), 7)
    again = io.load_all(io.save(io.load_all(tmp_path / "named.3dm"), tmp_path / "from3dm.step"))
    assert (again.objects[0].name, again.objects[0].layer) == ("starboard", "Hull")


def test_step_from_another_writer_has_no_invented_names(tmp_path):
    """A STEP file written without names (OCCT's plain writer names products after itself)."""
    loaded = io.load_all(_occt_write(_occt_solids(), tmp_path / "plain.step"), trims=True)
    assert {(o.name, o.layer) for o in loaded.objects} == {("", "")}


def test_step_assembly_components_keep_their_part_names(tmp_path):
    """A STEP assembly (OCCT's XCAF): each located component's faces carry its part's name and
    layer (not OCCT's invented component names), and sit where the component's placement puts
    them."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.gp import gp_Trsf, gp_Vec
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS_Compound
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    from bsjax.io import _occt

    _occt._quiet()
    doc = _occt._xcaf_document()
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    layers = XCAFDoc_DocumentTool.LayerTool_s(doc.Main())
    box = shapes.AddShape(BRepPrimAPI_MakeBox(1.0, 2.0, 3.0).Shape(), False)
    TDataStd_Name.Set_s(box, TCollection_ExtendedString("brick"))
    layers.SetLayer(box, TCollection_ExtendedString("Walls"))
    compound, builder = TopoDS_Compound(), BRep_Builder()
    builder.MakeCompound(compound)
    assembly = shapes.AddShape(compound, True)
    TDataStd_Name.Set_s(assembly, TCollection_ExtendedString("wall"))
    for dx in (0.0, 10.0):
        move = gp_Trsf()
        move.SetTranslation(gp_Vec(dx, 0.0, 0.0))
        shapes.AddComponent(assembly, box, TopLoc_Location(move))
    shapes.UpdateAssemblies()
    writer = STEPCAFControl_Writer()
    assert writer.Transfer(doc, STEPControl_AsIs)
    path = tmp_path / "wall.step"
    writer.Write(str(path))
    loaded = io.load_all(path)
    assert len(loaded) == 12 and {(o.name, o.layer) for o in loaded.objects} == {("brick", "Walls")}
    lowest_x = [float(np.asarray(o.geometry.ctrl)[..., 0].min()) for o in loaded.objects]
    np.testing.assert_allclose(sorted(lowest_x), [0] * 5 + [1] + [10] * 5 + [11], atol=1e-12)


def _knots_01(n: int, p: int) -> np.ndarray:
    return np.concatenate([np.zeros(p), np.linspace(0, 1, n - p + 1), np.ones(p)])


def _xyz_occt(p):
    return (p.X(), p.Y(), p.Z())


def test_step_units_are_kept(tmp_path):
    srf = _rhino_primitives()["cylinder"]
    loaded = io.load_all(_write(tmp_path, "m.3dm", srf, units=rhino3dm.UnitSystem.Meters))
    assert loaded.units == "m"
    for ext in (".step", ".igs"):
        again = io.load_all(io.save(loaded, tmp_path / f"m{ext}"))
        assert again.units == "m"
        _assert_same_surface(again[0], srf, 1e-10 if ext == ".step" else 1e-8)  # OCCT's IGES: 10 digits
        mm = io.load_all(tmp_path / f"m{ext}", units="mm")
        np.testing.assert_allclose(np.asarray(mm[0].ctrl), 1000 * np.asarray(again[0].ctrl), rtol=1e-14)


def test_step_curves_load(tmp_path):
    circle = rhino3dm.NurbsCurve.CreateFromCircle(rhino3dm.Circle(rhino3dm.Point3d(1, 2, 3), 2.0))
    loaded = io.load_all(_write(tmp_path, "c.3dm", circle))
    again = io.load_all(io.save(loaded, tmp_path / "c.step"))
    assert isinstance(again[0], BSplineCurve)
    t = np.linspace(0, 1, 21)
    np.testing.assert_allclose(
        np.asarray(again[0].evaluate(t)), np.asarray(loaded[0].evaluate(t)), atol=1e-12
    )


# --- 4. trims, orientation, extrusions, blocks (.3dm) ------------------------------------------
def _holed_extrusion():
    """A 4 × 3 × 2 box extruded from a rectangle with a circular inner profile (radius 0.7 about
    (2, 1.5)), capped: two planar caps trimmed with a hole."""
    corners = [(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)]
    rect = rhino3dm.Polyline([rhino3dm.Point3d(x, y, 0) for x, y in corners]).ToNurbsCurve()
    extrusion = rhino3dm.Extrusion.Create(rect, 2.0, True)
    assert extrusion.AddInnerProfile(rhino3dm.Circle(rhino3dm.Point3d(2, 1.5, 0), 0.7).ToNurbsCurve())
    return extrusion


def _cap_mask_matches_geometry(obj, count: int = 41):
    """The face's trim mask against the 3-D truth: inside the rectangle, outside the hole."""
    s, t = np.meshgrid(np.linspace(0.02, 0.98, count), np.linspace(0.02, 0.98, count), indexing="ij")
    points = np.asarray(obj.geometry.evaluate(s, t))
    r = np.hypot(points[..., 0] - 2, points[..., 1] - 1.5)
    clear = np.abs(r - 0.7) > 0.01  # polyline chords of the projected circle: ~2e-3 deep
    np.testing.assert_array_equal(np.asarray(obj.mask(s, t))[clear], (r > 0.7)[clear])


def test_extrusion_loads_with_caps_and_holes(tmp_path):
    path = _write(tmp_path, "ext.3dm", _holed_extrusion())
    with pytest.warns(UserWarning, match="2 trimmed faces loaded as their untrimmed surfaces"):
        plain = io.load_all(path)
    assert len(plain) == 4 + 1 + 2
    faces = io.load_all(path, trims=True)
    caps = [o for o in faces if o.trim is not None]
    assert len(caps) == 2 and all(o.trim.outer == (True, False) for o in caps)
    for cap in caps:
        _cap_mask_matches_geometry(cap)
    for ext in (".3dm", ".json", ".step"):  # bsjax's own files keep the trims
        back = io.load_all(io.save(faces, tmp_path / f"back{ext}"), trims=True)
        for cap in (o for o in back if o.trim is not None):
            _cap_mask_matches_geometry(cap)
        assert sum(o.trim is not None for o in back) == 2


def test_reversed_faces_keep_their_flag(tmp_path):
    brep = rhino3dm.Brep.CreateFromSurface(_rhino_primitives()["cylinder"])
    brep.Flip()
    path = _write(tmp_path, "rev.3dm", brep)
    with pytest.warns(UserWarning, match="1 faces have reversed orientation"):
        io.load_all(path)
    faces = io.load_all(path, trims=True)
    assert [o.reversed for o in faces] == [True]
    for ext in (".3dm", ".json", ".step"):
        assert [o.reversed for o in io.load_all(io.save(faces, tmp_path / f"r{ext}"), trims=True)] == [True]


def test_block_instances_are_expanded_with_their_transforms(tmp_path):
    sphere = _rhino_primitives()["sphere (collapsed poles)"]
    model = rhino3dm.File3dm()
    model.InstanceDefinitions.Add(
        "ball", "", "", "", rhino3dm.Point3d(0, 0, 0), (sphere,), (rhino3dm.ObjectAttributes(),)
    )
    idef = model.InstanceDefinitions[0]
    for dx in (5.0, -7.0):
        model.Objects.AddInstanceObject(
            rhino3dm.InstanceReference(idef.Id, rhino3dm.Transform.Translation(dx, 0, 0))
        )
    path = tmp_path / "blocks.3dm"
    assert model.Write(str(path), 7)
    loaded = io.load_all(path)
    assert len(loaded) == 2 and loaded.held["InstanceReference"] == 2
    for surface, dx in zip(loaded, (5.0, -7.0)):
        moved = sphere.Duplicate()
        moved.Translate(rhino3dm.Vector3d(dx, 0, 0))
        _assert_same_surface(surface, moved)


def test_contacts_masked_by_a_trim_exclude_the_hole(tmp_path):
    """A ball sitting in the cap's hole touches the untrimmed plane but not the trimmed face
    (`collide.contacts(..., sample_mask=CadObject.sample_mask(blending))`, or the caller's own
    masking with `CadObject.mask`: the same)."""
    from bsjax import collide

    faces = io.load_all(_write(tmp_path, "ext.3dm", _holed_extrusion()), trims=True)
    cap = next(o for o in faces if o.trim is not None and np.asarray(o.geometry.ctrl)[..., 2].max() < 1e-9)
    ball = collide.Sphere(np.array([2.0, 1.5, 0.0]), 0.3)  # inside the hole of radius 0.7
    contact = collide.contacts(cap.geometry.blending(60, 60), cap.geometry.ctrl, ball)
    assert bool(contact.hit)
    u, v = np.meshgrid(np.asarray(contact.params_u), np.asarray(contact.params_v), indexing="ij")
    assert not np.any(np.asarray(contact.mask) & np.asarray(cap.mask(u, v)))
    blending = cap.geometry.blending(60, 60)
    sample_mask = cap.sample_mask(blending)
    np.testing.assert_array_equal(np.asarray(sample_mask), np.asarray(cap.mask(u, v)))
    assert not bool(collide.contacts(blending, cap.geometry.ctrl, ball, sample_mask=sample_mask).hit)
    near = collide.Sphere(np.array([0.5, 0.5, 0.0]), 0.3)  # a corner of the solid cap: kept
    corner = collide.contacts(blending, cap.geometry.ctrl, near)
    assert np.any(np.asarray(corner.mask) & np.asarray(cap.mask(u, v)))
    trimmed = collide.contacts(blending, cap.geometry.ctrl, near, sample_mask=sample_mask)
    np.testing.assert_array_equal(np.asarray(trimmed.mask), np.asarray(corner.mask) & np.asarray(sample_mask))


# --- 5. the command line ----------------------------------------------------------------------
def test_cli_convert_keeps_geometry_trims_orientation_and_units(tmp_path, capsys):
    from bsjax.cli import convert

    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Millimeters
    model.Objects.AddExtrusion(_holed_extrusion())
    source = tmp_path / "part.3dm"
    assert model.Write(str(source), 7)
    reference = io.load_all(source, trims=True)
    for ext in (".step", ".igs", ".json", ".3dm"):
        target = tmp_path / f"part{ext}"
        assert convert.main([str(source), str(target)]) == 0
        back = io.load_all(target, trims=True)
        assert back.units == "mm" and len(back) == len(reference)
        assert sum(o.trim is not None for o in back) == 2
        if ext != ".igs":
            assert [o.reversed for o in back] == [o.reversed for o in reference]
        for a, b in zip(reference, back):
            u = np.linspace(0, 1, 7)
            np.testing.assert_allclose(
                np.asarray(b.geometry.evaluate(u, u)), np.asarray(a.geometry.evaluate(u, u)), atol=1e-8
            )
    assert convert.main([str(source), str(tmp_path / "m.json"), "--units", "m"]) == 0
    metres = io.load_all(tmp_path / "m.json")
    assert metres.units == "m"
    np.testing.assert_allclose(np.asarray(metres[0].ctrl), np.asarray(reference[0].geometry.ctrl) / 1000)
    assert convert.main([str(source), str(tmp_path / "part.stl")]) == 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["{d}/held.3dm", "{d}/o.json"], "object 0 (Point)"),
        (["{d}/held.3dm", "{d}/o.json", "--units", "furlong"], "--units"),
        (["{d}/absent.step", "{d}/o.json"], "absent.step"),
        (["{d}/garbage.step", "{d}/o.json"], "garbage.step"),
    ],
)
def test_cli_convert_errors_are_one_line(tmp_path, capsys, argv, message):
    from bsjax.cli import convert

    model = rhino3dm.File3dm()
    model.Objects.AddPoint(rhino3dm.Point3d(1, 2, 3))
    model.Objects.AddSurface(_rhino_primitives()["cylinder"])
    assert model.Write(str(tmp_path / "held.3dm"), 7)
    (tmp_path / "garbage.step").write_text("ISO-10303-21;\nnot a step file\n")
    assert convert.main([a.format(d=tmp_path) for a in argv]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_cli_convert_skips_unsupported_when_asked(tmp_path):
    from bsjax.cli import convert

    model = rhino3dm.File3dm()
    model.Objects.AddPoint(rhino3dm.Point3d(1, 2, 3))
    model.Objects.AddSurface(_rhino_primitives()["cylinder"])
    assert model.Write(str(tmp_path / "held.3dm"), 7)
    with pytest.warns(UserWarning, match="not loaded: object 0"):
        assert convert.main([str(tmp_path / "held.3dm"), str(tmp_path / "o.json"), "--skip-unsupported"]) == 0
    assert len(io.load_all(tmp_path / "o.json")) == 1


def test_trim_mask_against_a_closed_form_and_bad_values():
    """A unit square with a round hole: the even–odd mask against the closed form, under jit and
    vmap, and NaN parameters refused eagerly and under jit."""
    import jax

    from tests.helpers import raises_both

    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    hole = np.c_[0.5 + 0.25 * np.cos(t), 0.4 + 0.25 * np.sin(t)]
    trim = io.Trim.from_loops(
        [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), hole], [True, False]
    )
    rng = np.random.default_rng(2)
    u, v = rng.uniform(-0.2, 1.2, (2, 500))
    r = np.hypot(u - 0.5, v - 0.4)
    truth = (u > 0) & (u < 1) & (v > 0) & (v < 1) & (r > 0.25)
    clear = np.abs(r - 0.25) > 1e-4
    np.testing.assert_array_equal(np.asarray(trim.mask(u, v))[clear], truth[clear])
    np.testing.assert_array_equal(
        np.asarray(jax.jit(lambda a, b: trim.mask(a, b))(u, v)), np.asarray(trim.mask(u, v))
    )
    np.testing.assert_array_equal(np.asarray(jax.vmap(trim.mask)(u, v)), np.asarray(trim.mask(u, v)))
    raises_both(
        lambda a, b: trim.mask(a, b),
        np.array([0.5, np.nan]),
        np.array([0.5, 0.5]),
        match="u: expected finite",
    )
    with pytest.raises(ValueError, match=r"loops\[0\]: expected a closed polyline"):
        io.Trim.from_loops([np.zeros((2, 2))], [True])
