"""The haptic safety chain (issue #16): servo fault scenarios, argument checks, force shaping, and
poses validated where they enter.

Fault scenarios run the real `ServoLoop` with the simulated device (or a real pseudo-terminal for
serial) and assert on the recorded force: once the physics dies or the device stops answering,
every tick that starts later than `arrival + timeout + ramp_time` (plus 2 ms: one tick for the
servo to see the arrival, and float rounding of the ramp) writes exactly zero, whatever the
producers' own timestamps say. The arrival is taken from the recording (the first tick after the
producer's last output), so the assertion holds on a loaded machine too.
"""

import dataclasses
import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bsjax.device import (
    DeviceError,
    Proxy,
    SerialDevice,
    ServoLoop,
    SimulatedDevice,
    Workspace,
    decode_frames,
    encode_force,
    encode_frame,
    encode_pose,
)
from bsjax.device import _frames as frames
from bsjax.device._protocol import DeviceSample
from bsjax.device._shaping import ForceShaper, VelocityFilter, fresh
from tests.test_device_serial import Emulator

WALL = dict(point=(0.62, 0.0, 0.0), normal=(1.0, 0.0, 0.0), stiffness=30.0, damping=0.3, tool_radius=0.25)
TIMEOUT, RAMP, MARGIN = 0.03, 0.02, 0.002


def still(x=0.8):
    """A stylus held still at (x, 0, 0) model units: 0.07 into WALL (2.1 N)."""
    return SimulatedDevice(lambda t: ((x, 0.0, 0.0), 0), workspace=Workspace())


def recorded(loop):
    rec = loop.recording()
    return rec.time + loop.started_at, np.linalg.norm(rec.force, axis=1), rec


def assert_zero_after(t, force, fault, timeout, ramp=RAMP):
    """Every tick after the servo saw the last arrival + timeout + ramp writes exactly zero."""
    seen = t[t >= fault][0]  # the servo stamps an arrival at the first tick after it
    after = t > seen + timeout + ramp + MARGIN
    assert after.sum() > 30, "too few ticks after the fault to judge"
    assert np.all(force[after] == 0.0), force[after].max()
    late = t[after][0] - fault
    # the first tick past the limit is the next one the servo runs: at most one period late,
    # or one scheduling gap late when the loaded machine delayed that tick
    window = t[(t > seen) & (t <= t[after][0])]
    gap = float(np.max(np.diff(window))) if len(window) > 1 else 0.0
    assert late <= timeout + ramp + MARGIN + (seen - fault) + max(0.0015, gap)
    return t[(t > fault) & (force == 0.0)][0] - fault  # fault → first zero tick


class StampingModel:
    """Physics that renders WALL with its own `stamp` (another clock, inf, NaN, stale, future),
    until `die` is set: then it raises (`mode="raise"`) or hangs (`mode="hang"`)."""

    def __init__(self, stamp, mode="raise"):
        self.stamp, self.mode = stamp, mode
        self.die, self.release = threading.Event(), threading.Event()
        self.last_out = self.fault = -math.inf

    def update(self, sample):
        if self.die.is_set():
            if self.fault == -math.inf:
                self.fault = self.last_out  # the last proxy handed out before the death
            if self.mode == "raise":
                raise RuntimeError("physics died")
            self.release.wait(2.0)
        proxy = Proxy.plane(**WALL, stamp=self.stamp())
        self.last_out = time.perf_counter()
        return proxy


STAMPS = {
    "time.time": time.time,  # another clock: ~1.7e9 s, "in the future" for perf_counter
    "stale": lambda: 0.0,
    "future": lambda: time.perf_counter() + 1e6,
}


@pytest.mark.parametrize("mode", ["raise", "hang"])
@pytest.mark.parametrize("stamp", list(STAMPS))
def test_physics_death_zeroes_force_whatever_the_proxy_stamp(stamp, mode):
    model = StampingModel(STAMPS[stamp], mode)
    loop = ServoLoop(
        still(), model, physics_hz=200, proxy_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.25)
    model.die.set()
    time.sleep(0.2)
    model.release.set()
    stats = loop.stop()
    t, force, _ = recorded(loop)
    fault = model.fault
    alive = (t > loop.started_at + 0.1) & (t < fault)
    assert force[alive].min() > 1.5  # the stamp is ignored: a live physics renders the wall
    dead = t < fault + 0.19  # (a hung physics comes back when released)
    assert_zero_after(t[dead], force[dead], fault, TIMEOUT)
    assert stats.watchdog_trips >= 1 and (mode == "hang" or stats.physics_errors == 1)


@pytest.mark.parametrize("stamp", [math.nan, math.inf, -math.inf])
def test_a_proxy_refuses_a_stamp_that_is_not_a_time(stamp):
    with pytest.raises(ValueError, match="stamp: expected a finite time in s, got"):
        Proxy.plane((0, 0, 0), (0, 0, 1), 100.0, stamp=stamp)
    with pytest.raises(TypeError, match="stamp: expected a real number, got str"):
        Proxy("none", stamp="now")  # pyright: ignore[reportArgumentType]


class WrongClockDevice:
    """A third-party driver: delegates to a `SimulatedDevice` but stamps `received` with another
    clock (`time.time()`), or `inf`."""

    def __init__(self, received):
        self.inner, self.received = still(), received
        self.last_good = self.fault = -math.inf

    def read(self):
        sample = self.inner.read()
        if not self.inner._paused:
            self.last_good = time.perf_counter()
        elif self.fault == -math.inf:
            self.fault = self.last_good  # the last new sample before it fell silent
        return dataclasses.replace(sample, received=self.received())

    def write(self, force, torque=None):
        self.inner.write(force, torque)

    def close(self):
        self.inner.close()


@pytest.mark.parametrize("received", [time.time, lambda: math.inf, lambda: math.nan])
def test_silent_device_zeroes_force_whatever_its_clock(received):
    dev = WrongClockDevice(received)
    loop = ServoLoop(
        dev, Proxy.plane(**WALL), device_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.25)
    dev.inner.pause()  # stops answering: the same sample again, each read a fresh copy
    time.sleep(0.2)
    dev.inner.resume()
    time.sleep(0.15)
    stats = loop.stop()
    t, force, _ = recorded(loop)
    fault = dev.fault
    assert force[(t > loop.started_at + 0.1) & (t < fault)].min() > 1.5
    paused = t < fault + 0.19
    assert_zero_after(t[paused], force[paused], fault, TIMEOUT)
    assert force[-20:].min() > 1.5 and stats.watchdog_trips == 1  # back once it answers again


def test_silent_serial_device_zeroes_force_with_default_limits():
    """Defaults (device_timeout 50 ms, ramp 20 ms) over a real pty: the emulator stops sending."""
    emu = Emulator(position=(0.08, 0.0, 0.0))  # device metres = model units here
    try:
        with SerialDevice(emu.path) as dev:
            loop = ServoLoop(dev, Proxy.plane(**WALL), record=True, mode="thread")
            loop.start()
            time.sleep(0.3)
            emu._stream = False
            time.sleep(0.25)
            loop.stop()
        t, force, rec = recorded(loop)
        last_seq = rec.sequence.max()
        fault = t[np.argmax(rec.sequence == last_seq)]  # first tick that saw the last frame
        assert force[(t > loop.started_at + 0.15) & (t < fault)].min() > 0.1
        measured = assert_zero_after(t, force, fault, 0.05)
        assert measured <= 0.05 + 0.02 + MARGIN
    finally:
        emu.close()


class FailingDevice(SimulatedDevice):
    """A device whose driver dies: after `n` reads `read` raises a `BaseException` (not an
    `Exception`, which the servo counts and survives)."""

    class Unplugged(BaseException):
        pass

    def __init__(self, n):
        super().__init__(lambda t: ((0.8, 0.0, 0.0), 0), workspace=Workspace())
        self.n = n

    def read(self):
        self.n -= 1
        if self.n < 0:
            raise self.Unplugged("USB cable pulled")
        return super().read()


def test_dead_servo_thread_is_visible_and_writes_zero():
    dev = FailingDevice(200)
    loop = ServoLoop(dev, Proxy.plane(**WALL), mode="thread")
    loop.start()
    assert loop.finished.wait(3.0)
    assert not loop.running and isinstance(loop.error, FailingDevice.Unplugged)
    assert dev.last_force.tolist() == [0.0, 0.0, 0.0] and dev.writes >= 150
    with pytest.raises(DeviceError, match="Unplugged.*USB cable pulled"):
        loop.stop()


def test_device_exceptions_are_counted_and_the_watchdog_acts():
    class Flaky(SimulatedDevice):
        def read(self):
            sample = super().read()
            if self.failing:
                raise OSError("read failed")
            return sample

    dev = Flaky(lambda t: ((0.8, 0.0, 0.0), 0), workspace=Workspace())
    dev.failing = False
    loop = ServoLoop(
        dev, Proxy.plane(**WALL), device_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.2)
    fault = time.perf_counter()
    dev.failing = True
    time.sleep(0.15)
    stats = loop.stop()
    t, force, _ = recorded(loop)
    assert stats.device_errors > 30 and loop.error is None
    assert_zero_after(t, force, fault, TIMEOUT)


def nan_window(t):
    """Holds still in WALL, but the position is NaN for 100 ms from t = 0.2 s."""
    x = math.nan if 0.2 <= t < 0.3 else 0.8
    return (x, 0.0, 0.0), 0


def test_nan_pose_is_dropped_at_the_device_and_force_stays_finite():
    dev = SimulatedDevice(nan_window, workspace=Workspace())
    loop = ServoLoop(
        dev, Proxy.plane(**WALL), device_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.45)
    loop.stop()
    t, force, rec = recorded(loop)
    assert np.all(np.isfinite(rec.position)) and np.all(np.isfinite(rec.force))
    assert dev.counters["bad_pose"] > 50
    t0 = dev._t0  # script time 0 on the servo clock (a tick reads the device just after its start)
    window = (t > t0 + 0.2 + TIMEOUT + RAMP + 0.005) & (t < t0 + 0.3 - 0.002)
    assert window.sum() > 20 and np.all(force[window] == 0.0)  # no new sample: stale
    assert force[-20:].min() > 1.5


class RawDevice(SimulatedDevice):
    """A driver that skips the `_sample` gate: returns NaN positions for 100 ms as they come."""

    def read(self):
        sample = super().read()
        if 0.2 <= sample.timestamp < 0.3:
            return dataclasses.replace(sample, position=np.array([math.nan, 0.0, 0.0]))
        return sample


def test_nan_sample_from_any_device_is_not_rendered():
    dev = RawDevice(lambda t: ((0.8, 0.0, 0.0), 0), workspace=Workspace())
    loop = ServoLoop(
        dev, Proxy.plane(**WALL), device_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.45)
    stats = loop.stop()
    _, force, rec = recorded(loop)
    assert stats.bad_samples > 50 and np.all(np.isfinite(rec.position))
    assert np.all(np.isfinite(force)) and force.min() == 0.0 and force[-20:].min() > 1.5


def test_overflowing_wall_saturates_at_max_force_along_its_normal():
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    stiff = Proxy.plane(np.zeros(3), n * 1e300, 1e308, tool_radius=0.0)  # normal scaled before use
    assert stiff.normal == pytest.approx(tuple(n))
    assert all(math.isfinite(c) for c in stiff.force(-5.0 * n))  # k·depth = 5e308 overflows: saturated
    dev = SimulatedDevice(lambda t: (tuple(-5.0 * n), 0), workspace=Workspace())
    loop = ServoLoop(dev, stiff, max_force=2.5, record=True, mode="thread")
    loop.start()
    time.sleep(0.3)
    stats = loop.stop()
    _, force, rec = recorded(loop)
    held = rec.force[-100:]
    np.testing.assert_allclose(np.linalg.norm(held, axis=1), 2.5, rtol=1e-12)
    np.testing.assert_allclose(held / 2.5, np.tile(n, (100, 1)), atol=1e-12)
    assert force.max() <= 2.5 * (1 + 1e-12) and stats.clamped > 100 and stats.nonfinite == 0


def test_nan_force_is_zero_and_counted():
    class NanWall(Proxy):
        def force(self, position, velocity=(0.0, 0.0, 0.0)):
            return math.nan, 1.0, 0.0

    bad = NanWall("plane", WALL["point"], WALL["normal"], 0.0, False, 0.25, 30.0, 0.0, 0.0)
    loop = ServoLoop(still(), bad, record=True, mode="thread")
    loop.start()
    time.sleep(0.1)
    stats = loop.stop()
    assert np.all(loop.recording().force == 0.0) and stats.nonfinite == stats.ticks > 50


# --- ServoLoop arguments ------------------------------------------------------------------------
BAD_ARGUMENTS = [
    ("velocity_tau", 0.0, ValueError),
    ("velocity_tau", -0.005, ValueError),
    ("velocity_tau", math.nan, ValueError),
    ("cpu", "a", TypeError),
    ("cpu", 1.5, TypeError),
    ("cpu", True, TypeError),
    ("cpu", -1, ValueError),
    ("cpu", 100000, ValueError),
    ("spin_us", -1.0, ValueError),
    ("spin_us", math.inf, ValueError),
    ("spin_us", "150", TypeError),
    ("rate_hz", 0, ValueError),
    ("rate_hz", math.inf, ValueError),
    ("rate_hz", 1e9, ValueError),
    ("rate_hz", True, TypeError),
    ("max_force", math.inf, ValueError),
    ("max_force", -3.0, ValueError),
    ("max_force", 3.0 + 0j, TypeError),
    ("max_force", np.array([3.0]), TypeError),
    ("max_force_rate", 0.0, ValueError),
    ("physics_hz", math.nan, ValueError),
    ("proxy_timeout", -0.05, ValueError),
    ("device_timeout", 0.0, ValueError),
    ("ramp_time", math.inf, ValueError),
    ("switch_interval", 0.0, ValueError),
    ("realtime", "yes", TypeError),
    ("freeze_gc", 1, TypeError),
    ("record", 3.0, TypeError),
]


@pytest.mark.parametrize(("name", "value", "error"), BAD_ARGUMENTS)
def test_servo_arguments_are_checked_at_construction(name, value, error):
    with pytest.raises(error, match=f"^{name}: expected"):
        ServoLoop(still(), Proxy.plane(**WALL), **{name: value}, mode="thread")


def test_servo_refuses_a_device_without_read_and_write():
    with pytest.raises(TypeError, match="^device: expected a HapticDevice"):
        ServoLoop(object(), Proxy.plane(**WALL))


def test_numpy_scalars_are_accepted():
    loop = ServoLoop(
        still(),
        Proxy.plane(**WALL),
        rate_hz=np.int64(1000),
        max_force=np.float32(3.0),
        velocity_tau=np.float64(0.005),
        spin_us=np.float32(0.0),
        cpu=np.int64(sorted(__import__("os").sched_getaffinity(0))[0]),
        realtime=np.bool_(False),
        mode="thread",
    )
    assert loop.max_force == 3.0 and type(loop.max_force) is float and loop.cpu is not None
    loop.start()
    time.sleep(0.05)
    assert loop.running
    stats = loop.stop()
    assert stats.ticks > 10 and 0 < stats.force_max <= 3.0


# --- the pure parts: freshness, shaper, velocity ------------------------------------------------
def test_freshness_uses_arrival_times_only():
    assert fresh(1_000, 990, 50) and fresh(1_000, 950, 50) and not fresh(1_000, 949, 50)
    assert not fresh(1_000, 1_001, 50)  # in the future
    for arrival in (math.inf, -math.inf, math.nan):
        assert not fresh(1_000, arrival, 50)


finite_or_not = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=400, deadline=None)
@given(
    st.lists(st.tuples(finite_or_not, finite_or_not, finite_or_not), min_size=1, max_size=30),
    st.floats(1e-3, 1e3),
    st.one_of(st.floats(1e-3, 10.0), st.just(math.inf)),
)
def test_shaper_never_nan_never_above_max_force_keeps_direction(forces, max_force, step_max):
    shape = ForceShaper(max_force, step_max)
    for g in forces:
        shape.last = (0.0, 0.0, 0.0)
        out = shape(*g)
        assert all(math.isfinite(c) for c in out) and math.hypot(*out) <= max_force * (1 + 1e-12)
        if any(math.isnan(c) for c in g):
            assert out == (0.0, 0.0, 0.0)
            continue
        # the direction of the input survives (overflowing components: their signs)
        d = [math.copysign(1.0, c) if math.isinf(c) else c for c in g]
        if any(math.isinf(c) for c in g):
            d = [c if math.isinf(gc) else 0.0 for c, gc in zip(d, g)]
        m = max(map(abs, d))
        if m == 0.0 or math.hypot(*out) < 1e-300:
            continue
        u = [c / m for c in d]
        cos = sum(a * b for a, b in zip(u, out)) / (math.hypot(*u) * math.hypot(*out))
        assert cos == pytest.approx(1.0, abs=1e-9)
        if step_max == math.inf and (any(map(math.isinf, g)) or math.hypot(*u) * m > max_force):
            assert math.hypot(*out) == pytest.approx(max_force, rel=1e-12)  # saturated


def test_nan_counted_and_inf_saturated():
    shape = ForceShaper(3.0, math.inf)
    assert shape(math.nan, 0.0, 0.0) == (0.0, 0.0, 0.0) and shape.nonfinite == 1
    assert shape(math.inf, 0.0, -math.inf) == pytest.approx((3 / math.sqrt(2), 0.0, -3 / math.sqrt(2)))
    assert shape(1e300, 1e300, 0.0) == pytest.approx((3 / math.sqrt(2), 3 / math.sqrt(2), 0.0))
    assert shape.clamped == 2 and shape.nonfinite == 1


def _sample(x, t, seq):
    return DeviceSample(np.array([x, 0.0, 0.0]), np.array([1.0, 0, 0, 0]), 0, t, seq, 0.0)


def test_velocity_filter_survives_bad_timestamps():
    v = VelocityFilter(0.005)
    v(_sample(0.0, 0.0, 1), _sample(0.0, 0.0, 0))
    assert v(_sample(1.0, 0.001, 2), _sample(0.0, 0.0, 1))[0] > 0
    good = v.v
    assert v(_sample(1e300, 1e-300, 3), _sample(-1e300, 0.0, 2)) == good  # overflow: skipped
    assert v(_sample(1.0, math.nan, 4), _sample(0.0, 0.0, 3)) == good
    assert v(_sample(1.0, math.inf, 5), _sample(0.0, 0.0, 4)) == good
    assert v.skipped == 1 and all(map(math.isfinite, v.v))


# --- frames: encoders refuse, decoder never raises ----------------------------------------------
@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: encode_pose(0, (math.nan, 0.0, 0.0)), "position"),
        (lambda: encode_pose(0, (0.0, 0.0, 1e39)), "position"),
        (lambda: encode_pose(0, (0.0, 0.0, 0.0), (1.0, math.inf, 0.0, 0.0)), "orientation"),
        (lambda: encode_force(0, (0.0, -math.inf, 0.0)), "force"),
        (lambda: encode_force(0, (0.0, 0.0, 0.0), (math.nan, 0.0, 0.0)), "torque"),
        (lambda: encode_pose(0, (0.0, 0.0)), "position"),
    ],
)
def test_encoders_refuse_non_finite_values(call, name):
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        call()


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: encode_pose(0.5, (0.0, 0.0, 0.0)), "seq"),
        (lambda: encode_pose(0, ("a", 0.0, 0.0)), "position"),
        (lambda: encode_force(0, (1j, 0.0, 0.0)), "force"),
        (lambda: encode_pose(0, (0.0, 0.0, 0.0), buttons=1.0), "buttons"),
        (lambda: encode_frame(0, 1, "text"), "payload"),
    ],
)
def test_encoders_refuse_wrong_types(call, name):
    with pytest.raises(TypeError, match=f"^{name}: expected"):
        call()


anything = st.one_of(
    st.none(),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True),
    st.text(max_size=50),
    st.lists(st.integers(0, 255), max_size=20),
    st.binary(max_size=200).map(bytearray),
    st.binary(max_size=200).map(memoryview),
    st.binary(max_size=200).map(lambda b: np.frombuffer(b, np.uint8)),
    st.builds(object),
)


@settings(max_examples=300, deadline=None)
@given(anything)
def test_decoder_never_raises_on_any_object(obj):
    got = decode_frames(obj)
    assert isinstance(got.rest, bytes) and isinstance(got.frames, list)
    if isinstance(obj, (bytearray, memoryview, np.ndarray)):
        assert got == decode_frames(bytes(obj))  # bytes-like: decoded as its bytes
    else:
        assert got.frames == [] and got.rest == b"" and got.malformed == 1


def test_decoder_on_documented_odd_inputs():
    for obj in ("hello", None, 5, -1, 10**12, 3.5, object()):
        assert decode_frames(obj).malformed == 1
    released = memoryview(b"abc")
    released.release()
    assert decode_frames(released).malformed == 1
    assert decode_frames(memoryview(encode_pose(3, (0.0, 0.0, 0.0)))).frames[0].seq == 3


# --- transports drop bad poses ------------------------------------------------------------------
def raw_pose(seq, position):
    """A POSE frame with a valid CRC but any floats (what a buggy device firmware sends)."""
    payload = frames._POSE.pack(*position, 1.0, 0.0, 0.0, 0.0, 0, seq * 1000)
    return encode_frame(seq, frames.KIND_POSE, payload)


def test_serial_drops_non_finite_and_out_of_reach_poses():
    emu = Emulator(stream=False)
    try:
        dev = SerialDevice(emu.path)
        emu.send(raw_pose(1, (0.01, 0.0, 0.0)))
        assert dev.read().sequence == 1
        emu.send(raw_pose(2, (math.nan, 0.0, 0.0)) + raw_pose(3, (0.0, math.inf, 0.0)))
        emu.send(raw_pose(4, (0.0, 0.0, 1e30)) + raw_pose(5, (0.02, 0.0, 0.0)))
        end = time.perf_counter() + 2.0
        while dev.read().sequence != 5 and time.perf_counter() < end:
            time.sleep(0.005)
        sample = dev.read()
        assert sample.sequence == 5 and sample.position[0] == pytest.approx(0.02)
        assert dev.counters["bad_pose"] == 3 and dev.counters["frames"] == 2
        dev.close()
    finally:
        emu.close()


def test_simulated_device_drops_out_of_reach_poses():
    dev = SimulatedDevice(
        lambda t: ((1e300 if t > 0.02 else 0.1, 0.0, 0.0), 0), workspace=Workspace(reach=0.5)
    )
    first = dev.read()
    time.sleep(0.03)
    assert dev.read() is first and dev.counters["bad_pose"] == 1
    with pytest.raises(ValueError, match="^reach: expected"):
        Workspace(reach=-1.0)
    with pytest.raises(TypeError, match="^scale: expected"):
        Workspace(scale="2")


# --- constructors of the other public device objects --------------------------------------------
@pytest.mark.parametrize(
    ("make", "error", "name"),
    [
        (lambda: Proxy.plane((0, 0), (1, 0, 0), 1.0), ValueError, "point"),
        (lambda: Proxy.plane((0, 0, 0), (1, 0, math.nan), 1.0), ValueError, "normal"),
        (lambda: Proxy.plane((0, 0, 0), (1, 0, 0), "30"), TypeError, "stiffness"),
        (lambda: Proxy.plane((0, 0, 0), (1, 0, 0), 30.0, damping=-1.0), ValueError, "damping"),
        (lambda: Proxy.sphere(5.0, 1.0, 1.0), TypeError, "centre"),
        (lambda: Proxy.sphere((0, 0, 0), math.inf, 1.0), ValueError, "radius"),
        (lambda: Proxy.sphere((0, 0, 0), 1.0, 1.0, tool_radius=1j), TypeError, "tool_radius"),
        (lambda: SimulatedDevice(script=3), TypeError, "script"),
        (lambda: SimulatedDevice(duration=-1.0), ValueError, "duration"),
        (lambda: SimulatedDevice(workspace={"scale": 2}), TypeError, "workspace"),
        (lambda: SerialDevice("/dev/null", timeout=math.nan), ValueError, "timeout"),
        (lambda: SerialDevice("/dev/null", baudrate=115200.0), TypeError, "baudrate"),
        (lambda: SerialDevice("/dev/null", baudrate=0), ValueError, "baudrate"),
        (lambda: SerialDevice(3), TypeError, "port"),
        (lambda: Workspace(reach=math.nan), ValueError, "reach"),
    ],
)
def test_device_constructors_name_the_bad_argument(make, error, name):
    with pytest.raises(error, match=f"^{name}: expected"):
        make()


def test_plane_normals_of_extreme_magnitude_normalise():
    for normal in ((1e300, 1e300, 0.0), (1e-160, 0.0, 0.0), (np.float32(3.0), 0, 4)):
        n = Proxy.plane((0, 0, 0), normal, 1.0).normal
        assert math.hypot(*n) == pytest.approx(1.0) and all(map(math.isfinite, n))
    far = Proxy.sphere((0, 0, 0), 1.0, 1.0, tool_radius=0.5)
    assert far.force((1e200, 1e200, 0.0)) == (0.0, 0.0, 0.0)  # distance computed without overflow


def test_a_restarted_loop_does_not_trust_the_previous_runs_proxy():
    model = StampingModel(time.perf_counter)
    loop = ServoLoop(
        still(), model, physics_hz=200, proxy_timeout=TIMEOUT, ramp_time=RAMP, record=True, mode="thread"
    )
    loop.start()
    time.sleep(0.15)
    loop.stop()
    model.die.set()  # the physics is dead from the start of the second run
    loop.start()
    time.sleep(0.15)
    loop.stop()
    assert np.all(loop.recording().force == 0.0) and loop.physics_error is not None
