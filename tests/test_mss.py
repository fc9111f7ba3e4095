"""Mass-spring-damper physics: closed forms, direct linear solves, invariants, errors, gradients."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide, mss, shapes
from bsjax.mss._forces import spring_forces
from bsjax.mss._lattice import hex_volume
from tests.helpers import check_grad, raises_both

GRAVITY = jnp.array([0.0, 0.0, -9.81])

# Jitted once per lattice structure and reused across tests (compile time dominates on 2 cores).
simulate = jax.jit(
    mss.simulate,
    static_argnames=("n_steps", "method", "cg_iterations", "checkpoint_every", "check_stability"),
)
trajectory = jax.jit(mss.trajectory, static_argnames=("n_steps", "save_every", "method", "check_stability"))
relax = jax.jit(mss.relax, static_argnames=("max_steps", "check_every", "method", "cg_iterations"))


def grid(shape, spacing=1.0):
    g = np.stack(np.meshgrid(*[np.arange(float(s)) for s in shape], indexing="ij"), -1)
    return g * spacing


def one_spring(k=100.0, c=0.0, m=0.5, rest=1.0, free_both=False):
    x = np.array([[0.0, 0, 0], [rest, 0, 0]])
    fixed = np.array([not free_both, False])
    return mss.Lattice(x, np.array([[0, 1]]), k, c, m, fixed)


def oscillator(t, x0, k, c, m):
    """Closed form of m x'' + c x' + k x = 0, x(0) = x0, x'(0) = 0 (independent reference)."""
    w0 = np.sqrt(k / m)
    zeta = c / (2 * np.sqrt(k * m))
    if zeta < 1:
        wd = w0 * np.sqrt(1 - zeta**2)
        return x0 * np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta * w0 / wd * np.sin(wd * t))
    if zeta == 1:
        return x0 * np.exp(-w0 * t) * (1 + w0 * t)
    s = w0 * np.sqrt(zeta**2 - 1)
    r1, r2 = -zeta * w0 + s, -zeta * w0 - s
    a = x0 * r2 / (r2 - r1)
    return a * np.exp(r1 * t) + (x0 - a) * np.exp(r2 * t)


def test_damped_spring_matches_closed_form():
    """Under-, critically and over-damped (and undamped) springs, one vmapped rollout."""
    k, m, x0 = 100.0, 0.5, 0.05
    zetas = np.array([0.0, 0.2, 1.0, 2.5])
    start = np.array([[0.0, 0, 0], [1.0 + x0, 0, 0]])

    def run(c):
        lat = one_spring(k, c, m)
        return mss.trajectory(lat, mss.init(lat, start), 1e-4, 20000, save_every=100)[1].position

    saved = jax.jit(jax.vmap(run))(jnp.asarray(2 * zetas * np.sqrt(k * m)))
    t = 1e-4 * 100 * np.arange(1, 201)
    for zeta, pos in zip(zetas, np.asarray(saved)):
        # symplectic Euler advances a phase error O(ω dt); tolerance 1 % of the amplitude
        ref = oscillator(t, x0, k, 2 * zeta * np.sqrt(k * m), m)
        np.testing.assert_allclose(pos[:, 1, 0] - 1.0, ref, atol=1e-2 * x0)
        assert np.all(pos[:, 0] == 0)


def test_ratio_and_frequency_formulas():
    k, m, zeta = 250.0, 0.1, 0.3
    d = mss.spring_damping(mss.Material(1.0, 1.0, zeta), k, m)
    assert np.isclose(float(mss.damping_ratio(d, k, m)), zeta)
    assert np.isclose(float(mss.natural_frequency(k, m)), 50.0)
    assert np.isclose(float(mss.spring_stiffness(mss.PLASTICINE, 0.01, 1e-4)), 13e6 * 1e-4 / 0.01)


def plain_hex(shape, stiffness, damping, mass, fixed=None, node_damping=0.0, spacing=1.0):
    """A hexahedral lattice on the edge-list (segment_sum) kernel: smaller programs, faster compiles."""
    return mss.Lattice(
        grid(shape, spacing).reshape(-1, 3),
        mss.hex_edges(shape),
        stiffness,
        damping,
        mass,
        fixed,
        node_damping=node_damping,
    )


def perturbed_hex(shape=(3, 3, 3), seed=0, scale=0.05):
    rng = np.random.default_rng(seed)
    g = grid(shape)
    return g + scale * rng.normal(size=g.shape)


def test_energy_conserved_without_damping():
    lat = plain_hex((3, 3, 2), 50.0, 0.0, 0.2)
    x = perturbed_hex((3, 3, 2), scale=0.08).reshape(-1, 3)
    state = mss.init(lat, x)
    dt = 0.1 * float(mss.stable_dt(lat))
    _, saved = trajectory(lat, state, dt, n_steps=4000, save_every=20)
    e = np.asarray(sum(jax.jit(jax.vmap(lambda s: mss.energy(lat, s)))(saved)))
    e0 = sum(float(v) for v in mss.energy(lat, state))
    assert e0 > 0
    # symplectic Euler: energy oscillates with amplitude O(dt) but does not drift
    assert np.max(np.abs(e - e0)) / e0 < 0.05
    assert abs(e[-50:].mean() - e[:50].mean()) / e0 < 0.01


def linear_stiffness(lat):
    """Assembled linearised stiffness Σ k e eᵀ at rest (numpy reference)."""
    x = np.asarray(lat.rest_positions)
    n = len(x)
    kmat = np.zeros((3 * n, 3 * n))
    for (i, j), k in zip(np.asarray(lat.edges), np.asarray(lat.stiffness)):
        e = (x[i] - x[j]) / np.linalg.norm(x[i] - x[j])
        b = k * np.outer(e, e)
        for a, bb, s in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
            kmat[3 * a : 3 * a + 3, 3 * bb : 3 * bb + 3] += s * b
    return kmat


def test_clamped_bar_static_deflection_matches_linear_solve():
    g = grid((5, 2, 2))
    fixed = (g[..., 0] == 0).reshape(-1)
    lat = plain_hex((5, 2, 2), 1e4, 20.0, 0.01, fixed, node_damping=0.5)
    state, _, ok = relax(
        lat,
        mss.init(lat),
        0.02,
        gravity=GRAVITY,
        method="implicit",
        cg_iterations=60,
        tol=1e-16,
        max_steps=4000,
        check_every=20,
    )
    assert bool(ok)
    free = ~np.asarray(lat.fixed)
    dofs = np.repeat(free, 3)
    kmat = linear_stiffness(lat)[np.ix_(dofs, dofs)]
    f = (np.asarray(lat.mass)[:, None] * np.array([0, 0, -9.81])).reshape(-1)[dofs]
    u_ref = np.linalg.solve(kmat, f)
    u = (np.asarray(state.position) - np.asarray(lat.rest_positions)).reshape(-1)[dofs]
    assert np.abs(u_ref).max() > 1e-3  # a visible deflection
    np.testing.assert_allclose(u, u_ref, atol=2e-3 * np.abs(u_ref).max())


def test_fixed_nodes_never_move():
    # same structure and step count as the steel test below: the implicit rollout compiles once
    x = perturbed_hex((6, 3, 3))
    fixed = np.zeros(54, bool)
    fixed[[0, 5, 13, 26, 40]] = True
    lat = plain_hex((6, 3, 3), 80.0, 1.0, 0.1, fixed)
    rng = np.random.default_rng(1)
    force = jnp.asarray(rng.normal(size=(300, 54, 3)))
    state = mss.init(lat, x.reshape(-1, 3))
    for method in ("semi_implicit", "implicit"):
        out = simulate(
            lat,
            state,
            1e-3,
            n_steps=300,
            external_force=force,
            gravity=GRAVITY,
            method=method,
            cg_iterations=30,
        )
        assert np.array_equal(np.asarray(out.position)[fixed], x.reshape(-1, 3)[fixed])
        assert np.all(np.asarray(out.velocity)[fixed] == 0)
        assert not np.allclose(np.asarray(out.position)[~fixed], x.reshape(-1, 3)[~fixed])


def test_constant_force_converges_to_rest():
    g = grid((3, 3, 2))
    fixed = (g[..., 2] == 0).reshape(-1)
    lat = plain_hex((3, 3, 2), 100.0, 2.0, 0.05, fixed, node_damping=0.2)
    force = jnp.zeros((18, 3)).at[:, 0].set(0.5)
    state, steps, ok = relax(
        lat, mss.init(lat), 0.5 * float(mss.stable_dt(lat)), force, tol=1e-18, max_steps=200_000
    )
    assert bool(ok) and int(steps) < 200_000
    residual = mss.forces(lat, state, force)
    assert float(jnp.abs(jnp.where(lat.fixed[:, None], 0.0, residual)).max()) < 1e-6
    assert float(state.position[~fixed][:, 0].mean() - g.reshape(-1, 3)[~fixed][:, 0].mean()) > 1e-3


def test_stability_limit_is_tight_and_enforced():
    k, m = 400.0, 0.25
    lat = one_spring(k, 0.0, m, free_both=True)
    limit = float(mss.stable_dt(lat))
    assert np.isclose(limit, 2.0 / np.sqrt(2 * k / m))  # exact for one free spring
    start = mss.init(lat, np.array([[0.0, 0, 0], [1.1, 0, 0]]))
    ok = simulate(lat, start, 0.97 * limit, n_steps=2000, check_stability=False)
    assert float(jnp.abs(ok.position).max()) < 2.0
    bad = simulate(lat, start, 1.03 * limit, n_steps=2000, check_stability=False)
    assert not float(jnp.abs(bad.position).max()) < 2.0
    with pytest.raises(ValueError, match=r"dt: expected a time step <= mss\.stable_dt"):
        mss.simulate(lat, start, 1.03 * limit, 10)
    with pytest.raises(Exception, match="largest stable step"):
        jax.jit(lambda dt: mss.simulate(lat, start, dt, 10).position)(1.03 * limit).block_until_ready()


def test_implicit_is_stable_for_steel_at_1khz():
    g = grid((6, 3, 3), 0.01)
    fixed = (g[..., 0] == 0).reshape(-1)
    lat = mss.from_material(g.reshape(-1, 3), mss.hex_edges((6, 3, 3)), mss.STEEL, 0.05 * 0.02 * 0.02, fixed)
    assert float(mss.stable_dt(lat)) < 1e-5  # explicit would need > 100 steps per ms
    with pytest.raises(ValueError):
        mss.simulate(lat, mss.init(lat), 1e-3, 10)
    push = jnp.zeros((300, 54, 3)).at[:, -9:, 2].set(-50.0)
    out = simulate(
        lat,
        mss.init(lat),
        1e-3,
        n_steps=300,
        external_force=push,
        gravity=GRAVITY,
        method="implicit",
        cg_iterations=30,
    )
    u = np.asarray(out.position - lat.rest_positions)
    assert np.all(np.isfinite(u)) and np.abs(u).max() < 1e-4  # steel barely bends
    assert u[-9:, 2].mean() < 0  # but it bends the right way


def _steel_plate():
    g = grid((7, 3, 2), 0.01)
    fixed = (g[..., 0] == 0).reshape(-1)
    return mss.hex_lattice(g, material=mss.STEEL, fixed=jnp.asarray(fixed))


def test_linear_implicit_step_is_scipys_solve_of_the_rest_system():
    """One step of backward Euler linearised about the rest shape: `(M + hC + h²K₀) Δv = h f −
    h²K₀ v`, with K₀ and C assembled by scipy from the springs' rest directions and f the
    lattice's full force; bsjax's block Cholesky solve gives the same state."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from tests.oracles import lattice_stiffness

    lat = _steel_plate()
    rng = np.random.default_rng(4)
    free = ~np.asarray(lat.fixed)
    x = np.asarray(lat.rest_positions) + 1e-5 * rng.normal(size=(lat.n_nodes, 3)) * free[:, None]
    v = 1e-2 * rng.normal(size=(lat.n_nodes, 3)) * free[:, None]
    state, h = mss.State(jnp.asarray(x), jnp.asarray(v)), 1e-3
    out = mss.simulate(lat, state, h, 1, gravity=GRAVITY, method="linear_implicit")
    stiffness, damping = lattice_stiffness(lat), lattice_stiffness(lat, lat.damping)
    mass = np.repeat(np.asarray(lat.mass) + h * np.asarray(lat.node_damping), 3)
    system = sp.diags(mass) + h * damping + h * h * stiffness
    f = np.asarray(mss.forces(lat, state, gravity=GRAVITY)).reshape(-1)
    rhs = h * f - h * h * (stiffness @ v.reshape(-1))
    keep = np.repeat(free, 3)
    dv = np.zeros(3 * lat.n_nodes)
    dv[keep] = spla.spsolve(system[keep][:, keep].tocsc(), rhs[keep])
    v1 = v + dv.reshape(-1, 3)
    np.testing.assert_allclose(out.velocity, v1, rtol=1e-9, atol=1e-12 * np.abs(v1).max())
    np.testing.assert_allclose(out.position, x + h * v1, rtol=0, atol=1e-15)


def test_linear_implicit_relaxes_to_the_linear_deflection_and_differentiates():
    """Steel at 1 kHz (100× its explicit limit): relaxed under a small tip load it sits at
    scipy's linear static deflection; forward-mode derivatives through 300 steps equal central
    differences (unrolled CG iterations' derivatives grow without bound on such a body)."""
    from tests.oracles import lattice_linear_deflection

    lat = _steel_plate()
    assert float(mss.stable_dt(lat)) < 1e-5
    tip = np.asarray(lat.rest_positions)[:, 0] > 0.055
    load = jnp.zeros((lat.n_nodes, 3)).at[tip, 2].set(-0.5)
    rest, _, converged = mss.relax(lat, mss.init(lat), 1e-3, load, method="linear_implicit", tol=1e-16)
    want = lattice_linear_deflection(lat, load)
    assert bool(converged)
    np.testing.assert_allclose(rest.position - lat.rest_positions, want, atol=1e-3 * np.abs(want).max())

    def tip_height(scale):
        out = mss.simulate(lat, mss.init(lat), 1e-3, 300, load * scale, method="linear_implicit")
        return out.position[tip, 2].mean()

    tangent = jax.jvp(tip_height, (1.0,), (1.0,))[1]
    central = (tip_height(1.0 + 1e-4) - tip_height(1.0 - 1e-4)) / 2e-4
    assert float(tangent) == pytest.approx(float(central), rel=1e-6)
    with pytest.raises(ValueError, match="method: expected 'linear_implicit' on a hexahedral grid"):
        plain = mss.Lattice(lat.rest_positions, lat.edges, lat.stiffness, lat.damping, lat.mass)
        mss.simulate(plain, mss.init(plain), 1e-3, 2, method="linear_implicit")


def test_grid_and_edge_list_kernels_agree():
    x = perturbed_hex((3, 4, 2)).reshape(-1, 3)
    v = np.random.default_rng(2).normal(size=x.shape)
    n_edges = len(mss.hex_edges((3, 4, 2)))
    k = np.linspace(1, 2, n_edges)
    lat = mss.hex_lattice(grid((3, 4, 2)), k, 0.3, 0.2)
    plain = mss.Lattice(lat.rest_positions, lat.edges, k, 0.3, 0.2)
    forces = jax.jit(spring_forces)
    np.testing.assert_allclose(forces(lat, x, v), forces(plain, x, v), atol=1e-12)
    # the grid kernel's own derivative rule (a custom JVP, transposed for reverse mode) against
    # plain autodiff of the edge-list kernel, forward and reverse, in x, v and the stiffness
    rng = np.random.default_rng(5)
    dx, dv, dk, w = (rng.normal(size=s) for s in (x.shape, x.shape, k.shape, x.shape))

    def derivatives(make):
        f = jax.jit(lambda x, v, k: spring_forces(make(k), x, v))
        tangent = jax.jvp(f, (x, v, k), (dx, dv, dk))[1]
        cotangents = jax.vjp(f, x, v, k)[1](jnp.asarray(w))
        return tangent, cotangents

    on_grid = derivatives(lambda k: mss.hex_lattice(grid((3, 4, 2)), k, 0.3, 0.2))
    on_edges = derivatives(lambda k: mss.Lattice(lat.rest_positions, lat.edges, k, 0.3, 0.2))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10), on_grid, on_edges)
    s = mss.State(jnp.asarray(x), jnp.asarray(v))
    implicit = jax.jit(mss.implicit_step)
    a = implicit(lat, s, 0.1, gravity=GRAVITY)
    b = implicit(plain, s, 0.1, gravity=GRAVITY)
    np.testing.assert_allclose(a.position, b.position, atol=1e-12)


def spring_force_reference(x, v, edges, rest, k, c):
    """Loop-based numpy reference of eqs. 5.11–5.13 with Voigt damping."""
    f = np.zeros_like(x)
    for (i, j), l0, kk, cc in zip(edges, rest, k, c):
        d = x[i] - x[j]
        e = d / np.linalg.norm(d)
        s = kk * (np.linalg.norm(d) - l0) * e + cc * np.dot(v[i] - v[j], e) * e
        f[i] -= s
        f[j] += s
    return f


def test_spring_forces_match_loop_reference_and_grad():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(7, 3))
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [6, 0], [0, 3]])
    k, c = rng.uniform(1, 5, 8), rng.uniform(0, 1, 8)
    lat = mss.Lattice(x + 0.1 * rng.normal(size=x.shape), edges, k, c, 1.0)
    v = rng.normal(size=x.shape)
    ref = spring_force_reference(x, v, edges, np.asarray(lat.rest_length), k, c)
    np.testing.assert_allclose(spring_forces(lat, x, v), ref, atol=1e-12)
    np.testing.assert_allclose(jax.jit(spring_forces)(lat, x, v), ref, atol=1e-12)
    check_grad(lambda y: jnp.sum(spring_forces(lat, y.reshape(7, 3), v) ** 2), x.reshape(-1))


def test_zero_length_spring_is_finite_with_finite_gradient():
    lat = mss.Lattice(np.zeros((2, 3)), np.array([[0, 1]]), 10.0, 1.0, 1.0)
    x = jnp.zeros((2, 3))
    f = spring_forces(lat, x, x)
    assert np.all(np.asarray(f) == 0)
    g = jax.grad(lambda y: jnp.sum(spring_forces(lat, y, y) ** 2))(x)
    assert np.all(np.isfinite(np.asarray(g)))


def test_vmap_over_materials():
    g = grid((3, 3, 2), 0.01)
    fixed = (g[..., 2] == 0).reshape(-1)
    mats = mss.Material(
        jnp.array([1e4, 3e4, 1e5]), jnp.array([1000.0, 1200.0, 900.0]), jnp.array([0.1, 0.5, 1.0])
    )

    def run(mat):
        lat = mss.from_material(g.reshape(-1, 3), mss.hex_edges((3, 3, 2)), mat, 0.02 * 0.02 * 0.01, fixed)
        return mss.simulate(lat, mss.init(lat), 1e-5, 300, gravity=GRAVITY, check_stability=False).position

    batched = jax.jit(jax.vmap(run))(mats)
    single = jax.jit(run)
    for b in range(3):
        one = single(jax.tree.map(lambda a: a[b], mats))
        np.testing.assert_allclose(batched[b], one, rtol=1e-10, atol=1e-14)
    sag = -np.asarray(batched[:, ~fixed, 2] - g.reshape(-1, 3)[None, ~fixed, 2]).mean(axis=1)
    assert sag[0] > sag[1] > sag[2] > 0  # stiffer sags less


def test_material_presets():
    assert float(mss.PLASTICINE.youngs_modulus) == 13e6 and float(mss.PLASTICINE.density) == 2500
    assert set(mss.PRESETS) >= {"plasticine", "steel", "jelly"}
    g = grid((3, 3, 3), 0.01)
    lat = mss.hex_lattice(g, material=mss.PLASTICINE)
    total_mass = float(jnp.sum(lat.mass))
    assert np.isclose(total_mass, 2500 * 0.02**3)
    assert np.isclose(float(jnp.sum(lat.stiffness * lat.rest_length**2)), 13e6 * 0.02**3)


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(mass=-1.0), "mass"),
        (dict(stiffness=np.array([1.0, -2.0])), "stiffness"),
        (dict(edges=np.array([[0, 1], [1, 3]])), r"edges: expected node indices in \[0, 3\)"),
        (dict(rest_positions=np.array([[0, 0, 0], [np.nan, 0, 0], [1, 1, 1.0]])), "rest_positions"),
        (dict(fixed=np.array([True, False])), "fixed"),
        (dict(edges=np.array([[0, 1], [2, 2]])), "self-loop"),
        (dict(damping=np.ones(5)), "damping"),
    ],
)
def test_bad_inputs(bad, match):
    args = dict(
        rest_positions=np.eye(3),
        edges=np.array([[0, 1], [1, 2]]),
        stiffness=1.0,
        damping=0.1,
        mass=1.0,
        fixed=None,
    )
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        mss.Lattice(**args)


def test_bad_simulate_inputs():
    lat = one_spring()
    s = mss.init(lat)
    with pytest.raises(ValueError, match="external_force"):
        mss.simulate(lat, s, 1e-4, 5, external_force=jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="method"):
        mss.simulate(lat, s, 1e-4, 5, method="rk4")
    with pytest.raises(ValueError, match="state.position"):
        mss.simulate(lat, mss.State(jnp.full((2, 3), jnp.nan), jnp.zeros((2, 3))), 1e-4, 5)
    with pytest.raises(ValueError, match="dt"):
        mss.simulate(lat, s, -1e-4, 5)


def test_sphere_tool_and_table_contact():
    g = grid((5, 5, 2), 0.1) + np.array([-0.2, -0.2, 0.0])
    lat = mss.Lattice(g.reshape(-1, 3), mss.hex_edges((5, 5, 2)), 200.0, 1.0, 0.01, node_damping=0.05)
    table = collide.Plane(jnp.array([0.0, 0, 0]), jnp.array([0.0, 0, 1]))
    tool = collide.Sphere(jnp.array([0.0, 0.0, 0.12]), 0.06)
    contact = mss.Penalty(2e3, 1.0)
    state = mss.init(lat)
    out = simulate(lat, state, 2e-4, n_steps=5000, gravity=GRAVITY, tools=(table, tool), contact=contact)
    x = np.asarray(out.position)
    assert x[:, 2].min() > -0.01  # resting on the table, small penalty penetration
    depth = 0.06 - np.linalg.norm(x - np.array([0, 0, 0.12]), axis=1)
    assert depth.max() < 0.01  # pushed out of the tool
    assert x[2 * 10 + 2 * 2 + 1, 2] < 0.1 - 0.02  # the tool dented the top under its centre (node (2, 2, 1))


def test_yield_rest_lengths_closed_form():
    x = np.array([[0.0, 0, 0], [1, 0, 0], [10, 0, 0], [11, 0, 0]])
    lat = mss.Lattice(x, np.array([[0, 1], [2, 3]]), 100.0, 5.0, 0.1)
    stretched = jnp.asarray(x * np.array([[1.3, 1, 1]]))  # both springs at strain 0.3
    plastic = mss.Plasticity(0.05, radius=2.0, center=jnp.array([0.5, 0, 0]))
    rest = np.asarray(mss.yield_rest_lengths(lat, stretched, plastic))
    np.testing.assert_allclose(rest, [1.3 / 1.05, 1.0])  # strain left = yield; far spring untouched
    squeezed = jnp.asarray(x * np.array([[0.8, 1, 1]]))
    np.testing.assert_allclose(mss.yield_rest_lengths(lat, squeezed, mss.Plasticity(0.05))[0], 0.8 / 0.95)


def test_plastic_rollout_leaves_a_permanent_set():
    x = np.array([[0.0, 0, 0], [1, 0, 0], [10, 0, 0], [11, 0, 0]])
    lat = mss.Lattice(x, np.array([[0, 1], [2, 3]]), 100.0, 5.0, 0.1, np.array([True, False, True, False]))
    pull = jnp.zeros((3000, 4, 3)).at[:1000, 1, 0].set(20.0).at[:1000, 3, 0].set(20.0)  # load, then release
    plastic = mss.Plasticity(0.05, radius=2.0, center=jnp.array([0.5, 0, 0]))
    lat2, out = mss.simulate_plastic(lat, mss.init(lat), 1e-3, 3000, plastic, pull)
    rest = np.asarray(lat2.rest_length)
    assert rest[0] > 1.1 and rest[1] == 1.0
    # after release the yielded spring rests at its new length, the elastic one at 1
    assert abs(float(out.position[1, 0]) - rest[0]) < 1e-3
    assert abs(float(out.position[3, 0] - out.position[2, 0]) - 1.0) < 1e-3
    # the exact linear solve factors the rest lengths once: yield would leave it stale
    grid = mss.hex_lattice(
        jnp.asarray(np.indices((2, 2, 2)).transpose(1, 2, 3, 0), float), material=mss.JELLY
    )
    with pytest.raises(ValueError, match="method.*rest lengths"):
        mss.simulate_plastic(grid, mss.init(grid), 1e-4, 2, plastic, method="linear_implicit")


_TEARDROP = []


def teardrop_blending():
    """One teardrop sample grid for every test (building a Blending compiles; share it)."""
    if not _TEARDROP:
        surf = shapes.teardrop()
        _TEARDROP.append((surf, surf.blending(12, 10)))
    return _TEARDROP[0]


def test_surface_coupling_roundtrip_and_refit_rate():
    surf, blend = teardrop_blending()
    lat, coupling = mss.surface_lattice(blend, surf.ctrl, mss.JELLY)
    # poles merge to one node each, the periodic seam (v = 0 and 1) shares nodes
    assert lat.n_nodes == 2 + 10 * 9
    np.testing.assert_allclose(coupling.ctrl(coupling.nodes(surf.ctrl)), surf.ctrl, atol=1e-12)
    np.testing.assert_allclose(coupling.grid(lat.rest_positions), blend.points(surf.ctrl), atol=1e-12)
    state = mss.init(lat)
    final, ctrls = jax.jit(lambda s: mss.simulate_coupled(lat, coupling, s, 1e-4, 60, 20, gravity=GRAVITY))(
        state
    )
    assert ctrls.shape == (3, 8, 8, 3)
    np.testing.assert_allclose(ctrls[-1], coupling.ctrl(final.position), atol=1e-12)
    assert float(ctrls[-1, ..., 2].mean()) < float(surf.ctrl[..., 2].mean())


# --- differentiable rollouts ----------------------------------------------------------------------


def small_lattice():
    g = grid((3, 2, 2), 0.1)
    fixed = (g[..., 0] == 0).reshape(-1)
    return plain_hex((3, 2, 2), 50.0, 0.5, 0.02, fixed, spacing=0.1)


def test_grad_wrt_stiffness_damping_and_force():
    lat = small_lattice()
    s0 = mss.init(lat)

    def end_z(params):
        k, c, fz = params[0], params[1], params[2]
        l2 = eqx.tree_at(lambda l: (l.stiffness, l.damping), lat, (lat.stiffness * k, lat.damping * c))
        force = jnp.zeros((12, 3)).at[:, 2].set(fz)
        return jnp.sum(mss.simulate(l2, s0, 2e-3, 200, force, GRAVITY).position[:, 2])

    check_grad(jax.jit(end_z), jnp.array([1.0, 1.0, -0.1]), eps=1e-6, rtol=1e-4, n_dirs=2)


def test_grad_wrt_tool_trajectory_and_initial_ctrl():
    lat = small_lattice()
    n = 150
    t = jnp.linspace(0, 1, n)

    def pushed(offset):
        centers = jnp.stack([0.2 + 0 * t, 0.05 + 0 * t, 0.16 - 0.06 * t * offset], axis=-1)
        path = (
            eqx.tree_at(
                lambda s: (s.center, s.radius),
                collide.Sphere(jnp.zeros(3), 0.05),
                (centers, jnp.full((n,), 0.05)),
            ),
        )
        out = mss.simulate(lat, mss.init(lat), 2e-3, n, tool_path=path, contact=mss.Penalty(500.0))
        return jnp.sum(out.position[:, 2])

    check_grad(jax.jit(pushed), jnp.array(1.0).reshape(()), eps=1e-6, rtol=1e-4, n_dirs=1)

    surf, blend = teardrop_blending()
    slat, coupling = mss.surface_lattice(
        blend,
        surf.ctrl,
        stiffness=20.0,
        damping=0.1,
        mass=0.01,
        fixed=np.pad(np.ones((1, 10), bool), ((11, 0), (0, 0))),
    )

    def from_ctrl(ctrl):
        s = mss.init(slat, coupling.nodes(ctrl))
        out = mss.simulate(slat, s, 2e-3, 100, gravity=GRAVITY)
        return jnp.sum(coupling.ctrl(out.position)[..., 2] ** 2)

    check_grad(
        jax.jit(lambda c: from_ctrl(c.reshape(8, 8, 3))),
        surf.ctrl.reshape(-1) + 0.001,
        eps=1e-6,
        rtol=1e-4,
        n_dirs=2,
    )


def test_checkpointed_long_rollout_gradient_and_memory():
    lat = small_lattice()
    s0 = mss.init(lat)

    def loss(k, every):
        l2 = eqx.tree_at(lambda l: l.stiffness, lat, lat.stiffness * k)
        return jnp.sum(
            mss.simulate(l2, s0, 1e-3, 10_000, gravity=GRAVITY, checkpoint_every=every).position[:, 2]
        )

    g_ckpt = jax.jit(jax.grad(lambda k: loss(k, 100))).lower(1.0).compile()
    g_plain = jax.jit(jax.grad(lambda k: loss(k, None))).lower(1.0).compile()
    a, b = float(g_ckpt(1.0)), float(g_plain(1.0))
    assert np.isfinite(a) and np.isclose(a, b, rtol=1e-9)
    fwd = jax.jit(lambda k: loss(k, 100))
    fd = (float(fwd(1.0 + 1e-6)) - float(fwd(1.0 - 1e-6))) / 2e-6
    assert np.isclose(a, fd, rtol=1e-4)
    mem = lambda f: f.memory_analysis().temp_size_in_bytes
    assert mem(g_ckpt) * 10 < mem(g_plain)  # stores ~n/c + c states instead of n


# --- the compiled boundary: same values as called, inside jit, vmap and grad; checks that hold ------


def test_step_and_simulate_same_values_direct_jit_vmap_grad():
    lat = small_lattice()
    x0 = jnp.asarray(lat.rest_positions) + 0.01 * jnp.asarray(np.random.default_rng(4).normal(size=(12, 3)))
    s0 = mss.init(lat, x0)
    dt = 2e-3

    direct = mss.step(lat, s0, dt, gravity=GRAVITY)
    jitted = jax.jit(lambda l, s, h: mss.step(l, s, h, gravity=GRAVITY))(lat, s0, dt)
    np.testing.assert_array_equal(direct.position, jitted.position)
    # one step by hand (thesis eqs. 5.14-5.16) as the independent reference
    f = np.asarray(mss.forces(lat, s0, gravity=GRAVITY))
    free = ~np.asarray(lat.fixed)[:, None]
    v = np.where(free, dt * f / np.asarray(lat.mass)[:, None], 0.0)
    np.testing.assert_allclose(direct.velocity, v, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(direct.position, np.where(free, np.asarray(x0) + dt * v, x0), rtol=1e-12)

    def run(k, s):
        l2 = eqx.tree_at(lambda l: l.stiffness, lat, lat.stiffness * k)
        return mss.simulate(l2, s, dt, 50, gravity=GRAVITY).position

    ks = jnp.array([0.5, 1.0, 2.0])
    one_by_one = np.stack([np.asarray(run(float(k), s0)) for k in ks])
    np.testing.assert_allclose(jax.vmap(run, (0, None))(ks, s0), one_by_one, rtol=1e-12, atol=1e-15)
    states = jax.vmap(lambda a: mss.State(x0 + a, jnp.zeros_like(x0)))(jnp.array([0.0, 0.01]))
    by_state = jax.vmap(lambda s: run(1.0, s))(states)
    np.testing.assert_allclose(by_state[0], one_by_one[1], rtol=1e-12, atol=1e-15)
    assert not np.allclose(by_state[1], by_state[0])

    loss = lambda k: jnp.sum(run(k, s0)[:, 2])
    g = check_grad(loss, jnp.array(1.0).reshape(()), eps=1e-6, rtol=1e-5, n_dirs=1)
    np.testing.assert_allclose(jax.jit(jax.grad(loss))(1.0), g, rtol=1e-12)


def test_stable_dt_never_nan_for_extreme_finite_values():
    for k, m in [
        (100.0, 1e-300),
        (1e300, 1.0),
        (1e300, 1e-300),
        (1e-300, 1e300),
        (0.0, 1.0),
        (100.0, 1e-307),
    ]:
        lat = one_spring(k, 0.0, m, free_both=True)
        with np.errstate(all="ignore"):
            ref = 2.0 / np.sqrt(2 * k / m)  # exact for one free spring (inf when k/m underflows)
        if ref == 0:  # ω² overflows: no representable step, refused rather than 0
            with pytest.raises(ValueError, match="^lattice: expected"):
                mss.stable_dt(lat)
            continue
        h = float(mss.stable_dt(lat))
        assert not np.isnan(h) and h > 0, (k, m, h)
        if np.isfinite(ref) and ref > 0 and 2 * k / m < 1e300:
            np.testing.assert_allclose(h, ref, rtol=1e-12)
    heavy_damping = one_spring(1.0, 1e200, 1.0, free_both=True)
    h = float(mss.stable_dt(heavy_damping))
    assert np.isfinite(h) and 0 < h <= 2.0 / 1e200 * 1.01  # c ~ 4e200 dominates: h ~ 2/c, no c² overflow


def _two_nodes(mass=1.0, stiffness=100.0, damping=0.0):
    return mss.Lattice(jnp.array([[0.0, 0, 0], [1.0, 0, 0]]), np.array([[0, 1]]), stiffness, damping, mass)


_LAT = _two_nodes()
_S = mss.State(jnp.array([[0.0, 0, 0], [1.1, 0, 0]]), jnp.zeros((2, 3)))
_UNSTABLE = 1.0  # stable_dt of the two-node lattice is 2/sqrt(200) ≈ 0.14


@pytest.mark.parametrize(
    "fn, args, match",
    [
        (lambda h: mss.step(_LAT, _S, h), (jnp.nan,), "dt: expected finite values > 0"),
        (lambda h: mss.step(_LAT, _S, h), (-1e-3,), "dt: expected finite values > 0"),
        (lambda h: mss.step(_LAT, _S, h), (_UNSTABLE,), "dt: expected a time step <= mss.stable_dt"),
        (lambda h: mss.implicit_step(_LAT, _S, h), (jnp.nan,), "dt: expected finite values > 0"),
        (lambda h: mss.implicit_step(_LAT, _S, h), (-1e-3,), "dt: expected finite values > 0"),
        (lambda h: mss.implicit_step(_LAT, _S, h), (1e300,), "dt: .*overflows"),
        (
            lambda h: mss.implicit_step(_LAT, _S, h, cg_iterations=-1),
            (1e-3,),
            "cg_iterations: expected an int >= 1",
        ),
        (lambda h: mss.simulate(_LAT, _S, h, 5), (jnp.inf,), "dt: expected finite values > 0"),
        (lambda h: mss.simulate(_LAT, _S, h, 5), (_UNSTABLE,), "dt: expected a time step <= mss.stable_dt"),
        (lambda h: mss.simulate(_LAT, _S, h, 0), (1e-3,), "n_steps: expected an int >= 1, got 0"),
        (lambda h: mss.simulate(_LAT, _S, h, 5, checkpoint_every=-3), (1e-3,), "checkpoint_every: .*got -3"),
        (lambda h: mss.simulate(_LAT, _S, h, 5, checkpoint_every=0), (1e-3,), "checkpoint_every: .*got 0"),
        (
            lambda h: mss.simulate(_LAT, _S, h, 5, method="implicit", cg_iterations=-1),
            (1e-3,),
            "cg_iterations",
        ),
        (lambda h: mss.simulate(_LAT, _S, h, 5, method="implicit"), (jnp.nan,), "dt: expected finite"),
        (
            lambda x: mss.simulate(_LAT, mss.State(x, x), 1e-3, 5),
            (jnp.full((2, 3), jnp.nan),),
            "state.position",
        ),
        (lambda h: mss.trajectory(_LAT, _S, h, 6, save_every=0), (1e-3,), "save_every: .*got 0"),
        (lambda h: mss.trajectory(_LAT, _S, h, 6, save_every=4), (1e-3,), "save_every: expected a divisor"),
        (lambda h: mss.trajectory(_LAT, _S, h, 6, save_every=2), (-1.0,), "dt: expected finite values > 0"),
        (lambda h: mss.relax(_LAT, _S, h, check_every=-1), (1e-3,), "check_every: .*got -1"),
        (lambda h: mss.relax(_LAT, _S, h, max_steps=0), (1e-3,), "max_steps: .*got 0"),
        (lambda t: mss.relax(_LAT, _S, 1e-3, tol=t, max_steps=10, check_every=5), (-1.0,), "tol: expected"),
        (
            lambda h: mss.relax(_LAT, _S, h, max_steps=10, check_every=5),
            (_UNSTABLE,),
            "dt: expected a time step",
        ),
        (lambda e: mss.simulate_plastic(_LAT, _S, 1e-3, 5, mss.Plasticity(e)), (-0.1,), "yield_strain"),
        (
            lambda h: mss.simulate_plastic(_LAT, _S, h, 5, mss.Plasticity(0.1)),
            (jnp.nan,),
            "dt: expected finite",
        ),
        (
            lambda x: mss.yield_rest_lengths(_LAT, x, mss.Plasticity(0.1)),
            (jnp.full((2, 3), jnp.nan),),
            "position",
        ),
        (lambda k: mss.stable_dt(_LAT, k), (-1.0,), "contact_stiffness: expected finite values >= 0"),
        (lambda h: mss.check_dt(_LAT, h), (jnp.nan,), "dt: expected finite values > 0"),
        (lambda h: mss.check_dt(_LAT, h, 1e6), (0.1,), "dt: expected a time step <= mss.stable_dt"),
        (lambda m: mss.step(_two_nodes(mass=m), _S, 1e-3), (-1.0,), "mass: expected finite values > 0"),
        (lambda k: mss.simulate(_two_nodes(stiffness=k), _S, 1e-3, 5), (-1.0,), "stiffness: expected finite"),
        (lambda c: mss.simulate(_two_nodes(damping=c), _S, 1e-3, 5), (-1.0,), "damping: expected finite"),
        (
            lambda k: mss.simulate(
                _LAT, _S, 1e-3, 5, tools=(collide.Sphere(jnp.zeros(3), 0.5),), contact=mss.Penalty(k)
            ),
            (-1.0,),
            "stiffness",
        ),
        (lambda x: mss.init(_LAT, x), (jnp.full((2, 3), jnp.inf),), "position: expected finite"),
        (lambda g: mss.energy(_LAT, _S, g), (jnp.zeros(2),), "gravity: expected an acceleration of shape"),
        (
            lambda g: mss.forces(_LAT, _S, gravity=g),
            (jnp.zeros(2),),
            "gravity: expected an acceleration of shape",
        ),
        (
            lambda e: mss.from_material(np.eye(3), np.array([[0, 1]]), mss.Material(e, 1.0), 1.0),
            (-1.0,),
            "youngs_modulus",
        ),
        (lambda v: mss.from_material(np.eye(3), np.array([[0, 1]]), mss.JELLY, v), (-1.0,), "volume"),
        (lambda x: mss.hex_lattice(x, 1.0, 0.0, 1.0), (jnp.full((2, 2, 2, 3), jnp.nan),), "positions"),
        (lambda x: hex_volume(x), (jnp.zeros((2, 2, 3)),), "positions: expected an array with 4"),
        (
            lambda l: mss.spring_stiffness(mss.JELLY, l, 1e-4),
            (-0.01,),
            "rest_length: expected finite values > 0",
        ),
        (lambda m: mss.spring_damping(mss.JELLY, 10.0, m), (0.0,), "mass: expected finite values > 0"),
        (lambda m: mss.natural_frequency(10.0, m), (-1.0,), "mass"),
        (lambda d: mss.damping_ratio(d, 10.0, 1.0), (-1.0,), "damping: expected finite values >= 0"),
    ],
)
def test_bad_values_raise_eagerly_and_under_jit(fn, args, match):
    raises_both(fn, *args, match=match)
