"""The servo tick's small pure-Python parts: force clamp and rate limit, watchdog gain, velocity.

Plain classes with `__slots__` and float arithmetic: each call costs well under a microsecond,
and each can be tested on its own.
"""

from __future__ import annotations

import math

_INF = math.inf


def fresh(now_ns: int, arrived_ns: float, limit_ns: int) -> bool:
    """True when something that arrived at `arrived_ns` is at most `limit_ns` old at `now_ns`.

    Both times are on the servo's own monotonic clock (`time.perf_counter_ns`). A non-finite
    arrival (never arrived, NaN) or one in the future is stale: the watchdog never trusts a time
    it cannot order against its own clock.
    """
    age = now_ns - arrived_ns
    return 0 <= age <= limit_ns  # False for NaN and for ±inf arrivals


class ForceShaper:
    """Clamp `|F| ≤ max_force`, then limit the change per tick to `|ΔF| ≤ step_max`.

    - A force with a NaN component is replaced by zero and counted in `nonfinite`.
    - A force whose magnitude overflows (an infinite component, or finite components whose norm
      is beyond the float range: a very stiff wall) keeps its direction — the signs of the
      infinite components, or the direction of the finite vector, computed scaled — and is
      saturated at `max_force` (counted in `clamped`).
    - Both operations keep the force inside the ball of radius `max_force` (the rate limiter
      moves along a segment between two points of the ball), so the output is always finite.
    """

    __slots__ = ("clamped", "last", "limited", "max_force", "nonfinite", "step_max")

    def __init__(self, max_force: float, step_max: float):
        self.max_force, self.step_max = max_force, step_max
        self.last = (0.0, 0.0, 0.0)
        self.clamped = self.limited = self.nonfinite = 0

    def __call__(self, gx: float, gy: float, gz: float) -> tuple[float, float, float]:
        gx, gy, gz = self._clamp(gx, gy, gz)
        fx, fy, fz = self.last
        dx, dy, dz = gx - fx, gy - fy, gz - fz
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if d > self.step_max:
            self.limited += 1
            s = self.step_max / d
            dx, dy, dz = dx * s, dy * s, dz * s
        self.last = (fx + dx, fy + dy, fz + dz)
        return self.last

    def _clamp(self, gx: float, gy: float, gz: float) -> tuple[float, float, float]:
        if gx != gx or gy != gy or gz != gz:  # NaN: no direction to keep
            self.nonfinite += 1
            return 0.0, 0.0, 0.0
        m = max(abs(gx), abs(gy), abs(gz))
        if m == 0.0:
            return 0.0, 0.0, 0.0
        if m == _INF:  # overflowed: the direction of the infinite components, saturated
            ux, uy, uz = (math.copysign(1.0, g) if abs(g) == _INF else 0.0 for g in (gx, gy, gz))
        else:
            ux, uy, uz = gx / m, gy / m, gz / m  # scaled: the norm cannot overflow or underflow
        r = math.sqrt(ux * ux + uy * uy + uz * uz)
        if m * r <= self.max_force:
            return gx, gy, gz
        self.clamped += 1
        s = self.max_force / r
        return ux * s, uy * s, uz * s


class Watchdog:
    """A gain in [0, 1] that ramps linearly down over `ramp_time` while the inputs are stale and
    back up while they are fresh; it starts at 0 (soft start). Counts trips (fresh → stale)."""

    __slots__ = ("attenuated", "gain", "rate", "tripped", "trips")

    def __init__(self, ramp_time: float):
        self.rate = 1.0 / ramp_time
        self.gain, self.tripped = 0.0, True
        self.trips = self.attenuated = 0

    def __call__(self, fresh: bool, elapsed: float) -> float:
        step = elapsed * self.rate if elapsed > 0 else 0.0  # NaN or negative elapsed: no step
        if fresh:
            self.gain = min(1.0, self.gain + step)
            self.tripped = False
        else:
            gain = self.gain - step
            self.gain = gain if gain > 1e-9 else 0.0  # exactly zero, not a rounding residue
            if not self.tripped:
                self.trips += 1
            self.tripped = True
        if self.gain < 1.0:
            self.attenuated += 1
        return self.gain


class VelocityFilter:
    """Stylus velocity: finite differences on device timestamps, first-order low-pass `tau`.

    Only a new sample (another sequence number) with a later, finite device timestamp updates
    the estimate; an update that would make it non-finite (a zero-length time step, an
    overflowing difference) is skipped, so one bad timestamp cannot poison the damping term.
    """

    __slots__ = ("skipped", "tau", "v")

    def __init__(self, tau: float):
        self.tau, self.v = tau, (0.0, 0.0, 0.0)
        self.skipped = 0

    def __call__(self, sample, prev) -> tuple[float, float, float]:
        if sample is None or prev is None or sample.sequence == prev.sequence:
            return self.v
        h = sample.timestamp - prev.timestamp
        if not 0.0 < h < _INF:
            return self.v
        a = 1.0 - math.exp(-h / self.tau)
        p, q = sample.position, prev.position
        vx, vy, vz = self.v
        try:  # Python floats: an overflow is an OverflowError or inf, never a numpy warning
            v = (
                vx + a * ((float(p[0]) - float(q[0])) / h - vx),
                vy + a * ((float(p[1]) - float(q[1])) / h - vy),
                vz + a * ((float(p[2]) - float(q[2])) / h - vz),
            )
        except (OverflowError, ZeroDivisionError):
            v = (math.nan, 0.0, 0.0)
        if math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2]):
            self.v = v
        else:
            self.skipped += 1
        return self.v
