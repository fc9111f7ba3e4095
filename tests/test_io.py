"""File formats: exact JSON/.3dm round trips of surfaces and curves, Rhino's own evaluator as an
oracle, meshes."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
import rhino3dm
import trimesh

from bsjax import io, shapes
from bsjax.basis import BSplineCurve, BSplineSurface, clamped_knots
from tests.helpers import random_knots, random_surface

GRID = np.linspace(0.0, 1.0, 9)
U, V = np.meshgrid(GRID, GRID, indexing="ij")


def _surfaces():
    rng = np.random.default_rng(3)
    return {
        "teardrop (periodic v)": shapes.teardrop(),
        "random nonuniform": random_surface(rng, 6, 5, 3, 2),
        "rational": random_surface(rng, 5, 7, 2, 3, weights=True),
        "periodic u": BSplineSurface(
            np.asarray(shapes.teardrop().ctrl).transpose(1, 0, 2),
            None,
            clamped_knots(8, 3),
            3,
            3,
            periodic_u=True,
        ),
    }


@pytest.mark.parametrize("name", list(_surfaces()))
@pytest.mark.parametrize("ext", [".json", ".3dm"])
def test_round_trip_is_exact(tmp_path, name, ext):
    surface = _surfaces()[name]
    back = io.load(io.save(surface, tmp_path / f"s{ext}"))
    assert (back.degree_u, back.degree_v, back.periodic_u, back.periodic_v) == (
        surface.degree_u,
        surface.degree_v,
        surface.periodic_u,
        surface.periodic_v,
    )
    assert back.shape == surface.shape
    tol = 0.0 if ext == ".json" else 1e-15  # .3dm stores w·P: one rounding on the way back
    np.testing.assert_allclose(back.ctrl, surface.ctrl, rtol=0, atol=tol * 10)
    for a, b in (
        (back.knots_u, surface.knots_u),
        (back.knots_v, surface.knots_v),
        (back.weights, surface.weights),
    ):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=0, atol=tol)


@pytest.mark.parametrize("name", list(_surfaces()))
def test_rhino_evaluates_the_same_surface(tmp_path, name):
    """OpenNURBS (through rhino3dm) is an independent evaluator of what we wrote."""
    surface = _surfaces()[name]
    io.save(surface, tmp_path / "s.3dm")
    srf = rhino3dm.File3dm.Read(str(tmp_path / "s.3dm")).Objects[0].Geometry
    (u0, u1), (v0, v1) = (srf.Domain(0).T0, srf.Domain(0).T1), (srf.Domain(1).T0, srf.Domain(1).T1)
    ours = np.asarray(surface.evaluate(U, V))
    theirs = np.array(
        [[_xyz(srf.PointAt(u0 + (u1 - u0) * a, v0 + (v1 - v0) * b)) for b in GRID] for a in GRID]
    )
    np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-12)
    assert srf.IsClosed(1) == surface.periodic_v and srf.IsClosed(0) == surface.periodic_u


def test_json_is_plain_and_lists_several(tmp_path):
    a, b = shapes.spoon_handle(), shapes.spoon_bowl()
    path = io.save([a, b], tmp_path / "two.json")
    data = json.loads(path.read_text())
    assert data["format"] == "bsjax.surfaces" and len(data["surfaces"]) == 2
    back = io.load_all(path)
    np.testing.assert_array_equal(back[1].ctrl, b.ctrl)
    with pytest.raises(ValueError, match="exactly one surface"):
        io.load(path)


@pytest.mark.parametrize("ext", [".obj", ".stl", ".ply", ".glb"])
def test_mesh_export_reads_back(tmp_path, ext):
    surface = shapes.teardrop()
    io.save(surface, tmp_path / f"t{ext}", m=24, n=20)
    mesh = trimesh.load(tmp_path / f"t{ext}", force="mesh")
    points = np.asarray(surface.blending(24, 20).points(surface.ctrl)).reshape(-1, 3)
    # every vertex is a sample of the surface, and the closed teardrop gives a closed mesh
    d = np.min(np.linalg.norm(mesh.vertices[:, None] - points[None], axis=-1), axis=1)
    assert d.max() < 1e-6
    mesh.merge_vertices()
    assert mesh.is_watertight


def test_tessellated_volume_converges():
    """Closed teardrop: mesh volume converges (Richardson: error shrinks ~4× per doubling)."""
    vols = [io.tessellate(shapes.teardrop(), k, k).volume for k in (21, 41, 81, 161)]
    errs = np.abs(np.diff(vols))
    assert errs[2] < errs[1] < errs[0]
    assert 2.5 < errs[1] / errs[2] < 6.0


def test_float32_survives_json(tmp_path):
    s = shapes.plate(dtype=np.float32)
    back = io.load(io.save(s, tmp_path / "p.json"))
    assert back.ctrl.dtype == jnp.float32
    np.testing.assert_array_equal(back.ctrl, s.ctrl)


def test_bad_files_name_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json"):
        io.load(bad)
    wrong = tmp_path / "wrong.json"
    wrong.write_text(
        json.dumps(
            {
                "format": "bsjax.surface",
                "degree_u": 3,
                "degree_v": 3,
                "knots_u": [0, 1],
                "knots_v": [0, 1],
                "ctrl": np.zeros((4, 4, 3)).tolist(),
            }
        )
    )
    with pytest.raises(ValueError, match="wrong.json.*knots_u"):
        io.load(wrong)
    with pytest.raises(ValueError, match="path"):
        io.save(shapes.plate(), tmp_path / "x.dwg")
    garbage = tmp_path / "g.3dm"
    garbage.write_bytes(b"\x00" * 64)
    with pytest.raises(ValueError, match="g.3dm"):
        io.load(garbage)


def _plate_document(**change):
    doc = io.to_dict(shapes.plate(4, 4))
    doc.update(change)
    return doc


@pytest.mark.parametrize(
    "content, match",
    [
        (b"\xc5\x00\xff random bytes", "not UTF-8"),
        (b'{"a": ' * 100_000, "nested too deeply|not valid JSON"),
        (json.dumps(_plate_document(degree_u=3.7)).encode(), "degree_u: expected an integer"),
        (json.dumps(_plate_document(degree_v=True)).encode(), "degree_v: expected an integer"),
        (json.dumps(_plate_document(periodic_v="false")).encode(), "periodic_v: expected true or false"),
        (json.dumps(_plate_document(dtype="int64")).encode(), "dtype: expected 'float32' or 'float64'"),
        (json.dumps(_plate_document(ctrl="zeros")).encode(), "ctrl: expected nested lists of numbers"),
        (json.dumps(_plate_document(ctrl=[[[True, 0, 0]]])).encode(), "ctrl: expected nested lists of numbers"),  # noqa: E501
        (json.dumps(_plate_document()).replace("0.0", "1" + "0" * 400, 1).encode(), "knots_u: expected"),
        (json.dumps(_plate_document(dtype="float32")).replace("0.0", "1e39", 1).encode(), "knots_u: expected finite"),  # noqa: E501
        (json.dumps({"format": "bsjax.surfaces", "surfaces": {"a": 1}}).encode(), "surfaces: expected a list"),  # noqa: E501
        (json.dumps([1, 2]).encode(), "expected a JSON object"),
    ],
    ids=[
        "random bytes", "deep nesting", "float degree", "bool degree", "string flag", "int dtype",
        "string array", "boolean entries", "huge integer", "float32 overflow", "surfaces not a list",
        "wrong schema",
    ],
)  # fmt: skip
def test_bad_json_is_a_clear_error_naming_the_file_and_field(tmp_path, content, match):
    path = tmp_path / "bad.json"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=f"bad.json.*({match})"):
        io.load(path)


def test_missing_files_are_os_errors_naming_them(tmp_path):
    for name in ("absent.json", "absent.3dm"):
        with pytest.raises(FileNotFoundError, match=name):
            io.load(tmp_path / name)


def test_3dm_objects_not_loaded_are_listed(tmp_path):
    """A point, a mesh and a box Brep beside a surface: by default the file is refused with a
    message listing the point and the mesh; with `on_unsupported="skip"` the surface and the six
    box faces load and a warning lists the same objects."""
    model = rhino3dm.File3dm()
    model.Objects.AddPoint(rhino3dm.Point3d(1, 2, 3))
    mesh = rhino3dm.Mesh()
    for x, y in ((0, 0), (1, 0), (0, 1)):
        mesh.Vertices.Add(x, y, 0)
    mesh.Faces.AddFace(0, 1, 2)
    model.Objects.AddMesh(mesh)
    model.Objects.AddSurface(
        rhino3dm.NurbsSurface.CreateFromSphere(rhino3dm.Sphere(rhino3dm.Point3d(0, 0, 0), 1))
    )
    box = rhino3dm.Brep.CreateFromBox(rhino3dm.Box(rhino3dm.BoundingBox(0, 0, 0, 1, 1, 1)))
    model.Objects.AddBrep(box)
    path = tmp_path / "mixed.3dm"
    assert model.Write(str(path), 7)
    listed = r"mixed.3dm: .*object 0 \(Point\), object 1 \(Mesh\)"
    with pytest.raises(ValueError, match=listed + ".*on_unsupported='skip'"):
        io.load_all(path)
    with pytest.warns(UserWarning, match=r"mixed.3dm: not loaded: object 0 \(Point\), object 1 \(Mesh\)"):
        items = io.load_all(path, on_unsupported="skip")
    assert len(items) == 1 + 6 and all(isinstance(s, BSplineSurface) for s in items)
    assert items.held == {"Point": 1, "Mesh": 1, "NurbsSurface": 1, "Brep": 1}


def test_3dm_annotations_are_skipped_with_a_warning_and_carried_to_a_3dm(tmp_path):
    """Text dots beside a surface (as in OpenNURBS's own example files): annotations are not
    geometry, so the file loads by default (no `on_unsupported="skip"` needed) and a warning
    names them; they travel in `CadList.annotations` and `bsjax convert` to a `.3dm` writes them
    back (text, place, name, layer), scaled with the geometry when units are converted."""
    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Meters
    model.Objects.AddSurface(
        rhino3dm.NurbsSurface.CreateFromSphere(rhino3dm.Sphere(rhino3dm.Point3d(0, 0, 0), 1))
    )
    notes = model.Layers.AddLayer("notes", (0, 0, 0, 255))
    attributes = rhino3dm.ObjectAttributes()
    attributes.Name, attributes.LayerIndex = "label", notes
    model.Objects.AddTextDot("bulb", rhino3dm.Point3d(0, 0, 1.2), attributes)
    model.Objects.AddTextDot("base", rhino3dm.Point3d(0, 0, -1.2))
    path = tmp_path / "dots.3dm"
    assert model.Write(str(path), 7)
    with pytest.warns(UserWarning, match=r"dots.3dm: 2 annotations .*object 1 \(TextDot 'label'\), object 2"):
        items = io.load_all(path)
    assert len(items) == 1 and isinstance(items[0], BSplineSurface) and len(items.annotations) == 2
    from bsjax.cli import convert

    with pytest.warns(UserWarning, match="annotations"):
        assert convert.main([str(path), str(tmp_path / "dots.json")]) == 0  # geometry only there
    assert io.load(tmp_path / "dots.json").shape == items[0].shape
    with pytest.warns(UserWarning, match="annotations"):
        assert convert.main([str(path), str(tmp_path / "copy.3dm")]) == 0
    copy = rhino3dm.File3dm.Read(str(tmp_path / "copy.3dm"))
    dots = [o for o in copy.Objects if isinstance(o.Geometry, rhino3dm.TextDot)]
    assert sorted(d.Geometry.Text for d in dots) == ["base", "bulb"]
    bulb = next(d for d in dots if d.Geometry.Text == "bulb")
    assert bulb.Attributes.Name == "label" and copy.Layers[bulb.Attributes.LayerIndex].Name == "notes"
    assert bulb.Geometry.Point.Z == pytest.approx(1.2)
    with pytest.warns(UserWarning, match="annotations"):
        in_mm = io.load_all(path, units="mm")
    assert in_mm.annotations[0][0].Point.Z == pytest.approx(1200.0)


def test_mesh_with_a_non_finite_vertex_is_refused(tmp_path):
    from bsjax.collide import TriangleMesh

    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 nan\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    with pytest.raises(ValueError, match="nan.obj: vertices: expected finite"):
        TriangleMesh.load(path)
    good = tmp_path / "good.obj"
    good.write_text(path.read_text().replace("nan", "1"))
    assert TriangleMesh.load(good).faces.shape == (4, 3)


def _xyz(p):
    return (p.X, p.Y, p.Z)


# --- curves -----------------------------------------------------------------------------------
def _curves():
    rng = np.random.default_rng(4)
    p = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]], float)
    circle_knots = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]
    return {
        "planar nonuniform": BSplineCurve(rng.normal(size=(7, 2)), random_knots(rng, 7, 3), 3),
        "spatial rational": BSplineCurve(
            rng.normal(size=(6, 3)), random_knots(rng, 6, 2), 2, weights=rng.uniform(0.5, 2, 6)
        ),
        "rational circle": BSplineCurve(2 * p, circle_knots, 2, weights=np.array([1, 2**-0.5] * 4 + [1])),
        "periodic spatial": BSplineCurve(rng.normal(size=(8, 3)), None, 3, periodic=True),
    }


@pytest.mark.parametrize("name", list(_curves()))
@pytest.mark.parametrize("ext", [".json", ".3dm"])
def test_curve_round_trip_is_exact(tmp_path, name, ext):
    curve = _curves()[name]
    back = io.load(io.save(curve, tmp_path / f"c{ext}"))
    assert isinstance(back, BSplineCurve)
    assert (back.degree, back.periodic, back.dim, back.n_ctrl) == (
        curve.degree,
        curve.periodic,
        curve.dim,
        curve.n_ctrl,
    )
    tol = 0.0 if ext == ".json" else 1e-15  # .3dm stores w·P: one rounding on the way back
    np.testing.assert_allclose(back.ctrl, curve.ctrl, rtol=0, atol=tol * 10)
    for a, b in ((back.knots, curve.knots), (back.weights, curve.weights)):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=0, atol=tol)


@pytest.mark.parametrize("name", list(_curves()))
def test_rhino_evaluates_the_same_curve(tmp_path, name):
    """OpenNURBS `PointAt` (through rhino3dm) evaluates the `.3dm` curve bsjax wrote."""
    curve = _curves()[name]
    io.save(curve, tmp_path / "c.3dm")
    crv = rhino3dm.File3dm.Read(str(tmp_path / "c.3dm")).Objects[0].Geometry
    assert isinstance(crv, rhino3dm.NurbsCurve) and crv.Dimension == curve.dim
    t0, t1 = crv.Domain.T0, crv.Domain.T1
    theirs = np.array([_xyz(crv.PointAt(t0 + (t1 - t0) * a)) for a in GRID])[:, : curve.dim]
    np.testing.assert_allclose(theirs, np.asarray(curve.evaluate(GRID)), rtol=0, atol=1e-12)
    assert crv.IsClosed == (curve.periodic or name == "rational circle")
    assert crv.IsPeriodic == curve.periodic
    if name == "rational circle":
        assert crv.IsCircle()


def test_rhino_own_curves_read_back(tmp_path):
    """A periodic curve made by rhino3dm itself (its own layout of wrapped points) reads as periodic."""
    pts = [rhino3dm.Point3d(np.cos(a), np.sin(a), 0.1 * a) for a in np.linspace(0, 5, 6)]
    crv = rhino3dm.NurbsCurve.Create(True, 3, pts)
    model = rhino3dm.File3dm()
    model.Objects.AddCurve(crv)
    model.Write(str(tmp_path / "r.3dm"), 7)
    back = io.load(tmp_path / "r.3dm")
    assert back.periodic and back.n_ctrl == 6 and back.degree == 3
    t0, t1 = crv.Domain.T0, crv.Domain.T1
    theirs = np.array([_xyz(crv.PointAt(t0 + (t1 - t0) * a)) for a in GRID])
    np.testing.assert_allclose(theirs, np.asarray(back.evaluate(GRID)), rtol=0, atol=1e-12)


@pytest.mark.parametrize("ext", [".json", ".3dm"])
def test_surfaces_and_curves_in_one_file(tmp_path, ext):
    surface, curves = shapes.plate(), list(_curves().values())
    path = io.save([surface, *curves], tmp_path / f"mixed{ext}")
    items = io.load_all(path)
    assert isinstance(items[0], BSplineSurface) and all(isinstance(c, BSplineCurve) for c in items[1:])
    assert len(io.load_all(path, kind="curve")) == len(curves)
    np.testing.assert_allclose(io.load(path, kind="surface").ctrl, surface.ctrl, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="exactly one curve"):
        io.load(path, kind="curve")
    with pytest.raises(ValueError, match="kind"):
        io.load_all(path, kind="mesh")


def test_curves_refuse_mesh_formats(tmp_path):
    with pytest.raises(ValueError, match="only surfaces for a mesh format"):
        io.save(_curves()["planar nonuniform"], tmp_path / "c.stl")
    bad = tmp_path / "bad.json"
    data = io.to_dict(_curves()["planar nonuniform"])
    bad.write_text(json.dumps({**data, "knots": data["knots"][:-1]}))
    with pytest.raises(ValueError, match="bad.json.*knots"):
        io.load(bad)
