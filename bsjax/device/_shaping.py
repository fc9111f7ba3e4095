"""The servo tick's small pure-Python parts: force clamp and rate limit, watchdog gain, velocity.

Plain classes with `__slots__` and float arithmetic: each call costs well under a microsecond,
and each can be tested on its own.
"""

from __future__ import annotations

import math


class ForceShaper:
    """Clamp `|F| ≤ max_force`, then limit the change per tick to `|ΔF| ≤ step_max`.

    Non-finite input becomes zero. Both operations keep the force inside the ball of radius
    `max_force` (the rate limiter moves along a segment between two points of the ball).
    """

    __slots__ = ("clamped", "last", "limited", "max_force", "nonfinite", "step_max")

    def __init__(self, max_force: float, step_max: float):
        self.max_force, self.step_max = max_force, step_max
        self.last = (0.0, 0.0, 0.0)
        self.clamped = self.limited = self.nonfinite = 0

    def __call__(self, gx: float, gy: float, gz: float) -> tuple[float, float, float]:
        norm = math.sqrt(gx * gx + gy * gy + gz * gz)
        if not math.isfinite(norm):
            self.nonfinite += 1
            gx = gy = gz = norm = 0.0
        if norm > self.max_force:
            self.clamped += 1
            s = self.max_force / norm
            gx, gy, gz = gx * s, gy * s, gz * s
        fx, fy, fz = self.last
        dx, dy, dz = gx - fx, gy - fy, gz - fz
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if d > self.step_max:
            self.limited += 1
            s = self.step_max / d
            dx, dy, dz = dx * s, dy * s, dz * s
        self.last = (fx + dx, fy + dy, fz + dz)
        return self.last


class Watchdog:
    """A gain in [0, 1] that ramps linearly down over `ramp_time` while the inputs are stale and
    back up while they are fresh; it starts at 0 (soft start). Counts trips (fresh → stale)."""

    __slots__ = ("attenuated", "gain", "rate", "tripped", "trips")

    def __init__(self, ramp_time: float):
        self.rate = 1.0 / ramp_time
        self.gain, self.tripped = 0.0, True
        self.trips = self.attenuated = 0

    def __call__(self, fresh: bool, elapsed: float) -> float:
        if fresh:
            self.gain = min(1.0, self.gain + elapsed * self.rate)
            self.tripped = False
        else:
            self.gain = max(0.0, self.gain - elapsed * self.rate)
            if not self.tripped:
                self.trips += 1
            self.tripped = True
        if self.gain < 1.0:
            self.attenuated += 1
        return self.gain


class VelocityFilter:
    """Stylus velocity: finite differences on device timestamps, first-order low-pass `tau`."""

    __slots__ = ("tau", "v")

    def __init__(self, tau: float):
        self.tau, self.v = tau, (0.0, 0.0, 0.0)

    def __call__(self, sample, prev) -> tuple[float, float, float]:
        if sample is not None and prev is not None and sample.sequence != prev.sequence:
            h = sample.timestamp - prev.timestamp
            if h > 0:
                a = 1.0 - math.exp(-h / self.tau)
                p, q = sample.position, prev.position
                vx, vy, vz = self.v
                self.v = (
                    vx + a * ((p[0] - q[0]) / h - vx),
                    vy + a * ((p[1] - q[1]) / h - vy),
                    vz + a * ((p[2] - q[2]) / h - vz),
                )
        return self.v
