"""The `HapticDevice` protocol, the `DeviceSample` it returns, and device → model workspace mapping.

A device reports its stylus pose in its own coordinates (metres); `Workspace` maps positions into
model coordinates (`x_model = scale · R x_device + offset`) and forces back (`f_device = Rᵀ f`;
forces are not scaled, so a proxy stiffness `k` in N per model unit feels like `k · scale` N/m).

Every transport builds its samples through `DeviceBase._sample`, the one gate a pose passes on
its way in: a pose with a non-finite position, orientation or timestamp, or a position outside
the device's reach (`Workspace.reach`, device units), is dropped and counted
(`counters["bad_pose"]`), so it never reaches the servo or the physics.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

BUTTON_PRESS = 1  # bit 0 of `DeviceSample.buttons`: the stylus button (push/pull sculpting)


class DeviceError(RuntimeError):
    """A device failed in a way the caller should know about (not a single bad frame)."""


class DeviceTimeout(DeviceError):
    """No sample arrived within the device's timeout."""


@dataclass(frozen=True, slots=True)
class DeviceSample:
    """One stylus reading, in model coordinates.

    - `position (3,)`: tool centre; `orientation (4,)`: unit quaternion `w x y z`.
    - `buttons`: bit mask (`BUTTON_PRESS` = stylus button).
    - `timestamp`: seconds on the device's clock; `sequence`: the device's sample counter.
    - `received`: host `time.perf_counter()` when the transport built the sample. Informational:
      the servo's watchdog does not trust it (a device may stamp on another clock); it times the
      arrival of each new sample (new `sequence` or `timestamp`) on its own monotonic clock.
    """

    position: np.ndarray
    orientation: np.ndarray
    buttons: int
    timestamp: float
    sequence: int
    received: float

    @property
    def pressed(self) -> bool:
        return bool(self.buttons & BUTTON_PRESS)


@dataclass(frozen=True)
class Workspace:
    """Device → model coordinates: `x_model = scale · R x_device + offset`.

    **Arguments:** `scale > 0` (model units per metre), `offset (3,)`, `rotation (3, 3)` orthonormal,
    `reach > 0` (device units, default 10): a position with a coordinate beyond `±reach` is outside
    the workspace and dropped by the transports (a haptic arm reaches well under a metre; the
    default only catches garbage such as 1e30 or 1e300 from a corrupted frame).
    """

    scale: float = 1.0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    reach: float = 10.0

    def __post_init__(self):
        object.__setattr__(self, "scale", positive_number(self.scale, "scale"))
        object.__setattr__(self, "reach", positive_number(self.reach, "reach"))
        object.__setattr__(self, "offset", _vector(self.offset, "offset", 3))
        rot = np.asarray(self.rotation, dtype=np.float64)
        if rot.shape != (3, 3) or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6):
            raise ValueError(f"rotation: expected an orthonormal (3, 3) matrix, got {rot.tolist()}")
        object.__setattr__(self, "rotation", rot)
        # positions within reach map to finite model positions (|R x| <= √3 reach): no check needed
        bound = self.scale * self.reach * 2.0 + float(np.abs(self.offset).max())
        object.__setattr__(self, "bounded", math.isfinite(bound))

    def to_model(self, position) -> np.ndarray:
        return self.scale * (self.rotation @ np.asarray(position, dtype=np.float64)) + self.offset

    def to_device(self, position) -> np.ndarray:
        return self.rotation.T @ ((np.asarray(position, dtype=np.float64) - self.offset) / self.scale)

    def force_to_device(self, force) -> np.ndarray:
        return self.rotation.T @ np.asarray(force, dtype=np.float64)


@runtime_checkable
class HapticDevice(Protocol):
    """What `ServoLoop` needs from a device. Implementations: `SimulatedDevice`, `SerialDevice`,
    `HidDevice`.

    `read()` never blocks for long once a first sample has arrived: it returns the newest sample
    (the same one again when nothing new came: the servo sees no new `sequence`/`timestamp`, and
    the sample ages on the servo's own clock). `write(force, torque)`
    sends a force in model coordinates (newtons). `close()` releases the device; every
    implementation sends zero force first. Devices are context managers.
    """

    def read(self) -> DeviceSample: ...

    def write(self, force, torque=None) -> None: ...

    def close(self) -> None: ...

    def __enter__(self): ...

    def __exit__(self, *exc) -> None: ...


class DeviceBase:
    """Shared plumbing: context manager, workspace mapping, transport counters."""

    workspace: Workspace

    def __init__(self, workspace: Workspace | None = None):
        if workspace is not None and not isinstance(workspace, Workspace):
            raise TypeError(f"workspace: expected a Workspace or None, got {type(workspace).__name__}")
        self.workspace = workspace if workspace is not None else Workspace()
        self.counters: dict[str, int] = {}

    def _count(self, name: str, n: int = 1) -> None:
        if n:
            self.counters[name] = self.counters.get(name, 0) + n

    def _sample(self, position, orientation, buttons, timestamp, sequence) -> DeviceSample | None:
        """The model-frame sample of a device-frame pose, or None (counted as `bad_pose`) when the
        position, orientation or timestamp is not finite or the position is out of reach.

        Pure-Python checks (a few hundred nanoseconds: transports call this up to 1000 times a
        second in the servo thread)."""
        try:
            x, y, z = map(float, position)
            w, a, b, c = map(float, orientation)
            stamp = float(timestamp)
        except (TypeError, ValueError, OverflowError):
            self._count("bad_pose")
            return None
        r = self.workspace.reach
        ok = abs(x) <= r and abs(y) <= r and abs(z) <= r  # False for NaN
        if not (ok and math.isfinite(w + a + b + c) and math.isfinite(stamp)):
            self._count("bad_pose")
            return None
        p = self.workspace.to_model((x, y, z))
        if not self.workspace.bounded and not math.isfinite(p[0] + p[1] + p[2]):
            self._count("bad_pose")  # a huge scale or offset overflowed
            return None
        return DeviceSample(
            p, np.array((w, a, b, c)), int(buttons), stamp, int(sequence), time.perf_counter()
        )

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _vector(x, name: str, size: int) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (size,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected {size} finite numbers, got {np.asarray(x).tolist()}")
    return a


def positive_number(value, name: str, allow_zero: bool = False) -> float:
    """`value` as a float when it is a real number (Python or numpy, not bool), finite and `> 0`
    (`>= 0` with `allow_zero`); `TypeError`/`ValueError` naming the argument otherwise."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__} {value!r}")
    x = float(value)
    if not (math.isfinite(x) and (x >= 0 if allow_zero else x > 0)):
        raise ValueError(f"{name}: expected a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return x


def force_vector(force, name: str = "force") -> np.ndarray:
    """A finite `(3,)` float64 force, or `ValueError` naming the argument."""
    return _vector(force, name, 3)
