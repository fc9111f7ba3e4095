"""`mss.Body`, `mss.Scene`, `simulate_scene`: deformable bodies pushing on each other through
surface–surface contact — momentum, action = reaction (tools included), a body at rest carrying
its weight, prescribed motion, gradients against central differences, and bad input.

The shells are 0.1 m plates of 8 × 8 × 2 nodes (one compiled shape for the module); the volume
bodies 1 cm jelly spheres of 5 × 5 × 5 VSOFM nodes.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide, mss, shapes

PLATE = shapes.plate(5, 5, size=0.1)
SHAPE = (8, 8, 2)
K, C = 200.0, 0.5


@functools.cache
def _pair():
    """Plate `a` (surface z = 0, normal +z, shell below) and plate `b` facing it 2 mm above
    (normal −z, shell above)."""
    a = mss.Body.from_surface(PLATE, SHAPE, mss.JELLY, thickness=0.01)
    flipped = PLATE.with_ctrl(PLATE.ctrl[:, ::-1] + jnp.array([0.0, 0.0, 0.002])[None, None])
    b = mss.Body.from_surface(flipped, SHAPE, mss.JELLY, thickness=0.01)
    return a, b


BALL = shapes.sphere(0.01)


@functools.cache
def _balls():
    """Two jelly spheres (VSOFM volume bodies), `b` 0.5 mm above `a`."""
    a = mss.Body.from_surface(BALL, (5, 5, 5), mss.JELLY)
    b = mss.Body.from_surface(
        BALL.with_ctrl(BALL.ctrl + jnp.array([0.0, 0.0, 0.0205])[None, None]), (5, 5, 5), mss.JELLY
    )
    return a, b


def _with_velocity(states, speeds):
    return tuple(mss.State(s.position, s.velocity.at[:, 2].set(w)) for s, w in zip(states, speeds))


def _momentum(scene, states):
    return sum(np.asarray(s.velocity * b.lattice.mass[:, None]).sum(0) for s, b in zip(states, scene.bodies))


def test_body_is_a_shell_of_the_surface():
    a, _ = _pair()
    grid = np.asarray(a.lattice.rest_positions).reshape(SHAPE + (3,))
    np.testing.assert_allclose(
        grid[..., -1, :], np.asarray(PLATE.blending(8, 8).points(PLATE.ctrl)), atol=1e-15
    )
    np.testing.assert_allclose(grid[..., 0, 2], -0.01, atol=1e-15)
    np.testing.assert_allclose(a.coupling.grid(a.lattice.rest_positions), grid[..., -1, :], atol=0)
    mass = float(np.sum(a.lattice.mass))
    np.testing.assert_allclose(mass, float(mss.JELLY.density) * 0.1 * 0.1 * 0.01, rtol=1e-9)


def test_with_ctrl_rebuilds_the_shell_from_a_new_net_differentiably():
    """`Body.with_ctrl`: the same net gives the same body; a net moved rigidly moves every node
    and keeps every rest length; a bumped net is the shell `from_surface` builds from it (nodes
    and rest lengths); its derivative equals a central difference; a volume body is refused."""
    a, _ = _pair()
    same = a.with_ctrl(PLATE.ctrl)
    np.testing.assert_allclose(same.lattice.rest_positions, a.lattice.rest_positions, atol=1e-15)
    shift = jnp.array([0.01, -0.02, 0.03])
    moved = a.with_ctrl(PLATE.ctrl + shift[None, None])
    np.testing.assert_allclose(
        moved.lattice.rest_positions, a.lattice.rest_positions + shift[None], atol=1e-15
    )
    np.testing.assert_allclose(moved.lattice.rest_length, a.lattice.rest_length, rtol=1e-12)
    bump = jnp.zeros(PLATE.ctrl.shape).at[2:4, 2:4, 2].set(0.01)
    rebuilt = mss.Body.from_surface(PLATE.with_ctrl(PLATE.ctrl + bump), SHAPE, mss.JELLY, thickness=0.01)
    bumped = a.with_ctrl(PLATE.ctrl + bump)
    np.testing.assert_allclose(bumped.lattice.rest_positions, rebuilt.lattice.rest_positions, atol=1e-14)
    np.testing.assert_allclose(bumped.lattice.rest_length, rebuilt.lattice.rest_length, atol=1e-14)

    def spread(h):  # the summed rest lengths of the shell whose net is bumped by h
        return jnp.sum(a.with_ctrl(PLATE.ctrl + h * bump).lattice.rest_length)

    tangent = jax.jvp(spread, (0.5,), (1.0,))[1]
    central = (spread(0.5 + 1e-5) - spread(0.5 - 1e-5)) / 2e-5
    assert float(tangent) == pytest.approx(float(central), rel=1e-7) and abs(float(tangent)) > 1e-3
    with pytest.raises(ValueError, match="ctrl: expected a control net of shape"):
        a.with_ctrl(PLATE.ctrl[:3])
    with pytest.raises(ValueError, match="self: expected a shell body"):
        _balls()[0].with_ctrl(BALL.ctrl)


def test_volume_body_embeds_its_closed_surface():
    """A closed surface's body: a VSOFM lattice inside it, the surface's samples carried by
    trilinear weights (summing to 1) that reproduce them at rest, the refit giving the net back,
    the poles kept collapsed, and the mass that of the lattice's volume (a sphere's 4/3 π r³
    within the lattice's chord error)."""
    a, _ = _balls()
    rest = a.lattice.rest_positions
    samples = a.coupling.blending.points(BALL.ctrl)
    assert a.coupling.node_map.shape == (10, 10, 8) and a.lattice.grid_shape == (5, 5, 5)
    np.testing.assert_allclose(a.coupling.grid(rest), samples, atol=1e-14)
    np.testing.assert_allclose(np.sum(a.coupling.weights, -1), 1.0, atol=1e-12)
    np.testing.assert_allclose(a.coupling.ctrl(rest), BALL.ctrl, atol=1e-13)
    assert a.coupling.poles == (True, True, False, False)
    deformed = a.coupling.ctrl(rest + 1e-4 * jnp.sin(1e3 * rest))
    assert float(jnp.ptp(deformed[0], 0).max()) == 0.0 and float(jnp.ptp(deformed[-1], 0).max()) == 0.0
    ball = 4.0 / 3.0 * np.pi * 0.01**3 * float(mss.JELLY.density)
    np.testing.assert_allclose(float(jnp.sum(a.lattice.mass)), ball, rtol=0.15)
    with pytest.raises(ValueError, match="coupling"):
        a.coupling.nodes(BALL.ctrl, rest)


def test_volume_bodies_bounce_conserving_momentum_without_gaining_energy():
    """Two jelly spheres meet pole to pole at ±0.1 m/s without gravity: Σ m v stays at its
    start to 1e-9 of Σ |m v|, the scene's energy never rises above the start (the jelly's own
    damping only takes), and both turn round."""
    a, b = _balls()
    scene = mss.Scene((a, b), contact=collide.DistributedSprings(K))
    start = _with_velocity(mss.scene_init(scene), (0.1, -0.1))
    dt = 0.5 * float(mss.scene_stable_dt(scene))
    assert dt < 0.5 * float(mss.stable_dt(a.lattice, K))  # nodes carrying several samples
    states, energies = start, [sum(mss.scene_energy(scene, start))]
    for _ in range(5):
        states = mss.simulate_scene(scene, states, dt, 200)
        energies.append(sum(mss.scene_energy(scene, states)))
    scale = sum(
        np.abs(np.asarray(s.velocity * bd.lattice.mass[:, None])).sum() for s, bd in zip(start, scene.bodies)
    )
    np.testing.assert_allclose(_momentum(scene, states), _momentum(scene, start), atol=1e-9 * scale)
    energies = np.asarray(energies)
    assert np.all(energies <= energies[0] * (1 + 1e-6)), energies / energies[0]
    assert float(states[0].velocity[:, 2].mean()) < 0 < float(states[1].velocity[:, 2].mean())


def test_head_on_collision_conserves_momentum_bounces_and_loses_energy():
    """Two equal shells meet at ±0.5 m/s without gravity, the contact damped: Σ m v stays 0 to
    1e-9 of Σ |m v|, the contact turns both round, and the scene's energy (kinetic + springs +
    contact springs) at every 5th step never exceeds the start's and ends lower."""
    a, b = _pair()
    scene = mss.Scene((a, b), contact=collide.DistributedSprings(K, C))
    start = _with_velocity(mss.scene_init(scene), (0.5, -0.5))
    dt = 0.5 * float(mss.scene_stable_dt(scene))
    states, energies = start, [sum(mss.scene_energy(scene, start))]
    for _ in range(10):
        states = mss.simulate_scene(scene, states, dt, 5)
        energies.append(sum(mss.scene_energy(scene, states)))
    scale = sum(
        np.abs(np.asarray(s.velocity * bd.lattice.mass[:, None])).sum() for s, bd in zip(start, scene.bodies)
    )
    np.testing.assert_allclose(_momentum(scene, states), 0, atol=1e-9 * scale)
    assert float(states[0].velocity[:, 2].mean()) < 0 < float(states[1].velocity[:, 2].mean())
    energies = np.asarray(energies)
    assert np.all(energies <= energies[0] * (1 + 1e-6)), energies / energies[0]
    assert energies[-1] < 0.99 * energies[0]


def test_action_equals_reaction_with_a_tool():
    """Bodies pressed together and a sphere pushed into one: the nodes' contact forces plus the
    tool's reaction sum to zero."""
    a, b = _pair()
    ball = collide.Sphere(jnp.array([0.3 / 7, 0.3 / 7, 0.015]), 0.01)  # above node (3, 3)
    scene = mss.Scene((a, b), tools=(ball,), contact=collide.DistributedSprings(K, C))
    states = mss.scene_init(scene)
    pressed = (
        states[0],
        mss.State(states[1].position - jnp.array([0.0, 0.0, 0.004])[None], states[1].velocity),
    )
    pressed = _with_velocity(pressed, (0.1, -0.2))
    forces = mss.scene_contact_forces(scene, pressed)
    reactions = mss.tool_reactions(scene, pressed)
    assert float(jnp.abs(forces[0]).sum()) > 0 and float(jnp.abs(reactions).sum()) > 0
    total = sum(np.sum(f, 0) for f in forces) + np.sum(reactions, 0)
    scale = sum(float(jnp.abs(f).sum()) for f in forces)
    np.testing.assert_allclose(total, 0, atol=1e-12 * scale)


def test_body_resting_on_a_table_carries_its_weight():
    """A plate shell settles on a rigid plane under gravity: the contact force equals its weight
    within 1 %."""
    a, _ = _pair()
    table = collide.Plane(jnp.array([0.0, 0.0, -0.0105]), jnp.array([0.0, 0.0, 1.0]))
    g = 9.81
    scene = mss.Scene(
        (a,), tools=(table,), gravity=jnp.array([0.0, 0.0, -g]), contact=collide.DistributedSprings(K, C)
    )
    dt = 0.5 * float(mss.stable_dt(a.lattice, K, C))
    end = mss.simulate_scene(scene, mss.scene_init(scene), dt, 1500)
    weight = float(np.sum(a.lattice.mass)) * g
    lift = float(np.sum(mss.scene_contact_forces(scene, end)[0][:, 2]))
    np.testing.assert_allclose(lift, weight, rtol=0.01)
    np.testing.assert_allclose(-float(mss.tool_reactions(scene, end)[0, 2]), weight, rtol=0.01)


def test_body_resting_on_another_body_carries_its_weight():
    """Shell `b` settles under gravity on shell `a`, every node of `a` held: the contact force
    on `b` equals its weight within 1 %, the force on `a` is its reaction, and no sample of `b`
    is deeper in `a` than the contact springs' static compression (weight / (k · samples))."""
    _, b = _pair()
    held = mss.Body.from_surface(
        PLATE, SHAPE, mss.JELLY, thickness=0.01, fixed=lambda x: np.ones(len(x), bool)
    )
    g = 9.81
    scene = mss.Scene((held, b), gravity=jnp.array([0.0, 0.0, -g]), contact=collide.DistributedSprings(K, C))
    dt = 0.5 * float(mss.scene_stable_dt(scene))
    end = mss.simulate_scene(scene, mss.scene_init(scene), dt, 1500)
    weight = float(np.sum(b.lattice.mass)) * g
    forces = mss.scene_contact_forces(scene, end)
    np.testing.assert_allclose(float(np.sum(forces[1][:, 2])), weight, rtol=0.01)
    np.testing.assert_allclose(float(np.sum(forces[0][:, 2])), -weight, rtol=0.01)
    surfaces = [(bd.coupling.blending, bd.coupling.ctrl(st.position)) for bd, st in zip(scene.bodies, end)]
    _, b_in_a = collide.surface_penetration(*surfaces[0], *surfaces[1], reach=scene.reach)
    assert int(b_in_a.mask.sum()) > 0
    assert float(b_in_a.depth.max()) < 3 * weight / (K * 64)


def test_a_steel_body_stepped_implicitly_carries_a_jelly():
    """A jelly shell settles on a steel cantilever (one edge held) that steps implicitly (its
    springs by backward Euler, the contact explicitly): the step is set by the jelly and the
    contact, hundreds of times the steel's explicit limit; the contact carries the jelly's weight
    within 1 %, the steel bends by micrometres, and the progress reports reach `n_steps`."""
    _, b = _pair()
    steel = mss.Body.from_surface(PLATE, SHAPE, mss.STEEL, thickness=0.01, fixed=lambda x: x[:, 0] < 1e-9)
    g = 9.81
    scene = mss.Scene((steel, b), gravity=jnp.array([0.0, 0.0, -g]), contact=collide.DistributedSprings(K, C))
    methods = ("implicit", "semi_implicit")
    dt = 0.5 * float(mss.scene_stable_dt(scene, methods))
    assert dt > 100 * float(mss.scene_stable_dt(scene))
    done = []
    end = mss.simulate_scene(
        scene, mss.scene_init(scene), dt, 1500, method=methods, progress=lambda k, n: done.append((k, n))
    )
    assert done[-1] == (1500, 1500) and len(done) > 1
    weight = float(np.sum(b.lattice.mass)) * g
    np.testing.assert_allclose(
        float(np.sum(mss.scene_contact_forces(scene, end)[1][:, 2])), weight, rtol=0.01
    )
    sag = np.abs(np.asarray(end[0].position - steel.lattice.rest_positions)).max()
    assert 0 < sag < 1e-5


def test_motion_moves_the_fixed_nodes():
    """A held edge follows a prescribed translation `T(t) = (0, 0, w t)` with velocity w."""
    held = mss.Body.from_surface(PLATE, SHAPE, mss.JELLY, thickness=0.01, fixed=lambda x: x[:, 0] < 1e-9)
    scene = mss.Scene((held,))
    w, dt, n = 0.2, 1e-3, 30
    motion = (lambda t: (jnp.eye(3), jnp.array([0.0, 0.0, w]) * t),)
    end = mss.simulate_scene(scene, mss.scene_init(scene), dt, n, motion=motion)
    fixed = np.asarray(held.lattice.fixed)
    assert fixed.sum() == 16
    want = np.asarray(held.lattice.rest_positions)[fixed] + [0.0, 0.0, w * n * dt]
    np.testing.assert_allclose(np.asarray(end[0].position)[fixed], want, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(end[0].velocity)[fixed][:, 2], w, rtol=1e-12)


def test_gradient_through_a_contact_rollout_matches_central_differences():
    """d(final height of b)/d(approach speed) through contact and both lattices.

    Plate b is moved 1 mm sideways: with `_pair`'s edges exactly above each other, the feet of
    b's edge samples lie exactly on a's open boundary, where whether they count is decided by
    rounding (a 23 µm jump in the final height between speeds 2e-6 apart), and a central
    difference across such a jump measures the jump, not the derivative."""
    a, _ = _pair()
    flipped = PLATE.with_ctrl(PLATE.ctrl[:, ::-1] + jnp.array([0.001, 0.001, 0.002])[None, None])
    b = mss.Body.from_surface(flipped, SHAPE, mss.JELLY, thickness=0.01)
    scene = mss.Scene((a, b), contact=collide.DistributedSprings(K, C))
    start = mss.scene_init(scene)
    dt = 0.5 * float(mss.stable_dt(a.lattice, K, C))

    def height(speed):
        end = mss.simulate_scene(scene, _with_velocity(start, (speed, -speed)), dt, 25)
        return jnp.mean(end[1].position[:, 2])

    # one program (`jax.grad`'s reverse pass and the heights it starts from) for the derivative
    # and the central difference's heights: the rollout's direct call is the other tests'
    value_and_grad = jax.jit(jax.value_and_grad(height))
    speed, h = 0.4, 1e-5
    grad = float(value_and_grad(speed)[1])
    fd = (float(value_and_grad(speed + h)[0]) - float(value_and_grad(speed - h)[0])) / (2 * h)
    assert abs(fd) > 1e-4
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


def test_bad_input_names_the_argument():
    a, b = _pair()
    scene = mss.Scene((a, b))
    states = mss.scene_init(scene)
    with pytest.raises(TypeError, match="surface"):
        mss.Body.from_surface("plate", SHAPE, mss.JELLY, thickness=0.01)
    with pytest.raises(ValueError, match="shape"):
        mss.Body.from_surface(PLATE, (8, 8), mss.JELLY, thickness=0.01)
    with pytest.raises(ValueError, match="thickness"):
        mss.Body.from_surface(PLATE, SHAPE, mss.JELLY)
    with pytest.raises(ValueError, match="thickness"):
        mss.Body.from_surface(PLATE, SHAPE, mss.JELLY, thickness=-1.0)
    with pytest.raises(ValueError, match="fixed"):
        mss.Body.from_surface(PLATE, SHAPE, mss.JELLY, thickness=0.01, fixed=np.zeros(3, bool))
    with pytest.raises(ValueError, match="surface"):  # a closed surface is a volume, not a shell
        mss.Body.from_surface(BALL, (5, 5, 5), mss.JELLY, thickness=0.01)
    with pytest.raises(ValueError, match="samples"):  # a shell's samples are its nodes
        mss.Body.from_surface(PLATE, SHAPE, mss.JELLY, thickness=0.01, samples=(4, 4))
    with pytest.raises(ValueError, match="samples"):
        mss.Body.from_surface(BALL, (5, 5, 5), mss.JELLY, samples=(3,))
    with pytest.raises(ValueError, match="samples"):  # fewer samples than control points
        mss.Body.from_surface(BALL, (5, 5, 5), mss.JELLY, samples=(4, 4))
    with pytest.raises(TypeError, match=r"bodies\[1\]"):
        mss.Scene((a, "b"))
    with pytest.raises(TypeError, match="contact"):
        mss.Scene((a,), contact=mss.Penalty(1.0))
    with pytest.raises(ValueError, match="states"):
        mss.simulate_scene(scene, states[:1], 1e-4, 2)
    with pytest.raises(ValueError, match="dt"):  # 5 steps: the head-on test's program
        mss.simulate_scene(scene, states, 1.0, 5)
    damped = mss.Scene((a, b), contact=collide.DistributedSprings(K, 10.0))
    with pytest.raises(ValueError, match="dt"):  # the contact damper limits the step too
        mss.simulate_scene(damped, states, float(mss.stable_dt(a.lattice, K)), 5)
    with pytest.raises(ValueError, match="motion"):
        mss.simulate_scene(scene, states, 1e-4, 2, motion=(None,))
    with pytest.raises(ValueError, match="method"):
        mss.simulate_scene(scene, states, 1e-4, 2, method=("implicit",))
    with pytest.raises(ValueError, match="method"):
        mss.scene_stable_dt(scene, "backward")
    with pytest.raises(TypeError, match="progress"):
        mss.simulate_scene(scene, states, 1e-4, 2, progress=3)
    with pytest.raises(ValueError, match="gravity"):
        mss.Scene((a,), gravity=[0.0, jnp.nan, 0.0])
