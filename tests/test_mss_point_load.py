"""`mss.Body.point_load`: a user's force at a surface point (thesis §5.3.3, Figs 5.8–5.10) as
node forces — resultant and moment kept exactly — and the static deflection it causes against
an independent reference: the lattice's linearised stiffness solved by scipy.

One small plasticine cantilever (a 6 × 4 × 2 shell of a 6 × 4 cm plate, 3 cm thick, clamped
along x = 0) serves every test.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import mss, shapes
from tests.oracles import lattice_linear_deflection

SIZE = np.array([0.06, 0.04, 1.0])  # metres (the plate is flat: z stays 0)
THICKNESS = 0.03


@functools.cache
def _body():
    plate = shapes.plate(4, 4)
    surface = plate.with_ctrl(np.asarray(plate.ctrl) * SIZE)
    return surface, mss.Body.from_surface(
        surface, (6, 4, 2), mss.PLASTICINE, thickness=THICKNESS, fixed=lambda x: x[:, 0] < 1e-9
    )


def test_load_keeps_its_resultant_and_moment():
    """Virtual work through the coupling and the refit commutes with rigid motions, so the node
    forces add up to F and their moment about the origin is S(u, v) × F (to rounding)."""
    surface, body = _body()
    x = np.asarray(body.lattice.rest_positions)
    rng = np.random.default_rng(0)
    for u, v in ((1.0, 0.5), (0.3, 0.8), (0.0, 0.0)):
        force = rng.normal(size=3) * 10
        f = np.asarray(body.point_load(u, v, force))
        at = np.asarray(surface.evaluate(jnp.asarray(u), jnp.asarray(v)))
        np.testing.assert_allclose(f.sum(0), force, rtol=0, atol=1e-12 * np.abs(force).max())
        np.testing.assert_allclose(
            np.cross(x, f).sum(0), np.cross(at, force), atol=1e-12 * np.abs(force).max()
        )
    # the load sits on the surface layer, heaviest at the nodes around (u, v)
    f = np.linalg.norm(np.asarray(body.point_load(1.0, 0.5, [0.0, 0.0, -1.0])), axis=1)
    surface_nodes = np.asarray(body.coupling.node_map).reshape(-1)
    assert np.all(f[np.setdiff1d(np.arange(len(f)), surface_nodes)] == 0)
    assert np.argmax(f) in surface_nodes[-4:]  # the last row of the 6 × 4 surface nodes: u = 1


def _relaxed(body, force):
    state, _, converged = mss.relax(
        body.lattice, mss.init(body.lattice), 1e-2, external_force=force, tol=1e-18, max_steps=5000,
        method="implicit", cg_iterations=60,
    )  # fmt: skip
    assert bool(converged)
    return np.asarray(state.position - body.lattice.rest_positions)


def test_static_deflection_is_the_linear_solution_for_small_loads():
    """A pull down at the free edge's middle: the relaxed lattice's displacement equals the
    linearised stiffness solve, to a relative error proportional to the load (the springs'
    geometric nonlinearity: twice the load, twice the error; 8e-4 at 0.25 N)."""
    _, body = _body()
    unit = body.point_load(1.0, 0.5, [0.0, 0.0, -1.0])
    reference = lattice_linear_deflection(body.lattice, unit)
    errors = []
    for newtons in (0.25, 0.5):
        got = _relaxed(body, newtons * unit)
        errors.append(np.abs(got - newtons * reference).max() / np.abs(newtons * reference).max())
        assert got[:, 2].min() < 0 and np.argmin(got[:, 2]) in np.asarray(body.coupling.node_map)[-1]
    assert errors[0] < 2e-3 and errors[1] == pytest.approx(2 * errors[0], rel=0.2)


def test_point_load_jit_and_bad_input():
    _, body = _body()
    direct = body.point_load(0.5, 0.5, [1.0, 0.0, 0.0])
    jitted = jax.jit(lambda u, f: body.point_load(u, 0.5, f))(0.5, jnp.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(jitted, direct, rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="^u"):
        body.point_load(1.5, 0.5, [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="^force"):
        body.point_load(0.5, 0.5, [0.0, 1.0])
    with pytest.raises(ValueError, match="^force"):
        body.point_load(0.5, 0.5, [0.0, np.nan, 1.0])
    with pytest.raises(ValueError, match="^v"):
        body.point_load(0.5, [0.1, 0.2], [0.0, 0.0, 1.0])
