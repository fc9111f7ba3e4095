"""The spoon study on two deformable bodies (thesis §7.3; `bsjax.examples.spoon.study`): a
jelly resting in the bowl of a steel spoon held by its handle, at a small size (a 4³ jelly, a
30 × 8 × 2 spoon shell). The footprint classifies where placed nodes leave the bowl; a level
spoon holds the jelly and a steep backwards tilt spills it over the neck.
"""

import functools

import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import merge, shapes
from bsjax.examples import spoon


@functools.cache
def _study():
    merged = merge.merge([shapes.spoon_handle(), shapes.spoon_bowl()], direction="u", continuity=1)
    return spoon.study(merged, lattice=4, jelly_samples=(12, 12), spoon_shape=(30, 8, 2), cycles=60)


def test_footprint_says_where_the_jelly_left():
    """Nodes moved by hand past the tip, the neck and a side are spilled there; at rest none."""
    s = _study()
    rest = s.scene.bodies[1].lattice.rest_positions
    assert spoon.spilled(s, rest)["spilled"] == 0.0
    assert float(spoon.spill_risk(s, rest)) < 0.05
    for shift, where in (((0.1, 0, 0), "front"), ((-0.1, 0, 0), "back"), ((0, 0.05, 0), "side")):
        moved = rest + jnp.asarray(shift, rest.dtype)[None]
        out = spoon.spilled(s, moved)
        assert out["spilled"] == out[where] == pytest.approx(1.0), (where, out)
        assert float(spoon.spill_risk(s, moved)) > 0.95
    hand = spoon.shake(s, "across", 0.05, 1.0)  # the footprint moves with the hand: +5 cm at 1.25 s
    assert spoon.spilled(s, rest + jnp.asarray([[0.0, 0.05, 0.0]], rest.dtype), 1.25, hand)["spilled"] == 0.0
    with pytest.raises(ValueError, match="shake_axis"):
        spoon.shake(s, "diagonal", 0.01, 1.0)


def test_level_spoon_holds_and_a_steep_backwards_tilt_spills_over_the_neck():
    s = _study()
    jelly = s.scene.bodies[1].lattice
    level, t = spoon.run(s, 0.0, seconds=0.15)
    assert spoon.spilled(s, level[1].position, t)["spilled"] == 0.0
    assert np.isfinite(np.asarray(level[0].position)).all()
    steep, t = spoon.run(s, 45.0, seconds=0.15)
    out = spoon.spilled(s, steep[1].position, t)
    assert out["spilled"] > 0.5 and out["back"] == out["spilled"], out
    moved = np.asarray(steep[1].position).mean(0) - np.asarray(jelly.rest_positions).mean(0)
    assert moved[0] < -0.02  # down the tilted bowl, towards the handle
