"""The haptic physics tick (`SculptModel`'s lean kernel) against the chain of public, checked
`bsjax.mss` calls it replaces, and `mss.edge_lengths` against the edge-list gather."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import _safe, collide, mss
from bsjax.device._physics import SculptModel
from bsjax.mss._forces import spring_forces
from tests.helpers import check_grad, raises_both


def _reference_tick(model, carry, inputs, sphere):
    """The tick written with the public checked calls: `mss.coupled_step` on every substep (refit
    each time), the proxy grid's `points`/`normals`, `collide.contacts`, rest lengths by gather."""
    state, rest, rest_seam = carry
    centre, axes, rot = inputs[0:3], inputs[3:6], inputs[6:15].reshape(3, 3)
    pressing, settle = inputs[15], inputs[16] > 0
    tool = collide.Sphere(centre, axes[0]) if sphere else collide.Ellipsoid(centre, axes, rot)
    if settle:
        x = state.position
        e = model.lattice.edges
        rest = _safe.norm(x[e[:, 0]] - x[e[:, 1]])
        if model.seam is not None:
            e = model.seam.edges
            rest_seam = _safe.norm(x[e[:, 0]] - x[e[:, 1]])
    tools = (tool,) if pressing > 0 else ()
    contact = mss.Penalty(model.tool_stiffness * pressing, 0.0)
    for _ in range(model.substeps):
        seam = spring_forces(model.seam, state.position, state.velocity, rest_seam)
        state, ctrl = mss.coupled_step(
            model.lattice,
            model.coupling,
            state,
            model.dt,
            tools,
            contact,
            external_force=seam,
            rest_length=rest,
        )
    x = state.position
    f = mss.tool_forces(tools, x, jnp.zeros_like(x), contact.stiffness) if tools else x * 0
    reaction = _safe.norm(jnp.sum(f, axis=0))
    pts = model.dense.points(ctrl).reshape(-1, 3)
    nrm = model.sign * model.dense.normals(ctrl).reshape(-1, 3)
    k = jnp.argmin(jnp.sum((pts - centre[None]) ** 2, axis=-1))
    q, nq = pts[k], nrm[k]
    support = axes[0] if sphere else _safe.norm(axes * (nq @ rot))
    hits = collide.contacts(model.dense, ctrl, tool, method="dense")
    spring = model.sign * collide.contact_force(hits, model.contact_stiffness)
    out = jnp.concatenate([q, nq, support[None], reaction[None], spring, hits.hit.astype(x.dtype)[None]])
    return (state, rest, rest_seam), ctrl, out


@pytest.fixture(scope="module")
def small_model():
    return SculptModel(grid=(8, 9), layers=4, proxy_grid=12, fixed_layers=1)


@pytest.mark.parametrize("sphere", [True, False])
def test_tick_matches_the_checked_chain(small_model, sphere):
    """Press (tool in contact), hold, release (plastic set), free: state, control net and proxy
    data equal the public chain's to 1e-12 at every tick."""
    model = small_model
    model.set_tool(radius=0.3) if sphere else model.set_tool(axes=(0.35, 0.25, 0.2))
    q = np.array([0.9, 0.1, 0.2, 0.1])
    q = q / np.linalg.norm(q)
    carry = ref = model._initial
    hit_seen = False
    for step, (x, pressed, settle) in enumerate(
        [(0.75, True, False), (0.65, True, False), (0.65, False, True), (0.7, False, False)]
    ):
        inputs = model._inputs(np.array([x, 0.05, 0.1]), q, pressed, settle)
        carry, ctrl, out = model._tick(carry, inputs, sphere)
        ref, ref_ctrl, ref_out = _reference_tick(model, ref, jnp.asarray(inputs), sphere)
        for a, b in zip(jax.tree.leaves((carry, ctrl)), jax.tree.leaves((ref, ref_ctrl))):
            np.testing.assert_allclose(
                np.asarray(a), np.asarray(b), rtol=0, atol=1e-12, err_msg=f"tick {step}"
            )
        np.testing.assert_allclose(np.asarray(out[:-1]), np.asarray(ref_out), rtol=0, atol=1e-12)
        assert out[-1] == 1.0  # finite
        hit_seen |= bool(ref_out[-1] > 0)
        if pressed:  # the tool pushes the nodes: the reaction is not zero
            assert ref_out[7] > 0
    assert hit_seen
    # the release tick set the shape: rest lengths moved away from the initial ones
    assert float(jnp.max(jnp.abs(carry[1] - model._initial[1]))) > 1e-6


def _hex(shape=(3, 4, 2), seed=0):
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.arange(float(n)) for n in shape], indexing="ij"), -1)
    lat = mss.hex_lattice(g, 10.0, 0.1, 0.01)
    x = jnp.asarray(g.reshape(-1, 3) + 0.1 * rng.standard_normal((lat.n_nodes, 3)))
    return lat, x


@pytest.mark.parametrize("shape", [(3, 4, 2), (2, 2, 2), (4, 1, 3)])
def test_edge_lengths_dense_equals_gather(shape):
    lat, x = _hex(shape)
    e = np.asarray(lat.edges)
    expected = np.linalg.norm(np.asarray(x)[e[:, 0]] - np.asarray(x)[e[:, 1]], axis=-1)
    np.testing.assert_allclose(np.asarray(mss.edge_lengths(lat, x)), expected, rtol=1e-14, atol=0)
    plain = mss.Lattice(lat.rest_positions, lat.edges, 10.0, 0.1, 0.01)  # edge list, no grid_shape
    np.testing.assert_allclose(np.asarray(mss.edge_lengths(plain, x)), expected, rtol=1e-14, atol=0)
    np.testing.assert_allclose(np.asarray(jax.jit(mss.edge_lengths)(lat, x)), expected, rtol=1e-14)
    # the rest shape's lengths are the lattice's rest lengths
    np.testing.assert_allclose(mss.edge_lengths(lat, lat.rest_positions), lat.rest_length, rtol=1e-14)


def test_edge_lengths_vmap_grad_and_degenerate():
    lat, x = _hex()
    batch = jnp.stack([x, 2.0 * x])
    out = jax.vmap(lambda p: mss.edge_lengths(lat, p))(batch)
    np.testing.assert_allclose(out[1], 2.0 * out[0], rtol=1e-14)
    w = jnp.asarray(np.random.default_rng(1).random(lat.n_edges))
    check_grad(lambda p: jnp.sum(w * mss.edge_lengths(lat, p.reshape(-1, 3)) ** 3), x.ravel())
    # all nodes at one point: zero lengths with a finite gradient
    same = jnp.zeros_like(x)
    assert float(jnp.max(mss.edge_lengths(lat, same))) == 0.0
    g = jax.grad(lambda p: jnp.sum(mss.edge_lengths(lat, p)))(same)
    assert bool(jnp.all(jnp.isfinite(g)))


def test_edge_lengths_errors():
    lat, x = _hex()
    raises_both(lambda p: mss.edge_lengths(lat, p), x.at[3, 1].set(jnp.nan), match="x: expected")
    raises_both(lambda p: mss.edge_lengths(lat, p), x[:-1], match=r"x: expected node positions of shape")


def test_seam_forces_by_slices_equal_the_edge_list(small_model):
    """The seam springs of a body closed in v, summed by slices, equal `spring_forces` of
    the seam's edge-list lattice (non-square grid, stretched rest lengths, random velocities)."""
    model = small_model
    rng = np.random.default_rng(0)
    x = model._initial[0].position + 0.01 * rng.standard_normal((model.n_nodes, 3))
    v = jnp.asarray(rng.standard_normal((model.n_nodes, 3)))
    rest = model.seam.rest_length * (1 + 0.1 * rng.random(model.seam.n_edges))
    expected = spring_forces(model.seam, x, v, rest)
    got = jax.jit(model._seam_forces)(x, v, rest)
    np.testing.assert_allclose(np.asarray(got), np.asarray(expected), rtol=0, atol=1e-13)
    assert float(jnp.max(jnp.abs(expected))) > 0.1
