"""Trims on closed surfaces (issue #17): a face whose trim loop crosses or lies on the seam of a
cylinder. The mask is compared with OCCT's own face classifier (`BRepClass_FaceClassifier`) at
many points on both sides of the seam, for the loops as OCCT gives them (split at the seam), for
the same loops shifted by a period, and for a hole given as one loop across the seam."""

import numpy as np
import pytest
import rhino3dm

from bsjax import io
from bsjax.basis import closest_points
from bsjax.io import _rhino

pytest.importorskip("OCP")


def _holed_cylinder():
    """A unit cylinder (height 2) drilled along x at z = 1 (radius 0.3): the hole at +x crosses
    OCCT's seam (u = 0), the one at −x (u = π) lies inside the face."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

    drill = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(-2, 0, 1), gp_Dir(1, 0, 0)), 0.3, 4.0).Shape()
    return BRepAlgoAPI_Cut(BRepPrimAPI_MakeCylinder(1.0, 2.0).Shape(), drill).Shape()


@pytest.fixture(scope="module")
def drilled(tmp_path_factory):
    from tests.test_io_cad import _occt_write

    return _wall(_occt_write(_holed_cylinder(), tmp_path_factory.mktemp("seam") / "drilled.step"))


def _wall(path):
    """The drilled cylinder's wall: (OCCT face from the file, bsjax object from the file)."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_Cylinder

    from tests.test_io_cad import _occt_faces

    faces, loaded = _occt_faces(path), io.load_all(path, trims=True)
    walls = [
        (face, obj)
        for face, obj in zip(faces, loaded)
        if BRepAdaptor_Surface(face).GetType() == GeomAbs_Cylinder and obj.domain[1] == (0.0, 2.0)
    ]
    assert len(walls) == 1
    return walls[0]


def _occt_inside(face, points):
    """OCCT's classifier at the (angle, height) of each 3-D point on the unit cylinder:
    `(inside, decided)`; a point on the seam itself is `ON` the face's boundary for OCCT (its
    seam is an edge), so not decided."""
    from OCP.BRepClass import BRepClass_FaceClassifier
    from OCP.gp import gp_Pnt2d
    from OCP.TopAbs import TopAbs_IN, TopAbs_ON

    angle = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
    states = [
        BRepClass_FaceClassifier(face, gp_Pnt2d(float(a), float(z)), 1e-9).State()
        for a, z in zip(angle, points[:, 2])
    ]
    return np.array([s == TopAbs_IN for s in states]), np.array([s != TopAbs_ON for s in states])


def _samples(obj, count: int = 60):
    """Parameters crowded near the seam (u = 0 and u = 1) and spread over the face."""
    u = np.concatenate(
        [
            np.linspace(0.0, 0.12, count // 3),
            np.linspace(0.88, 1.0, count // 3),
            np.linspace(0.0, 1.0, count // 3),
        ]
    )
    s, t = np.meshgrid(u, np.linspace(0.3, 0.7, 21), indexing="ij")
    points = np.asarray(obj.geometry.evaluate(s, t)).reshape(-1, 3)
    # polyline chords of the round holes lie up to ~1e-3 inside: keep clear of the hole edges
    clear = np.all(np.abs(np.hypot(points[:, 1:2] - 0, points[:, 2:3] - 1.0) - 0.3) > 0.01, axis=1)
    return s.ravel(), t.ravel(), points, clear


def test_step_cylinder_with_a_hole_across_the_seam_matches_occt(drilled):
    face, obj = drilled
    assert obj.trim is not None and obj.trim.closed == (True, False)
    s, t, points, clear = _samples(obj)
    occt, decided = _occt_inside(face, points)
    clear &= decided
    assert not occt[clear].all() and occt[clear].any()  # both holes are sampled
    near_seam = (s < 0.05) | (s > 0.95)
    assert not occt[clear & near_seam].all()  # the seam hole is sampled on both sides
    np.testing.assert_array_equal(np.asarray(obj.mask(s, t))[clear], occt[clear])

    # the same loops shifted by a period (as a file may give them): the same mask
    loops = obj.trim.loops()
    shifted = io.Trim.from_loops([loop + (1.0, 0.0) for loop in loops], obj.trim.outer, (True, False))
    np.testing.assert_array_equal(np.asarray(shifted.mask(s, t))[clear], occt[clear])


def test_a_hole_given_as_one_loop_across_the_seam(drilled):
    """The full wall as the outer loop and the seam hole as one closed loop around u = 0 (half of
    it below 0): inside the hole on both sides of the seam, as OCCT's classifier says for the
    drilled cylinder (the other hole left out of both)."""
    face, obj = drilled
    s, t, points, clear = _samples(obj)
    away = np.abs(np.arctan2(points[:, 1], points[:, 0])) < np.pi / 2  # the seam hole's half
    a = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    y, z = 0.3 * np.cos(a), 1.0 + 0.3 * np.sin(a)  # the drill's rim on the unit cylinder
    xyz = np.c_[np.sqrt(1 - y**2), y, z]
    uv = np.array(closest_points(obj.geometry, xyz).params)  # the rim's (u, v) on the NURBS
    uv[:, 0] = np.unwrap(uv[:, 0], period=1.0)
    wall = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trim = io.Trim.from_loops([wall, uv], [True, False], (True, False))
    assert np.asarray(trim.segments)[:, :, 0].min() < 0 or np.asarray(trim.segments)[:, :, 0].max() > 1
    occt, decided = _occt_inside(face, points)
    keep = clear & away & decided
    np.testing.assert_array_equal(np.asarray(trim.mask(s, t))[keep], occt[keep])
    # without the seam wrap the hole's far half is lost: the mask would be wrong there
    flat = io.Trim.from_loops([wall, uv], [True, False])
    assert np.any(np.asarray(flat.mask(s, t))[keep] != occt[keep])


def _rhino_closed_breps():
    cylinder = rhino3dm.Cylinder(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 1.0), 2.0)
    sphere = rhino3dm.Sphere(rhino3dm.Point3d(1, 2, 3), 1.5)
    return {
        "cylinder": rhino3dm.Brep.CreateFromCylinder(cylinder, False, False),
        "sphere": rhino3dm.Brep.CreateFromSphere(sphere),  # two poles: singular trims
    }


@pytest.mark.parametrize("name", ["cylinder", "sphere"])
def test_rhino_seam_trims_project_to_one_closed_loop(name):
    """A Rhino cylinder's or sphere's face loop runs along the seam twice (the sphere's also
    through two poles, trims without an edge); seam points project to u = 0 or 1 at random.
    Each piece is placed by its direction, so the whole face is inside."""
    brep = _rhino_closed_breps()[name]
    face = brep.Faces[0]
    surface, _ = _rhino.surface_from_rhino(face.ToNurbsSurface())
    trim = _rhino._face_trim(brep, face, surface)
    assert trim.closed[0] != trim.closed[1]
    s, t = np.meshgrid(np.linspace(0.0, 1.0, 41), np.linspace(0.02, 0.98, 11), indexing="ij")
    if trim.closed[1]:
        s, t = t, s
    assert np.asarray(trim.mask(s, t)).all()


def test_closed_trim_round_trips_through_json_and_3dm(tmp_path):
    loop = np.array([[-0.1, 0.4], [0.1, 0.4], [0.1, 0.6], [-0.1, 0.6]])
    wall = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trim = io.Trim.from_loops([wall, loop], [True, False], (True, False))
    cylinder = rhino3dm.Cylinder(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 1.0), 2.0)
    surface, _ = _rhino.surface_from_rhino(cylinder.ToNurbsSurface())
    obj = io.CadObject(surface, trim=trim)
    s, t = np.meshgrid(np.linspace(0, 1, 31), np.linspace(0, 1, 31), indexing="ij")
    expected = np.asarray(trim.mask(s, t))
    assert not expected[-1, 15] and not expected[0, 15] and expected[15, 15]
    back = io.load_all(io.save(obj, tmp_path / "c.json"), trims=True).objects[0]
    assert back.trim.closed == (True, False)
    np.testing.assert_array_equal(np.asarray(back.mask(s, t)), expected)
    # .3dm: the seam is moved off the hole before writing (a trim must lie in the surface's
    # domain), so the file's parametrisation differs: compare at the same 3-D points
    back = io.load_all(io.save(obj, tmp_path / "c.3dm"), trims=True).objects[0]
    assert back.trim.closed == (True, False)
    points = np.asarray(surface.evaluate(s.ravel(), t.ravel())).reshape(-1, 3)
    uv = np.asarray(closest_points(back.geometry, points).params)
    clear = _off_loops(trim, s.ravel(), t.ravel(), 1e-6)
    got = np.asarray(back.mask(uv[:, 0], uv[:, 1]))
    np.testing.assert_array_equal(got[clear], expected.ravel()[clear])


def test_mask_on_a_torus_wraps_both_directions():
    """A round hole about the corner (0, 0) of a surface closed in u and v (a torus) covers all
    four corners of [0, 1]²: the mask against the periodic distance, under jit too."""
    import jax

    a = np.linspace(0, 2 * np.pi, 160, endpoint=False)
    hole = np.c_[0.15 * np.cos(a), 0.15 * np.sin(a)]
    wall = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trim = io.Trim.from_loops([wall, hole], [True, False], (True, True))
    u, v = np.random.default_rng(3).uniform(0.0, 1.0, (2, 2000))
    r = np.hypot(np.minimum(u, 1 - u), np.minimum(v, 1 - v))
    clear = np.abs(r - 0.15) > 1e-3
    np.testing.assert_array_equal(np.asarray(trim.mask(u, v))[clear], (r > 0.15)[clear])
    np.testing.assert_array_equal(
        np.asarray(jax.jit(lambda x, y: trim.mask(x, y))(u, v)), np.asarray(trim.mask(u, v))
    )
    flat = io.Trim.from_loops([wall, hole], [True, False])  # not closed: three corners lost
    assert np.any(np.asarray(flat.mask(u, v))[clear] != (r > 0.15)[clear])


def _seam_hole_object():
    """A Rhino cylinder (closed in u) with a round hole given as one loop across its seam (half
    of it below u = 0) and a second hole inside the face."""
    cylinder = rhino3dm.Cylinder(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 1.0), 2.0)
    surface, domain = _rhino.surface_from_rhino(cylinder.ToNurbsSurface())
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    across = np.c_[0.08 * np.cos(a), 0.5 + 0.2 * np.sin(a)][::-1]
    inside = np.c_[0.4 + 0.05 * np.cos(a), 0.3 + 0.1 * np.sin(a)][::-1]
    wall = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    trim = io.Trim.from_loops([wall, across, inside], [True, False, False], (True, False))
    u = np.asarray(trim.segments)[..., 0]
    assert u.min() < 0 or u.max() > 1  # the loop runs past the seam
    return io.CadObject(surface, domain=domain, trim=trim)


def _classify(face, points):
    """OCCT's classifier on `face` at each 3-D point (projected onto the face's surface):
    `(inside, decided)`."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepClass import BRepClass_FaceClassifier
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt, gp_Pnt2d
    from OCP.TopAbs import TopAbs_IN, TopAbs_ON

    geom = BRep_Tool.Surface_s(face)
    inside, decided = [], []
    for x, y, z in points:
        u, v = GeomAPI_ProjectPointOnSurf(
            gp_Pnt(float(x), float(y), float(z)), geom
        ).LowerDistanceParameters()
        state = BRepClass_FaceClassifier(face, gp_Pnt2d(u, v), 1e-9).State()
        inside.append(state == TopAbs_IN)
        decided.append(state != TopAbs_ON)
    return np.array(inside), np.array(decided)


@pytest.mark.parametrize("ext", [".step", ".iges"])
def test_a_loop_across_the_seam_is_written_inside_the_surface(tmp_path, ext):
    """STEP/IGES: the seam is moved off the loops (knot insertion, same geometry), so the written
    face is valid for OCCT's `BRepCheck_Analyzer` and its classifier agrees with the original
    trim's mask at points compared in 3-D (the parametrisation moved)."""
    from OCP.BRepCheck import BRepCheck_Analyzer

    from tests.test_io_cad import _occt_faces

    obj = _seam_hole_object()
    path = io.save(obj, tmp_path / f"seam{ext}", units="mm")  # OCCT reads in mm: numbers unchanged
    (face,) = _occt_faces(path)
    assert BRepCheck_Analyzer(face).IsValid()
    u, v = np.random.default_rng(5).uniform(0.0, 1.0, (2, 400))
    u = np.concatenate([u, np.linspace(0.0, 0.05, 20), np.linspace(0.95, 1.0, 20)])
    v = np.concatenate([v, np.full(40, 0.5)])
    points = np.asarray(obj.geometry.evaluate(u, v)).reshape(-1, 3)
    expected = np.asarray(obj.trim.mask(u, v))
    assert not expected[-40:].any()  # the seam hole is sampled on both sides of the seam
    occt, decided = _classify(face, points)
    clear = decided & _off_loops(obj.trim, u, v, 2e-3)
    assert clear.sum() > 350 and (~expected[clear]).sum() > 30
    np.testing.assert_array_equal(occt[clear], expected[clear])


def _off_loops(trim, u, v, gap: float):
    """Samples farther than `gap` (in [0, 1]², over the period) from every loop edge."""
    seg = np.asarray(trim.segments)
    a, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    best = np.full(u.shape, np.inf)
    for shift in (-1.0, 0.0, 1.0):
        p = np.c_[u - shift, v][:, None, :]
        t = np.clip(np.sum((p - a) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-300), 0, 1)
        best = np.minimum(best, np.linalg.norm(p - (a + t[..., None] * d), axis=-1).min(axis=1))
    return best > gap


def test_seam_moved_keeps_geometry_and_mask():
    """`seam_moved`: the moved surface is the same point set (every old point lies on it) and the
    moved trim's mask at its parameters equals the old mask; a band loop stays the band."""
    from bsjax.io._cad import seam_moved

    obj = _seam_hole_object()
    moved = seam_moved(obj)
    loops = moved.trim.loops()
    assert all(loop.min() >= 0 and loop.max() <= 1 for loop in loops)
    np.testing.assert_allclose(loops[0][:, 0].min(), 0.0) and np.testing.assert_allclose(
        loops[0][:, 0].max(), 1.0
    )
    u, v = np.random.default_rng(1).uniform(0.0, 1.0, (2, 300))
    points = np.asarray(obj.geometry.evaluate(u, v)).reshape(-1, 3)
    uv = np.asarray(closest_points(moved.geometry, points).params)
    again = np.asarray(moved.geometry.evaluate(uv[:, 0], uv[:, 1])).reshape(-1, 3)
    np.testing.assert_allclose(again, points, atol=1e-9)
    np.testing.assert_array_equal(
        np.asarray(moved.trim.mask(uv[:, 0], uv[:, 1])), np.asarray(obj.trim.mask(u, v))
    )
    # a loop around the whole band (every seam position crossed): unchanged
    band = io.Trim.from_loops(
        [np.array([[-0.2, 0.1], [1.0, 0.1], [1.0, 0.9], [-0.2, 0.9]])], [True], (True, False)
    )
    wide = io.CadObject(obj.geometry, trim=band)
    assert seam_moved(wide) is wide
