"""Collision queries and contact forces: closed forms, dense references, trimesh and python-fcl."""

import functools

import fcl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from scipy.optimize import brentq

from bsjax import shapes
from bsjax.basis import BSplineSurface
from bsjax.collide import (
    Ellipsoid,
    Implicit,
    Plane,
    Point,
    Sphere,
    TriangleMesh,
    contact_force,
    contacts,
    grid_mesh,
    sample_forces,
    surface_contacts,
)
from bsjax.collide._broad import hulls_apart, parametric_window
from bsjax.collide._contact import sample_window
from bsjax.collide._flat import block_planes, normal_cones, resolve_flat_pairs
from bsjax.collide._hierarchy import (
    FlatPairs,
    block_order,
    cell_triangles,
    levels_for,
    sphere_hierarchy,
    traverse,
)
from tests.helpers import check_grad, raises_both, random_surface

# the queries are compiled at their public boundary: the tests call them as users do
_contacts = contacts
_surfaces = surface_contacts

# one control-net shape, degree and grid for most tests, so the jitted queries compile once per tool
PLATE = shapes.plate(6, 6)
PLATE_B = PLATE.blending(15, 15)


def _cylinder(radius=1.0):
    """Exact quarter cylinder (rational quadratic arc × line): axis z, angle 0..90°, z in [0, 1]."""
    w = np.sqrt(0.5)
    arc = np.array([[radius, 0.0], [radius, radius], [0.0, radius]])
    ctrl = np.stack([np.concatenate([arc, np.full((3, 1), z)], 1) for z in (0.0, 1.0)], 1)
    return BSplineSurface(
        ctrl, [0, 0, 0, 1, 1, 1], [0, 0, 1, 1], 2, 1, weights=np.array([[1, 1], [w, w], [1, 1]])
    )


CYL = _cylinder()
CYL_B = CYL.blending(21, 11)


def _shift(ctrl, offset):
    """A control net translated by `offset (3,)`."""
    return jnp.asarray(ctrl) + jnp.asarray(offset, jnp.float64)[None, None]


def _bumpy(seed, r=6, s=6, l=3):
    return random_surface(np.random.default_rng(seed), r, s, 3, l)


# --- analytic cases ---------------------------------------------------------------------------


def test_sphere_on_plate_closed_form():
    h, radius = 0.05, 0.3
    c = _contacts(PLATE_B, PLATE.ctrl, Sphere([0.5, 0.5, h], radius))
    pts = np.asarray(PLATE_B.points(PLATE.ctrl))
    rho2 = (pts[..., 0] - 0.5) ** 2 + (pts[..., 1] - 0.5) ** 2
    inside = rho2 < radius**2 - h**2
    np.testing.assert_array_equal(np.asarray(c.mask), inside)
    expect = np.where(inside, np.sqrt(np.maximum(radius**2 - rho2, 0)) - h, 0)
    np.testing.assert_allclose(np.asarray(c.depth), expect, atol=1e-12)
    assert float(c.depth.max()) == pytest.approx(radius - h, abs=1e-12)  # u = v = 0.5 is sampled
    assert bool(c.hit) and not bool(c.apart)


def test_ellipsoid_on_plate_closed_form_and_rotation():
    center, radii = np.array([0.45, 0.55, 0.1]), np.array([0.3, 0.2, 0.15])
    c = _contacts(PLATE_B, PLATE.ctrl, Ellipsoid(center, radii))
    pts = np.asarray(PLATE_B.points(PLATE.ctrl))
    q = ((pts[..., 0] - center[0]) / radii[0]) ** 2 + ((pts[..., 1] - center[1]) / radii[1]) ** 2
    inside = q + (center[2] / radii[2]) ** 2 < 1
    np.testing.assert_array_equal(np.asarray(c.mask), inside)
    # along +z the surface of the ellipsoid is at z = c_z ± c √(1 − q): the closer root
    expect = np.where(inside, radii[2] * np.sqrt(np.maximum(1 - q, 0)) - center[2], 0)
    np.testing.assert_allclose(np.asarray(c.depth), expect, atol=1e-12)
    # the same solid described with a rotation of 90° about z and swapped semi-axes
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    c2 = _contacts(PLATE_B, PLATE.ctrl, Ellipsoid(center, radii[[1, 0, 2]], rot))
    np.testing.assert_allclose(np.asarray(c2.depth), np.asarray(c.depth), atol=1e-12)


def test_sphere_on_cylinder_max_depth_and_ray_roots():
    h, radius = 0.04, 0.25
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    centre = (1.0 + h) * axis + np.array([0, 0, 0.5])
    c = _contacts(CYL_B, CYL.ctrl, Sphere(centre, radius))
    assert float(c.depth.max()) == pytest.approx(radius - h, abs=1e-12)  # R − h at the arc middle
    assert int(np.argmax(np.asarray(c.depth)).item()) == 10 * 11 + 5
    pts, nrm = np.asarray(c.points), np.asarray(c.normals)
    f = lambda t, x, n: np.sum((x + t * n - centre) ** 2) - radius**2
    for i, j in zip(*np.nonzero(np.asarray(c.mask))):
        x, n = pts[i, j], nrm[i, j]
        roots = [brentq(f, 0, 2 * radius, args=(x, n)), brentq(f, -2 * radius, 0, args=(x, n))]
        assert float(c.depth[i, j]) == pytest.approx(min(abs(r) for r in roots), abs=1e-10)


def test_plane_and_point_on_cylinder():
    # plane x + y = s√2 with the solid beyond it (normal towards the axis): max depth 1 − s
    s = 0.9
    n = -np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    c = _contacts(CYL_B, CYL.ctrl, Plane(-n * s, n * 3.0))  # non-unit normal is normalised
    pts = np.asarray(CYL_B.points(CYL.ctrl))
    signed = pts[..., :2] @ (-n[:2]) - s
    np.testing.assert_array_equal(np.asarray(c.mask), signed > 0)
    np.testing.assert_allclose(np.asarray(c.depth), np.maximum(signed, 0), atol=1e-12)
    assert float(c.depth.max()) == pytest.approx(1 - s, abs=1e-12)
    # a point tool just behind the cylinder wall (opposite the surface normal) is in contact
    mid_normal = np.asarray(CYL.normal(jnp.array(0.5), jnp.array(0.5)))
    probe = np.asarray(CYL.evaluate(jnp.array(0.5), jnp.array(0.5))) - 0.01 * mid_normal
    cp = _contacts(CYL_B, CYL.ctrl, Point(probe))
    assert bool(cp.hit) and int(cp.mask.sum()) == 3
    assert float(cp.depth.sum()) == pytest.approx(0.01, abs=2e-3)  # tessellation error of the arc
    assert not bool(_contacts(CYL_B, CYL.ctrl, Point(probe + 0.02 * mid_normal)).hit)
    assert not bool(_contacts(CYL_B, CYL.ctrl, Point(probe, reach=0.001)).hit)


def test_point_on_plate_depth_and_reach():
    c = _contacts(PLATE_B, PLATE.ctrl, Point([0.37, 0.61, -0.02]))
    assert bool(c.hit) and float(c.depth.sum()) == pytest.approx(0.02, abs=1e-12)
    f = contact_force(c, 100.0)
    np.testing.assert_allclose(np.asarray(f), [0, 0, 2.0], atol=1e-10)  # Hooke: k · depth along +z
    assert not bool(_contacts(PLATE_B, PLATE.ctrl, Point([0.37, 0.61, 0.02])).hit)
    far = _contacts(PLATE_B, PLATE.ctrl, Point([0.37, 0.61, -0.02], reach=0.01))
    assert not bool(far.hit) and bool(far.apart)  # the broad phase certifies it


def test_implicit_torus_projection_depth():
    big, small = 0.3, 0.1

    def torus(x, params):
        rho = jnp.sqrt(jnp.sum((x[:2] - 0.5) ** 2) + 1e-30)
        return (rho - params[0]) ** 2 + x[2] ** 2 - params[1] ** 2

    tool = Implicit(torus, params=jnp.array([big, small]))
    c = _contacts(PLATE_B, PLATE.ctrl, tool)
    pts = np.asarray(PLATE_B.points(PLATE.ctrl))
    rho = np.hypot(pts[..., 0] - 0.5, pts[..., 1] - 0.5)
    inside = np.abs(rho - big) < small
    np.testing.assert_array_equal(np.asarray(c.mask), inside)
    np.testing.assert_allclose(np.asarray(c.depth), np.where(inside, small - np.abs(rho - big), 0), atol=1e-8)
    # differentiable in the tool's parameters: d Σ depth / d small = number of contacts
    g = jax.grad(lambda p: contacts(PLATE_B, PLATE.ctrl, Implicit(torus, params=p)).depth.sum())(
        jnp.array([big, small])
    )
    assert float(g[1]) == pytest.approx(inside.sum(), rel=1e-6)


def test_triangle_mesh_tool_matches_trimesh():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    mesh.apply_translation([0.5, 0.5, 0.15])
    c = _contacts(PLATE_B, PLATE.ctrl, TriangleMesh.from_trimesh(mesh))
    pts = np.asarray(PLATE_B.points(PLATE.ctrl)).reshape(-1, 3)
    inside = mesh.contains(pts)
    np.testing.assert_array_equal(np.asarray(c.mask).reshape(-1), inside)
    dist = trimesh.proximity.ProximityQuery(mesh).signed_distance(pts)  # > 0 inside
    np.testing.assert_allclose(np.asarray(c.depth).reshape(-1), np.where(inside, dist, 0), atol=1e-9)


# --- broad phase, window and hierarchy against the dense references -------------------------


def _rotation(seed):
    q = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))[0]
    return q * np.sign(np.linalg.det(q))


TOOLS = [
    Sphere([0.5, 0.4, 0.05], 0.25),
    Ellipsoid([0.3, 0.6, 0.0], [0.3, 0.1, 0.2], _rotation(0)),
    Plane([0.0, 0.0, 0.05], [0.2, -0.1, 1.0]),
]


@jax.jit
def _both_methods(blending, ctrl, tools):
    """Window and dense results for several tools, in one compiled function."""
    return [(contacts(blending, ctrl, t), contacts(blending, ctrl, t, method="dense")) for t in tools]


def _assert_same(pairs, expect_hit=True):
    for w, d in pairs:
        assert bool(d.hit) == expect_hit
        np.testing.assert_array_equal(np.asarray(w.mask), np.asarray(d.mask))
        np.testing.assert_allclose(np.asarray(w.depth), np.asarray(d.depth), atol=1e-14)


def test_window_method_matches_dense():
    for seed in (0, 1):
        surf = _bumpy(seed)
        _assert_same(_both_methods(PLATE_B, surf.ctrl, TOOLS))


def test_closed_surface_window_and_early_exit():
    drop = shapes.teardrop()
    b = drop.blending(12, 12)
    near = [
        Sphere([0.6, 0.1, -0.2], 0.3),
        Ellipsoid([0, 0, 0.9], [0.2, 0.2, 0.3]),
        Plane([0, 0, -0.6], [0, 0, 1.0]),
    ]
    _assert_same(_both_methods(b, drop.ctrl, near))
    far = [
        Sphere([3.0, 0, 0], 0.5),
        Ellipsoid([0, 0, 3.0], [0.2, 0.2, 0.3]),
        Plane([0, 0, -1.5], [0, 0, 1.0]),
    ]
    results = _both_methods(b, drop.ctrl, far)
    _assert_same(results, expect_hit=False)
    assert all(bool(w.apart) and not bool(w.mask.any()) for w, _ in results)


def _fcl_masks(va, fa, vb, fb):
    objs = []
    for v, f in ((va, fa), (vb, fb)):
        model = fcl.BVHModel()
        model.beginModel(len(v), len(f))
        model.addSubModel(np.asarray(v, np.float64), np.asarray(f, np.int64))
        model.endModel()
        objs.append(fcl.CollisionObject(model, fcl.Transform()))
    res = fcl.CollisionResult()
    fcl.collide(objs[0], objs[1], fcl.CollisionRequest(num_max_contacts=100000, enable_contact=True), res)
    ma, mb = np.zeros(len(va), bool), np.zeros(len(vb), bool)
    for con in res.contacts:
        ma[fa[con.b1]] = True
        mb[fb[con.b2]] = True
    return ma, mb


def test_surfaces_hierarchy_matches_dense_and_fcl():
    rng = np.random.default_rng(3)
    a, b = _bumpy(3), _bumpy(13)
    ctrl_b = np.asarray(b.ctrl).copy()
    ctrl_b[..., 2] = (ctrl_b[..., 0] - 0.5) * 1.2 + 0.05 * rng.normal(size=ctrl_b.shape[:2])
    ba = bb = a.blending(10, 10)
    pairs = [(a.ctrl, jnp.asarray(ctrl_b)), (a.ctrl, _shift(ctrl_b, [0.05, 0.0, 0.02]))]
    for ctrl_a, ctrl_b2 in pairs:
        hier = _surfaces(ba, ctrl_a, bb, ctrl_b2, capacity=512)
        dense = _surfaces(ba, ctrl_a, bb, ctrl_b2, method="dense")
        assert bool(dense.hit) and not bool(hier.overflow)
        np.testing.assert_array_equal(np.asarray(hier.mask_a), np.asarray(dense.mask_a))
        np.testing.assert_array_equal(np.asarray(hier.mask_b), np.asarray(dense.mask_b))
        assert int(hier.pair_hit.sum()) > 0
        va, fa = grid_mesh(ba.points(ctrl_a))
        vb, fb = grid_mesh(bb.points(ctrl_b2))
        ma, mb = _fcl_masks(np.asarray(va), np.asarray(fa), np.asarray(vb), np.asarray(fb))
        np.testing.assert_array_equal(np.asarray(dense.mask_a).reshape(-1), ma)
        np.testing.assert_array_equal(np.asarray(dense.mask_b).reshape(-1), mb)
    # moved apart: certified by the control hulls, no contact
    far = _surfaces(ba, a.ctrl, bb, _shift(ctrl_b, [0, 0, 5.0]), capacity=512)
    assert bool(far.apart) and not bool(far.hit)


def test_surface_contacts_direct_jit_vmap_and_retry():
    """The compiled boundary of `surface_contacts`: a direct call, the same call inside the
    caller's `jit` and `vmap` over translations of one surface agree; an overflow is retried
    on the host with a larger (static) capacity, as `bsjax.merge` does."""
    rng = np.random.default_rng(3)
    a, b = _bumpy(3), _bumpy(13)
    ctrl_b = np.asarray(b.ctrl).copy()
    ctrl_b[..., 2] = (ctrl_b[..., 0] - 0.5) * 1.2 + 0.05 * rng.normal(size=ctrl_b.shape[:2])
    ctrl_b = jnp.asarray(ctrl_b)
    ba = a.blending(10, 10)
    shifts = jnp.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.02], [0.0, 0.0, 5.0]])
    query = lambda shift: surface_contacts(ba, a.ctrl, ba, ctrl_b + shift[None, None], capacity=512)
    direct = [query(d) for d in shifts]
    assert [bool(r.hit) for r in direct] == [True, True, False] and bool(direct[2].apart)
    batched = jax.jit(jax.vmap(query))(shifts)  # one compilation for both transformations
    # every field: the direct call (the exact program, the flat one only after an overflow) is
    # the one program that decides in one loop inside the caller's `jit`
    for name in direct[0].__dataclass_fields__:
        for k in range(3):
            got, want = getattr(batched, name)[k], getattr(direct[k], name)
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want), err_msg=f"{name} {k}")
    # retry: a capacity of 8 overflows along the crossing curve; the host retries with 512
    tried = []
    for capacity in (8, 512):
        result = surface_contacts(ba, a.ctrl, ba, ctrl_b, capacity=capacity)
        tried.append(bool(result.overflow))
        if not tried[-1]:
            break
    assert tried == [True, False]
    dense = surface_contacts(ba, a.ctrl, ba, ctrl_b, method="dense")
    np.testing.assert_array_equal(np.asarray(result.mask_a), np.asarray(dense.mask_a))
    np.testing.assert_array_equal(np.asarray(result.mask_b), np.asarray(dense.mask_b))


def test_closed_surface_against_plate_hierarchy():
    drop = shapes.teardrop()
    plate = shapes.plate(4, 4, size=2.0)
    ctrl_p = _shift(plate.ctrl, [-1.0, -1.0, 0.3])
    bd, bp = drop.blending(10, 10), plate.blending(9, 9)
    hier = _surfaces(bd, drop.ctrl, bp, ctrl_p, capacity=256)
    dense = _surfaces(bd, drop.ctrl, bp, ctrl_p, method="dense")
    assert bool(hier.hit) and not bool(hier.overflow)
    np.testing.assert_array_equal(np.asarray(hier.mask_a), np.asarray(dense.mask_a))
    np.testing.assert_array_equal(np.asarray(hier.mask_b), np.asarray(dense.mask_b))


def test_traversal_reports_overflow():
    pts = jnp.asarray(
        np.stack(np.meshgrid(np.linspace(0, 1, 4), np.linspace(0, 1, 4), [0.0], indexing="ij"), -1)[:, :, 0]
    )
    run = jax.jit(lambda p: traverse(sphere_hierarchy(p, 1), sphere_hierarchy(p, 1), 4))
    _, _, valid, overflow, count, _ = run(pts)  # coplanar sheets: every cell meets several others
    assert bool(overflow) and int(count) > 4 and int(valid.sum()) == 4


def _sheets(kind):
    """Two 6×6 plates at 22×22 samples lying on each other: coplanar, 1e-3 apart, or crossing at 1.1°."""
    b = PLATE.blending(22, 22)
    ctrl = jnp.asarray(PLATE.ctrl)
    other = {
        "coplanar": ctrl,
        "gap": _shift(ctrl, [0, 0, 1e-3]),
        "tilted": ctrl.at[..., 2].set(0.02 * (ctrl[..., 0] - 0.6)),
    }[kind]
    return b, ctrl, b, _shift(other, [0.3, 0.2, 0.0])


@pytest.mark.parametrize("kind", ["coplanar", "gap", "tilted"])
def test_flat_contact_resolved_by_planes_without_overflow(kind):
    """Sheets lying on each other: every sphere intersects, exact refinement overflows a small
    capacity; the flat-pair pruning (thesis §3.3.3.5) answers like the dense triangle tests."""
    args = _sheets(kind)
    dense = _surfaces(*args, method="dense")
    exact = _surfaces(*args, capacity=64, flat_angle=None)
    flat = _surfaces(*args, capacity=64)
    assert not bool(flat.overflow)
    assert bool(exact.overflow) or bool(exact.apart)  # 1e-3 apart: the flat control hulls already separate
    assert bool(flat.hit) == bool(dense.hit) == (kind != "gap")
    assert (int(flat.flat_pairs) > 0) == (kind != "gap")
    for got, want in ((flat.mask_a, dense.mask_a), (flat.mask_b, dense.mask_b)):
        got, want = np.asarray(got), np.asarray(want)
        assert not np.any(want & ~got)  # every dense contact vertex is reported
        assert np.sum(got & ~want) <= max(2, 0.05 * want.sum())  # within one cell of the contact
    if kind == "coplanar":  # flat reports whole cells: an extra vertex is a corner of a cell over b
        pa, pb = np.asarray(args[0].points(args[1])), np.asarray(args[2].points(args[3]))
        lo, hi = pb[..., :2].min((0, 1)), pb[..., :2].max((0, 1))
        for i, j in np.argwhere(np.asarray(flat.mask_a) & ~np.asarray(dense.mask_a)):
            cells = [pa[r : r + 2, c : c + 2, :2].reshape(-1, 2) for r in (i - 1, i) for c in (j - 1, j)]
            assert any(
                np.all(cell.min(0) < hi) and np.all(cell.max(0) > lo) for cell in cells if len(cell) == 4
            ), (i, j)


def test_flat_pass_reports_more_cells_than_slots():
    """The flat pass tests a fixed number of cell slots per side: flat pairs holding more cells
    than that are reported as overflow (so the direct call's caller retries), never cut."""
    b, ca, _, cb = _sheets("coplanar")
    levels = levels_for(21)  # 22 samples, 21 cells: one top block of 27 x 27 leaves
    leaves = 9**levels

    @jax.jit  # one program for every case below: the pairs' levels and validity are data
    def run(pa, pb, la, lb, valid):
        blocks = jnp.zeros(2, jnp.int32)
        pairs = FlatPairs(la, blocks, lb, blocks, valid)
        planes_a, planes_b = block_planes(pa, levels), block_planes(pb, levels)
        return resolve_flat_pairs(pa, planes_a, pb, planes_b, pairs, leaves + 1, leaves + 1)

    pa, pb = b.points(ca), b.points(cb)
    pair = lambda *v: jnp.array(v, jnp.int32)
    # the whole sheets against each other (and an unused slot): all cells fit
    mask_a, mask_b, in_contact, overflow = run(
        pa, pb, pair(levels, 0), pair(levels, 0), jnp.array([True, False])
    )
    assert not bool(overflow) and int(in_contact) == 1
    assert int(mask_a.sum()) > 0 and int(mask_b.sum()) > 0
    # a second pair of one leaf of a against all of b: b's side holds 2 * 9^L cells
    assert bool(run(pa, pb, pair(levels, 0), pair(levels, levels), jnp.array([True, True]))[3])
    # ... and the mirror: a's side overflows
    assert bool(run(pa, pb, pair(levels, levels), pair(levels, 0), jnp.array([True, True]))[3])
    # a leaf against a leaf beside the whole sheets fits on both sides
    assert not bool(run(pa, pb, pair(levels, 0), pair(levels, 0), jnp.array([True, True]))[3])


def test_normal_cones_bound_every_triangle_normal():
    surf = _bumpy(7, 8, 7)
    points = surf.blending(20, 17).points(surf.ctrl)
    levels = 3
    tris, _ = cell_triangles(points)
    normals = np.cross(tris[..., 1, :] - tris[..., 0, :], tris[..., 2, :] - tris[..., 0, :])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)  # (m-1, n-1, 2, 3)
    rows, cols = block_order(levels)
    cones = jax.jit(normal_cones, static_argnums=1)(points, levels)  # one program, not one per operation
    for level, (axis, half) in enumerate(cones):
        per = 9**level
        for q in range(0, len(half), 7):
            r, c = rows[q * per : (q + 1) * per], cols[q * per : (q + 1) * per]
            keep = (r < points.shape[0] - 1) & (c < points.shape[1] - 1)
            if not keep.any():
                continue
            angles = np.arccos(np.clip(normals[r[keep], c[keep]] @ np.asarray(axis[q]), -1, 1))
            assert angles.max() <= float(half[q]) + 1e-9
            if level == levels:
                assert float(half[q]) < np.pi  # a bumpy sheet, not everything
    plate = PLATE.blending(10, 10).points(PLATE.ctrl)
    assert max(float(jnp.max(h)) for _, h in jax.jit(normal_cones, static_argnums=1)(plate, 2)) < 1e-6


# --- jit / vmap / gradients -------------------------------------------------------------------


def test_contacts_direct_jit_vmap_grad_agree():
    """The compiled boundary of `contacts`: a direct call, the same call inside the caller's
    `jit`, `vmap` over tool centres and `grad` w.r.t. the radius and centre agree, and the
    gradients match the closed form of a ball over a flat plate."""
    b, ctrl = PLATE_B, jnp.asarray(PLATE.ctrl)
    centres = jnp.array([[0.5, 0.5, 0.05], [0.2, 0.7, 0.1], [0.5, 0.5, 3.0], [0.8, 0.3, -0.05]])
    depth = lambda c, r: contacts(b, ctrl, Sphere(c, r)).depth
    direct = [np.asarray(depth(c, 0.2)) for c in centres]
    batched = np.asarray(jax.jit(jax.vmap(depth, (0, None)))(centres, 0.2))  # one compilation for both
    for k in range(4):
        np.testing.assert_allclose(batched[k], direct[k], atol=1e-14)
    assert float(direct[2].sum()) == 0.0 and float(direct[0].sum()) > 0
    # Σ depth = Σ_contacts √(r² − ρ²) − h: ∂/∂r = Σ r / √(r² − ρ²), ∂/∂h = −(number of contacts)
    total = lambda c, r: depth(c, r).sum()
    radius, h = 0.2, 0.05
    grads = jax.grad(total, (0, 1))(centres[0], radius)
    grads_batched = jax.jit(jax.vmap(jax.grad(total, (0, 1)), (0, None)))(centres[:2], radius)
    pts = np.asarray(b.points(ctrl))
    rho2 = (pts[..., 0] - 0.5) ** 2 + (pts[..., 1] - 0.5) ** 2
    inside = rho2 < radius**2 - h**2
    assert float(grads[1]) == pytest.approx(np.sum(radius / np.sqrt(radius**2 - rho2[inside])), rel=1e-10)
    np.testing.assert_allclose(np.asarray(grads[0]), [0, 0, -inside.sum()], atol=1e-9)
    np.testing.assert_allclose(np.asarray(grads_batched[0][0]), np.asarray(grads[0]), atol=1e-12)
    np.testing.assert_allclose(float(grads_batched[1][0]), float(grads[1]), rtol=1e-12)


def test_gradients_match_finite_differences():
    surf = _bumpy(6)
    b = PLATE_B
    ctrl = jnp.asarray(surf.ctrl)
    centre = jnp.array([0.47, 0.52, 0.06])

    @jax.jit
    def pose_and_size(x):  # sphere centre, radius; ellipsoid centre, semi-axes; force
        sphere = contacts(b, ctrl, Sphere(x[:3], x[3]))  # one query for its depth and its force
        ellipsoid = contacts(b, ctrl, Ellipsoid(x[4:7], x[7:10])).depth.sum()
        return sphere.depth.sum() + ellipsoid + 1e-2 * contact_force(sphere, 50.0)[2]

    x = jnp.array([0.47, 0.52, 0.06, 0.23, 0.5, 0.45, 0.05, 0.3, 0.2, 0.12])
    check_grad(pose_and_size, x, rtol=1e-4)
    depth_p = jax.jit(lambda p: contacts(b, p, Sphere(centre, 0.23)).depth.sum())
    check_grad(depth_p, ctrl, rtol=1e-4)
    # no contact: gradients are exactly zero, not NaN
    g = jax.grad(lambda c: contact_force(contacts(b, ctrl, Sphere(c, 0.1)), 50.0).sum())(
        jnp.array([0.5, 0.5, 2.0])
    )
    assert np.all(np.asarray(g) == 0)


def test_gradient_steps_push_surface_out_of_sphere():
    b = PLATE_B
    tool = Sphere([0.5, 0.5, 0.1], 0.25)
    loss = jax.jit(lambda p: jnp.sum(contacts(b, p, tool).depth ** 2))
    step = jax.jit(lambda p: p - 2.0 * jax.grad(loss)(p))
    ctrl = jnp.asarray(PLATE.ctrl)
    start = float(loss(ctrl))
    for _ in range(40):
        ctrl = step(ctrl)
    assert start > 1e-3 and float(loss(ctrl)) < 1e-3 * start
    assert float(jnp.min(ctrl[1:-1, 1:-1, 2])) < -0.01  # the middle control points moved down


# --- forces -----------------------------------------------------------------------------------


def test_forces_spring_sum_direction_and_reaction():
    tool = Sphere([0.5, 0.5, 0.1], 0.25)
    c = _contacts(PLATE_B, PLATE.ctrl, tool)
    k = 200.0
    total = float(c.depth.sum())
    for method in ("surface_normal", "probe_normal"):
        f = np.asarray(contact_force(c, k, method))
        np.testing.assert_allclose(f, [0, 0, k * total], atol=1e-9)
        reaction = np.asarray(sample_forces(c, k, method)).sum((0, 1))
        np.testing.assert_allclose(reaction, -f, atol=1e-9)
    # damping resists the tool moving into the surface, per contact spring
    v = jnp.array([0.0, 0.0, -0.3])
    f_d = np.asarray(contact_force(c, k, damping=2.0, velocity=v))
    np.testing.assert_allclose(f_d[2], k * total + 2.0 * 0.3 * int(c.mask.sum()), rtol=1e-12)
    # probe on a sharp edge: the probe normal keeps pointing away from the tool centre
    tilted = _contacts(PLATE_B, PLATE.ctrl, Sphere([-0.1, 0.5, 0.05], 0.2))
    f_p = np.asarray(contact_force(tilted, k, "probe_normal"))
    assert f_p[0] < 0 and f_p[2] > 0
    with pytest.raises(ValueError, match="method"):
        contact_force(c, k, "bogus")
    with pytest.raises(ValueError, match="stiffness"):
        contact_force(c, -1.0)


# --- bad input --------------------------------------------------------------------------------


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="radius"):
        Sphere([0, 0, 0], -1.0)
    with pytest.raises(ValueError, match="center"):
        Sphere([0, np.nan, 0], 1.0)
    with pytest.raises(ValueError, match="center"):
        Sphere([0, 0], 1.0)
    with pytest.raises(ValueError, match="normal"):
        Plane([0, 0, 0], [0, 0, 0])
    np.testing.assert_allclose(np.asarray(Plane([0, 0, 0], [0, 0, 5.0]).normal), [0, 0, 1])
    with pytest.raises(ValueError, match="radii"):
        Ellipsoid([0, 0, 0], [1, 0, 1])
    with pytest.raises(ValueError, match="rotation"):
        Ellipsoid([0, 0, 0], [1, 1, 1], np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="position"):
        Point([np.inf, 0, 0])
    with pytest.raises(ValueError, match="reach"):
        Point([0, 0, 0], reach=-1.0)
    with pytest.raises(ValueError, match="faces"):
        TriangleMesh(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(TypeError, match="fn"):
        Implicit(3.0)
    with pytest.raises(ValueError, match="ctrl"):
        contacts(PLATE_B, jnp.zeros((5, 6, 3)), Sphere([0, 0, 0], 1.0))
    with pytest.raises(ValueError, match="method"):
        contacts(PLATE_B, PLATE.ctrl, Sphere([0, 0, 0], 1.0), method="fast")
    with pytest.raises(ValueError, match="capacity"):
        surface_contacts(PLATE_B, PLATE.ctrl, PLATE_B, PLATE.ctrl, capacity=0)
    with pytest.raises(ValueError, match="flat_angle"):
        surface_contacts(PLATE_B, PLATE.ctrl, PLATE_B, PLATE.ctrl, flat_angle=-0.1)
    with pytest.raises(TypeError, match="tool"):
        contacts(PLATE_B, PLATE.ctrl, "sphere")


# every public query that takes values: the same clear error eagerly and inside `jax.jit`
SMALL_B = PLATE.blending(4, 4)
PLANE = Plane([0.0, 0.0, 0.05], [0.0, 0.0, 1.0])


def _with_nan(x):
    return jnp.asarray(x).at[(0,) * jnp.ndim(x)].set(jnp.nan)


@functools.cache
def _plate_contact():
    return contacts(PLATE_B, PLATE.ctrl, Sphere([0.5, 0.5, 0.1], 0.25))  # as in the force test


_GRID = jnp.asarray(PLATE_B.points(PLATE.ctrl))
_TRI = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
BAD_INPUTS = {
    "contacts ctrl shape": (
        lambda c: contacts(SMALL_B, c, PLANE),
        jnp.zeros((5, 6, 3)),
        "ctrl: expected shape",
    ),
    "contacts NaN ctrl": (
        lambda c: contacts(SMALL_B, c, PLANE),
        _with_nan(PLATE.ctrl),
        "ctrl: expected finite",
    ),
    "contacts tool type": (lambda c: contacts(SMALL_B, c, "sphere"), PLATE.ctrl, "tool: expected"),
    "contacts blending type": (lambda c: contacts(PLATE, c, PLANE), PLATE.ctrl, "blending: expected"),
    "surfaces capacity type": (
        lambda c: surface_contacts(SMALL_B, c, SMALL_B, c, capacity=2.5),
        PLATE.ctrl,
        "capacity: expected an int",
    ),
    "surfaces capacity 0": (
        lambda c: surface_contacts(SMALL_B, c, SMALL_B, c, capacity=0),
        PLATE.ctrl,
        "capacity: expected an int >= 1",
    ),
    "surfaces NaN ctrl_b": (
        lambda c: surface_contacts(SMALL_B, PLATE.ctrl, SMALL_B, c, method="dense"),
        _with_nan(PLATE.ctrl),
        "ctrl_b: expected finite",
    ),
    "force negative stiffness": (lambda k: contact_force(_plate_contact(), k), jnp.array(-1.0), "stiffness"),
    "force overflow": (lambda k: contact_force(_plate_contact(), k), jnp.array(1e308), "overflow"),
    "force NaN velocity": (
        lambda v: contact_force(_plate_contact(), 10.0, damping=1.0, velocity=v),
        jnp.array([0.0, jnp.nan, 0.0]),
        "velocity: expected finite",
    ),
    "sample forces negative damping": (
        lambda d: sample_forces(_plate_contact(), 10.0, damping=d),
        jnp.array(-2.0),
        "damping",
    ),
    "hulls NaN": (
        lambda a: hulls_apart(a, jnp.ones((2, 3))),
        _with_nan(jnp.zeros((3, 3))),
        "a: expected finite",
    ),
    "hulls margin": (
        lambda m: hulls_apart(jnp.zeros((3, 3)), jnp.ones((2, 3)), m),
        jnp.array(-1.0),
        "margin",
    ),
    "window NaN ctrl": (
        lambda c: sample_window(SMALL_B, c, PLANE),
        _with_nan(PLATE.ctrl),
        "ctrl: expected finite",
    ),
    "parametric window shape": (
        lambda p: parametric_window(jnp.ones((4, 5), bool), p, jnp.linspace(0, 1, 5)),
        jnp.linspace(0, 1, 5),
        "params_u: expected shape",
    ),
    "parametric window NaN": (
        lambda p: parametric_window(jnp.ones((4, 5), bool), jnp.linspace(0, 1, 4), p),
        _with_nan(jnp.linspace(0, 1, 5)),
        "params_v: expected finite",
    ),
    "hierarchy NaN": (lambda p: sphere_hierarchy(p, 2), _with_nan(_GRID), "points: expected finite"),
    "hierarchy levels": (lambda p: sphere_hierarchy(p, -1), _GRID, "levels"),
    "cell triangles shape": (cell_triangles, jnp.zeros((4, 3)), "points: expected an array with 3"),
    "grid_mesh NaN": (grid_mesh, _with_nan(_GRID), "points: expected finite"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_values_raise_eagerly_and_under_jit(case):
    fn, arg, match = BAD_INPUTS[case]
    raises_both(fn, arg, match=match)
