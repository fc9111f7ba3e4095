"""`collide.DistributedSprings`: the distributed-spring contact model between two surfaces —
closed forms (plate on plate), action = reaction, the damper, jit, and bad input.

Every pair is two 24 × 24 sample grids of 6 × 6 plates (one compiled shape for the module).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import shapes
from bsjax.collide import DistributedSprings, surface_penetration
from tests.helpers import raises_both

GRID = 24
PLATE = shapes.plate(6, 6)
B = PLATE.blending(GRID, GRID)
K, C = 2.0e3, 5.0


def _bumpy(seed: int, lift: float):
    """A plate with a random bump field (±2 mm) lifted by `lift` along z."""
    rng = np.random.default_rng(seed)
    ctrl = np.array(PLATE.ctrl)
    ctrl[..., 2] += lift + 0.002 * rng.standard_normal(ctrl.shape[:2])
    return jnp.asarray(ctrl)


def _pair(ctrl_a, ctrl_b, reach=0.05):
    return surface_penetration(B, ctrl_a, B, ctrl_b, reach=reach)


def test_plate_below_plate_closed_form():
    """A at z = −δ under B (normals +z): every A sample in contact carries exactly k δ ẑ, B's
    samples carry the reactions, and nothing else moves; the totals cancel."""
    delta = 0.004
    ctrl_a = PLATE.ctrl.at[..., 2].add(-delta)
    ab, ba = _pair(ctrl_a, PLATE.ctrl)
    assert int(ab.mask.sum()) > (GRID - 2) ** 2 // 2 and not bool(ba.mask.any())
    fa, fb = DistributedSprings(K).surface_forces(ab, ba)
    want = np.where(np.asarray(ab.mask)[..., None], [0.0, 0.0, K * delta], 0.0)
    np.testing.assert_allclose(fa, want, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sum(fb, (0, 1)), [0, 0, -K * delta * int(ab.mask.sum())], rtol=1e-9)
    np.testing.assert_allclose(np.sum(fa, (0, 1)) + np.sum(fb, (0, 1)), 0, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_action_equals_reaction_with_velocities(seed):
    """Two bumpy plates pressed together, moving: Σ forces on both = 0 to rounding."""
    rng = np.random.default_rng(10 + seed)
    ab, ba = _pair(_bumpy(seed, 0.0), _bumpy(seed + 5, 0.001))
    assert bool(ab.mask.any()) and bool(ba.mask.any())
    va, vb = (jnp.asarray(0.05 * rng.standard_normal((GRID, GRID, 3))) for _ in range(2))
    fa, fb = DistributedSprings(K, C).surface_forces(ab, ba, va, vb)
    total = np.sum(fa, (0, 1)) + np.sum(fb, (0, 1))
    scale = np.abs(fa).sum() + np.abs(fb).sum()
    assert scale > 0
    np.testing.assert_allclose(total, 0, atol=1e-12 * scale)


def test_damper_resists_closing_and_never_pulls():
    """Closing at speed w adds c w per sample; separating fast enough gives no force (no pull)."""
    delta = 0.004
    ab, ba = _pair(PLATE.ctrl.at[..., 2].add(-delta), PLATE.ctrl)
    model = DistributedSprings(K, C)
    mask = np.asarray(ab.mask)
    up = jnp.zeros((GRID, GRID, 3)).at[..., 2].set(1.0)
    for w, want in ((-0.1, K * delta + C * 0.1), (0.1, K * delta - C * 0.1), (10.0, 0.0)):
        fa, _ = model.surface_forces(ab, ba, w * up, None)  # A moving along +z at w
        np.testing.assert_allclose(np.asarray(fa)[mask][:, 2], want, rtol=1e-9, atol=1e-12)


def test_jit_equals_direct():
    ab, ba = _pair(_bumpy(3, 0.0), _bumpy(4, 0.001))
    model = DistributedSprings(K, C)
    direct = model.surface_forces(ab, ba)
    inside = jax.jit(lambda m, p, q: m.surface_forces(p, q))(model, ab, ba)
    for d, i in zip(direct, inside):
        np.testing.assert_allclose(d, i, rtol=1e-12, atol=1e-15)


def test_bad_input_names_the_argument():
    ab, ba = _pair(PLATE.ctrl.at[..., 2].add(-0.004), PLATE.ctrl)
    with pytest.raises(ValueError, match="stiffness"):
        DistributedSprings(-1.0).surface_forces(ab, ba)
    with pytest.raises(ValueError, match="damping"):
        DistributedSprings(K, jnp.nan).surface_forces(ab, ba)
    with pytest.raises(TypeError, match="penetration_ba"):
        DistributedSprings(K).surface_forces(ab, "b")
    with pytest.raises(ValueError, match="velocity_a"):
        DistributedSprings(K).surface_forces(ab, ba, jnp.zeros((3, 3)))
    bad = jnp.zeros((GRID, GRID, 3)).at[0, 0, 0].set(jnp.inf)
    raises_both(lambda v: DistributedSprings(K).surface_forces(ab, ba, v)[0], bad, match="velocity_a")
