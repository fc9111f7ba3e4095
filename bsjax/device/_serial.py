"""`SerialDevice`: a haptic arm over a serial line (pyserial), speaking the frame of `frames.py`.

The device streams POSE frames; the host answers with FORCE frames. Reads are non-blocking (the
servo thread calls `read()` 1000 times a second), every byte that arrives is decoded, bad frames
are counted and dropped, POSE frames that are not newer than the last one (sequence numbers,
serial-number arithmetic) are counted as `out_of_order` and dropped, and POSE frames whose floats are
not finite or out of the workspace's reach (a device bug: the CRC was valid) are counted as
`bad_pose` and dropped. When the port fails (unplugged,
the other end closed) the device closes it and re-opens it every `reconnect_interval` seconds;
meanwhile `read()` returns the last sample, whose growing age makes the servo watchdog ramp the force
to zero.
"""

from __future__ import annotations

import numbers
import os
import time

import numpy as np

from bsjax._optional import require
from bsjax.device import _frames as frames
from bsjax.device._protocol import (
    DeviceBase,
    DeviceSample,
    DeviceTimeout,
    Workspace,
    force_vector,
    positive_number,
)

_READ_CHUNK = 4096


def _pyserial():
    # pyserial is the `haptics` extra: imported when a port is opened, so `bsjax.device` (and the
    # simulated device) imports without it; an `except` clause names it only once an error is raised
    return require("serial", "haptics", "bsjax.device.SerialDevice")


class SerialDevice(DeviceBase):
    """A haptic device on a serial port.

    **Arguments:**
    - `port`: device path (`/dev/ttyACM0`, a `/dev/serial/by-id/…` link, a pty) or a pyserial URL.
    - `baudrate`: line rate (≥ 460800 for 1 kHz POSE frames on a real UART).
    - `timeout`: seconds `read()` waits for the very first sample before `DeviceTimeout`.
    - `write_timeout`: seconds a force write may block; 0 (default) never blocks — a frame the OS
      cannot take at once is counted in `counters["write_dropped"]`.
    - `reconnect_interval`: seconds between re-open attempts after the port failed.
    - `workspace`: device → model mapping.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 921600,
        timeout: float = 1.0,
        write_timeout: float = 0.0,
        reconnect_interval: float = 0.1,
        workspace: Workspace | None = None,
    ):
        super().__init__(workspace)
        timeout = positive_number(timeout, "timeout", allow_zero=True)
        write_timeout = positive_number(write_timeout, "write_timeout", allow_zero=True)
        reconnect_interval = positive_number(reconnect_interval, "reconnect_interval", allow_zero=True)
        if isinstance(baudrate, (bool, np.bool_)) or not isinstance(baudrate, numbers.Integral):
            raise TypeError(f"baudrate: expected a positive int, got {type(baudrate).__name__} {baudrate!r}")
        if baudrate <= 0:
            raise ValueError(f"baudrate: expected a positive int, got {baudrate!r}")
        if not isinstance(port, (str, os.PathLike)):
            raise TypeError(f"port: expected a device path or pyserial URL, got {type(port).__name__}")
        baudrate, port = int(baudrate), os.fspath(port)
        self.port_name = port
        self.baudrate, self.timeout, self.write_timeout = baudrate, timeout, write_timeout
        self.reconnect_interval = reconnect_interval
        self._buffer = b""
        self._last: DeviceSample | None = None
        self._last_seq: int | None = None
        self._tx_seq = 0
        self._retry_at = 0.0
        self._port = None
        self._closed = False
        self._open()  # the first open must succeed: a wrong path is a user error, not a loss

    # --- connection ---------------------------------------------------------------------------
    def _open(self) -> None:
        self._port = _pyserial().serial_for_url(
            self.port_name, baudrate=self.baudrate, timeout=0, write_timeout=self.write_timeout
        )
        self._buffer = b""
        self._last_seq = None  # a re-plugged device restarts its sequence

    def _lost(self) -> None:
        self._count("disconnects")
        try:
            self._port.close()
        except Exception:
            pass
        self._port = None
        self._retry_at = time.perf_counter() + self.reconnect_interval

    def _try_reconnect(self) -> None:
        if time.perf_counter() < self._retry_at:
            return
        try:
            self._open()
            self._count("reconnects")
        except (OSError, _pyserial().SerialException):
            self._retry_at = time.perf_counter() + self.reconnect_interval

    @property
    def connected(self) -> bool:
        return self._port is not None

    # --- I/O --------------------------------------------------------------------------------
    def _poll(self) -> None:
        if self._port is None:
            if self._closed:
                return
            self._try_reconnect()
            if self._port is None:
                return
        try:
            chunk = self._port.read(max(1, min(self._port.in_waiting, _READ_CHUNK)))
        except (OSError, _pyserial().SerialException):
            self._lost()
            return
        if chunk:
            self._feed(chunk)

    def _feed(self, chunk: bytes) -> None:
        got = frames.decode_frames(self._buffer + chunk)
        self._buffer = got.rest
        for name in ("crc_errors", "truncated", "malformed"):
            self._count(name, getattr(got, name))
        for frame in got.frames:
            if frame.kind != frames.KIND_POSE:
                self._count("unexpected_kind")
            elif not frames.seq_newer(frame.seq, self._last_seq):
                self._count("out_of_order")
            else:
                self._last_seq = frame.seq
                position, orientation, buttons, stamp_us = frames.parse_pose(frame.payload)
                # a valid CRC says nothing about the floats: NaN or out-of-reach poses are dropped
                sample = self._sample(position, orientation, buttons, stamp_us * 1e-6, frame.seq)
                if sample is not None:
                    self._last = sample
                    self._count("frames")

    def read(self) -> DeviceSample:
        """The newest pose; waits up to `timeout` only while no sample has ever arrived."""
        self._poll()
        if self._last is None:
            give_up = time.perf_counter() + self.timeout
            while self._last is None:
                if time.perf_counter() > give_up:
                    raise DeviceTimeout(f"{self.port_name}: no POSE frame within {self.timeout} s")
                time.sleep(0.0005)
                self._poll()
        return self._last

    def write(self, force, torque=None) -> None:
        """Send one FORCE frame (model-frame newtons mapped to the device frame)."""
        f = self.workspace.force_to_device(force_vector(force))
        t = np.zeros(3) if torque is None else self.workspace.force_to_device(force_vector(torque, "torque"))
        data = frames.encode_force(self._tx_seq, f, t)
        self._tx_seq = (self._tx_seq + 1) & 0xFFFF
        if self._port is None:
            self._count("write_dropped")
            return
        try:
            written = self._port.write(data)
        except _pyserial().SerialTimeoutException:
            written = 0
        except (OSError, _pyserial().SerialException):
            self._lost()
            return
        if written is not None and written < len(data):
            self._count("write_dropped")

    def close(self) -> None:
        """Send zero force (best effort), then close the port."""
        self._closed = True
        if self._port is None:
            return
        try:
            self._port.write(frames.encode_force(self._tx_seq, (0.0, 0.0, 0.0)))
            self._port.flush()
        except (OSError, _pyserial().SerialException):
            pass
        self._port.close()
        self._port = None
