"""The servo protocol that every device model shares (its safety rules): pose gating,
rollback of a bad tick, counters, and the degenerate-plane guard of the proxies.

A model derives from `AbstractHapticModel`, calls `_init_protocol` in its constructor and
implements `_advance(sample) -> Proxy | None` (one tick, its state committed only when the tick
is good; `None` or an exception means the tick went non-finite and is rolled back).
"""

from __future__ import annotations

import math
import numbers
import threading

import numpy as np

from bsjax.device._protocol import DeviceSample
from bsjax.device._proxy import Proxy


class AbstractHapticModel:
    """Pose gating, rollback and counters of a model the `ServoLoop` runs.

    Counters: `ticks` (good ticks), `dropped_poses` (refused by `accepts`), `rollbacks`.
    """

    def _init_protocol(self, surface, reach: float | None, max_rollbacks: int) -> None:
        """Workspace gate from the control net's bounding box (`reach`: model units from its
        centre; default 10 × its diagonal; `math.inf`: no limit), counters, lock, no proxy yet."""
        net = np.asarray(surface.ctrl, dtype=np.float64).reshape(-1, 3)
        lo, hi = net.min(axis=0), net.max(axis=0)
        self.centre = (lo + hi) / 2
        self._centre = tuple(float(c) for c in self.centre)  # the servo process's workspace gate
        reach = 10.0 * float(np.linalg.norm(hi - lo)) if reach is None else reach
        if isinstance(reach, bool) or not isinstance(reach, numbers.Real):
            raise TypeError(f"reach: expected a number > 0 (math.inf: no limit), got {reach!r}")
        if not reach > 0:
            raise ValueError(f"reach: expected a number > 0 (math.inf: no limit), got {reach!r}")
        self.reach = float(reach)
        self.max_rollbacks = max_rollbacks
        self.ticks = self.dropped_poses = self.rollbacks = self._bad_ticks = 0
        self._last_proxy = Proxy()  # what update returns until a first good tick
        self._lock = threading.Lock()

    def accepts(self, sample) -> bool:
        """True when `sample`'s pose may be fed to the physics: a finite `(3,)` position within
        `reach` of the body's centre and a `(4,)` orientation whose squared norm is finite.

        Pure Python (about a microsecond): the servo thread asks it too, for every new sample, so
        that a pose the physics refuses is not rendered either (`ServoLoop`)."""
        try:
            x, y, z = map(float, sample.position)
            w, a, b, c = map(float, sample.orientation)
        except (AttributeError, TypeError, ValueError):
            return False
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return False
        if not math.isfinite(w * w + a * a + b * b + c * c):  # NaN, inf, or a norm that overflows
            return False
        cx, cy, cz = self._centre
        return math.hypot(x - cx, y - cy, z - cz) <= self.reach

    def update(self, sample: DeviceSample) -> Proxy:
        """One physics tick with the tool at `sample`; returns the proxy for the servo.

        A pose `accepts` refuses is dropped (`dropped_poses`), and a tick that fails or whose
        result is not finite is rolled back (`rollbacks`); both return the last good proxy.
        """
        if not self.accepts(sample):
            self.dropped_poses += 1
            return self._last_proxy
        with self._lock:
            try:
                proxy = self._advance(sample)
            except Exception as err:  # a value check inside the tick fired (a non-finite state)
                return self._rolled_back(err)
            if proxy is None:
                return self._rolled_back(None)
            self._bad_ticks = 0
            self.ticks += 1
            self._last_proxy = proxy
        return proxy

    def _advance(self, sample: DeviceSample) -> Proxy | None:
        """One tick (state committed only when good); `None` when its result is not finite."""
        raise NotImplementedError

    def _rolled_back(self, cause: Exception | None) -> Proxy:
        """Keep the last good state (the tick's result is dropped) and return the last good proxy;
        after `max_rollbacks` bad ticks in a row raise `FloatingPointError`, which stops the
        servo's physics thread (its watchdog then ramps the force to zero)."""
        self.rollbacks += 1
        self._bad_ticks += 1
        if self._bad_ticks > self.max_rollbacks:
            raise FloatingPointError(
                f"{type(self).__name__}.update: {self._bad_ticks} ticks in a row failed or went "
                f"non-finite (max_rollbacks = {self.max_rollbacks}); the model cannot recover"
            ) from cause
        return self._last_proxy

    @staticmethod
    def _plane(point, normal, stiffness, damping, tool_radius) -> Proxy:
        """`Proxy.plane`, or no contact model (`Proxy()`) rather than a bad one when the plane is
        degenerate (a zero normal)."""
        try:
            return Proxy.plane(point, normal, stiffness, damping, tool_radius=tool_radius)
        except ValueError:
            return Proxy()
