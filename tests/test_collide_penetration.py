"""`collide.surface_penetration`: closed forms, a dense closest-point reference, action = reaction,
jit/vmap/grad, and bad input.

The round surfaces are exact NURBS (rational quadratic arcs), so their samples lie on the sphere
or cylinder to rounding; the only approximation is the other surface's tessellation, whose
error is bounded from the samples in each test. Every surface pair uses one of three compiled
shapes (plate × plate, round × plate, round × round, all 24 × 24 samples) so the module compiles
few programs.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import trimesh

from bsjax import shapes
from bsjax.basis import BSplineSurface, ProjectionSolver, closest_points
from bsjax.collide import Penetration, _penetration, grid_mesh, surface_penetration
from tests.helpers import raises_both, random_surface

GRID = 24
W = np.sqrt(0.5)
_HALF_KNOTS = [0, 0, 0, 0.5, 0.5, 1, 1, 1]  # a rational quadratic half circle: 5 points
_FULL_KNOTS = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]  # a full circle: 9 points
_CIRCLE = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]], float)
_CIRCLE_W = np.array([1, W, 1, W, 1, W, 1, W, 1])


def _sphere(centre, radius) -> BSplineSurface:
    """Exact NURBS sphere: u from the top pole (u = 0) to the bottom pole (u = 1), v a clamped full
    circle (its seam v = 0 ≡ v = 1 is a coincident pair of columns); normals point outwards."""
    rho, z, w_u = np.array([0, 1, 1, 1, 0.0]), np.array([1, 1, 0, -1, -1.0]), np.array([1, W, 1, W, 1])
    ring = np.broadcast_to(_CIRCLE[None], (5, 9, 2))
    ctrl = np.concatenate([rho[:, None, None] * ring, np.broadcast_to(z[:, None, None], (5, 9, 1))], -1)
    weights = w_u[:, None] * _CIRCLE_W[None]
    return BSplineSurface(np.asarray(centre) + radius * ctrl, _HALF_KNOTS, _FULL_KNOTS, 2, 2, weights=weights)


def _cylinder(x0, x1, y, z, radius) -> BSplineSurface:
    """Exact NURBS cylinder along x (the sphere's net shape and knots: one compilation for both):
    u along the axis (5 collinear points), v the circle from its bottom line round to it again
    (the seam lies on the bottom line); open ends at x0, x1; normals point outwards."""
    circle = np.concatenate([np.roll(_CIRCLE[:-1], -6, 0), _CIRCLE[-3:-2]])[::-1]  # starts at (0, −1)
    w_v = np.concatenate([np.roll(_CIRCLE_W[:-1], -6), _CIRCLE_W[-3:-2]])[::-1]
    x = np.broadcast_to(np.linspace(x0, x1, 5)[:, None, None], (5, 9, 1))
    yz = np.array([y, z]) + radius * np.broadcast_to(circle[None], (5, 9, 2))
    return BSplineSurface(
        np.concatenate([x, yz], -1), _HALF_KNOTS, _FULL_KNOTS, 2, 2, weights=np.tile(w_v, (5, 1))
    )


PLATE = shapes.plate(6, 6)  # [0, 1]² at z = 0, normal +z
PLATE_B = PLATE.blending(GRID, GRID)


def _flipped(ctrl):
    """The same plate with its normal reversed (v runs backwards)."""
    return jnp.asarray(ctrl)[:, ::-1]


def _moved(ctrl, offset, scale=(1.0, 1.0, 1.0)):
    scale, offset = (np.asarray(v, float).reshape(1, 1, 3) for v in (scale, offset))
    return jnp.asarray(ctrl) * scale + offset


def _np(x):
    return np.asarray(x)


def _triangle_stats(points, normals):
    """Per triangle of the tessellation of a sample grid: vertices `(F, 3, 3)`, circumradius `(F,)`,
    and the largest angle between a vertex normal and the triangle's normal `(F,)`."""
    verts, faces = grid_mesh(points)
    tri = _np(verts)[_np(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    la, lb, lc = (np.linalg.norm(e, axis=1) for e in (b - c, a - c, a - b))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rho = np.where(
        area > 1e-14, la * lb * lc / (4 * np.maximum(area, 1e-300)), np.maximum(la, np.maximum(lb, lc))
    )
    face_n = np.cross(b - a, c - a)
    face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-300)
    vn = _np(normals).reshape(-1, 3)[_np(faces)]
    cos = np.clip(np.einsum("fkc,fc->fk", vn, face_n), -1, 1)
    return tri, rho, np.where(area > 1e-14, np.arccos(cos.min(1)), 0.0)


def _sphere_tolerance(points, normals, radius, depth_max):
    """How far a depth measured to the tessellation of a sphere's samples may fall short of the
    exact `R − |x − c|` for a point inside: the triangles are inscribed (vertices on the sphere),
    so they lie inside by at most `R − √(R² − ρ²)` (ρ: circumradius), and the interpolated normal
    tilts from the triangle's by at most θ, which shortens a depth d by `d (1 − cos θ)`."""
    _, rho, theta = _triangle_stats(points, normals)
    chord = np.max(radius - np.sqrt(np.maximum(radius**2 - rho**2, 0)))
    return chord + depth_max * (1 - np.cos(theta.max())) + 1e-12


# --- closed forms -----------------------------------------------------------------------------


@functools.cache
def _sphere_in_plate():
    radius, delta = 0.3, 0.05
    sphere = _sphere([0.5, 0.45, radius - delta], radius)
    blending = sphere.blending(GRID, GRID)
    a, b = surface_penetration(blending, sphere.ctrl, PLATE_B, PLATE.ctrl, reach=0.2)
    return sphere, blending, radius, delta, a, b


def test_sphere_pushed_into_plate_closed_form():
    sphere, blending, radius, delta, a, b = _sphere_in_plate()
    # the sphere's samples: exactly d = 0 − z behind the plate z = 0, normal +z
    z = _np(blending.points(sphere.ctrl))[..., 2]
    assert np.abs(z).min() > 1e-6  # no sample on the plane itself
    np.testing.assert_array_equal(_np(a.mask), z < 0)
    np.testing.assert_allclose(_np(a.depth), np.where(z < 0, -z, 0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(_np(a.normals)[_np(a.mask)], [[0, 0, 1]] * int(a.mask.sum()), atol=1e-12)
    np.testing.assert_array_equal(_np(a.normals)[~_np(a.mask)], 0)
    assert float(a.depth[-1].max()) == pytest.approx(delta, abs=1e-12)  # the bottom pole: the intrusion
    # the plate's samples inside the ball: R − |x − c| along the radius, to the tessellation's error
    centre = np.array([0.5, 0.45, radius - delta])
    x = _np(PLATE_B.points(PLATE.ctrl))
    exact = radius - np.linalg.norm(x - centre, axis=-1)
    tol = _sphere_tolerance(blending.points(sphere.ctrl), blending.normals(sphere.ctrl), radius, delta)
    assert tol < 0.01
    clear = np.abs(exact) > tol
    np.testing.assert_array_equal(_np(b.mask)[clear], (exact > 0)[clear])
    inside = _np(b.mask)
    assert inside.sum() > 20
    assert np.all(_np(b.depth)[inside] <= exact[inside] + 1e-12)
    assert np.all(_np(b.depth)[inside] >= exact[inside] - tol)
    radial = (x - centre)[inside] / np.linalg.norm((x - centre)[inside], axis=-1, keepdims=True)
    assert np.all(np.sum(_np(b.normals)[inside] * radial, -1) > np.cos(np.radians(5)))


def test_cylinder_lying_on_plate_closed_form():
    radius, delta, axis_y = 0.2, 0.03, 0.52
    cyl = _cylinder(0.2, 0.8, axis_y, radius - delta, radius)
    blending = cyl.blending(GRID, GRID)
    a, b = surface_penetration(blending, cyl.ctrl, PLATE_B, PLATE.ctrl, reach=0.1)
    z = _np(blending.points(cyl.ctrl))[..., 2]
    assert np.abs(z).min() > 1e-6
    np.testing.assert_array_equal(_np(a.mask), z < 0)
    np.testing.assert_allclose(_np(a.depth), np.where(z < 0, -z, 0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(_np(a.depth)[:, 0], delta, atol=1e-12)  # the bottom line (the seam)
    np.testing.assert_allclose(_np(a.depth)[:, -1], delta, atol=1e-12)
    # the plate's samples under the cylinder, between its open ends: R − √((y − y₀)² + (R − δ)²)
    x = _np(PLATE_B.points(PLATE.ctrl))
    exact = radius - np.sqrt((x[..., 1] - axis_y) ** 2 + (radius - delta) ** 2)
    between = (x[..., 0] > 0.2) & (x[..., 0] < 0.8)
    assert np.min(np.abs(x[..., 0] - 0.2)) > 1e-3 and np.min(np.abs(x[..., 0] - 0.8)) > 1e-3
    # the triangles' vertices lie on the cylinder at angles at most Δθ apart, so the triangles
    # lie inside it by at most R (1 − cos(Δθ/2)); the interpolated normal tilts by at most θ
    points = _np(blending.points(cyl.ctrl))
    angle = np.unwrap(np.arctan2(points[0, :, 2] - (radius - delta), points[0, :, 1] - axis_y))
    _, _, theta = _triangle_stats(points, blending.normals(cyl.ctrl))
    tol = radius * (1 - np.cos(np.abs(np.diff(angle)).max() / 2)) + delta * (1 - np.cos(theta.max())) + 1e-12
    assert tol < 0.005
    clear = np.abs(exact) > tol
    np.testing.assert_array_equal(_np(b.mask)[clear], (between & (exact > 0))[clear])
    inside = _np(b.mask)
    assert inside.sum() >= 20 and not np.any(inside & ~between)  # beyond the open ends: never
    assert np.all(np.abs(_np(b.depth)[inside] - exact[inside]) <= tol)
    # the seam runs along the contact: feet on both of its coincident columns count
    columns = _np(b.faces)[inside] % GRID
    assert np.any(columns <= 1) and np.any(columns >= GRID - 2)


@functools.cache
def _plates(delta=0.01, reach=0.1):
    """A = [0, 1]² at z = 0 (solid below); B = the flipped plate (solid above) moved to
    [0.31, 1.31] × [0.2, 1.2] at z = −δ: they overlap by δ where the squares do."""
    ctrl_b = _moved(_flipped(PLATE.ctrl), [0.31, 0.2, -delta])
    return ctrl_b, surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, ctrl_b, reach=reach)


def test_plates_overlapping_by_delta():
    ctrl_b, (a, b) = _plates()
    xa, xb = _np(PLATE_B.points(PLATE.ctrl)), _np(PLATE_B.points(ctrl_b))
    over_b = (xa[..., 0] > 0.31) & (xa[..., 0] < 1.31) & (xa[..., 1] > 0.2) & (xa[..., 1] < 1.2)
    over_a = (xb[..., 0] > 0) & (xb[..., 0] < 1) & (xb[..., 1] > 0) & (xb[..., 1] < 1)
    margin = min(
        np.abs(xa[..., 0] - 0.31).min(), np.abs(xa[..., 1] - 0.2).min(), np.abs(xb[..., 0] - 1).min()
    )
    assert margin > 1e-6  # no sample right above the other plate's edge
    assert 100 < over_b.sum() < GRID * GRID
    # interior samples: depth δ, normal ±z; beyond the other plate's edge: not in contact
    np.testing.assert_array_equal(_np(a.mask), over_b)
    np.testing.assert_array_equal(_np(b.mask), over_a)
    np.testing.assert_allclose(_np(a.depth), np.where(over_b, 0.01, 0), rtol=0, atol=1e-14)
    np.testing.assert_allclose(_np(b.depth), np.where(over_a, 0.01, 0), rtol=0, atol=1e-14)
    np.testing.assert_allclose(_np(a.normals)[over_b], [[0, 0, -1]] * int(over_b.sum()), atol=1e-14)
    np.testing.assert_allclose(_np(b.normals)[over_a], [[0, 0, 1]] * int(over_a.sum()), atol=1e-14)
    for side in (a, b):
        assert side.faces.dtype == jnp.int32 and int(side.faces.min()) >= 0
        assert int(side.faces.max()) < GRID * GRID
        np.testing.assert_allclose(_np(side.bary).sum(-1), 1, atol=1e-12)
        assert float(side.bary.min()) >= 0


def test_reach_counts_no_deeper_sample():
    ctrl_b, _ = _plates()
    a, b = surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, ctrl_b, reach=0.009)  # δ = 0.01 > reach
    assert not bool(a.mask.any()) and not bool(b.mask.any())
    assert float(jnp.abs(a.depth).max()) == 0 and float(jnp.abs(b.normals).max()) == 0


def test_far_apart_is_empty():
    far = _moved(PLATE.ctrl, [0.0, 0.0, 0.5])
    a, b = surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, far, reach=0.1)  # hulls apart: early exit
    for side in (a, b):
        assert not bool(side.mask.any()) and float(side.depth.max()) == 0
        assert not _np(side.faces).any() and not _np(side.normals).any()  # empty, as documented
        np.testing.assert_array_equal(_np(side.bary), np.broadcast_to([1.0, 0.0, 0.0], side.bary.shape))
    # apart, the foot points are on a placeholder triangle: the gradient is zero, not NaN
    loss = lambda c: sum(jnp.sum(p.depth) for p in surface_penetration(PLATE_B, c, PLATE_B, far, reach=0.1))
    np.testing.assert_array_equal(_np(jax.grad(loss)(PLATE.ctrl)), 0)
    # behind within reach counts (an open surface's inside is the side its normal points away from)
    a, b = surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, far, reach=0.6)
    assert bool(a.mask[3:-3, 3:-3].all()) and not bool(b.mask.any())
    np.testing.assert_allclose(_np(a.depth)[3:-3, 3:-3], 0.5, atol=1e-12)


def _reaction(side: Penetration, forces, count):
    """The reactions `−f_i` of forces on X's samples scattered onto Y's samples by `faces, bary`."""
    out = np.zeros((count, 3))
    np.add.at(
        out,
        _np(side.faces).reshape(-1),
        -(_np(side.bary)[..., None] * _np(forces)[..., None, :]).reshape(-1, 3),
    )
    return out


def test_action_equals_reaction():
    stiffness = 250.0
    for side, count in ((_plates()[1][0], GRID * GRID), (_sphere_in_plate()[4], GRID * GRID)):
        force = stiffness * _np(side.depth)[..., None] * _np(side.normals)
        assert np.abs(force).max() > 1
        total = force.reshape(-1, 3).sum(0) + _reaction(side, force, count).sum(0)
        np.testing.assert_allclose(total, 0, atol=1e-12)


@functools.cache
def _nested_spheres():
    inner, outer = _sphere([0.4, 0.1, -0.05], 0.3), _sphere([0.0, 0.0, 0.0], 1.0)
    blending = inner.blending(GRID, GRID)  # the same basis for both
    return inner, outer, blending, surface_penetration(blending, inner.ctrl, blending, outer.ctrl, reach=0.5)


def test_sphere_inside_larger_sphere():
    inner, outer, blending, (a, b) = _nested_spheres()
    x = _np(blending.points(inner.ctrl))
    exact = 1.0 - np.linalg.norm(x, axis=-1)  # depth below the outer sphere, along its radius
    assert exact.min() > 0.25 and exact.max() > 0.5
    tol = _sphere_tolerance(blending.points(outer.ctrl), blending.normals(outer.ctrl), 1.0, 0.5)
    assert tol < 0.02  # 24 × 24 samples of a unit sphere: circumradius ≈ 0.15, chord ≈ 0.012
    mask = _np(a.mask)
    clear = np.abs(exact - 0.5) > tol
    np.testing.assert_array_equal(mask[clear], (exact <= 0.5)[clear])  # deeper than reach: not counted
    assert mask.sum() > 100 and (~mask).sum() > 100
    assert np.all(_np(a.depth)[mask] <= exact[mask] + 1e-12)
    assert np.all(_np(a.depth)[mask] >= exact[mask] - tol)
    radial = x[mask] / np.linalg.norm(x[mask], axis=-1, keepdims=True)
    assert np.all(np.sum(_np(a.normals)[mask] * radial, -1) > np.cos(np.radians(5)))
    assert not bool(b.mask.any())  # the outer sphere's samples are all outside the inner one


def test_spheres_pole_to_pole():
    """Two spheres overlapping by δ along z, pole against pole: each pole's samples (one row,
    all at the pole) lie δ inside the other sphere, their foot is on the fan of triangles around
    the other's pole (a sample shared by a whole row: not an open boundary), and they count
    with depth δ less at most the triangles' chord error, normal ∓z. Also after a rounding-sized perturbation
    of the nets (a deformed body's refit pole is not exactly one point)."""
    radius, delta = 0.3, 0.02
    low, high = _sphere([0, 0, 0], radius), _sphere([0, 0, 2 * radius - delta], radius)
    blending = low.blending(GRID, GRID)
    tol = _sphere_tolerance(blending.points(low.ctrl), blending.normals(low.ctrl), radius, delta)
    noise = 1e-9 * np.random.default_rng(3).normal(size=low.ctrl.shape)
    for ctrl_low in (low.ctrl, low.ctrl + noise):
        a, b = surface_penetration(blending, ctrl_low, blending, high.ctrl, reach=0.1)
        top, bottom = (0, slice(None)), (-1, slice(None))  # low's top pole row, high's bottom one
        assert bool(a.mask[top].all()) and bool(b.mask[bottom].all())
        for depth in (a.depth[top], b.depth[bottom]):
            assert np.all(_np(depth) <= delta + 1e-7) and np.all(_np(depth) >= delta - tol)
        assert np.all(_np(a.normals[top])[:, 2] < -np.cos(np.radians(5)))
        assert np.all(_np(b.normals[bottom])[:, 2] > np.cos(np.radians(5)))


# --- an independent dense reference -------------------------------------------------------------


@functools.cache
def _bumpy():
    """A gently curved surface over [0, 1]² (normal ≈ +z, z within ±0.07) and a sheared plate
    (cells that are parallelograms: no ties between the two diagonals of a cell) at z = −0.2
    under it, inside its square."""
    rough = random_surface(np.random.default_rng(3), 6, 6, 3, 3, uniform=True)
    surface = rough.with_ctrl(_moved(rough.ctrl, [0, 0, 0], [1, 1, 0.15]))
    shear = np.array([[0.5, 0.1, 0.0], [0.0, 0.45, 0.0], [0.0, 0.0, 0.0]])
    below = jnp.asarray(PLATE.ctrl) @ jnp.asarray(shear.T) + jnp.asarray([[[0.25, 0.25, -0.2]]])
    return surface, surface.blending(GRID, GRID), below


def test_depth_matches_exact_closest_points():
    surface, blending, below = _bumpy()
    a, b = surface_penetration(PLATE_B, below, blending, surface.ctrl, reach=1.0)
    x = _np(PLATE_B.points(below)).reshape(-1, 3)
    proj = closest_points(surface, x, solver=ProjectionSolver(max_steps=50))
    ok = _np(proj.result == optx.RESULTS.successful)
    assert ok.mean() > 0.95
    uv, dist = _np(proj.params), _np(proj.distances)
    # the surface's point, normal and normal curvatures at the feet and on a 97 × 97 grid, from
    # central differences of its points (step 1e-4: one evaluation of one batch)
    g = np.linspace(0.01, 0.99, 97)
    where = np.concatenate([uv, np.stack([t.reshape(-1) for t in np.meshgrid(g, g, indexing="ij")], -1)])
    step = 1e-4
    stencil = np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)]) * step
    at = (where[:, None] + stencil[None]).reshape(-1, 2)
    p = _np(surface.evaluate(at[:, 0], at[:, 1])).reshape(-1, 3, 3, 3)  # [point, du, dv, xyz]
    s_u, s_v = (p[:, 2, 1] - p[:, 0, 1]) / (2 * step), (p[:, 1, 2] - p[:, 1, 0]) / (2 * step)
    normal = np.cross(s_u, s_v)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    s_exact = np.sum((x - p[: len(x), 1, 1]) * normal[: len(x)], -1)
    assert np.all(s_exact < 0) and np.all((uv > 0.01) & (uv < 0.99))  # behind B, feet interior
    # the tessellation's chord error: linear interpolation on a triangle is off by at most
    # M R² / 2 (Waldron), R the radius of the smallest ball holding the triangle in parameter
    # space (half the cell's diagonal, the hypotenuse), M the largest |eigenvalue| of the normal
    # component of the Hessian (the second fundamental form); the interpolated normal tilts
    # from the triangle's by at most θ, which shortens a depth d by d (1 − cos θ)
    s_uu = (p[:, 2, 1] - 2 * p[:, 1, 1] + p[:, 0, 1]) / step**2
    s_vv = (p[:, 1, 2] - 2 * p[:, 1, 1] + p[:, 1, 0]) / step**2
    s_uv = (p[:, 2, 2] - p[:, 2, 0] - p[:, 0, 2] + p[:, 0, 0]) / (4 * step**2)
    e, f, h = (np.sum(d * normal, -1)[len(x) :] for d in (s_uu, s_uv, s_vv))
    curvature = np.abs(e + h) / 2 + np.sqrt(((e - h) / 2) ** 2 + f**2)
    pu, pv = _np(blending.params_u), _np(blending.params_v)
    radius2 = (np.diff(pu).max() ** 2 + np.diff(pv).max() ** 2) / 4
    _, _, theta = _triangle_stats(blending.points(surface.ctrl), blending.normals(surface.ctrl))
    bound = 1.1 * curvature.max() * radius2 / 2 + dist.max() * (1 - np.cos(theta.max()))
    assert bound < 0.02
    assert bool(a.mask.all())
    err = np.abs(_np(a.depth).reshape(-1) - dist)[ok]
    assert err.max() <= bound, (err.max(), bound)
    assert not bool(b.mask.any())  # the curved surface lies in front of the plate


def test_small_grids_searched_whole_match_trimesh_and_the_tiled_search(monkeypatch):
    """Grids of at most 200 triangles are searched whole (every sample against every triangle):
    the feet are trimesh's closest points on the same tessellation, and the tiled search with
    its certificate, forced on the same grids, finds the same feet."""
    surface, _, below = _bumpy()
    small, plate = surface.blending(11, 11), PLATE.blending(9, 9)  # 200 and 128 triangles
    assert _penetration._EXHAUSTIVE == 200

    def penetrate():  # in a caller's jit: a fresh trace (`_EXHAUSTIVE` is read when tracing)
        surface_penetration.clear_cache()
        pair = jax.jit(lambda ca, cb: surface_penetration(plate, ca, small, cb, reach=1.0))(
            below, surface.ctrl
        )
        surface_penetration.clear_cache()
        return pair

    whole = penetrate()
    verts, faces = (_np(v) for v in grid_mesh(small.points(surface.ctrl)))
    x = _np(plate.points(below)).reshape(-1, 3)
    closest, dist, _ = trimesh.proximity.closest_point(trimesh.Trimesh(verts, faces, process=False), x)
    foot = np.einsum("mnk,mnkc->mnc", _np(whole[0].bary), verts[_np(whole[0].faces)]).reshape(-1, 3)
    np.testing.assert_allclose(foot, closest, rtol=0, atol=1e-12)
    assert bool(whole[0].mask.all())  # the plate lies behind the curved surface, within reach
    np.testing.assert_allclose(_np(whole[0].depth).reshape(-1), dist, rtol=0, atol=0.01)  # along n_Y
    monkeypatch.setattr(_penetration, "_EXHAUSTIVE", 0)
    tiled = penetrate()
    for p, q, other in zip(whole, tiled, (small.points(surface.ctrl), plate.points(below))):
        _assert_same(p, q, other)


# --- transformations ------------------------------------------------------------------------


def _as_tuple(pair):
    return jax.tree_util.tree_leaves(pair)


def _assert_same(p: Penetration, q: Penetration, other_points):
    """Equal results up to rounding; the foot triangle may differ where two are equally near
    (the plates' feet on shared edges), so the foot points `Σ bary · Y[faces]` are compared."""
    np.testing.assert_array_equal(_np(p.mask), _np(q.mask))
    for x, y in ((p.depth, q.depth), (p.normals, q.normals)):
        np.testing.assert_allclose(_np(x), _np(y), rtol=0, atol=1e-12)
    flat = _np(other_points).reshape(-1, 3)
    foot = [np.einsum("mnk,mnkc->mnc", _np(r.bary), flat[_np(r.faces)]) for r in (p, q)]
    np.testing.assert_allclose(foot[0], foot[1], rtol=0, atol=1e-12)


def test_jit_equals_direct_and_vmap_equals_loop():
    ctrl_b, direct = _plates()
    pa, pb = PLATE_B.points(PLATE.ctrl), PLATE_B.points(ctrl_b)
    jitted = _JIT_PLATES(PLATE.ctrl, ctrl_b, 0.1)
    _assert_same(direct[0], jitted[0], pb)
    _assert_same(direct[1], jitted[1], pa)
    batch = jnp.stack([_moved(PLATE.ctrl, [0.0, 0.0, dz], [1.0, 1.0 + dz, 1.0]) for dz in (0.0, -0.004, 0.2)])
    mapped = jax.vmap(lambda ca: surface_penetration(PLATE_B, ca, PLATE_B, ctrl_b, reach=0.1))(batch)
    assert mapped[0].depth.shape == (3, GRID, GRID)
    for k in range(batch.shape[0]):
        one = surface_penetration(PLATE_B, batch[k], PLATE_B, ctrl_b, reach=0.1)
        row = jax.tree_util.tree_map(lambda x: x[k], mapped)
        _assert_same(one[0], row[0], pb)
        _assert_same(one[1], row[1], PLATE_B.points(batch[k]))


def _loss(blending_a, ctrl_a, blending_b, ctrl_b, reach, weights):
    pen = surface_penetration(blending_a, ctrl_a, blending_b, ctrl_b, reach=reach)
    w = iter(weights)
    return sum(jnp.sum(next(w) * side.depth) + jnp.sum(next(w) * side.normals) for side in pen)


_value_and_grad = jax.jit(jax.value_and_grad(_loss, argnums=(1, 3)))


def _weights(seed=0):
    rng = np.random.default_rng(seed)
    return [jnp.asarray(rng.normal(size=s)) for s in [(GRID, GRID), (GRID, GRID, 3)] * 2]


def _kinks(pen_plus, pen_minus):
    """Samples whose foot changes triangle, or moves between a triangle's inside, an edge and a
    vertex (the support of `bary`), or leaves contact, between two results: there the
    piecewise-linear depth has a kink (or a jump), and a central difference straddles it."""
    changed = lambda x, y: _np(x) != _np(y)
    return [
        changed(p.faces, m.faces).any(-1) | changed(p.bary > 0, m.bary > 0).any(-1) | changed(p.mask, m.mask)
        for p, m in zip(pen_plus, pen_minus)
    ]


def test_gradients_match_central_differences():
    # A: the sheared plate under the curved surface B, flipped (solid above it), so A's samples
    # lie behind B and the B samples over A's parallelogram lie inside A; reach 1 counts them all
    surface, blending, below = _bumpy()
    ctrl_a, ctrl_b = _flipped(below), surface.ctrl
    a, b = surface_penetration(PLATE_B, ctrl_a, blending, ctrl_b, reach=1.0)
    assert bool(a.mask.all()) and 50 < int(b.mask.sum()) < GRID * GRID - 50
    base = (PLATE_B, ctrl_a, blending, ctrl_b, 1.0)
    rng, eps = np.random.default_rng(1), 1e-6
    for which in (1, 3):  # ctrl_a, ctrl_b
        for _ in range(2):
            d = jnp.asarray(rng.normal(size=base[which].shape))
            plus, minus = list(base), list(base)
            plus[which], minus[which] = base[which] + eps * d, base[which] - eps * d
            kinks = _kinks(
                surface_penetration(*plus[:4], reach=1.0), surface_penetration(*minus[:4], reach=1.0)
            )
            assert all(k.mean() < 0.1 for k in kinks)  # few samples straddle a kink
            keep = [jnp.asarray(~k, jnp.float64) for k in kinks]
            weights = [
                w * keep[i // 2].reshape(keep[i // 2].shape + (1,) * (w.ndim - 2))
                for i, w in enumerate(_weights())
            ]
            value, grads = _value_and_grad(*base, weights)
            fd = (float(_loss(*plus, weights)) - float(_loss(*minus, weights))) / (2 * eps)
            analytic = float(jnp.vdot(grads[which // 2], d))
            assert abs(analytic) > 1
            assert fd == pytest.approx(analytic, rel=1e-6, abs=1e-8)
            assert float(value) == pytest.approx(float(_loss(*base, weights)), rel=1e-12)


def _cone(tip_z):
    """A closed bicubic cone with the plate's net shape (so the plate's compiled programs serve):
    its first row collapses to the tip (a pole), its first and last columns coincide (a clamped
    seam); the tip at (0.5, 0.5, tip_z) points down."""
    i, j = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    angle = 2 * np.pi * j / 5
    ctrl = np.stack([0.5 + 0.08 * i * np.cos(angle), 0.5 + 0.08 * i * np.sin(angle), tip_z + 0.06 * i], -1)
    return jnp.asarray(ctrl)


def test_finite_at_tangency_coincidence_poles_and_seams():
    weights = _weights(2)

    def finite(*trees):
        leaves = jax.tree_util.tree_leaves(trees)
        return all(bool(jnp.all(jnp.isfinite(x))) for x in leaves if jnp.issubdtype(x.dtype, jnp.floating))

    # plates exactly touching face to face: s = 0 at every sample, each foot the sample itself
    touching = _flipped(PLATE.ctrl)
    value, grads = _value_and_grad(PLATE_B, PLATE.ctrl, PLATE_B, touching, 0.1, weights)
    pen = surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, touching, reach=0.1)
    assert not bool(pen[0].mask.any() | pen[1].mask.any()) and float(value) == 0
    assert finite(grads, pen)
    # a cone's tip (a pole, on its seam) touching the plate, then pressed into it
    for tip in (0.0, -0.02):
        value, grads = _value_and_grad(PLATE_B, _cone(tip), PLATE_B, PLATE.ctrl, 0.1, weights)
        pen = surface_penetration(PLATE_B, _cone(tip), PLATE_B, PLATE.ctrl, reach=0.1)
        assert bool(pen[0].mask.any()) == (tip < 0) and finite(grads, pen)
        if tip < 0:
            assert float(pen[0].depth[0].max()) == pytest.approx(0.02, abs=1e-12)  # the tip row
            assert float(jnp.abs(grads[0]).max()) > 0 and float(jnp.abs(grads[1]).max()) > 0
    # the exact sphere's pole on the plate (its seam columns reach the pole too)
    sphere = _sphere([0.5, 0.45, 0.3], 0.3)
    pen = surface_penetration(sphere.blending(GRID, GRID), sphere.ctrl, PLATE_B, PLATE.ctrl, reach=0.2)
    assert finite(pen) and not bool(pen[0].mask.any() | pen[1].mask.any())


# --- bad input --------------------------------------------------------------------------------

_NAN = jnp.where(jnp.arange(3) == 0, jnp.nan, PLATE.ctrl[:1, :1]).reshape(1, 1, 3)
_NAN = jnp.asarray(PLATE.ctrl).at[:1, :1].set(_NAN)
_GOOD = (PLATE.ctrl, PLATE.ctrl, 0.1)  # a Python float: the direct program of the tests above


def _penetrate_plates(ctrl_a, ctrl_b, reach):
    """The plate pair: its direct program is compiled by the tests above, its program inside
    `jax.jit` (`_JIT_PLATES`, one wrapper: one compilation) serves the jit test and every bad
    value below."""
    return surface_penetration(PLATE_B, ctrl_a, PLATE_B, ctrl_b, reach=reach)


_JIT_PLATES = jax.jit(_penetrate_plates)


def _nets_of(blending_a, ctrl, blending_b):
    return surface_penetration(blending_a, ctrl, blending_b, ctrl, reach=0.1)


def _case(k, value):
    return tuple(value if i == k else x for i, x in enumerate(_GOOD))


BAD = {
    "blending_a type": (lambda c: _nets_of(PLATE, c, PLATE_B), (PLATE.ctrl,), "blending_a: expected"),
    "blending_b type": (lambda c: _nets_of(PLATE_B, c, 0), (PLATE.ctrl,), "blending_b: expected"),
    "ctrl_a shape": (_penetrate_plates, _case(0, jnp.zeros((5, 6, 3))), "ctrl_a: expected shape"),
    "ctrl_b shape": (_penetrate_plates, _case(1, jnp.zeros((6, 6))), "ctrl_b: expected shape"),
    "ctrl_a NaN": (_penetrate_plates, _case(0, _NAN), "ctrl_a: expected finite"),
    "ctrl_b NaN": (_penetrate_plates, _case(1, _NAN), "ctrl_b: expected finite"),
    "reach 0": (_penetrate_plates, _case(2, 0.0), "reach: expected finite values > 0"),
    "reach negative": (_penetrate_plates, _case(2, -1.0), "reach: expected finite values > 0"),
    "reach NaN": (_penetrate_plates, _case(2, float("nan")), "reach: expected finite values > 0"),
    "reach inf": (_penetrate_plates, _case(2, float("inf")), "reach: expected finite values > 0"),
    "reach shape": (_penetrate_plates, _case(2, jnp.array([0.1, 0.2])), "reach: expected a scalar"),
    "reach complex": (_penetrate_plates, _case(2, 0.1 + 0j), "reach: expected real numbers"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_names_the_argument_eagerly_and_under_jit(case):
    fn, args, match = BAD[case]
    if fn is not _penetrate_plates:
        raises_both(fn, *args, match=match)
        return
    # `tests.helpers.raises_both` with the shared jit wrapper
    with pytest.raises((ValueError, TypeError), match=match):
        jax.block_until_ready(fn(*args))
    with pytest.raises((ValueError, TypeError, jax.errors.JaxRuntimeError), match=match):
        jax.block_until_ready(_JIT_PLATES(*args))


def test_reach_is_required_and_keyword_only():
    with pytest.raises(TypeError):
        surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, PLATE.ctrl)  # pyright: ignore[reportCallIssue]
    with pytest.raises(TypeError):
        surface_penetration(PLATE_B, PLATE.ctrl, PLATE_B, PLATE.ctrl, 0.1)  # pyright: ignore[reportCallIssue]
    line = PLATE.blending(4, 4, params_v=[0.5])  # one sample column: no triangles
    with pytest.raises(ValueError, match="blending_b: expected a sample grid of at least 2 x 2"):
        surface_penetration(PLATE_B, PLATE.ctrl, line, PLATE.ctrl, reach=0.1)
