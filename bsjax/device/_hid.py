"""`HidDevice`: a haptic arm over USB HID (hidapi), configured by a `HidLayout`, not by code.

A `HidLayout` says where each quantity sits in the device's input report (byte offset, `struct`
format, scale to SI units) and how to build the output report that carries the force. A new arm
needs a new layout (a dict / JSON file, see `HidLayout.from_dict`), nothing else.
"""

from __future__ import annotations

import dataclasses
import numbers
import struct
import time
from dataclasses import dataclass

import numpy as np

from bsjax import _checks
from bsjax._optional import require
from bsjax.device._protocol import (
    DeviceBase,
    DeviceSample,
    DeviceTimeout,
    Workspace,
    force_vector,
    positive_number,
)


@dataclass(frozen=True)
class HidField:
    """One number in a report: `value = unpack(fmt, report[offset:]) * scale`.

    `fmt` is a single-value `struct` format with byte order, e.g. `"<h"` (int16 LE), `"<f"`, `"B"`.
    """

    offset: int
    fmt: str = "<h"
    scale: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "offset", _checks.check_count(self.offset, "offset", minimum=0))
        if not isinstance(self.fmt, str):
            raise TypeError(f"fmt: expected a struct format string, got {type(self.fmt).__name__}")
        if isinstance(self.scale, bool) or not isinstance(self.scale, numbers.Real):
            raise TypeError(f"scale: expected a real number, got {type(self.scale).__name__} {self.scale!r}")
        try:
            n = len(struct.unpack(self.fmt, bytes(struct.calcsize(self.fmt))))
        except struct.error as err:
            raise ValueError(
                f"fmt: expected a struct format of one number, got {self.fmt!r} ({err})"
            ) from None
        if n != 1:
            raise ValueError(f"fmt: expected a struct format of one number, got {self.fmt!r}")
        if not (np.isfinite(self.scale) and self.scale != 0):
            raise ValueError(f"scale: expected a finite non-zero number, got {self.scale}")

    @property
    def end(self) -> int:
        return self.offset + struct.calcsize(self.fmt)

    def get(self, report: bytes) -> float:
        return struct.unpack_from(self.fmt, report, self.offset)[0] * self.scale

    def put(self, report: bytearray, value: float) -> None:
        raw = value / self.scale
        code = self.fmt[-1]
        if code in "fd":
            struct.pack_into(self.fmt, report, self.offset, raw)
            return
        bits = 8 * struct.calcsize(self.fmt)
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code.islower() else (0, (1 << bits) - 1)
        struct.pack_into(self.fmt, report, self.offset, int(min(max(round(raw), lo), hi)))


# HidLayout's integers: name, lowest, highest value
_LAYOUT_INTS = (
    ("vendor_id", 0, 0xFFFF),
    ("product_id", 0, 0xFFFF),
    ("report_length", 1, 1 << 16),
    ("force_length", 1, 1 << 16),
    ("sequence_bits", 1, 64),
    ("report_id", 0, 255),
    ("force_report_id", 0, 255),
)


def _field(f, name: str) -> HidField:
    if isinstance(f, HidField):
        return f
    if not isinstance(f, dict):
        raise TypeError(f"{name}: expected fields as dicts {{offset, fmt, scale}}, got {type(f).__name__}")
    unknown = sorted(set(f) - {"offset", "fmt", "scale"})
    if unknown or "offset" not in f:
        raise ValueError(f"{name}: expected a field {{offset, fmt, scale}}, got the keys {sorted(f)}")
    return HidField(**f)


def _fields(items, name: str, count: int) -> tuple[HidField, ...]:
    if isinstance(items, (HidField, dict)) or not isinstance(items, (list, tuple)):
        raise TypeError(f"{name}: expected a list of {count} fields, got {type(items).__name__}")
    out = tuple(_field(f, name) for f in items)
    if len(out) != count:
        raise ValueError(f"{name}: expected {count} fields, got {len(out)}")
    return out


@dataclass(frozen=True)
class HidLayout:
    """Report layout of one HID haptic arm.

    **Fields:** `vendor_id`, `product_id`; `report_length` (bytes read per input report, report
    id included when the device numbers its reports); `position` (3 fields, metres);
    `orientation` (4 fields, quaternion w x y z) or None (identity); `buttons` or None;
    `timestamp` (seconds after scaling) or None (host time); `sequence` or None, with
    `sequence_bits`; `report_id` expected at byte 0 of input reports, or None;
    `force_report_id`, `force_length`, `force` (3 fields, newtons per count as scale).
    """

    vendor_id: int
    product_id: int
    report_length: int
    position: tuple[HidField, ...]
    force: tuple[HidField, ...]
    force_length: int
    orientation: tuple[HidField, ...] | None = None
    buttons: HidField | None = None
    timestamp: HidField | None = None
    sequence: HidField | None = None
    sequence_bits: int = 16
    report_id: int | None = None
    force_report_id: int = 0

    def __post_init__(self):
        for name, lo, hi in _LAYOUT_INTS:
            value = getattr(self, name)
            if value is None and name == "report_id":
                continue
            value = _checks.check_count(value, name, minimum=lo)
            if value > hi:
                _checks.fail(name, f"an int in {lo}..{hi}", value)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "position", _fields(self.position, "position", 3))
        object.__setattr__(self, "force", _fields(self.force, "force", 3))
        if self.orientation is not None:
            object.__setattr__(self, "orientation", _fields(self.orientation, "orientation", 4))
        for name in ("buttons", "timestamp", "sequence"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _field(value, name))
        need = max(f.end for f in self._input_fields())
        if self.report_length < need:
            raise ValueError(
                f"report_length: expected >= {need} (the last field's end), got {self.report_length}"
            )
        if self.force_length < max(f.end for f in self.force):
            raise ValueError(
                f"force_length: expected >= {max(f.end for f in self.force)}, got {self.force_length}"
            )

    def _input_fields(self):
        fields = list(self.position) + list(self.orientation or ())
        return fields + [f for f in (self.buttons, self.timestamp, self.sequence) if f is not None]

    @classmethod
    def from_dict(cls, spec: dict) -> "HidLayout":
        """Build from plain data (e.g. a JSON file): fields as `{"offset":…, "fmt":…, "scale":…}`.
        An unknown or missing key is a `ValueError` naming it."""
        if not isinstance(spec, dict):
            raise TypeError(f"spec: expected a dict, got {type(spec).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(spec) - known)
        if unknown:
            raise ValueError(f"{unknown[0]}: expected one of the layout keys {sorted(known)}, got {unknown}")
        required = {f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING}
        missing = sorted(required - set(spec))
        if missing:
            raise ValueError(f"{missing[0]}: expected in the layout, got the keys {sorted(spec)}")
        return cls(**spec)

    @classmethod
    def generic(cls, vendor_id: int, product_id: int) -> "HidLayout":
        """The bsjax reference layout (what `bsjax haptics --hid` assumes without a layout file).

        Input report (20 bytes): id 1 | x y z int16 (0.1 mm) | w x y z int16 (1/32767) |
        buttons uint8 | sequence uint16 | pad. Output report (8 bytes): id 2 | fx fy fz int16 (mN).
        """
        pos = tuple(HidField(1 + 2 * k, "<h", 1e-4) for k in range(3))
        quat = tuple(HidField(7 + 2 * k, "<h", 1.0 / 32767) for k in range(4))
        force = tuple(HidField(1 + 2 * k, "<h", 1e-3) for k in range(3))
        return cls(
            vendor_id,
            product_id,
            20,
            pos,
            force,
            8,
            orientation=quat,
            buttons=HidField(15, "B"),
            sequence=HidField(16, "<H"),
            report_id=1,
            force_report_id=2,
        )


def parse_report(
    layout: HidLayout, report
) -> tuple[np.ndarray, np.ndarray, int, float | None, int | None] | None:
    """Input report → `(position, orientation, buttons, timestamp, sequence)`, or None when the
    report is short, carries another report id, or its buttons/sequence are not integers (a NaN
    in a float field). Never raises. Position and orientation are returned as read (they may be
    non-finite): the device's `_sample` gate drops such poses and counts them as `bad_pose`."""
    try:
        data = bytes(report)
        if len(data) < layout.report_length or (layout.report_id is not None and data[0] != layout.report_id):
            return None
        position = np.array([f.get(data) for f in layout.position])
        if layout.orientation is None:
            orientation = np.array([1.0, 0.0, 0.0, 0.0])
        else:
            q = np.array([f.get(data) for f in layout.orientation])
            n = np.linalg.norm(q)
            orientation = q / n if n > 0 else np.array([1.0, 0.0, 0.0, 0.0])
        buttons = int(layout.buttons.get(data)) if layout.buttons else 0
        stamp = layout.timestamp.get(data) if layout.timestamp else None
        seq = int(layout.sequence.get(data)) if layout.sequence else None
    except (TypeError, ValueError, OverflowError, struct.error):
        return None
    return position, orientation, buttons, stamp, seq


def force_report(layout: HidLayout, force) -> bytes:
    """The output report carrying `force` (newtons, device frame); counts saturate at the field range."""
    out = bytearray(layout.force_length)
    out[0] = layout.force_report_id
    for f, value in zip(layout.force, force_vector(force)):
        f.put(out, float(value))
    return bytes(out)


class HidDevice(DeviceBase):
    """A haptic device on USB HID.

    **Arguments:** `layout` (`HidLayout`); `path` (hidapi path, else the first device with the
    layout's vendor/product id); `timeout` (seconds to wait for the first report);
    `reconnect_interval`; `workspace`; `device` — an already created `hid.device`-like object
    (`open`, `open_path`, `set_nonblocking`, `read`, `write`, `close`), default `hid.device()`.
    """

    def __init__(
        self,
        layout: HidLayout,
        path: bytes | None = None,
        timeout: float = 1.0,
        reconnect_interval: float = 0.2,
        workspace: Workspace | None = None,
        device=None,
    ):
        super().__init__(workspace)
        if not isinstance(layout, HidLayout):
            raise TypeError(f"layout: expected a HidLayout, got {type(layout).__name__}")
        timeout = positive_number(timeout, "timeout", allow_zero=True)
        reconnect_interval = positive_number(reconnect_interval, "reconnect_interval", allow_zero=True)
        self.layout, self.path, self.timeout, self.reconnect_interval = (
            layout,
            path,
            timeout,
            reconnect_interval,
        )
        self._factory = device
        self._dev = None
        self._closed = False
        self._retry_at = 0.0
        self._last: DeviceSample | None = None
        self._last_seq: int | None = None
        self._open()

    def _open(self) -> None:
        if self._factory is not None:
            dev = self._factory
        else:
            dev = require("hid", "haptics", "bsjax.device.HidDevice").device()
        if self.path is not None:
            dev.open_path(self.path)
        else:
            dev.open(self.layout.vendor_id, self.layout.product_id)
        dev.set_nonblocking(1)
        self._dev, self._last_seq = dev, None

    def _lost(self) -> None:
        self._count("disconnects")
        try:
            self._dev.close()
        except Exception:
            pass
        self._dev = None
        self._retry_at = time.perf_counter() + self.reconnect_interval

    def _poll(self) -> None:
        if self._dev is None:
            if self._closed or time.perf_counter() < self._retry_at:
                return
            try:
                self._open()
                self._count("reconnects")
            except (OSError, ValueError):
                self._retry_at = time.perf_counter() + self.reconnect_interval
                return
        for _ in range(64):  # drain what is queued, keep the newest valid report
            try:
                report = self._dev.read(self.layout.report_length)
            except (OSError, ValueError):
                self._lost()
                return
            if not report:
                return
            self._take(report)

    def _take(self, report) -> None:
        parsed = parse_report(self.layout, report)
        if parsed is None:
            self._count("malformed")
            return
        position, orientation, buttons, stamp, seq = parsed
        if seq is not None:
            half = 1 << (self.layout.sequence_bits - 1)
            if self._last_seq is not None and not 0 < (seq - self._last_seq) % (2 * half) < half:
                self._count("out_of_order")
                return
            self._last_seq = seq
        stamp = time.perf_counter() if stamp is None else stamp
        sample = self._sample(position, orientation, buttons, stamp, seq if seq is not None else 0)
        if sample is not None:  # else counted as bad_pose: non-finite or out of reach
            self._last = sample
            self._count("frames")

    def read(self) -> DeviceSample:
        self._poll()
        give_up = time.perf_counter() + self.timeout
        while self._last is None:
            if time.perf_counter() > give_up:
                raise DeviceTimeout(
                    f"HID {self.layout.vendor_id:04x}:{self.layout.product_id:04x}: "
                    f"no input report within {self.timeout} s"
                )
            time.sleep(0.0005)
            self._poll()
        return self._last

    def write(self, force, torque=None) -> None:
        report = force_report(self.layout, self.workspace.force_to_device(force_vector(force)))
        if self._dev is None:
            self._count("write_dropped")
            return
        try:
            if self._dev.write(report) < 0:
                self._count("write_dropped")
        except (OSError, ValueError):
            self._lost()

    def close(self) -> None:
        self._closed = True
        if self._dev is None:
            return
        try:
            self._dev.write(force_report(self.layout, np.zeros(3)))
        except (OSError, ValueError):
            pass
        self._dev.close()
        self._dev = None
