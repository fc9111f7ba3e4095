"""One tool family: `push(x) -> (depth, normal)` on every solid `bsjax.collide` tool, against
closed forms, dense sampling, trimesh and each tool's own implicit function; the mass-spring
penalty contact through `push` (a torus, an ellipsoid; a point refused); the coupled chain."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.spatial
import trimesh

from bsjax import collide, mss, shapes
from bsjax.mss import _forces
from tests.helpers import check_grad, raises_both

R_TORUS, r_TORUS = 0.6, 0.25


def torus_fn(x):
    """A torus about z, as a non-distance implicit: `(√(x² + y²) − R)² + z² − r²`."""
    rho = jnp.sqrt(x[0] ** 2 + x[1] ** 2 + 1e-30)
    return (rho - R_TORUS) ** 2 + x[2] ** 2 - r_TORUS**2


def torus_with(x, p):
    """The torus of `torus_fn` with radii `p = (R, r)` as differentiable parameters."""
    return (jnp.sqrt(x[0] ** 2 + x[1] ** 2) - p[0]) ** 2 + x[2] ** 2 - p[1] ** 2


def torus_closed_form(x):
    """Depth and outward normal of points inside the torus tube (distance to its centre circle)."""
    x = np.asarray(x)
    rho = np.hypot(x[:, 0], x[:, 1])
    ring = np.stack([R_TORUS * x[:, 0] / rho, R_TORUS * x[:, 1] / rho, np.zeros(len(x))], -1)
    d = x - ring
    dist = np.linalg.norm(d, axis=-1)
    return np.maximum(r_TORUS - dist, 0.0), d / dist[:, None]


def rotation(seed=0):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def tools():
    icosphere = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    return {
        "sphere": collide.Sphere(jnp.array([0.1, -0.2, 0.05]), 0.7),
        "ellipsoid": collide.Ellipsoid(jnp.array([0.05, 0.1, -0.1]), jnp.array([0.35, 0.6, 0.9]), rotation()),
        "plane": collide.Plane(jnp.array([0.0, 0.0, 0.1]), jnp.array([0.3, -0.2, 1.0])),
        "implicit": collide.Implicit(torus_fn),
        "mesh": collide.TriangleMesh.from_trimesh(icosphere),
    }


def points(n=300, seed=1):
    return jnp.asarray(np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 3)))


# --- push against each tool's own implicit function ---------------------------------------------
@pytest.mark.parametrize("name", ["sphere", "ellipsoid", "plane", "implicit", "mesh"])
def test_push_depth_exactly_inside_and_lands_on_the_surface(name):
    tool = tools()[name]
    x = points()
    depth, normal = tool.push(x)
    value = np.asarray(tool.value(x))
    depth, normal = np.asarray(depth), np.asarray(normal)
    assert depth.shape == (300,) and normal.shape == (300, 3)
    inside = value < 0
    assert 20 < inside.sum() < 280  # both sides are exercised
    np.testing.assert_array_equal(depth > 0, inside)  # pushed exactly where the implicit is < 0
    assert np.all(depth >= 0)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=-1), 1.0, atol=1e-12)
    landed = jnp.asarray(x[inside] + depth[inside, None] * normal[inside])
    if name == "mesh":  # the surface of a mesh is its faces: the winding number is ½ there
        _, dist, _ = trimesh.proximity.closest_point(_trimesh(tool), np.asarray(landed))
        assert dist.max() < 1e-9
    else:
        scale = {"sphere": 0.7**2, "ellipsoid": 1.0, "plane": 1.0, "implicit": r_TORUS**2}[name]
        assert np.abs(np.asarray(tool.value(landed))).max() < 1e-9 * scale
    # the normal is outward: a small step along it from the surface leaves the solid
    if name != "mesh":
        out = jnp.asarray(np.asarray(landed) + 1e-4 * normal[inside])
        assert np.all(np.asarray(tool.value(out)) > 0)


def _trimesh(mesh_tool):
    return trimesh.Trimesh(np.asarray(mesh_tool.vertices), np.asarray(mesh_tool.faces), process=False)


def test_sphere_and_plane_push_closed_forms():
    x = points()
    c, r = np.array([0.1, -0.2, 0.05]), 0.7
    depth, normal = collide.Sphere(c, r).push(x)
    d = np.asarray(x) - c
    dist = np.linalg.norm(d, axis=-1)
    np.testing.assert_allclose(depth, np.maximum(r - dist, 0), atol=1e-15)
    np.testing.assert_allclose(normal, d / dist[:, None], atol=1e-15)
    centre_depth, centre_normal = collide.Sphere(c, r).push(jnp.asarray(c))
    assert float(centre_depth) == pytest.approx(r) and np.linalg.norm(centre_normal) == pytest.approx(1)

    n = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    depth, normal = collide.Plane(jnp.array([0.0, 0.0, 0.1]), jnp.array([0.3, -0.2, 1.0])).push(x)
    np.testing.assert_allclose(depth, np.maximum(-(np.asarray(x) - [0, 0, 0.1]) @ n, 0), atol=1e-15)
    np.testing.assert_allclose(normal, np.broadcast_to(n, (300, 3)), atol=1e-15)


def _ellipsoid_reference(e, x):
    """Distance of `x` to the ellipsoid surface: dense sampling of the surface, then the best
    sample polished by scipy (Nelder–Mead over the two angles)."""
    a, rot, c = (np.asarray(v) for v in (e.radii, e.rotation, e.center))

    def surface(t, p):
        return c + rot @ (a * np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]))

    t, p = np.meshgrid(np.linspace(0, np.pi, 121), np.linspace(0, 2 * np.pi, 241), indexing="ij")
    local = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3) * a
    dense = local @ rot.T + c
    tree = scipy.spatial.cKDTree(dense)
    sampled, idx = tree.query(x)
    angles = np.stack([t.ravel(), p.ravel()], -1)[idx]
    out = []
    for xi, start in zip(x, angles):
        res = scipy.optimize.minimize(
            lambda tp, xi=xi: np.sum((surface(*tp) - xi) ** 2),
            start,
            method="Nelder-Mead",
            options={"xatol": 1e-12, "fatol": 1e-24, "maxiter": 4000},
        )
        out.append(np.sqrt(res.fun))
    return np.asarray(sampled), np.asarray(out)


@pytest.mark.parametrize("radii", [(0.35, 0.6, 0.9), (0.05, 0.5, 1.2), (0.4, 0.4, 0.8)])
def test_ellipsoid_closest_point_against_dense_sampling(radii):
    e = collide.Ellipsoid(jnp.array([0.05, 0.1, -0.1]), jnp.asarray(radii), rotation(3))
    x = np.asarray(points(400, seed=4))
    inside = np.asarray(e.value(jnp.asarray(x))) < 0
    x = x[inside][:12]
    depth = np.asarray(e.push(jnp.asarray(x))[0])
    sampled, polished = _ellipsoid_reference(e, x)
    assert np.all(depth <= sampled + 1e-12)  # the exact closest point is at least as close
    np.testing.assert_allclose(depth, polished, atol=1e-7)


def test_ellipsoid_medial_points_and_centre():
    a = jnp.array([0.3, 0.5, 0.8])
    e = collide.Ellipsoid(jnp.zeros(3), a)
    # on the medial plane of the smallest axis (x = 0) close to the centre: closest along ±x
    x = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.02], [0.0, -0.02, 0.1]])
    depth, normal = e.push(x)
    landed = x + depth[:, None] * normal
    np.testing.assert_allclose(e.value(landed), 0, atol=1e-12)
    # the closest point of the medial ellipse (Eberly's case): x_k = a_k √(1 − Σ …)
    z = np.array([0.0, 0.05, 0.02])
    zy, zz = (0.5**2 * z[1] / (0.5**2 - 0.09), 0.8**2 * z[2] / (0.8**2 - 0.09))
    expected = np.linalg.norm([0.3 * np.sqrt(1 - (zy / 0.5) ** 2 - (zz / 0.8) ** 2), zy - z[1], zz - z[2]])
    assert float(depth[1]) == pytest.approx(expected, abs=1e-12)
    assert float(depth[0]) == pytest.approx(0.3, abs=1e-14)


def test_implicit_torus_push_matches_the_closed_form():
    x = points(500, seed=2)
    depth, normal = collide.Implicit(torus_fn).push(x)
    ref_depth, ref_normal = torus_closed_form(x)
    np.testing.assert_allclose(depth, ref_depth, atol=1e-9)
    inside = ref_depth > 0
    assert inside.sum() > 20
    np.testing.assert_allclose(np.asarray(normal)[inside], ref_normal[inside], atol=1e-7)


def test_triangle_mesh_push_matches_trimesh():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    tool = collide.TriangleMesh.from_trimesh(mesh)
    x = np.asarray(points(300, seed=5))
    depth, normal = tool.push(jnp.asarray(x))
    signed = trimesh.proximity.signed_distance(mesh, x)  # positive inside
    np.testing.assert_allclose(depth, np.maximum(signed, 0), atol=1e-9)
    closest, _, _ = trimesh.proximity.closest_point(mesh, x)
    inside = signed > 1e-9
    toward = (closest - x)[inside] / signed[inside, None]
    np.testing.assert_allclose(np.asarray(normal)[inside], toward, atol=1e-7)


# --- gradients ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["sphere", "ellipsoid", "plane", "implicit", "mesh"])
def test_push_gradient_in_the_points(name):
    tool = tools()[name]
    x = points(60, seed=7)
    inside = np.asarray(tool.value(x)) < -1e-3
    x = x[inside][:6]

    def loss(flat):
        depth, normal = tool.push(flat.reshape(-1, 3))
        return jnp.sum(depth**2) + jnp.sum(depth[:, None] * normal * jnp.array([0.3, -0.5, 0.7])[None])

    check_grad(loss, x.reshape(-1), eps=1e-6, rtol=1e-5, atol=1e-8, n_dirs=3)


def test_push_gradient_in_the_tool():
    x = jnp.array([[0.1, 0.2, 0.3], [-0.2, 0.1, -0.3], [0.05, -0.3, 0.4]])

    def loss(p):
        e = collide.Ellipsoid(p[:3], p[3:6], rotation())
        depth, normal = e.push(x)
        return jnp.sum(depth) + jnp.sum(normal[:, 0] * depth)

    check_grad(loss, jnp.array([0.02, -0.01, 0.03, 0.45, 0.6, 0.9]), eps=1e-6, rtol=1e-5, n_dirs=3)

    def loss_torus(params):
        tool = collide.Implicit(torus_with, params)
        return jnp.sum(tool.push(jnp.array([[0.55, 0.1, 0.05], [0.0, -0.7, 0.1]]))[0])

    check_grad(loss_torus, jnp.array([0.6, 0.25]), eps=1e-6, rtol=1e-5, n_dirs=2)


def test_push_under_jit_and_vmap():
    e = tools()["ellipsoid"]
    x = points()  # the shape of the push test above: its direct program serves this call
    d, n = e.push(x)
    dv, nv = jax.jit(jax.vmap(e.push))(x)  # one program for both transformations
    np.testing.assert_allclose(dv, d, atol=1e-14)
    np.testing.assert_allclose(nv, n, atol=1e-14)
    # a tool built inside jit/vmap (batched poses, e.g. a tool path)
    balls = jax.vmap(collide.Sphere)(jnp.zeros((4, 3)), jnp.array([0.1, 0.2, 0.3, 0.4]))
    np.testing.assert_allclose(
        jax.vmap(lambda b: b.push(jnp.zeros((1, 3)))[0][0])(balls), [0.1, 0.2, 0.3, 0.4]
    )


# --- bad input ----------------------------------------------------------------------------------------
def test_point_has_no_push():
    with pytest.raises(TypeError, match="no volume"):
        collide.Point(jnp.zeros(3)).push(jnp.zeros((2, 3)))


def test_tool_constructors_check_values_eagerly_and_under_jit():
    raises_both(lambda r: collide.Sphere(jnp.zeros(3), r).push(jnp.zeros(3)), jnp.array(-1.0), match="radius")
    raises_both(
        lambda c: collide.Sphere(c, 1.0).push(jnp.zeros(3)), jnp.array([0.0, jnp.nan, 0.0]), match="center"
    )
    raises_both(
        lambda a: collide.Ellipsoid(jnp.zeros(3), a).push(jnp.zeros(3)),
        jnp.array([1.0, 0.0, 1.0]),
        match="radii",
    )
    raises_both(
        lambda r: collide.Ellipsoid(jnp.zeros(3), jnp.ones(3), r).push(jnp.zeros(3)),
        jnp.diag(jnp.array([1.0, 1.0, -1.0])),
        match="rotation",
    )
    raises_both(lambda n: collide.Plane(jnp.zeros(3), n).push(jnp.zeros(3)), jnp.zeros(3), match="normal")
    raises_both(lambda r: collide.Point(jnp.zeros(3), r).reach, jnp.array(-1.0), match="reach")
    raises_both(
        lambda f: collide.TriangleMesh(jnp.eye(3), f).push(jnp.zeros(3)),
        jnp.array([[0, 1, 3]]),
        match="faces",
    )
    with pytest.raises(TypeError, match="complex"):
        collide.Sphere(jnp.zeros(3, jnp.complex128), 1.0)
    with pytest.raises(TypeError, match="complex"):
        collide.Sphere(jnp.zeros(3), 1.0).push(jnp.zeros(3, jnp.complex128))
    with pytest.raises(ValueError, match="x: expected points"):
        collide.Sphere(jnp.zeros(3), 1.0).push(jnp.zeros((4, 2)))


# --- the mass-spring penalty contact through push ----------------------------------------------------
def grid_lattice(spacing=0.1, half=0.9):
    """A free node grid over [−half, half]² × {−0.05, 0.05}, light springs (the contact dominates)."""
    ticks = np.arange(-half, half + 1e-9, spacing)
    g = np.stack(np.meshgrid(ticks, ticks, [-0.05, 0.05], indexing="ij"), -1)
    return mss.hex_lattice(jnp.asarray(g), 1.0, 0.0, 0.01)


def one_step_push(tool, lattice, k=1e3, dt=1e-3):
    """Node displacement after one step with the tool minus one step without it (the penalty only)."""
    s0 = mss.init(lattice)
    free = mss.step(lattice, s0, dt)
    pushed = mss.step(lattice, s0, dt, tools=(tool,), contact=mss.Penalty(k))
    return np.asarray(pushed.position - free.position)


def test_simulate_with_a_torus_pushes_the_tube_and_not_the_hole():
    lattice = grid_lattice()
    x = np.asarray(lattice.rest_positions)
    torus = collide.Implicit(torus_fn)
    moved = one_step_push(torus, lattice)
    value = np.asarray(torus.value(jnp.asarray(x)))
    hole = np.hypot(x[:, 0], x[:, 1]) < R_TORUS - r_TORUS
    assert hole.sum() >= 20 and (value < 0).sum() >= 20
    assert np.abs(moved[hole]).max() == 0.0  # nodes in the hole are untouched
    # pushed exactly where the torus's own implicit is negative, by k δ n dt² / m
    np.testing.assert_array_equal(np.linalg.norm(moved, axis=-1) > 0, value < 0)
    depth, normal = torus_closed_form(x)
    expected = (1e3 * depth[:, None] * normal) * 1e-3**2 / 0.01
    np.testing.assert_allclose(moved, expected, atol=1e-12)
    # the 3-step case: the hole moves only through the (light) springs, 1e-4 of the tube
    s0 = mss.init(lattice)
    contact = mss.Penalty(1e3)
    shift = np.linalg.norm(
        mss.simulate(lattice, s0, 1e-3, 3, tools=(torus,), contact=contact).position
        - mss.simulate(lattice, s0, 1e-3, 3).position,
        axis=-1,
    )
    assert shift[value < 0].min() > 1e-3 and shift[hole].max() < 1e-4 * shift.max()


def test_simulate_with_an_ellipsoid_follows_its_implicit_function():
    lattice = grid_lattice()
    x = np.asarray(lattice.rest_positions)
    e = collide.Ellipsoid(jnp.array([0.1, 0.0, 0.0]), jnp.array([0.5, 0.3, 0.2]), rotation(5))
    moved = one_step_push(e, lattice)
    value = np.asarray(e.value(jnp.asarray(x)))
    assert (value < 0).sum() >= 10
    np.testing.assert_array_equal(np.linalg.norm(moved, axis=-1) > 0, value < 0)
    depth = np.linalg.norm(moved, axis=-1) * 0.01 / (1e3 * 1e-6)
    _, polished = _ellipsoid_reference(e, x[value < 0][:10])
    np.testing.assert_allclose(depth[value < 0][:10], polished, atol=1e-7)


@pytest.mark.parametrize("name", ["sphere", "plane", "mesh"])
def test_simulate_accepts_every_solid_tool(name):
    lattice = grid_lattice(0.2)
    tool = tools()[name]
    moved = one_step_push(tool, lattice)
    value = np.asarray(tool.value(lattice.rest_positions))
    np.testing.assert_array_equal(np.linalg.norm(moved, axis=-1) > 0, value < 0)


def test_simulate_refuses_a_point_and_foreign_tools():
    lattice = grid_lattice(0.3)
    s0 = mss.init(lattice)
    with pytest.raises(TypeError, match="no volume"):
        mss.simulate(lattice, s0, 1e-3, 2, tools=(collide.Point(jnp.zeros(3)),))
    with pytest.raises(TypeError, match="collide tools"):
        mss.tool_forces((object(),), s0.position, s0.velocity, 1e3)


def test_sphere_penalty_closed_form():
    x = points(50)
    v = jnp.asarray(np.random.default_rng(3).normal(size=(50, 3)))
    f = _forces.sphere_penalty(x, v, jnp.zeros(3), 0.5, 100.0, 2.0)
    d = np.asarray(x)
    dist = np.linalg.norm(d, axis=-1)
    n = d / dist[:, None]
    vn = np.sum(np.asarray(v) * n, -1)
    inside = dist < 0.5
    mag = np.where(inside, 100.0 * (0.5 - dist) - 2.0 * np.minimum(vn, 0), 0)
    np.testing.assert_allclose(f, mag[:, None] * n, atol=1e-12)


# --- one coupling, one chain ----------------------------------------------------------------------
def test_coupled_step_on_a_volumetric_lattice_refits_the_surface_layer():
    surf = shapes.teardrop()
    m, n, layers = 8, 8, 2
    pu = np.linspace(0, 1, m + 2)[1:-1]
    blend = surf.blending(m, n, pu, np.arange(n) / n)
    pts = np.asarray(blend.points(surf.ctrl))
    centre = pts.mean(axis=1, keepdims=True)
    rho = (np.arange(layers) + 1.0) / layers
    nodes = centre[:, :, None] + rho[None, None, :, None] * (pts - centre)[:, :, None]
    fixed = np.zeros((m, n, layers), bool)
    fixed[:, :, 0] = True
    lattice = mss.hex_lattice(jnp.asarray(nodes), 5.0, 0.05, 0.01, jnp.asarray(fixed))
    ids = np.arange(m * n * layers).reshape(m, n, layers)[:, :, -1]
    coupling = mss.SurfaceCoupling.on_nodes(blend, ids, lattice.n_nodes)
    state = mss.init(lattice)
    np.testing.assert_allclose(coupling.ctrl(state.position), surf.ctrl, atol=1e-12)
    np.testing.assert_allclose(coupling.nodes(surf.ctrl, state.position), state.position, atol=1e-12)
    with pytest.raises(ValueError, match="position"):
        coupling.nodes(surf.ctrl)
    tool = collide.Sphere(jnp.array([0.75, 0.0, 0.0]), 0.25)
    contact = mss.Penalty(100.0)
    after, ctrl = mss.coupled_step(lattice, coupling, state, 1e-3, (tool,), contact)
    ref = mss.step(lattice, state, 1e-3, tools=(tool,), contact=contact)
    np.testing.assert_allclose(after.position, ref.position, atol=1e-15)
    outer = jnp.asarray(np.asarray(ref.position).reshape(m, n, layers, 3)[:, :, -1])
    np.testing.assert_allclose(ctrl, blend.refit(outer), atol=1e-12)
    # the chain inside the caller's jit gives the same
    jitted = jax.jit(lambda s: mss.coupled_step(lattice, coupling, s, 1e-3, (tool,), contact))(state)
    np.testing.assert_allclose(jitted[1], ctrl, atol=1e-14)
    raises_both(
        lambda dt: mss.coupled_step(lattice, coupling, state, dt, (tool,), contact)[1],
        jnp.array(-1e-3),
        match="dt",
    )
    with pytest.raises(ValueError, match="method"):
        mss.coupled_step(lattice, coupling, state, 1e-3, method="rk4")
