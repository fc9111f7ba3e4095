"""Trims in collision and tessellation (issue #17): `collide.contacts(..., sample_mask=)`,
`io.CadObject.sample_mask` and `io.tessellate(..., mask=)` on a flat plate with a square hole."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide, io
from bsjax._boundary import clear_caches
from bsjax.basis import BSplineSurface, clamped_knots, greville
from bsjax.collide import _contact as contact_module
from tests.helpers import raises_both

HOLE = (0.35, 0.65)  # the hole is HOLE × HOLE in (u, v) and in (x, y)
M, N = 24, 20


def _plate() -> io.CadObject:
    """The unit square in z = 0 (a degree-2 × degree-3 B-spline with x = u, y = v) with a square
    hole, as a trimmed face."""
    r, s = 5, 6
    ku, kv = np.asarray(clamped_knots(r, 2)), np.asarray(clamped_knots(s, 3))
    # control points at the Greville abscissae: x = u, y = v exactly (linear precision)
    gu, gv = np.meshgrid(greville(ku, 2), greville(kv, 3), indexing="ij")
    ctrl = np.stack([gu, gv, np.zeros((r, s))], -1)
    surface = BSplineSurface(jnp.asarray(ctrl), jnp.asarray(ku), jnp.asarray(kv), 2, 3)
    a, b = HOLE
    outer = [(0, 0), (1, 0), (1, 1), (0, 1)]
    hole = [(a, a), (a, b), (b, b), (b, a)]
    return io.CadObject(surface, trim=io.Trim.from_loops([outer, hole], [True, False]))


def _in_hole(u, v):
    a, b = HOLE
    return (u > a) & (u < b) & (v > a) & (v < b)


def test_the_plate_is_the_identity_map():
    plate = _plate()
    u, v = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 5), indexing="ij")
    xyz = np.asarray(plate.surface.evaluate(u, v))
    np.testing.assert_allclose(xyz, np.stack([u, v, 0 * u], -1), atol=1e-14)


def test_sample_mask_is_the_trim_on_the_grid():
    plate = _plate()
    blending = plate.surface.blending(M, N)
    mask = np.asarray(plate.sample_mask(blending))
    u, v = np.meshgrid(np.asarray(blending.params_u), np.asarray(blending.params_v), indexing="ij")
    assert mask.shape == (M, N) and mask.dtype == np.bool_
    # samples on the outer boundary may fall either side of the even–odd test: compare inside
    interior = (u > 0) & (u < 1) & (v > 0) & (v < 1)
    np.testing.assert_array_equal(mask[interior], ~_in_hole(u, v)[interior])
    untrimmed = io.CadObject(plate.surface)
    assert np.all(np.asarray(untrimmed.sample_mask(blending)))
    with pytest.raises(TypeError, match="blending: expected a Blending"):
        plate.sample_mask(plate.surface)
    other = BSplineSurface(jnp.zeros((4, 4, 3)), clamped_knots(4, 2), clamped_knots(4, 2), 2, 2)
    with pytest.raises(ValueError, match=r"blending: expected a blending of this surface"):
        plate.sample_mask(other.blending(M, N))


@pytest.mark.parametrize("method", ["window", "dense"])
def test_a_sphere_over_the_hole_makes_no_contact(method):
    plate = _plate()
    blending = plate.surface.blending(M, N)
    sample_mask = plate.sample_mask(blending)
    over = collide.Sphere(jnp.array([0.5, 0.5, 0.05]), 0.1)  # inside the hole (0.35..0.65)²
    bare = collide.contacts(blending, plate.surface.ctrl, over, method=method)
    assert bool(bare.hit)  # the untrimmed surface is touched …
    trimmed = collide.contacts(blending, plate.surface.ctrl, over, method=method, sample_mask=sample_mask)
    assert not bool(trimmed.hit)  # … the trimmed face is not
    assert not np.any(np.asarray(trimmed.mask)) and np.all(np.asarray(trimmed.depth) == 0)


@pytest.mark.parametrize("method", ["window", "dense"])
def test_a_sphere_beside_the_hole_is_unchanged(method):
    plate = _plate()
    blending = plate.surface.blending(M, N)
    sample_mask = plate.sample_mask(blending)
    beside = collide.Sphere(jnp.array([0.17, 0.5, 0.05]), 0.12)  # x in (0.05, 0.29): solid plate
    bare = collide.contacts(blending, plate.surface.ctrl, beside, method=method)
    trimmed = collide.contacts(blending, plate.surface.ctrl, beside, method=method, sample_mask=sample_mask)
    assert bool(trimmed.hit) and int(np.sum(np.asarray(trimmed.mask))) > 3
    np.testing.assert_array_equal(np.asarray(trimmed.mask), np.asarray(bare.mask))
    np.testing.assert_array_equal(np.asarray(trimmed.depth), np.asarray(bare.depth))
    # depth against the closed form: the ball's depth below the plate along the normal
    u, v = np.meshgrid(np.asarray(blending.params_u), np.asarray(blending.params_v), indexing="ij")
    inside = (u - 0.17) ** 2 + (v - 0.5) ** 2 < 0.12**2 - 0.05**2
    np.testing.assert_array_equal(np.asarray(trimmed.mask), inside)


def test_a_sphere_across_the_hole_edge_keeps_only_the_solid_part():
    plate = _plate()
    blending = plate.surface.blending(M, N)
    sample_mask = np.asarray(plate.sample_mask(blending))
    across = collide.Sphere(jnp.array([0.35, 0.5, 0.0]), 0.15)
    bare = collide.contacts(blending, plate.surface.ctrl, across)
    trimmed = collide.contacts(blending, plate.surface.ctrl, across, sample_mask=jnp.asarray(sample_mask))
    np.testing.assert_array_equal(np.asarray(trimmed.mask), np.asarray(bare.mask) & sample_mask)
    np.testing.assert_array_equal(
        np.asarray(trimmed.depth), np.where(sample_mask, np.asarray(bare.depth), 0.0)
    )
    assert np.any(np.asarray(bare.mask) & ~sample_mask)  # the hole side was really cut off


def test_a_point_tool_is_masked_too():
    plate = _plate()
    blending = plate.surface.blending(M, N)
    sample_mask = plate.sample_mask(blending)
    probe = collide.Point(jnp.array([0.5, 0.5, -0.01]), 0.1)  # behind the plate, in the hole
    assert bool(collide.contacts(blending, plate.surface.ctrl, probe).hit)
    assert not bool(collide.contacts(blending, plate.surface.ctrl, probe, sample_mask=sample_mask).hit)


def test_jit_vmap_grad_and_no_recompilation(monkeypatch):
    plate = _plate()
    blending = plate.surface.blending(M, N)
    ctrl = plate.surface.ctrl
    sample_mask = plate.sample_mask(blending)
    tool = collide.Sphere(jnp.array([0.17, 0.5, 0.05]), 0.12)
    direct = collide.contacts(blending, ctrl, tool, sample_mask=sample_mask)
    inside = jax.jit(lambda c, m: collide.contacts(blending, c, tool, sample_mask=m))(ctrl, sample_mask)
    np.testing.assert_array_equal(np.asarray(direct.depth), np.asarray(inside.depth))
    # a new mask of the same shape is traced, not compiled again
    traces = []
    checked = contact_module._checked_mask
    monkeypatch.setattr(contact_module, "_checked_mask", lambda *a: traces.append(1) or checked(*a))
    clear_caches()
    first = collide.contacts(blending, ctrl, tool, sample_mask=sample_mask)
    none = collide.contacts(blending, ctrl, tool, sample_mask=jnp.zeros((M, N), bool))
    assert len(traces) == 1 and bool(first.hit) and not bool(none.hit)
    # vmap over masks; grad of the depth through the mask
    masks = jnp.stack([sample_mask, jnp.zeros((M, N), bool)])
    hits = jax.vmap(lambda m: collide.contacts(blending, ctrl, tool, sample_mask=m).hit)(masks)
    np.testing.assert_array_equal(np.asarray(hits), [True, False])
    depth = lambda c, m: collide.contacts(blending, c, tool, sample_mask=m).depth.sum()
    g_all = jax.grad(depth)(ctrl, sample_mask)
    g_none = jax.grad(depth)(ctrl, jnp.zeros((M, N), bool))
    assert float(jnp.abs(g_all).sum()) > 0 and float(jnp.abs(g_none).sum()) == 0


def test_a_bad_mask_is_named():
    plate = _plate()
    blending = plate.surface.blending(M, N)
    ctrl = plate.surface.ctrl
    tool = collide.Sphere(jnp.array([0.5, 0.5, 0.0]), 0.1)
    call = lambda c, m: collide.contacts(blending, c, tool, sample_mask=m)
    raises_both(call, ctrl, jnp.ones((N, M), bool), match=r"sample_mask: expected shape \(24, 20\)")
    raises_both(call, ctrl, jnp.ones((M, N)), match="sample_mask: expected booleans")
    raises_both(call, ctrl.at[0, 0, 0].set(jnp.nan), jnp.ones((M, N), bool), match="ctrl: expected finite")


def test_tessellation_has_no_triangle_in_the_hole():
    plate = _plate()
    full = io.tessellate(plate.surface, M, N)
    mask = np.asarray(plate.sample_mask(plate.surface.blending(M, N)))
    mesh = io.tessellate(plate.surface, M, N, mask=mask)
    assert len(mesh.faces) < len(full.faces)
    centres = mesh.triangles_center
    assert not np.any(_in_hole(centres[:, 0], centres[:, 1]))
    # every triangle of the full mesh with all three vertices kept survives: the area lost is
    # the hole plus at most one ring of cells around it (independent of the mask's rule)
    a, b = HOLE
    cell = max(1 / (M - 1), 1 / (N - 1))
    assert (b - a) ** 2 <= full.area - mesh.area <= (b - a + 4 * cell) ** 2
    assert len(mesh.vertices) == len(np.unique(mesh.faces))  # no unused vertex left
    with pytest.raises(ValueError, match=r"mask: expected shape \(24, 20\)"):
        io.tessellate(plate.surface, M, N, mask=mask.T)
    with pytest.raises(TypeError, match="mask: expected booleans"):
        io.tessellate(plate.surface, M, N, mask=mask.astype(float))


def test_a_trimmed_face_saved_as_a_mesh_keeps_its_hole(tmp_path):
    import trimesh

    plate = _plate()
    path = io.save(plate, tmp_path / "plate.stl", m=M, n=N)
    mesh = trimesh.load(str(path))
    centres = mesh.triangles_center
    assert len(mesh.faces) > 0 and not np.any(_in_hole(centres[:, 0], centres[:, 1]))
