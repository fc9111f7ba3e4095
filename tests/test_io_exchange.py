"""CAD exchange (issue #17): polycurves load as lists of curves (one per segment, in order) and
save back as polycurves (`.3dm` `PolyCurve`, a STEP/IGES wire); IGES names and layers through
OCCT's XCAF (`IGESCAFControl`). Each segment is compared with OpenNURBS's own evaluator."""

import numpy as np
import pytest
import rhino3dm

from bsjax import io
from bsjax.basis import BSplineCurve, BSplineSurface, clamped_knots

pytest.importorskip("OCP")


def _polycurve():
    """A line, a quarter arc and a cubic NURBS, joined end to start."""
    out = rhino3dm.PolyCurve()
    out.Append(rhino3dm.Line(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0)))
    out.Append(
        rhino3dm.Arc(rhino3dm.Point3d(1, 0, 0), rhino3dm.Point3d(1.5, 0.5, 0), rhino3dm.Point3d(2, 0, 0))
    )
    points = [rhino3dm.Point3d(*p) for p in ((2, 0, 0), (3, 1, 0), (4, -1, 1), (5, 0, 0))]
    assert out.AppendSegment(rhino3dm.NurbsCurve.Create(False, 3, points))
    return out


def _write_polycurve(path, name="path"):
    model = rhino3dm.File3dm()
    attributes = rhino3dm.ObjectAttributes()
    attributes.Name = name
    model.Objects.AddCurve(_polycurve(), attributes)
    assert model.Write(str(path), 7)
    return path


def _assert_segments_match(segments, polycurve, atol):
    """Each loaded segment against OpenNURBS's `SegmentCurve(i).PointAt(t)` over its domain (a
    line or arc segment's parameter mapped to its NURBS form's, which bsjax's [0, 1] follows)."""
    assert polycurve.SegmentCount == len(segments)
    for i, curve in enumerate(segments):
        theirs = polycurve.SegmentCurve(i)
        t0, t1 = theirs.Domain.T0, theirs.Domain.T1
        ts = np.linspace(t0, t1, 17)
        expected = np.array([[(p := theirs.PointAt(float(t))).X, p.Y, p.Z] for t in ts])
        nurbs = np.array([theirs.GetNurbsFormParameterFromCurveParameter(float(t))[1] for t in ts])
        s = (nurbs - t0) / (t1 - t0)  # the NURBS form keeps the segment's domain
        np.testing.assert_allclose(np.asarray(curve.evaluate(np.clip(s, 0, 1))), expected, rtol=0, atol=atol)


def test_3dm_polycurve_loads_as_a_list_and_saves_as_a_polycurve(tmp_path):
    path = _write_polycurve(tmp_path / "p.3dm")
    loaded = io.load_all(path)
    assert len(loaded) == 1 and isinstance(loaded[0], list) and len(loaded[0]) == 3
    assert all(isinstance(c, BSplineCurve) for c in loaded[0])
    assert loaded.objects[0].name == "path" and loaded.held["PolyCurve"] == 1
    _assert_segments_match(loaded[0], _polycurve(), 1e-12)
    assert len(io.load_all(path, "curve")) == 1 and len(io.load_all(path, "surface")) == 0

    back = rhino3dm.File3dm.Read(str(io.save(loaded, tmp_path / "back.3dm")))
    written = back.Objects[0].Geometry
    assert isinstance(written, rhino3dm.PolyCurve) and back.Objects[0].Attributes.Name == "path"
    _assert_segments_match(loaded[0], written, 1e-12)
    # a plain list of curves as one item of `save`'s list: a polycurve too
    written = rhino3dm.File3dm.Read(str(io.save([loaded[0]], tmp_path / "list.3dm"))).Objects[0].Geometry
    assert isinstance(written, rhino3dm.PolyCurve) and written.SegmentCount == 3
    # two curves (not nested): two curves
    assert len(rhino3dm.File3dm.Read(str(io.save(loaded[0][:2], tmp_path / "two.3dm"))).Objects) == 2


@pytest.mark.parametrize("ext, atol", [(".json", 0.0), (".step", 1e-12), (".igs", 1e-9)])
def test_polycurve_round_trips(tmp_path, ext, atol):
    """.3dm → `ext` → bsjax: the same segments, in order, with the name (STEP: OCCT writes a wire
    as a curve set of its edges; a part of edges meeting end to start reads back as a polycurve)."""
    loaded = io.load_all(_write_polycurve(tmp_path / "p.3dm"), trims=True)
    back = io.load_all(io.save(loaded, tmp_path / f"back{ext}"), trims=True)
    assert len(back) == 1 and isinstance(back[0].geometry, tuple) and back[0].name == "path"
    _assert_segments_match(back[0].geometry, _polycurve(), atol + 1e-12)
    np.testing.assert_allclose(back[0].domain, loaded[0].domain, rtol=0, atol=1e-9)


def test_polycurve_with_a_gap_is_refused_for_step(tmp_path):
    line = BSplineCurve(np.array([[0.0, 0, 0], [1, 0, 0]]), clamped_knots(2, 1), 1)
    apart = line.with_ctrl(np.asarray(line.ctrl) + np.array([[0.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match="polycurve '' segment 1: expected a segment starting where"):
        io.save([[line, apart]], tmp_path / "gap.step")
    with pytest.raises(ValueError, match="surfaces: expected"):
        io.save([[line, "not a curve"]], tmp_path / "bad.step")


def _plate(offset: float = 0.0) -> BSplineSurface:
    g = np.linspace(0.0, 1.0, 3)
    ctrl = np.stack([*np.meshgrid(g, g, indexing="ij"), np.full((3, 3), offset)], -1)
    return BSplineSurface(ctrl, clamped_knots(3, 2), clamped_knots(3, 2), 2, 2)


def test_iges_names_and_layers(tmp_path):
    """IGES keeps ASCII names (entity label / name property) and integer layers (levels); a
    layer with another name comes back as the level number OCCT gave it; an unnamed entity
    stays unnamed."""
    curve = BSplineCurve(np.array([[0.0, 0, 0], [1, 2, 0], [3, 1, 1]]), clamped_knots(3, 2), 2)
    objects = [
        io.CadObject(_plate(), "wall A", "12"),
        io.CadObject(_plate(1.0), "", "Walls"),
        io.CadObject(curve, "rail", "3"),
    ]
    back = io.load_all(io.save(objects, tmp_path / "named.igs", units="mm"), trims=True)
    assert [o.name for o in back] == ["wall A", "", "rail"]
    assert back[0].layer == "12" and back[2].layer == "3"
    assert back[1].layer.isdigit() and back[1].layer not in ("12", "3")
    for a, b in zip(objects, back):
        s = np.linspace(0, 1, 5)
        args = (s,) if isinstance(a.geometry, BSplineCurve) else np.meshgrid(s, s, indexing="ij")
        np.testing.assert_allclose(
            np.asarray(b.geometry.evaluate(*args)), np.asarray(a.geometry.evaluate(*args)), atol=1e-9
        )


@pytest.mark.parametrize("ext", ["json", "3dm", "step", "obj"])
def test_save_reports_each_object_and_writes_the_same_file(tmp_path, ext):
    """`io.save(..., progress=)` calls `progress(k, 3)` once per object, in order, and writes
    what a save without it writes (read back: the same nets)."""
    from bsjax import shapes

    items = [shapes.plate(4, 4), shapes.teardrop(), shapes.plate(5, 4)]
    calls = []
    io.save(items, tmp_path / f"shown.{ext}", 5, 5, progress=lambda done, total: calls.append((done, total)))
    io.save(items, tmp_path / f"plain.{ext}", 5, 5)
    assert calls == [(1, 3), (2, 3), (3, 3)]
    if ext == "obj":
        assert (tmp_path / "shown.obj").read_bytes() == (tmp_path / "plain.obj").read_bytes()
        return
    shown, plain = io.load_all(tmp_path / f"shown.{ext}"), io.load_all(tmp_path / f"plain.{ext}")
    assert len(shown) == len(plain) == 3
    for a, b in zip(shown, plain):
        np.testing.assert_array_equal(np.asarray(a.ctrl), np.asarray(b.ctrl))
    with pytest.raises(TypeError, match="progress: expected a callable"):
        io.save(items, tmp_path / f"bad.{ext}", progress=3)
