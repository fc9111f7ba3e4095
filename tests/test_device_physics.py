"""The JAX sculpting model behind the servo loop, and a 2-second run of the two-rate loop."""

import dataclasses
import math
import threading
import time

import numpy as np
import pytest

from bsjax import mss
from bsjax.device import ServoLoop, SimulatedDevice, Workspace
from bsjax.device._physics import SculptModel, check_step
from bsjax.device._protocol import DeviceSample


@pytest.fixture(scope="module")
def model():
    m = SculptModel(grid=(8, 8), layers=4, fixed_layers=1)  # small: tests; the benchmark runs 12×12×12
    m.warmup()
    return m


def at(x, pressed=False, y=0.0, z=0.0):
    return DeviceSample(
        np.array([x, y, z]), np.array([1.0, 0.0, 0.0, 0.0]), int(pressed), 0.0, 0, time.perf_counter()
    )


def displacement(model):
    return np.asarray(model.ctrl) - np.asarray(model.surface0.ctrl)


def test_rest_state_reproduces_the_surface(model):
    model.reset()
    model.update(at(3.0))
    assert np.abs(displacement(model)).max() < 1e-6  # refit of the undeformed lattice
    assert model.n_nodes == 8 * 8 * 4 and model.ctrl.dtype == np.float64


def test_push_from_outside_dents_and_sets_on_release(model):
    model.reset()
    for _ in range(60):
        model.update(at(0.75, pressed=True))  # sphere r = 0.25 reaches x = 0.5, the wall is at ≈ 0.62
    dent = displacement(model)[..., 0].min()
    assert dent < -0.02
    for _ in range(40):
        model.update(at(3.0))  # released, far away: the dent stays (plastic set)
    kept = displacement(model)
    assert kept[..., 0].min() < 0.8 * dent and np.all(np.isfinite(kept))


def test_pull_from_inside_bulges(model):
    model.reset()
    for _ in range(60):
        model.update(at(0.45, pressed=True))  # inside the body: nodes pushed outwards
    assert displacement(model)[..., 0].max() > 0.02


def test_no_deformation_without_the_button(model):
    model.reset()
    for _ in range(30):
        model.update(at(0.75))
    assert np.abs(displacement(model)).max() < 1e-6


def test_proxy_normal_faces_the_tool_side_and_latches(model):
    model.reset()
    outside = model.update(at(0.95))
    assert outside.kind == "plane" and outside.normal[0] > 0.8 and outside.tool_radius == pytest.approx(0.25)
    assert outside.force((0.8, 0.0, 0.0))[0] > 0  # touching the wall from outside pushes out
    inside = model.update(at(0.75))  # moved into contact: the side stays latched
    assert inside.normal[0] > 0.8
    for _ in range(20):
        pressing = model.update(at(0.7, pressed=True))
    assert pressing.force((0.7, 0.0, 0.0))[0] > 0.02  # sculpting: the material pushes back
    model.reset()
    cavity = model.update(at(0.2))
    assert cavity.normal[0] < -0.8 and cavity.force((0.45, 0.0, 0.0))[0] < 0  # from inside: pushes in


def sphere_depths(points, normals, centre, radius):
    """Gao–Gibson depth of each sample inside a sphere: distance along its normal to the sphere
    (the root of |p + t n − c| = r closer to the sample), a closed form in numpy."""
    y = points - centre
    b = np.sum(y * normals, axis=-1)
    c = np.sum(y * y, axis=-1) - radius**2
    root = np.sqrt(np.maximum(b * b - c, 0.0))
    t = np.where(np.abs(-b - root) < np.abs(-b + root), -b - root, -b + root)
    return np.where(c < 0, np.abs(t), 0.0)


def test_contact_proxy_renders_the_distributed_spring_force(model):
    model.reset()
    model.update(at(0.95))  # approach from outside
    proxy = model.update(at(0.8))  # 0.07 into the wall
    c, radius = np.array([0.8, 0.0, 0.0]), 0.25
    # reference: paper 002 eq. 3.3 — F = k Σ d_i along Σ d_i N_i — on the same sample grid
    points = np.asarray(model.dense.points(model.ctrl)).reshape(-1, 3)
    normals = model.sign * np.asarray(model.dense.normals(model.ctrl)).reshape(-1, 3)
    depth = sphere_depths(points, normals, c, radius)
    assert depth.max() > 0
    expected = model.contact_stiffness * depth.sum()
    direction = (depth[:, None] * normals).sum(axis=0)
    direction /= np.linalg.norm(direction)
    rendered = np.array(proxy.force(c))
    assert np.linalg.norm(rendered) == pytest.approx(expected, rel=1e-6)
    np.testing.assert_allclose(rendered / np.linalg.norm(rendered), direction, atol=1e-9)
    closer = np.linalg.norm(proxy.force(c - np.array([0.01, 0.0, 0.0])))  # the local plane model
    assert closer == pytest.approx(expected + model.proxy_stiffness * 0.01 * direction[0])


def test_tool_shape_changes_at_run_time(model):
    model.reset()
    model.set_tool(axes=(0.1, 0.3, 0.3))
    proxy = model.update(at(0.95))
    n = np.array(proxy.normal)  # ellipsoid support distance |diag(a) n| (identity orientation)
    assert proxy.tool_radius == pytest.approx(np.linalg.norm(np.array([0.1, 0.3, 0.3]) * n))
    assert proxy.tool_radius < 0.16
    model.set_tool(radius=0.2)
    assert model.update(at(0.95)).tool_radius == pytest.approx(0.2)
    with pytest.raises(ValueError, match="tool"):
        model.set_tool(axes=(0.1, -1.0, 0.1))
    model.set_tool(radius=0.25)


def test_unstable_step_and_small_grid_are_refused(model):
    limit = float(mss.stable_dt(model.lattice, model.tool_stiffness))
    assert model.dt < limit  # the default material runs inside the stability limit
    check_step(model.lattice, 0.9 * limit, model.tool_stiffness)
    with pytest.raises(ValueError, match="unstable"):  # what the constructor raises for a bad dt
        check_step(model.lattice, 1.1 * limit, model.tool_stiffness)
    with pytest.raises(ValueError, match="grid"):
        SculptModel(grid=(4, 4))


def test_two_second_simulated_session_meets_the_rate(model):
    """1 kHz servo with the JAX physics running beside it. On a loaded 2-core CI machine the
    assertion leaves a margin (≥ 950 Hz, ≤ 5 % lost slots with real-time priority; measured here
    at load 11: 999.5 Hz, 0 lost; without it 529 Hz); the strict 10 s figures are in
    `benchmarks/haptics.py` and the README."""
    model.reset()
    threads = set()
    update = model.update

    def spy(sample):
        threads.add(threading.current_thread().name)
        return update(sample)

    model.update = spy
    try:
        loop = ServoLoop(SimulatedDevice(), model, rate_hz=1000, max_force=3.0, physics_hz=100, mode="thread")
        loop.start()
        time.sleep(2.0)
        stats = loop.stop()
    finally:
        del model.update
    assert abs(stats.period_p50 - 1.0) < 0.05, stats.report()  # the loop is scheduled at 1 kHz
    if stats.realtime:  # SCHED_FIFO granted (root or CAP_SYS_NICE), as on a haptics rig
        # ≤ 5 % of the ticks late: the suite's other worker compiles beside it (24 late once;
        # 71 once, 42 of them one 43 ms stall, the rate still 963 Hz)
        assert stats.rate_hz >= 950 and stats.missed_deadlines <= 100, stats.report()
    else:  # normal priority on a loaded shared machine: other processes preempt the servo
        assert stats.rate_hz >= 400, stats.report()
    assert stats.physics_updates >= 40 and threads == {"bsjax-physics"}, stats.report()
    assert 0 < stats.force_max <= 3.0 and stats.nonfinite == 0
    assert np.abs(displacement(model)).max() > 1e-3  # the scripted press sculpted the surface


def contact_proxy(model):
    """The proxy of a tool 0.07 into the wall after an approach from outside (a fresh model)."""
    model.update(at(0.95))
    return model.update(at(0.8))


def test_bad_poses_are_dropped_and_never_reach_the_physics(model):
    model.reset()
    reference = contact_proxy(model)
    model.reset()
    model.update(at(0.95))
    ticks, dropped, ctrl = model.ticks, model.dropped_poses, np.asarray(model.ctrl).copy()
    bad = [at(np.nan, True), at(np.inf, True), at(1e300, True), at(0.8, True, y=-1e30)]
    bad.append(DeviceSample(np.array([0.8, 0, 0]), np.array([np.nan, 0, 0, 0]), 1, 0.0, 0, 0.0))
    for sample in bad:
        assert model.update(sample) is model._last_proxy  # the last good proxy, unchanged
    assert model.dropped_poses == dropped + 5 and model.ticks == ticks and model.rollbacks == 0
    np.testing.assert_array_equal(np.asarray(model.ctrl), ctrl)
    after = model.update(at(0.8))  # the next good pose renders the normal force
    np.testing.assert_allclose(after.force((0.8, 0.0, 0.0)), reference.force((0.8, 0.0, 0.0)), rtol=1e-12)
    assert np.linalg.norm(reference.force((0.8, 0.0, 0.0))) > 0.05
    assert model.accepts(at(3.0)) and not model.accepts(at(model.reach + 1.0))


def test_a_non_finite_tick_is_rolled_back(model):
    """A tool so large that the lattice forces overflow makes the tick non-finite: the state is
    rolled back, the last good proxy returned; the next good tick is as if nothing happened."""
    model.reset()
    reference = contact_proxy(model)
    model.reset()
    model.update(at(0.95))
    last = model.update(at(0.8))
    state, ctrl = model._state, np.asarray(model.ctrl).copy()
    try:
        model.set_tool(radius=1e300)
        assert model.update(at(0.8, pressed=True)) is last
        assert model.rollbacks == 1 and model._state is state
        np.testing.assert_array_equal(np.asarray(model.ctrl), ctrl)
    finally:
        model.set_tool(radius=0.25)
    after = model.update(at(0.8))
    assert np.all(np.isfinite(np.asarray(model.ctrl)))
    np.testing.assert_allclose(after.force((0.8, 0.0, 0.0)), reference.force((0.8, 0.0, 0.0)), rtol=1e-9)


def test_a_model_that_keeps_failing_raises(model):
    model.reset()
    try:
        model.set_tool(radius=1e300)
        for _ in range(model.max_rollbacks):
            model.update(at(0.8, pressed=True))
        with pytest.raises(FloatingPointError, match="in a row failed or went non-finite"):
            model.update(at(0.8, pressed=True))
    finally:
        model.set_tool(radius=0.25)
        model.reset()
    with pytest.raises(ValueError, match="^reach: expected"):
        SculptModel(reach=-1.0)


class Glitching(SimulatedDevice):
    """A driver without the pose gate: 1e300 / NaN positions for 60 ms from t = 0.3 s."""

    def read(self):
        sample = super().read()
        if 0.3 <= sample.timestamp < 0.36:
            bad = 1e300 if sample.sequence % 2 else np.nan
            return dataclasses.replace(sample, position=np.array([bad, 0.0, 0.0]))
        return sample


def test_servo_with_glitching_device_keeps_the_model_sane(model):
    """A wild but finite pose rendered once would also have poisoned the servo's velocity
    estimate (1e300 / 1 ms decays over seconds): after the glitch the force is the one before."""
    model.reset()
    dev = Glitching(lambda t: ((0.8 if t > 0.1 else 0.95, 0.0, 0.0), 0), workspace=Workspace())
    loop = ServoLoop(dev, model, physics_hz=100, record=True, mode="thread")
    dropped = model.dropped_poses
    loop.start()
    time.sleep(0.6)
    stats = loop.stop()
    rec = loop.recording()
    force = np.linalg.norm(rec.force, axis=1)
    assert np.all(np.isfinite(rec.force)) and stats.physics_errors == 0 and stats.bad_samples > 5
    # the servo asked model.accepts: neither the NaN nor the 1e300 poses reached the physics
    assert model.dropped_poses == dropped and np.all(np.isfinite(np.asarray(model.ctrl)))
    t = rec.device_time
    before, after = force[(t > 0.2) & (t < 0.3)], force[t > 0.5]
    assert before.min() > 0.05 and after.min() == pytest.approx(before.mean(), rel=0.05)


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        (dict(substeps=0), ValueError, "substeps"),
        (dict(substeps=2.5), TypeError, "substeps"),
        (dict(layers=1), ValueError, "layers"),
        (dict(grid=12), ValueError, "grid"),
        (dict(grid=(12.0, 12)), TypeError, "grid"),
        (dict(physics_hz=-100.0), ValueError, "physics_hz"),
        (dict(damping=math.nan), ValueError, "damping"),
        (dict(tool_radius="big"), TypeError, "tool_radius"),
        (dict(tool_axes=(0.1, 0.0, 0.1)), ValueError, "axes"),
        (dict(reach="far"), TypeError, "reach"),
        (dict(max_rollbacks=0), ValueError, "max_rollbacks"),
    ],
)
def test_sculpt_model_arguments_are_checked(kwargs, error, name):
    with pytest.raises(error, match=f"^{name}: expected"):
        SculptModel(**kwargs)
