"""The triangle-mesh tool's face hierarchy (`collide.mesh_bvh`): the hierarchical nearest-face
search and pseudo-normal inside test against every face (the same tie rule), the tool's
results against trimesh (`contains`, `proximity.closest_point`) and against the all-faces
winding number, jit / vmap / gradients, open meshes and bad input."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from bsjax import collide
from bsjax.collide import _mesh_bvh as mesh_bvh
from bsjax.collide._tools import _winding_number
from bsjax.collide._triangles import _closest_point_on_triangle
from tests.helpers import check_grad, raises_both


def stepped_part():
    """A small revolved flange with a bore (non-convex, long thin faces): 8 × 17 · 2 faces."""
    r = [0.15, 0.45, 0.45, 0.3, 0.3, 0.55, 0.55, 0.15]
    z = [-0.4, -0.4, -0.3, -0.3, -0.05, -0.05, 0.05, 0.05]
    profile = np.array(list(zip(r, z)) + [(r[0], z[0])])
    return trimesh.creation.revolve(profile, sections=17)


MESHES = {
    "icosphere": lambda: trimesh.creation.icosphere(subdivisions=2, radius=0.7),
    "box": lambda: trimesh.creation.box((0.9, 0.6, 0.5)),
    "part": stepped_part,
}


def points(n=400, seed=0, half=0.9):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-half, half, (n, 3))
    x[: n // 8] = np.round(x[: n // 8], 1)  # on a lattice: exactly on faces, edges, planes of a box
    return jnp.asarray(x)


def without_tree(tool):
    return eqx.tree_at(lambda m: m.tree, tool, None, is_leaf=lambda v: v is None)


@pytest.mark.parametrize("name", list(MESHES))
def test_tree_is_closed_and_covers_every_face(name):
    mesh = MESHES[name]()
    tree = collide.TriangleMesh.from_trimesh(mesh).tree
    assert mesh.is_watertight and tree.closed
    assert set(np.asarray(tree.leaf_faces).ravel()) == set(range(len(mesh.faces)))
    assert tree.leaf_faces.shape[0] == 2**tree.depth
    # every edge's neighbour shares that edge, reversed
    f = np.asarray(mesh.faces)
    nb = np.asarray(tree.neighbours)
    for i in range(3):
        a, b = f[:, i], f[:, (i + 1) % 3]
        g = f[nb[:, i]]
        assert np.all(np.any((g == b[:, None]) & (np.roll(g, -1, 1) == a[:, None]), 1))


@pytest.mark.parametrize("name", list(MESHES))
def test_nearest_faces_equal_every_face_search(name):
    mesh = MESHES[name]()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    x = points(200, seed=1, half=1.5)
    fast = jax.jit(mesh_bvh.nearest_faces)(tool.tree, tool.vertices, tool.faces, x)
    dense = mesh_bvh.nearest_faces_dense(tool.triangles, x)
    np.testing.assert_array_equal(fast, dense)
    # and it is a nearest face: its distance equals trimesh's closest distance
    closest, _ = _closest_point_on_triangle(x, tool.triangles[fast])
    _, dist, _ = trimesh.proximity.closest_point(mesh, np.asarray(x))
    np.testing.assert_allclose(np.linalg.norm(np.asarray(closest - x), axis=-1), dist, atol=1e-12)


@pytest.mark.parametrize("name", list(MESHES))
def test_inside_equals_winding_number_and_trimesh(name):
    mesh = MESHES[name]()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    x = points(200, seed=2, half=0.6)
    value = np.asarray(tool.value(x))
    winding = np.asarray(_winding_number(x, tool.triangles))
    _, dist, _ = trimesh.proximity.closest_point(mesh, np.asarray(x))
    off = dist > 1e-9  # off the surface: the winding number is an integer there
    assert off.sum() > 150
    np.testing.assert_allclose(value[off], 0.5 - winding[off], atol=1e-12)
    np.testing.assert_array_equal(value[off] < 0, mesh.contains(np.asarray(x)[off]))
    assert 5 <= np.sum(value < 0) <= len(value) - 5  # both sides exercised


@pytest.mark.parametrize("name", list(MESHES))
def test_push_and_penetration_equal_the_every_face_tool(name):
    tool = collide.TriangleMesh.from_trimesh(MESHES[name]())
    old = without_tree(tool)  # every face: the winding number and an argmin over all faces
    x = points(200, seed=3)
    # off the surface (on it, the inside test is undecided for both: winding number ½ ± rounding)
    _, dist, _ = trimesh.proximity.closest_point(MESHES[name](), np.asarray(x))
    off = dist > 1e-9
    for new_out, old_out in ((tool.push(x), old.push(x)), (tool.penetration(x, x), old.penetration(x, x))):
        np.testing.assert_allclose(new_out[0], old_out[0], atol=1e-12)
        np.testing.assert_allclose(np.asarray(new_out[1])[off], np.asarray(old_out[1])[off], atol=1e-12)


def test_push_matches_trimesh_signed_distance_on_the_part():
    mesh = stepped_part()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    x = np.asarray(points(300, seed=5))
    depth, normal = tool.push(jnp.asarray(x))
    signed = trimesh.proximity.signed_distance(mesh, x)  # positive inside
    np.testing.assert_allclose(depth, np.maximum(signed, 0), atol=1e-12)
    closest, _, _ = trimesh.proximity.closest_point(mesh, x)
    inside = signed > 1e-9
    np.testing.assert_allclose(
        np.asarray(normal)[inside], (closest - x)[inside] / signed[inside, None], atol=1e-9
    )


def _plate(n=6, half=0.67, amp=0.02):
    from bsjax.basis import BSplineSurface, clamped_knots

    g = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    ctrl = jnp.asarray(np.stack([xx, yy, amp * np.cos(3 * xx) * np.sin(2 * yy)], -1))
    knots = clamped_knots(n, 3, np.float64)
    return BSplineSurface(ctrl, knots, knots, 3, 3), ctrl


CONTACT_MESHES = {
    **MESHES,
    # partly off the plate: most samples lie outside its box and are not searched
    "shifted icosphere": lambda: trimesh.creation.icosphere(subdivisions=2, radius=0.3).apply_translation(
        [0.55, -0.5, 0.1]
    ),
    "open": lambda: trimesh.Trimesh(
        MESHES["icosphere"]().vertices, MESHES["icosphere"]().faces[1:], process=False
    ),
}


def _nearest_face_normals(mesh, x, tol=1e-9):
    """Distances `(P,)` of points `x (P, 3)` to the mesh, the unit normal of their nearest face
    `(P, 3)` and whether it is defined: every face's closest point by trimesh, and the faces within
    `tol` of the nearest distance all with that normal (not at an edge or corner between faces
    of different normals, where the nearest face is a tie)."""
    tris = np.asarray(mesh.triangles)
    each = trimesh.triangles.closest_point(
        np.repeat(tris[None], len(x), 0).reshape(-1, 3, 3), np.repeat(x, len(tris), 0)
    ).reshape(len(x), len(tris), 3)
    dist = np.linalg.norm(each - x[:, None], axis=-1)
    normals = np.asarray(mesh.face_normals)
    normal = normals[dist.argmin(1)]
    near = dist <= dist.min(1, keepdims=True) + tol
    disagree = np.where(near, np.linalg.norm(normals[None] - normal[:, None], axis=-1), 0).max(1)
    return dist.min(1), normal, disagree <= tol


@pytest.mark.parametrize("name", list(CONTACT_MESHES))
def test_contacts_equal_trimesh_and_on_an_open_mesh_the_every_face_tool(name):
    """A closed mesh against trimesh (inside by `contains`, depth by the closest point and the
    tool normal by the nearest face, every face searched); an open one (no inside for trimesh)
    against the tool without its tree, which tests every face."""
    mesh = CONTACT_MESHES[name]()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    surf, ctrl = _plate()
    b = surf.blending(17, 13)
    new = collide.contacts(b, ctrl, tool)
    assert 3 < int(new.mask.sum()) < 17 * 13
    # the samples outside a closed mesh's box are not searched: zero tool normal there
    pts = np.asarray(new.points)
    in_box = np.all((pts >= mesh.bounds[0]) & (pts <= mesh.bounds[1]), -1)
    searched = in_box if tool.tree.closed else np.ones_like(in_box)
    assert 0 < searched.sum() and (name != "shifted icosphere" or searched.mean() < 0.2)
    np.testing.assert_array_equal(np.asarray(new.tool_normals)[~searched], 0)
    if not tool.tree.closed:  # trimesh's `contains` needs a watertight mesh
        old = collide.contacts(b, ctrl, without_tree(tool))
        np.testing.assert_array_equal(new.mask, old.mask)
        np.testing.assert_allclose(new.depth, old.depth, atol=1e-12)
        np.testing.assert_allclose(new.tool_normals, old.tool_normals, atol=1e-12)
        return
    x = pts.reshape(-1, 3)
    inside = mesh.contains(x)
    np.testing.assert_array_equal(new.mask, inside.reshape(17, 13))
    dist, normal, defined = _nearest_face_normals(mesh, x)
    np.testing.assert_allclose(new.depth, np.where(new.mask, dist.reshape(17, 13), 0), atol=1e-12)
    # the tool normal: the outward unit normal of the nearest face, where one face is nearest
    check = searched.reshape(-1) & defined
    assert check.sum() >= 0.8 * searched.sum()
    np.testing.assert_allclose(np.asarray(new.tool_normals).reshape(-1, 3)[check], normal[check], atol=1e-12)


def test_contacts_under_jit_and_vmap():
    tool = collide.TriangleMesh.from_trimesh(stepped_part())
    surf, ctrl = _plate()
    b = surf.blending(9, 11)
    ref = collide.contacts(b, ctrl, tool)
    lifted = ctrl + jnp.array([0.0, 0.0, 0.2])[None, None]
    # one program for both transformations: vmap over nets inside jit, the tool a jit argument
    query = jax.vmap(lambda c, t: collide.contacts(b, c, t), in_axes=(0, None))
    both = jax.jit(query)(jnp.stack([ctrl, lifted]), tool)
    np.testing.assert_array_equal(both.mask[0], ref.mask)
    np.testing.assert_allclose(both.depth[0], ref.depth, atol=1e-15)
    np.testing.assert_array_equal(both.mask[1], collide.contacts(b, lifted, tool).mask)


@pytest.mark.parametrize("name", list(MESHES))
def test_nearest_faces_of_active_points_only(name):
    tool = collide.TriangleMesh.from_trimesh(MESHES[name]())
    x = points(160, seed=11, half=1.2)
    active = jnp.asarray(np.random.default_rng(4).random(160) < 0.4)
    nearest = eqx.filter_jit(mesh_bvh.nearest_faces)  # the kernel as one program
    got = nearest(tool.tree, tool.vertices, tool.faces, x, active)
    dense = eqx.filter_jit(mesh_bvh.nearest_faces_dense)(tool.triangles, x)
    np.testing.assert_array_equal(np.asarray(got)[np.asarray(active)], np.asarray(dense)[np.asarray(active)])
    # none active: no search, any face
    assert nearest(tool.tree, tool.vertices, tool.faces, x, jnp.zeros(160, bool)).shape == (160,)


def test_value_outside_the_box_is_one_half():
    mesh = MESHES["part"]()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    x = points(120, seed=12, half=0.7)
    value = np.asarray(tool.value(x))
    in_box = np.all((np.asarray(x) >= mesh.bounds[0]) & (np.asarray(x) <= mesh.bounds[1]), -1)
    assert 10 < in_box.sum() < 110
    np.testing.assert_array_equal(value[~in_box], 0.5)
    _, dist, _ = trimesh.proximity.closest_point(mesh, np.asarray(x))
    off = dist > 1e-9  # on the surface the winding number is ½ ± rounding
    np.testing.assert_allclose(value[off], np.asarray(without_tree(tool).value(x))[off], atol=1e-12)


def test_jit_vmap_and_a_moved_mesh():
    tool = collide.TriangleMesh.from_trimesh(MESHES["icosphere"]())
    x = points(200, seed=6)  # the shape of the every-face test's: its direct program serves this call
    depth, _ = tool.push(x)
    # one program for both transformations: vmap over point batches inside jit, the tool a jit argument
    vd, _ = jax.jit(jax.vmap(lambda t, p: t.push(p), in_axes=(None, 0)))(tool, x.reshape(10, 20, 3))
    np.testing.assert_allclose(vd.reshape(-1), depth, atol=1e-15)
    # a translated mesh (the tree keeps only topology): same depths for translated points
    shift = jnp.array([0.3, -0.2, 0.1])
    moved = eqx.tree_at(lambda m: m.vertices, tool, tool.vertices + shift[None])
    np.testing.assert_allclose(moved.push(x + shift[None])[0], depth, atol=1e-12)
    # under vmap over meshes
    stacked = jax.vmap(lambda s: eqx.tree_at(lambda m: m.vertices, tool, tool.vertices + s[None]))(
        jnp.stack([jnp.zeros(3), shift])
    )
    both = jax.vmap(lambda t, p: t.push(p)[0])(stacked, jnp.stack([x, x + shift[None]]))
    np.testing.assert_allclose(both[1], depth, atol=1e-12)


def test_gradients_through_the_search():
    tool = collide.TriangleMesh.from_trimesh(stepped_part())
    x = points(80, seed=7, half=0.5)[10:]  # off the lattice, whose z = 0 is the flange's medial plane
    x = x[np.asarray(tool.value(x)) < 0][:5]

    def in_points(flat):
        depth, normal = tool.push(flat.reshape(-1, 3))
        return jnp.sum(depth**2) + jnp.sum(depth[:, None] * normal * jnp.array([0.3, -0.5, 0.7])[None])

    check_grad(in_points, x.reshape(-1), eps=1e-6, rtol=1e-5, atol=1e-8, n_dirs=3)

    def in_vertices(v):
        moved = eqx.tree_at(lambda m: m.vertices, tool, v)
        return jnp.sum(moved.penetration(x, x)[0])

    check_grad(in_vertices, tool.vertices, eps=1e-6, rtol=1e-5, atol=1e-8, n_dirs=3)


def test_open_or_inverted_mesh_keeps_the_winding_number():
    mesh = MESHES["icosphere"]()
    open_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[1:], process=False)
    tool = collide.TriangleMesh.from_trimesh(open_mesh)
    assert not tool.tree.closed
    x = points(100, seed=8)
    np.testing.assert_allclose(tool.value(x), 0.5 - _winding_number(x, tool.triangles), atol=1e-14)
    inverted = collide.TriangleMesh(mesh.vertices, mesh.faces[:, ::-1])
    assert not inverted.tree.closed  # negative volume: the pseudo-normal sign would be wrong
    assert not np.any(np.asarray(inverted.value(x)) < 0)  # the winding number is -1 inside
    # built inside a jit from traced arrays: no tree, every face
    v = jax.jit(lambda vs, fs: collide.TriangleMesh(vs, fs).value(x))(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(v, tool_value(mesh, x), atol=1e-12)


def tool_value(mesh, x):
    return collide.TriangleMesh.from_trimesh(mesh).value(x)


def test_bad_input_is_named():
    mesh = MESHES["box"]()
    faces = jnp.asarray(mesh.faces)
    bad_vertices = jnp.asarray(mesh.vertices).at[2, 1].set(jnp.nan)
    raises_both(lambda v: collide.TriangleMesh(v, faces).push(jnp.zeros(3)), bad_vertices, match="vertices")
    bad_faces = faces.at[3, 0].set(99)
    raises_both(
        lambda f: collide.TriangleMesh(jnp.asarray(mesh.vertices), f).value(jnp.zeros(3)),
        bad_faces,
        match="faces",
    )
    with pytest.raises(ValueError, match="faces"):
        collide.TriangleMesh(mesh.vertices, np.asarray(mesh.faces)[:, :2])
    with pytest.raises(ValueError, match="x: expected points"):
        collide.TriangleMesh.from_trimesh(mesh).push(jnp.zeros((4, 2)))
