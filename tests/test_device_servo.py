"""The servo loop's safety: watchdog, clamp, rate limit, zero force on stop/exception; record/replay."""

import math
import threading
import time

import matplotlib.image
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bsjax.cli import haptics as cli
from bsjax.device import (
    DeviceError,
    Proxy,
    Recording,
    ServoLoop,
    SimulatedDevice,
    Workspace,
    plot_recording,
)
from bsjax.device._shaping import ForceShaper, Watchdog

WALL = dict(point=(0.62, 0.0, 0.0), normal=(1.0, 0.0, 0.0), stiffness=30.0, damping=0.3, tool_radius=0.25)


def still(x=0.8):
    """A stylus held still at (x, 0, 0) (model units), in contact with WALL for x < 0.87."""
    return SimulatedDevice(lambda t: ((x, 0.0, 0.0), 0), workspace=Workspace())


class StallingModel:
    """A physics model that keeps a wall proxy fresh until `stall` is set, then hangs."""

    def __init__(self):
        self.stall, self.release = threading.Event(), threading.Event()
        self.last_stamp = 0.0
        self.threads = set()

    def update(self, sample):
        self.threads.add(threading.get_ident())
        if self.stall.is_set() and not self.release.is_set():
            self.stalled_at = self.last_stamp  # the freshest proxy the servo has during the stall
            self.release.wait(5.0)
        proxy = Proxy.plane(**WALL)
        self.last_stamp = proxy.stamp
        return proxy


def test_watchdog_ramps_force_to_zero_when_physics_stalls():
    model = StallingModel()
    loop = ServoLoop(
        still(), model, physics_hz=200, proxy_timeout=0.03, ramp_time=0.02, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.4)
    model.stall.set()
    time.sleep(0.3)
    model.release.set()
    time.sleep(0.2)
    stats = loop.stop()
    rec = loop.recording()
    t = rec.time + loop.started_at
    force = np.linalg.norm(rec.force, axis=1)
    stalled = model.stalled_at
    before = (t > loop.started_at + 0.2) & (t < stalled)
    assert force[before].min() > 0.5  # in contact, pushing
    limit = stalled + 0.03 + 0.02 + 0.005  # timeout + ramp + one scheduling slip
    zeroed = (t > limit) & (t < limit + 0.15)
    assert zeroed.sum() > 100 and np.all(force[zeroed] == 0.0)
    ramp = (t > stalled + 0.03) & (t < limit)
    assert 0.0 < force[ramp].max() and np.any((force[ramp] > 0) & (force[ramp] < force[before].min()))
    assert stats.watchdog_trips >= 1 and force[-50:].min() > 0.5  # back after the stall
    assert threading.main_thread().ident not in model.threads and len(model.threads) == 1


def test_watchdog_zeroes_force_when_device_stops_answering():
    dev = still()
    loop = ServoLoop(
        dev, Proxy.plane(**WALL), device_timeout=0.02, ramp_time=0.02, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.3)
    dev.pause()
    paused_at = time.perf_counter()
    time.sleep(0.2)
    dev.resume()
    time.sleep(0.2)
    stats = loop.stop()
    rec = loop.recording()
    t = rec.time + loop.started_at
    force = np.linalg.norm(rec.force, axis=1)
    quiet = (t > paused_at + 0.02 + 0.02 + 0.005) & (t < paused_at + 0.18)
    assert quiet.sum() > 50 and np.all(force[quiet] == 0.0)
    assert force[(t > paused_at - 0.1) & (t < paused_at)].min() > 0.5 and force[-20:].min() > 0.5
    assert stats.watchdog_trips == 1


class ChaosModel:
    """Adversarial physics: every update a random plane or sphere with huge stiffness."""

    def __init__(self, seed=0):
        self.rng = np.random.default_rng(seed)

    def update(self, sample):
        r = self.rng
        k = 10.0 ** r.uniform(-2, 9)
        if r.random() < 0.5:
            return Proxy.plane(
                r.normal(size=3), r.normal(size=3), k, r.uniform(0, 1e4), tool_radius=r.uniform(0, 5)
            )
        return Proxy.sphere(
            r.normal(size=3),
            r.uniform(0, 3),
            k,
            r.uniform(0, 1e4),
            tool_radius=r.uniform(0, 2),
            inside=bool(r.random() < 0.5),
        )


def test_clamp_and_rate_limit_hold_for_any_model_state():
    wobble = SimulatedDevice(
        lambda t: ((math.sin(40 * t), math.cos(33 * t), 0.3 * math.sin(7 * t)), 0), workspace=Workspace()
    )
    loop = ServoLoop(
        wobble, ChaosModel(), max_force=2.5, max_force_rate=500.0, physics_hz=500, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.6)
    stats = loop.stop()
    f = loop.recording().force
    norms = np.linalg.norm(f, axis=1)
    assert np.all(np.isfinite(f)) and norms.max() <= 2.5 + 1e-12 and norms.max() > 2.0
    # per tick: rate limit (500 N/s · 1 ms) plus what the watchdog gain may add (ramp 20 ms)
    steps = np.linalg.norm(np.diff(f, axis=0), axis=1)
    assert steps.max() <= 0.5 + 2.5 * 1.0 / 20 * 1.5 + 1e-9
    assert stats.clamped > 0 and stats.rate_limited > 0
    assert wobble.last_force.tolist() == [0.0, 0.0, 0.0]


class ExplodingProxy(Proxy):
    def force(self, position, velocity=(0.0, 0.0, 0.0)):
        raise RuntimeError("model bug")


def test_zero_force_written_when_the_servo_thread_fails():
    dev = still()
    bad = ExplodingProxy("plane", WALL["point"], WALL["normal"], 0.0, False, 0.25, 30.0, 0.0, 0.0)
    loop = ServoLoop(dev, bad, mode="thread")
    loop.start()
    assert loop.finished.wait(2.0)
    with pytest.raises(DeviceError, match="model bug"):
        loop.stop()
    assert dev.last_force.tolist() == [0.0, 0.0, 0.0] and dev.writes >= 1


def test_physics_exception_ramps_to_zero_and_is_reported():
    class Broken:
        calls = 0

        def update(self, sample):
            self.calls += 1
            if self.calls > 20:
                raise FloatingPointError("diverged")
            return Proxy.plane(**WALL)

    dev = still()
    loop = ServoLoop(
        dev, Broken(), physics_hz=200, proxy_timeout=0.03, ramp_time=0.02, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.5)
    stats = loop.stop()
    force = np.linalg.norm(loop.recording().force, axis=1)
    assert force.max() > 0.5 and np.all(force[-200:] == 0.0)
    assert stats.physics_errors == 1 and isinstance(loop.physics_error, FloatingPointError)


def approach(t):
    """Starts out of contact, pushes into WALL, pulls back, with the button toggling."""
    x = 1.0 - 0.25 * math.sin(min(t, 0.5) * math.pi)
    return (x, 0.01 * math.sin(25 * t), 0.0), int(t > 0.25)


def test_record_and_replay_give_identical_forces(tmp_path):
    path = tmp_path / "session.npz"
    loop = ServoLoop(
        SimulatedDevice(approach, workspace=Workspace()), Proxy.plane(**WALL), record=path, mode="thread"
    )
    loop.start()
    time.sleep(0.5)
    loop.stop()
    rec = Recording.load(path)
    assert len(rec) > 300 and np.abs(rec.force).max() > 0.5 and rec.buttons.max() == 1
    replay = SimulatedDevice.replay(path, realtime=False)
    loop2 = ServoLoop(replay, Proxy.plane(**WALL), record=True, mode="thread")
    loop2.start()
    assert loop2.finished.wait(5.0)
    loop2.stop()
    again = loop2.recording()
    np.testing.assert_array_equal(again.sequence, rec.sequence)
    np.testing.assert_array_equal(again.force, rec.force)
    # real-time replay returns the sample due at the elapsed time
    live = SimulatedDevice.replay(rec, realtime=True)
    live.read()
    time.sleep(0.1)
    s = live.read()
    i = int(np.searchsorted(rec.sequence, s.sequence))
    assert abs(rec.time[i] - rec.time[0] - 0.1) < 0.05


def test_plot_of_a_recorded_session(tmp_path):
    loop = ServoLoop(
        SimulatedDevice(approach, workspace=Workspace()), Proxy.plane(**WALL), record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.3)
    loop.stop()
    plot_recording(loop.recording(), tmp_path / "session.png")
    image = matplotlib.image.imread(tmp_path / "session.png")
    assert image.shape[0] > 400 and image.shape[1] > 600 and image.std() > 0.01


def test_cli_reports_a_missing_hid_device(capsys):
    assert cli.main(["--hid", "ffff:fffe", "--proxy-only", "--duration", "0.1"]) == 2
    assert "cannot open the device" in capsys.readouterr().err


def test_recording_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a recording")
    with pytest.raises(ValueError, match="bad.npz"):
        Recording.load(bad)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="max_force"):
        ServoLoop(still(), Proxy.plane(**WALL), max_force=0.0, mode="thread")
    with pytest.raises(ValueError, match="rate_hz"):
        ServoLoop(still(), Proxy.plane(**WALL), rate_hz=float("nan"), mode="thread")
    with pytest.raises(TypeError, match="model"):
        ServoLoop(still(), object())
    with pytest.raises(ValueError, match="normal"):
        Proxy.plane((0, 0, 0), (0, 0, 0), 1.0)
    with pytest.raises(ValueError, match="stiffness"):
        Proxy.sphere((0, 0, 0), 1.0, -1.0)


def test_proxy_forces_plane_and_sphere():
    wall = Proxy.plane(**WALL)
    assert wall.force((0.9, 0, 0)) == (0.0, 0.0, 0.0)
    fx, fy, fz = wall.force((0.77, 0, 0))
    assert fx == pytest.approx(30.0 * 0.1) and fy == fz == 0.0
    assert wall.force((0.77, 0, 0), (-1.0, 0, 0))[0] == pytest.approx(3.0 + 0.3)  # damper resists entry
    assert wall.force((0.86, 0, 0), (10.0, 0, 0)) == (0.0, 0.0, 0.0)  # never pulls
    ball = Proxy.sphere((0, 0, 0), 1.0, 10.0, tool_radius=0.1)
    assert ball.force((0, 1.0, 0))[1] == pytest.approx(1.0)
    cave = Proxy.sphere((0, 0, 0), 1.0, 10.0, tool_radius=0.1, inside=True)
    assert cave.force((0, 0, 0.95))[2] == pytest.approx(-0.5) and cave.force((0, 0, 0.5)) == (0.0, 0.0, 0.0)


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(finite_or_not, finite_or_not, finite_or_not), min_size=1, max_size=40),
    st.floats(0.1, 10.0),
    st.floats(1e-3, 5.0),
)
def test_force_shaper_bounds_any_input(forces, max_force, step_max):
    shape = ForceShaper(max_force, step_max)
    last = (0.0, 0.0, 0.0)
    for f in forces:
        out = shape(*f)
        assert all(math.isfinite(c) for c in out)
        assert math.hypot(*out) <= max_force * (1 + 1e-12)
        assert math.dist(out, last) <= step_max * (1 + 1e-12)
        last = out


def test_watchdog_ramps_linearly_and_counts_trips():
    dog = Watchdog(ramp_time=0.02)
    gains = [dog(True, 0.001) for _ in range(25)]
    assert gains[9] == pytest.approx(0.5) and gains[-1] == 1.0 and dog.trips == 0
    down = [dog(False, 0.001) for _ in range(25)]
    assert down[9] == pytest.approx(0.5) and down[19] == 0.0 and dog.trips == 1
