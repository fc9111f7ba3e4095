"""The haptic device drives constraint sculpting (`ConstraintSculptModel`, `bsjax haptics --sculpt drag`)."""

import math
import re
import time

import numpy as np
import pytest

from bsjax import sculpt, shapes
from bsjax.device._constraint_sculpt import ConstraintSculptModel, border_free
from bsjax.device._model import AbstractHapticModel
from bsjax.device._physics import SculptModel
from bsjax.device._protocol import DeviceSample
from bsjax.device._record import Recording


@pytest.fixture(scope="module")
def model():
    m = ConstraintSculptModel(proxy_grid=24)  # the teardrop, 8×8 bicubic, closed in v
    m.warmup()
    return m


def at(x, pressed=False, y=0.0, z=0.0, w=1.0):
    return DeviceSample(
        np.array([x, y, z]), np.array([w, 0.0, 0.0, 0.0]), int(pressed), 0.0, 0, time.perf_counter()
    )


def pose(c, pressed=True):
    return at(c[0], pressed, c[1], c[2])


def grabbed(model):
    """Approach from outside along −x, press, move in until the model grabs: the grab centre."""
    model.reset()
    assert model.update(at(1.3)).force((1.3, 0.0, 0.0)) == (0.0, 0.0, 0.0)
    for x in np.arange(1.0, 0.5, -0.02):
        model.update(at(x, True))
        if model.dragging:
            return x
    raise AssertionError("the pressed tool never grabbed the surface")


def test_push_moves_the_point_by_the_min_norm_edit(model):
    x0 = grabbed(model)
    grab = model.grab
    surface0 = model.surface0
    np.testing.assert_allclose(np.asarray(model.ctrl), np.asarray(surface0.ctrl), atol=1e-15)  # δ = 0
    # the grabbed point is the closest surface point to the tool (dense 200×200 sample reference)
    pts = np.asarray(surface0.blending(200, 200).points(surface0.ctrl)).reshape(-1, 3)
    nearest = np.min(np.linalg.norm(pts - grab.centre, axis=-1))
    assert np.linalg.norm(grab.point - grab.centre) <= nearest + 1e-9
    assert np.linalg.norm(grab.point - grab.centre) <= model.tool_radius + 0.05  # it touched
    delta = np.array([-0.15, 0.02, 0.01])
    model.update(pose(grab.centre + delta))
    u0, v0 = grab.uv
    # against sculpt.min_norm directly: the point at (u0, v0) moved to p0 + δ, border rows blocked
    ref = sculpt.min_norm(surface0, [sculpt.Position(u0, grab.point + delta, v0)], model.free)
    assert int(ref.status) == 0
    np.testing.assert_allclose(np.asarray(model.ctrl), np.asarray(ref.shape.ctrl), rtol=0, atol=1e-12)
    moved = np.asarray(model.surface().evaluate(u0, v0))
    np.testing.assert_allclose(moved, grab.point + delta, atol=1e-12)
    # and against the closed form of one point row (eq. 6-10): d_i = F_i δ / Σ_free F_j²
    f = np.kron(np.asarray(surface0.rows("u", [u0]))[0], np.asarray(surface0.rows("v", [v0]))[0])
    f = np.where(model.free.reshape(-1), f, 0.0)
    d = (f / (f @ f))[:, None] * delta[None, :]
    np.testing.assert_allclose(
        np.asarray(model.ctrl) - np.asarray(surface0.ctrl), d.reshape(8, 8, 3), atol=1e-12
    )
    # blocked control points (the poles' rows of the teardrop) stay exactly
    assert not model.free[0].any() and not model.free[-1].any()
    np.testing.assert_array_equal(np.asarray(model.ctrl)[~model.free], np.asarray(surface0.ctrl)[~model.free])
    assert abs(x0 - grab.centre[0]) < 1e-15


def test_release_keeps_the_shape_and_the_next_grab_factors_it(model):
    grabbed(model)
    first = model.grab
    model.update(pose(first.centre + [-0.1, 0.0, 0.0]))
    dragged = np.asarray(model.ctrl).copy()
    model.update(at(1.3))  # released and withdrawn
    assert not model.dragging
    np.testing.assert_array_equal(np.asarray(model.ctrl), dragged)
    assert np.abs(dragged - np.asarray(model.surface0.ctrl)).max() > 0.05
    # a second push grabs the dented surface: the new factor's shape is the dragged one
    for x in np.arange(1.0, 0.3, -0.02):
        model.update(at(x, True))
        if model.dragging:
            break
    assert model.dragging and model.grabs >= 2
    np.testing.assert_array_equal(np.asarray(model.grab.factor.shape.ctrl), dragged)


def test_drag_force_is_the_clamped_spring_back(model):
    grabbed(model)
    grab, k, limit = model.grab, model.drag_stiffness, model.max_force
    for delta in ([0.0, 0.0, 0.0], [-0.03, 0.01, 0.0], [-0.3, 0.1, 0.05], [0.2, 0.0, 0.0]):
        c = grab.centre + np.asarray(delta)
        proxy = model.update(pose(c))
        force = np.asarray(proxy.force(tuple(c)))
        expected = -k * np.asarray(delta)
        if np.linalg.norm(expected) > limit:  # clamped, direction kept
            expected *= limit / np.linalg.norm(expected)
        assert np.all(np.isfinite(force)) and np.linalg.norm(force) <= limit * (1 + 1e-12)
        np.testing.assert_allclose(force, expected, atol=1e-9)
    assert np.linalg.norm(model.drag_force([1e300, 0.0, 0.0])) == pytest.approx(limit)


def test_without_the_button_the_surface_is_felt_not_moved(model):
    model.reset()
    model.update(at(1.3))
    proxy = model.update(at(0.8))  # inside the tool's reach of the surface, button up
    force = np.asarray(proxy.force((0.8, 0.0, 0.0)))
    assert force[0] > 0.1 and not model.dragging  # pushed back out along +x
    np.testing.assert_array_equal(np.asarray(model.ctrl), np.asarray(model.surface0.ctrl))
    assert model.update(at(1.3)).force((1.3, 0.0, 0.0)) == (0.0, 0.0, 0.0)


def test_bad_poses_are_dropped_and_never_reach_the_solve(model):
    grabbed(model)
    good = model.update(pose(model.grab.centre + [-0.05, 0, 0]))
    ticks, dropped, ctrl = model.ticks, model.dropped_poses, np.asarray(model.ctrl).copy()
    bad = [
        at(np.nan, True),
        at(np.inf, True),
        at(1e300, True),
        at(0.8, True, y=-1e30),
        at(0.8, True, w=np.nan),
    ]
    for sample in bad:
        assert model.update(sample) is good  # the last good proxy
    assert model.dropped_poses == dropped + 5 and model.ticks == ticks and model.rollbacks == 0
    assert model.dragging  # a bad pose does not release the grab
    np.testing.assert_array_equal(np.asarray(model.ctrl), ctrl)
    assert model.accepts(at(3.0)) and not model.accepts(at(model.reach + 1.0))


def test_a_non_finite_drag_is_rolled_back_then_raises():
    m = ConstraintSculptModel(proxy_grid=24, reach=math.inf, max_rollbacks=2)
    grabbed(m)
    good = m.update(pose(m.grab.centre + [-0.05, 0, 0]))
    ctrl = np.asarray(m.ctrl).copy()
    huge = at(-1.7e308, True)  # accepted (reach = inf); C b overflows
    assert m.update(huge) is good and m.rollbacks == 1 and m.dragging
    np.testing.assert_array_equal(np.asarray(m.ctrl), ctrl)
    again = m.update(pose(m.grab.centre + [-0.05, 0, 0]))  # recovers
    assert np.asarray(again.force(tuple(m.grab.centre + [-0.05, 0, 0])))[0] > 0
    m.update(huge)
    m.update(huge)
    with pytest.raises(FloatingPointError, match="max_rollbacks = 2"):
        m.update(huge)


def test_border_mask_blocks_clamped_directions_only():
    free = border_free(shapes.teardrop(), 2)  # closed in v: only u's ends
    assert free.shape == (8, 8) and not free[:2].any() and not free[-2:].any() and free[2:-2].all()


@pytest.mark.parametrize(
    "kwargs, error, name",
    [
        (dict(surface="teardrop"), TypeError, "surface"),
        (dict(free=np.ones((3, 3), bool)), ValueError, "free"),
        (dict(free=np.zeros((8, 8), bool)), ValueError, "free"),
        (dict(border=-1), ValueError, "border"),
        (dict(tool_radius=math.nan), ValueError, "tool_radius"),
        (dict(drag_stiffness=-1.0), ValueError, "drag_stiffness"),
        (dict(max_force=0.0), ValueError, "max_force"),
        (dict(reach=-1.0), ValueError, "reach"),
        (dict(proxy_grid=1), ValueError, "proxy_grid"),
    ],
)
def test_arguments_are_checked(kwargs, error, name):
    with pytest.raises(error, match=name):
        ConstraintSculptModel(**kwargs)


# --- the command ------------------------------------------------------------------------------
def test_cli_sculpt_drag_runs_a_short_simulated_session(tmp_path, capsys):
    from bsjax.cli import haptics

    rec = tmp_path / "drag.npz"
    # the scripted session presses at t = 1 s and pushes 0.2 units in until t = 2.4 s
    assert haptics.main(["--sculpt", "drag", "--duration", "2.3", "--record", str(rec)]) == 0
    out = capsys.readouterr().out
    moved = float(re.search(r"largest control-point displacement ([0-9.]+)", out).group(1))
    grabs = int(re.search(r"drag interactions: (\d+)", out).group(1))
    assert grabs >= 1 and 0.02 < moved < 1.0, out
    recording = Recording.load(rec)
    force = np.linalg.norm(recording.force, axis=-1)
    assert len(recording) > 500 and np.all(np.isfinite(force)) and force.max() <= 3.0 + 1e-9
    assert force.max() > 0.5  # the spring back was felt


@pytest.mark.parametrize(
    "argv, name",
    [
        (["--sculpt", "knead"], "--sculpt"),
        (["--sculpt", "drag", "--proxy-only"], "--sculpt"),
        (["--sculpt", "drag", "--ellipsoid", "0.3,0.2,0.2"], "--ellipsoid"),
    ],
)
def test_cli_sculpt_errors_are_one_line(argv, name, capsys):
    from bsjax.cli import haptics

    assert haptics.main([*argv, "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bsjax haptics: ") and name in err and "\n" not in err


def test_both_models_share_one_servo_protocol():
    """Pose gating, rollback, counters and the degenerate-plane guard live once, in
    `AbstractHapticModel`; the rollback message names the model's class."""
    for cls in (SculptModel, ConstraintSculptModel):
        assert issubclass(cls, AbstractHapticModel)
        for name in ("accepts", "update", "_rolled_back", "_plane"):
            assert getattr(cls, name) is getattr(AbstractHapticModel, name), (cls, name)
    # a zero normal: no contact model rather than a bad plane
    none = AbstractHapticModel._plane((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 10.0, 0.1, 0.2)
    assert none.kind == "none"
    plane = AbstractHapticModel._plane((0.0, 0.0, 0.0), (0.0, 0.0, 2.0), 10.0, 0.1, 0.2)
    assert plane.kind == "plane" and np.allclose(plane.normal, (0.0, 0.0, 1.0))
    m = ConstraintSculptModel(proxy_grid=8, max_rollbacks=1)
    m._advance = lambda sample: None  # every tick non-finite
    good = DeviceSample(np.asarray(m.centre) + 2.0, np.array([1.0, 0, 0, 0]), 0, 0.0, 0, 0.0)
    assert m.update(good).kind == "none" and m.rollbacks == 1
    with pytest.raises(FloatingPointError, match=r"^ConstraintSculptModel\.update: 2 ticks in a row"):
        m.update(good)
