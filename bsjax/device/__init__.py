"""Haptic device bridge: devices, the serial frame, and the safe two-rate force loop.

```python
import time
from bsjax.device import SculptModel, ServoLoop, SimulatedDevice

with SimulatedDevice() as dev, ServoLoop(dev, SculptModel(), max_force=3.0) as loop:
    time.sleep(10)
print(loop.stats.report())
```
The simulated device and the servo loop need only the core; `SerialDevice` and `HidDevice` need
the `haptics` extra (pyserial, hidapi), `plot_recording` the `plot` extra.
"""

from typing import TYPE_CHECKING

from bsjax.device._frames import Decoded, Frame, decode_frames, encode_force, encode_frame, encode_pose
from bsjax.device._hid import HidDevice, HidField, HidLayout
from bsjax.device._protocol import (
    DeviceError,
    DeviceSample,
    DeviceTimeout,
    HapticDevice,
    Workspace,
)
from bsjax.device._proxy import Proxy
from bsjax.device._record import Recorder, Recording
from bsjax.device._serial import SerialDevice
from bsjax.device._servo import ServoLoop
from bsjax.device._simulated import SimulatedDevice
from bsjax.device._telemetry import ServoStats, plot_recording

if TYPE_CHECKING:  # loaded on first use at run time (`__getattr__` below); named here for checkers
    from bsjax.device._constraint_sculpt import ConstraintSculptModel, border_free
    from bsjax.device._physics import PhysicsModel, SculptModel

__all__ = [
    "ConstraintSculptModel",
    "Decoded",
    "DeviceError",
    "DeviceSample",
    "DeviceTimeout",
    "Frame",
    "HapticDevice",
    "HidDevice",
    "HidField",
    "HidLayout",
    "PhysicsModel",
    "Proxy",
    "Recorder",
    "Recording",
    "SculptModel",
    "SerialDevice",
    "ServoLoop",
    "ServoStats",
    "SimulatedDevice",
    "Workspace",
    "border_free",
    "decode_frames",
    "encode_force",
    "encode_frame",
    "encode_pose",
    "plot_recording",
]


def __getattr__(name: str):
    # The physics model pulls in bsjax.mss and bsjax.collide: loaded on first use, so that the
    # devices, the frame codec and the servo loop import quickly (e.g. `bsjax haptics --proxy-only`).
    if name in ("SculptModel", "PhysicsModel"):
        from bsjax.device import _physics as physics

        return getattr(physics, name)
    if name in ("ConstraintSculptModel", "border_free"):
        from bsjax.device import _constraint_sculpt as constraint_sculpt

        return getattr(constraint_sculpt, name)
    raise AttributeError(f"module 'bsjax.device' has no attribute {name!r}")
