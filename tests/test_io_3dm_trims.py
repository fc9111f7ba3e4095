"""Trimmed faces written to `.3dm` as real trimmed Breps (issue #17): the OpenNURBS archive
bsjax encodes (`bsjax.io._3dm_archive`) decodes in rhino3dm to a valid Brep (OpenNURBS's own
`IsValid` is the oracle), its loops follow the written trim, and reading the file back *without*
bsjax's user string (from the Brep's own edges) gives the written trim's mask."""

import numpy as np
import pytest
import rhino3dm

from bsjax import io
from bsjax.basis import closest_points
from bsjax.io import _rhino
from bsjax.io._3dm_archive import trimmed_brep
from tests.helpers import random_surface

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _plate_with_hole():
    """A bumpy bicubic plate with a round hole (a 20-gon) and a rectangular outer loop inset."""
    surface = random_surface(np.random.default_rng(4), uniform=True)
    a = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    hole = np.c_[0.5 + 0.2 * np.cos(a), 0.45 + 0.15 * np.sin(a)][::-1]
    outer = np.array([[0.05, 0.1], [0.95, 0.1], [0.95, 0.9], [0.05, 0.9]])
    return surface, io.Trim.from_loops([outer, hole], [True, False])


def _cylinder_with_seam_hole():
    """A Rhino cylinder (closed in u) whose outer loop is the whole wall (along the seam) and
    whose hole runs across the seam (one loop, half of it below u = 0)."""
    cylinder = rhino3dm.Cylinder(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 1.0), 2.0)
    surface, domain = _rhino.surface_from_rhino(cylinder.ToNurbsSurface())
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    hole = np.c_[0.08 * np.cos(a), 0.5 + 0.2 * np.sin(a)][::-1]
    return surface, domain, io.Trim.from_loops([SQUARE, hole], [True, False], (True, False))


def _written_brep(path):
    (obj,) = rhino3dm.File3dm.Read(str(path)).Objects
    return obj.Geometry


def _without_user_string(path, out):
    """The file's Breps written again with bsjax's user string emptied (so a reader sees only
    the Brep's own loops)."""
    model = rhino3dm.File3dm()
    for obj in rhino3dm.File3dm.Read(str(path)).Objects:
        brep = obj.Geometry
        brep.SetUserString("bsjax.trim", "")
        model.Objects.AddBrep(brep)
    assert model.Write(str(out), 7)
    return out


def _off_loops(trim, u, v, gap: float):
    """Parameters farther than `gap` from every loop edge (over the period on closed directions)."""
    seg = np.asarray(trim.segments)
    a, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    best = np.full(u.shape, np.inf)
    for shift in (-1.0, 0.0, 1.0) if trim.closed[0] else (0.0,):
        p = np.c_[u - shift, v][:, None, :]
        t = np.clip(np.sum((p - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-300), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (a + t[..., None] * d), axis=-1).min(axis=1))
    return best > gap


def _loop_types(brep):
    return [str(loop.LoopType).rsplit(".", 1)[-1] for loop in brep.Faces[0].Loops]


def test_plate_with_a_hole_is_a_valid_trimmed_brep(tmp_path):
    surface, trim = _plate_with_hole()
    path = io.save(io.CadObject(surface, trim=trim), tmp_path / "plate.3dm")
    brep = _written_brep(path)
    assert brep.IsValid, brep.IsValidWithLog
    assert not brep.IsSurface and len(brep.Faces) == 1
    assert _loop_types(brep) == ["Outer", "Inner"]
    # the face's trims follow the loops: one trim per polyline edge, starting at its points
    for loop, polyline in zip(brep.Faces[0].Loops, trim.loops()):
        assert len(loop.Trims) == len(polyline) - 1
        starts = np.array([_xyz(brep.Vertices[t.StartVertexIndex].Location) for t in loop.Trims])
        on_surface = np.asarray(surface.evaluate(polyline[:-1, 0], polyline[:-1, 1])).reshape(-1, 3)
        distance = np.linalg.norm(starts[:, None] - on_surface[None], axis=-1).min(axis=1)
        assert distance.max() < 1e-9
    # the user string still holds the exact loops
    back = io.load_all(path, trims=True).objects[0]
    np.testing.assert_allclose(np.asarray(back.trim.segments), np.asarray(trim.segments), atol=0)

    # read from the Brep's own edges (no user string): the same mask away from the loops
    bare = io.load_all(_without_user_string(path, tmp_path / "bare.3dm"), trims=True).objects[0]
    assert bare.trim is not None and bare.trim.outer == (True, False)
    u, v = np.random.default_rng(0).uniform(0.0, 1.0, (2, 1500))
    clear = _off_loops(trim, u, v, 1e-3)
    expected = np.asarray(trim.mask(u, v))
    assert (~expected[clear]).sum() > 100 and expected[clear].sum() > 100  # hole and border hit
    np.testing.assert_array_equal(np.asarray(bare.mask(u, v))[clear], expected[clear])


def test_face_on_a_closed_surface_with_a_hole_across_the_seam(tmp_path):
    """The outer loop runs along the seam (two seam trims of one edge), the hole across it: the
    seam is moved off the hole first, the Brep is valid, and its mask at the same 3-D points
    equals the written one, with and without the user string."""
    surface, domain, trim = _cylinder_with_seam_hole()
    path = io.save(io.CadObject(surface, domain=domain, trim=trim), tmp_path / "wall.3dm")
    brep = _written_brep(path)
    assert brep.IsValid, brep.IsValidWithLog
    assert not brep.IsSurface and _loop_types(brep) == ["Outer", "Inner"]
    outer = brep.Faces[0].Loops[0]
    edges = [t.EdgeIndex for t in outer.Trims]
    assert len(edges) == 4 and len(set(edges)) == 3  # the seam edge is used twice
    u, v = np.random.default_rng(1).uniform(0.0, 1.0, (2, 800))
    u = np.concatenate([u, np.linspace(0.0, 0.06, 15), np.linspace(0.94, 1.0, 15)])
    v = np.concatenate([v, np.full(30, 0.5)])
    expected = np.asarray(trim.mask(u, v))
    assert not expected[-30:].any()  # both sides of the old seam lie in the hole
    points = np.asarray(surface.evaluate(u, v)).reshape(-1, 3)
    clear = _off_loops(trim, u, v, 2e-3)
    for read in (path, _without_user_string(path, tmp_path / "bare.3dm")):
        back = io.load_all(read, trims=True).objects[0]
        assert back.trim.closed == (True, False)
        uv = np.asarray(closest_points(back.geometry, points).params)
        np.testing.assert_allclose(np.asarray(back.geometry.evaluate(uv[:, 0], uv[:, 1])), points, atol=1e-9)
        np.testing.assert_array_equal(np.asarray(back.mask(uv[:, 0], uv[:, 1]))[clear], expected[clear])


def test_reversed_trimmed_face_keeps_its_flag(tmp_path):
    surface, trim = _plate_with_hole()
    path = io.save(io.CadObject(surface, reversed=True, trim=trim), tmp_path / "flip.3dm")
    brep = _written_brep(path)
    assert brep.IsValid and not brep.IsSurface
    assert brep.Faces[0].OrientationIsReversed
    bare = io.load_all(_without_user_string(path, tmp_path / "bare.3dm"), trims=True).objects[0]
    assert bare.reversed and bare.trim is not None
    u, v = np.random.default_rng(2).uniform(0.0, 1.0, (2, 600))
    clear = _off_loops(trim, u, v, 1e-3)
    np.testing.assert_array_equal(np.asarray(bare.mask(u, v))[clear], np.asarray(trim.mask(u, v))[clear])


def test_loops_given_clockwise_are_written_with_opennurbs_orientation(tmp_path):
    """The outer loop given clockwise and the hole counter-clockwise: written the other way round
    (outer counter-clockwise, holes clockwise), else OpenNURBS calls the Brep invalid."""
    surface, trim = _plate_with_hole()
    flipped = io.Trim.from_loops([loop[::-1] for loop in trim.loops()], trim.outer)
    brep = _written_brep(io.save(io.CadObject(surface, trim=flipped), tmp_path / "cw.3dm"))
    assert brep.IsValid and _loop_types(brep) == ["Outer", "Inner"]
    # the plate's x, y grow with u, v: the sign of a loop's area in x, y is its sign in (u, v)
    areas = []
    for loop in brep.Faces[0].Loops:
        x, y, _ = np.array([_xyz(brep.Vertices[t.StartVertexIndex].Location) for t in loop.Trims]).T
        areas.append(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    assert areas[0] > 0 > areas[1]


def test_a_loop_around_every_seam_position_falls_back_to_the_user_string(tmp_path):
    """A loop wider than the period (no seam position free): the untrimmed surface with the exact
    loops in the user string, as before; loading gives the trim back."""
    surface, domain, _ = _cylinder_with_seam_hole()
    wide = np.array([[-0.2, 0.1], [1.0, 0.1], [1.0, 0.9], [-0.2, 0.9]])
    trim = io.Trim.from_loops([wide], [True], (True, False))
    path = io.save(io.CadObject(surface, domain=domain, trim=trim), tmp_path / "wide.3dm")
    brep = _written_brep(path)
    assert brep.IsSurface
    back = io.load_all(path, trims=True).objects[0]
    np.testing.assert_array_equal(np.asarray(back.trim.segments), np.asarray(trim.segments))


def test_encoder_without_a_hole_decodes_to_the_surface():
    """The archive of an untrimmed square loop: a valid Brep whose face is the surface itself
    (`IsSurface`), evaluated as OpenNURBS evaluates the input surface."""
    surface, _ = _plate_with_hole()
    srf = _rhino.surface_to_rhino(surface)
    brep = trimmed_brep(srf, [np.vstack([SQUARE, SQUARE[:1]])], [True], False)
    assert brep is not None and brep.IsValid and brep.IsSurface
    face = brep.Faces[0].ToNurbsSurface()
    for s, t in np.random.default_rng(3).uniform(0.0, 1.0, (20, 2)):
        a, b = face.PointAt(float(s), float(t)), srf.PointAt(float(s), float(t))
        assert np.allclose(_xyz(a), _xyz(b), atol=1e-12)


@pytest.mark.parametrize("ext", [".3dm"])
def test_several_trimmed_faces_in_one_file(tmp_path, ext):
    surface, trim = _plate_with_hole()
    objects = [io.CadObject(surface, name=f"face {k}", trim=trim) for k in range(2)]
    model = rhino3dm.File3dm.Read(str(io.save(objects, tmp_path / f"two{ext}")))
    breps = [obj.Geometry for obj in model.Objects]
    assert [b.IsValid and not b.IsSurface for b in breps] == [True, True]
    assert [obj.Attributes.Name for obj in model.Objects] == ["face 0", "face 1"]


def _xyz(p):
    return (p.X, p.Y, p.Z)


def test_sphere_face_has_singular_and_seam_trims(tmp_path):
    """A Rhino sphere (closed in u, both v sides collapsed to poles) with a hole: the outer loop
    is two singular trims (no edge) and one seam edge used twice; valid for OpenNURBS, and the
    mask read from the Brep's edges equals the written one."""
    sphere = rhino3dm.Sphere(rhino3dm.Point3d(1, 2, 3), 1.5)
    surface, domain = _rhino.surface_from_rhino(sphere.ToNurbsSurface())
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    hole = np.c_[0.3 + 0.05 * np.cos(a), 0.5 + 0.1 * np.sin(a)]
    trim = io.Trim.from_loops([SQUARE, hole], [True, False], (True, False))
    path = io.save(io.CadObject(surface, domain=domain, trim=trim), tmp_path / "ball.3dm")
    brep = _written_brep(path)
    assert brep.IsValid and not brep.IsSurface
    edges = [t.EdgeIndex for t in brep.Faces[0].Loops[0].Trims]
    assert sorted(edges) == [-1, -1, 0, 0]
    bare = io.load_all(_without_user_string(path, tmp_path / "bare.3dm"), trims=True).objects[0]
    u, v = np.random.default_rng(6).uniform(0.02, 0.98, (2, 600))
    clear = _off_loops(trim, u, v, 2e-3)
    np.testing.assert_array_equal(np.asarray(bare.mask(u, v))[clear], np.asarray(trim.mask(u, v))[clear])
