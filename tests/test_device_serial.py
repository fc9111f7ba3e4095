"""Real serial I/O over pseudo-terminals: a device emulator thread on the master end,
`SerialDevice` (pyserial) on the slave end; the `bsjax haptics` command end to end."""

import os
import select
import signal
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest

from bsjax.device import DeviceTimeout, HapticDevice, Proxy, SerialDevice, ServoLoop, Workspace
from bsjax.device import _frames as frames


class Emulator:
    """The device side of a pty pair: streams POSE frames at `rate_hz`, collects FORCE frames."""

    def __init__(self, position=(0.01, 0.02, 0.03), buttons=1, rate_hz=1000.0, stream=True):
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF mapping before pyserial configures the port
        self.path = os.ttyname(self._slave)
        os.set_blocking(self.master, False)  # a full queue drops frames, like an overrun UART
        self.position, self.buttons, self.period = position, buttons, 1.0 / rate_hz
        self.seq = 0
        self.forces: list[tuple[int, tuple]] = []
        self._rest = b""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._stream = stream
        self._thread.start()

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def pose(self, seq=None) -> bytes:
        seq = self.seq if seq is None else seq
        return frames.encode_pose(seq, self.position, buttons=self.buttons, timestamp_us=int(seq * 1000))

    def _run(self):
        next_t = time.perf_counter()
        while not self._stop.is_set():
            if self._stream:
                try:
                    self.send(self.pose())
                except BlockingIOError:
                    pass
                except OSError:
                    return
                self.seq = (self.seq + 1) & 0xFFFF
            while select.select([self.master], [], [], 0)[0]:
                try:
                    chunk = os.read(self.master, 4096)
                except OSError:
                    break
                got = frames.decode_frames(self._rest + chunk)
                self._rest = got.rest
                self.forces += [
                    (f.seq, frames.parse_force(f.payload)[0])
                    for f in got.frames
                    if f.kind == frames.KIND_FORCE
                ]
            next_t += self.period
            time.sleep(max(0.0, next_t - time.perf_counter()))

    def close(self):
        self._stop.set()
        self._thread.join()
        os.close(self.master)
        os.close(self._slave)


@pytest.fixture
def emulator():
    emu = Emulator()
    yield emu
    emu.close()


def _wait(predicate, timeout=2.0):
    end = time.perf_counter() + timeout
    while time.perf_counter() < end:
        if predicate():
            return True
        time.sleep(0.005)
    return False


def test_pose_in_force_out(emulator):
    with SerialDevice(emulator.path, workspace=Workspace(scale=10.0, offset=(0.0, 0.0, 1.0))) as dev:
        assert isinstance(dev, HapticDevice)
        sample = dev.read()
        np.testing.assert_allclose(sample.position, (0.1, 0.2, 1.3), rtol=1e-5)
        assert sample.pressed and sample.sequence == int(sample.timestamp * 1000 + 0.5)
        dev.write((1.0, -2.0, 0.5))
        assert _wait(lambda: any(f == (1.0, -2.0, 0.5) for _, f in emulator.forces))
    # close() sends a zero force last
    assert _wait(lambda: emulator.forces and emulator.forces[-1][1] == (0.0, 0.0, 0.0))


def test_bad_frames_counted_and_dropped_without_stopping():
    emu = Emulator(stream=False)
    try:
        dev = SerialDevice(emu.path)  # opening flushes the input queue: send afterwards
        emu.send(emu.pose(10))
        assert dev.read().sequence == 10
        bad = bytearray(emu.pose(11))
        bad[-1] ^= 0x55
        emu.send(
            bytes(bad) + emu.pose(12)[:17] + emu.pose(13) + emu.pose(9) + b"\xa5\xff garbage" + emu.pose(14)
        )
        assert _wait(lambda: dev.read().sequence == 14)
        c = dev.counters
        assert c["crc_errors"] >= 1 and c["truncated"] >= 1 and c["out_of_order"] == 1 and c["malformed"] >= 1
        assert c["frames"] == 3  # 10, 13, 14
        dev.close()
    finally:
        emu.close()


def test_first_read_times_out_without_frames():
    emu = Emulator(stream=False)
    try:
        with SerialDevice(emu.path, timeout=0.05) as dev, pytest.raises(DeviceTimeout):
            dev.read()
    finally:
        emu.close()


def test_disconnect_and_reconnect_through_a_stable_link(tmp_path):
    link = tmp_path / "ttyHAPTIC"  # like /dev/serial/by-id/…: the path survives a re-plug
    emu = Emulator(position=(0.0, 0.0, 0.01))
    os.symlink(emu.path, link)
    dev = SerialDevice(str(link), reconnect_interval=0.02)
    try:
        first = dev.read()
        emu.close()  # unplug
        assert _wait(lambda: (dev.read(), not dev.connected)[1])
        stale = dev.read()
        assert stale.received == dev.read().received  # the last sample, ageing
        emu = Emulator(position=(0.0, 0.0, 0.02))  # re-plug: a new pty behind the same link
        os.unlink(link)
        os.symlink(emu.path, link)
        assert _wait(lambda: dev.read().position[2] == pytest.approx(0.02))
        assert dev.counters["disconnects"] >= 1 and dev.counters["reconnects"] >= 1
        assert dev.read().received > first.received
    finally:
        dev.close()
        emu.close()


def test_servo_loop_over_serial_clamps_and_ends_with_zero(emulator):
    emulator.position = (0.55, 0.0, 0.0)  # deep inside a wall at x = 0.62 facing +x
    wall = Proxy.plane((0.62, 0.0, 0.0), (1.0, 0.0, 0.0), stiffness=30.0, tool_radius=0.25, stamp=0.0)
    with SerialDevice(emulator.path) as dev:
        loop = ServoLoop(dev, wall, max_force=2.0, mode="thread")
        loop.start()
        assert _wait(lambda: len(emulator.forces) > 300)
        stats = loop.stop()
        assert _wait(lambda: emulator.forces[-1][1] == (0.0, 0.0, 0.0))
    forces = np.array([f for _, f in emulator.forces])
    norms = np.linalg.norm(forces, axis=1)
    assert norms.max() == pytest.approx(2.0, rel=1e-6) and np.all(norms <= 2.0 + 1e-6)
    assert forces[norms > 0][:, 0].min() > 0  # pushes out of the wall
    assert stats.clamped > 0 and stats.rate_hz > 500
    assert dev.counters["frames"] > 300


def test_cli_ctrl_c_writes_zero_force(emulator):
    emulator.position = (0.058, 0.0, 0.0)  # device metres ×10 → in contact with the wall
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bsjax.cli",
            "haptics",
            "--serial",
            emulator.path,
            "--proxy-only",
            "--duration",
            "60",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        assert _wait(lambda: sum(1 for _, f in emulator.forces if f[0] > 0) > 200, timeout=60)
        proc.send_signal(signal.SIGINT)
        # generous: in the full suite other tests' SCHED_FIFO servo threads share the 2 cores
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert "zero force written (interrupted)" in out and "servo" in out
    assert _wait(lambda: emulator.forces[-1][1] == (0.0, 0.0, 0.0))
