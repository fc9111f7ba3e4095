"""`SimulatedDevice`: the default device — a scripted trajectory or a recorded session, in real time.

`read()` evaluates the script at the wall-clock time since the first read (so a 1 kHz servo sees
a smooth 1 kHz pose stream), or, for a replay, returns the recorded sample due at that time.
`realtime=False` replays tick by tick instead (one recorded sample per `read()`), which makes
the force sequence of a replay reproducible exactly. `pause()`/`resume()` emulate a device that
stops answering (the last sample is returned again and ages).

A scripted or recorded pose that is not finite or out of the workspace's reach is dropped and
counted (`counters["bad_pose"]`) like a bad frame on a real transport: `read()` returns the last
good sample again (None before the first one), whose age makes the servo's watchdog act.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Callable

import numpy as np

from bsjax.device._protocol import DeviceBase, DeviceSample, Workspace, force_vector, positive_number
from bsjax.device._record import Recording

Script = Callable[[float], tuple]  # t → (position (3,), buttons) or (position, orientation, buttons)


class SimulatedDevice(DeviceBase):
    """A virtual stylus.

    **Arguments:**
    - `script`: `t ↦ (position, buttons)` or `t ↦ (position, orientation, buttons)` in device
      coordinates, t in seconds; default `sculpt_script()` (push and pull on the teardrop).
    - `workspace`: device → model mapping (default: the one `sculpt_script` was written for).
    - `duration`: seconds after which `read()` raises `EOFError` (None: forever).
    """

    DEFAULT_WORKSPACE = Workspace(scale=10.0)  # the mapping `sculpt_script` was written for

    def __init__(
        self, script: Script | None = None, workspace: Workspace | None = None, duration: float | None = None
    ):
        super().__init__(
            workspace if workspace is not None else (self.DEFAULT_WORKSPACE if script is None else None)
        )
        if script is not None and not callable(script):
            raise TypeError(
                f"script: expected a function t -> (position, buttons), got {type(script).__name__}"
            )
        self.script = script if script is not None else sculpt_script()
        self.duration = None if duration is None else positive_number(duration, "duration")
        self._recording: Recording | None = None
        self._realtime, self._loop = True, False
        self._t0: float | None = None
        self._seq = 0
        self._paused = False
        self._last: DeviceSample | None = None
        self.last_force = np.zeros(3)
        self.writes = 0
        self.closed = False

    @classmethod
    def replay(
        cls, recording: Recording | str | os.PathLike, realtime: bool = True, loop: bool = False
    ) -> "SimulatedDevice":
        """Play a `Recording` (or a file written by `Recording.save`); positions are already in
        model coordinates. At the end: start again (`loop=True`) or raise `EOFError`."""
        rec = recording if isinstance(recording, Recording) else Recording.load(recording)
        if len(rec) == 0:
            raise ValueError("recording: expected at least one sample, got an empty recording")
        # positions are model coordinates already: identity map, any finite position in reach
        dev = cls(script=_origin, workspace=Workspace(reach=sys.float_info.max))
        dev._recording, dev._realtime, dev._loop = rec, realtime, loop
        return dev

    def pause(self) -> None:
        """Stop answering: `read()` returns the last sample again (its age grows)."""
        self._paused = True

    def resume(self) -> None:
        self._paused = False

    def read(self) -> DeviceSample | None:
        """The pose due now; the last good one again while paused or when the new one is bad."""
        if self._paused and self._last is not None:
            return self._last
        now = time.perf_counter()
        if self._t0 is None:
            self._t0 = now
        t = now - self._t0
        if self.duration is not None and t > self.duration:
            raise EOFError("simulated session finished")
        sample = self._from_recording(t) if self._recording is not None else self._from_script(t)
        if sample is not None:
            self._last = sample
        return self._last

    def _from_script(self, t: float) -> DeviceSample | None:
        out = self.script(t)
        position, orientation, buttons = (out[0], (1.0, 0.0, 0.0, 0.0), out[1]) if len(out) == 2 else out
        self._seq += 1
        return self._sample(position, orientation, buttons, t, self._seq)

    def _from_recording(self, t: float) -> DeviceSample | None:
        rec = self._recording
        if self._realtime:
            span = rec.time[-1] - rec.time[0]
            if t > span and self._loop and span > 0:
                t = math.fmod(t, span)
            elif t > span:
                raise EOFError("replay finished")
            i = int(np.searchsorted(rec.time - rec.time[0], t, side="right")) - 1
        else:
            i = self._seq
            if i >= len(rec):
                if not self._loop:
                    raise EOFError("replay finished")
                i %= len(rec)
            self._seq += 1
        # recorded positions are in model coordinates: through the identity workspace of replay()
        return self._sample(
            rec.position[i], rec.orientation[i], rec.buttons[i], rec.device_time[i], rec.sequence[i]
        )

    def write(self, force, torque=None) -> None:
        self.last_force = force_vector(force)
        self.writes += 1

    def close(self) -> None:
        self.last_force = np.zeros(3)
        self.closed = True


# The default script works in device metres; this workspace maps 10 cm of stylus travel to one
# model unit around the teardrop (height 2, equator radius ≈ 0.62).
def sculpt_script(
    equator: float = 0.62, tool_radius: float = 0.25, period: float = 4.0, scale: float = 10.0
) -> Script:
    """A repeating push/pull session on a body of revolution about z (the teardrop).

    Each cycle of `period` seconds at azimuth `θ_k = k·45°`: approach from outside (0–25 %),
    press the button and push `0.2` units into the surface (25–60 %), release and withdraw
    (60–80 %), orbit to the next azimuth (80–100 %). Returns device coordinates (model / `scale`).
    The script is a picklable object, so a `SimulatedDevice()` can be sent to the servo process.
    """
    return SculptScript(equator, tool_radius, period, scale)


@dataclasses.dataclass(frozen=True)
class SculptScript:
    """`t ↦ (position, buttons)` of `sculpt_script` (a class so that it pickles)."""

    equator: float = 0.62
    tool_radius: float = 0.25
    period: float = 4.0
    scale: float = 10.0

    def __call__(self, t: float):
        touch = self.equator + self.tool_radius
        far, deep = touch + 0.35, touch - 0.2
        k, phase = divmod(t / self.period, 1.0)
        theta = k * math.pi / 4
        buttons = 0
        if phase < 0.25:
            r = far + (touch + 0.02 - far) * _smooth(phase / 0.25)
        elif phase < 0.6:
            r, buttons = touch + 0.02 + (deep - touch - 0.02) * _smooth((phase - 0.25) / 0.35), 1
        elif phase < 0.8:
            r = deep + (far - deep) * _smooth((phase - 0.6) / 0.2)
        else:
            r, theta = far, theta + math.pi / 4 * _smooth((phase - 0.8) / 0.2)
        z = 0.08 * math.sin(2 * math.pi * t / (3 * self.period))
        s = self.scale
        return (r * math.cos(theta) / s, r * math.sin(theta) / s, z / s), buttons


def _origin(t: float):
    """The script of a replay (never evaluated: the recording supplies the poses)."""
    return np.zeros(3), 0


def _smooth(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3 - 2 * s)
