"""The local contact model the 1 kHz servo thread renders: a plane or sphere proxy.

Pure Python on floats (no numpy dispatch, no JAX) so one evaluation costs a few microseconds.
The physics thread builds a new immutable `Proxy` at its own rate and swaps it in atomically
(one reference assignment); between updates the servo renders the local model at the current
tool position — the "intermediate representation" of two-rate haptics (Adachi 1995, Mark 1996).

Force (Gao & Gibson §3.2.2, a penalty spring with damping): depth `s` of the tool into the proxy,
`F = max(0, k s + d ṡ) n` along the proxy normal `n`, zero when out of contact. The damper
opposes the penetration rate `ṡ` (the paper's `F = k s − d ṡ` measures ṡ on the surface point,
which moves the other way); the clip at 0 keeps the wall from pulling the tool in. A magnitude
beyond the float range (a very stiff wall, a tool far inside) saturates at the largest float, so
the force keeps its direction and the servo's clamp saturates it at `max_force`; a NaN magnitude
is passed on as NaN, which the servo zeroes and counts.
"""

from __future__ import annotations

import math
import numbers
import sys
import time
from dataclasses import dataclass

PLANE, SPHERE, NONE = "plane", "sphere", "none"
_FLOAT_MAX = sys.float_info.max


@dataclass(frozen=True, slots=True)
class Proxy:
    """An immutable local contact model.

    - `kind`: `"plane"` (half-space below `point` along `normal`), `"sphere"` (ball of `radius`
      at `point`; with `inside=True` the tool is inside a cavity of that radius), or `"none"`.
    - `tool_radius`: the tool's extent along the contact normal (for an ellipsoid tool the physics
      puts its support distance here).
    - `stiffness` (N per model unit), `damping` (N·s per model unit), both ≥ 0.
    - `stamp`: `time.perf_counter()` when the physics made it — informational only (recordings,
      debugging): the servo's watchdog never reads it, it times each proxy's *arrival* on its
      own monotonic clock, so a stamp on another clock or in the future is harmless. A finite
      real number (NaN or inf is not a time: refused).
    """

    kind: str = NONE
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    radius: float = 0.0
    inside: bool = False
    tool_radius: float = 0.0
    stiffness: float = 0.0
    damping: float = 0.0
    stamp: float = 0.0

    def __post_init__(self):
        if self.kind not in (PLANE, SPHERE, NONE):
            raise ValueError(f"kind: expected 'plane', 'sphere' or 'none', got {self.kind!r}")
        for name in ("point", "normal"):
            object.__setattr__(self, name, _vec(getattr(self, name), name))
            if not all(math.isfinite(c) for c in getattr(self, name)):
                raise ValueError(f"{name}: expected 3 finite numbers, got {getattr(self, name)}")
        for name in ("radius", "tool_radius", "stiffness", "damping"):
            value = _real(getattr(self, name), name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value}")
            object.__setattr__(self, name, value)
        stamp = _real(self.stamp, "stamp")
        if not math.isfinite(stamp):
            raise ValueError(f"stamp: expected a finite time in s, got {stamp}")
        object.__setattr__(self, "stamp", stamp)
        if self.kind == PLANE:
            n = math.hypot(*self.normal)  # scaled: (1e300, 1e300, 0) and (1e-160, 0, 0) normalise
            if n == 0:
                raise ValueError("normal: expected a non-zero vector for a plane proxy, got (0, 0, 0)")
            object.__setattr__(self, "normal", tuple(float(c) / n for c in self.normal))

    @classmethod
    def plane(cls, point, normal, stiffness, damping=0.0, tool_radius=0.0, stamp=None) -> "Proxy":
        return cls(
            PLANE,
            point,
            normal,
            0.0,
            False,
            tool_radius,
            stiffness,
            damping,
            time.perf_counter() if stamp is None else stamp,
        )

    @classmethod
    def sphere(
        cls, centre, radius, stiffness, damping=0.0, tool_radius=0.0, inside=False, stamp=None
    ) -> "Proxy":
        return cls(
            SPHERE,
            _vec(centre, "centre"),
            (0.0, 0.0, 1.0),
            radius,
            bool(inside),
            tool_radius,
            stiffness,
            damping,
            time.perf_counter() if stamp is None else stamp,
        )

    def contact(self, x: float, y: float, z: float) -> tuple[float, float, float, float]:
        """`(depth, nx, ny, nz)`: penetration of a tool centred at (x, y, z) and the push direction."""
        if self.kind == PLANE:
            nx, ny, nz = self.normal
            px, py, pz = self.point
            return self.tool_radius - ((x - px) * nx + (y - py) * ny + (z - pz) * nz), nx, ny, nz
        if self.kind == SPHERE:
            dx, dy, dz = x - self.point[0], y - self.point[1], z - self.point[2]
            dist = math.hypot(dx, dy, dz)  # scaled: no overflow for a tool far away
            if dist == 0.0:
                dx, dy, dz, dist = 0.0, 0.0, 1.0, 1.0  # any direction: the centre is symmetric
            nx, ny, nz = dx / dist, dy / dist, dz / dist
            if self.inside:  # the cavity wall pushes the tool back towards the centre
                return dist + self.tool_radius - self.radius, -nx, -ny, -nz
            return self.radius + self.tool_radius - dist, nx, ny, nz
        return -1.0, 0.0, 0.0, 1.0

    def force(self, position, velocity=(0.0, 0.0, 0.0)) -> tuple[float, float, float]:
        """Penalty force on the tool: `max(0, k s + d ṡ) n` (002 §3.2.2), zero out of contact."""
        # Python floats: faster than numpy scalars, and an overflow saturates below without a warning
        depth, nx, ny, nz = self.contact(float(position[0]), float(position[1]), float(position[2]))
        if depth <= 0.0:
            return 0.0, 0.0, 0.0
        # ṡ = −v·n (depth grows when moving against the normal); the spring never pulls.
        rate = -(float(velocity[0]) * nx + float(velocity[1]) * ny + float(velocity[2]) * nz)
        magnitude = self.stiffness * depth + self.damping * rate
        if magnitude != magnitude:  # NaN (e.g. inf − inf): the servo zeroes and counts it
            return math.nan, math.nan, math.nan
        magnitude = min(max(0.0, magnitude), _FLOAT_MAX)  # saturate: keep the direction finite
        return magnitude * nx, magnitude * ny, magnitude * nz


def _real(x, name: str) -> float:
    """A real number (Python or numpy scalar; not bool, complex or str) as a float."""
    if type(x) is float:  # the common case, without the ABC check (the physics rate builds many)
        return x
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {type(x).__name__} {x!r}")
    return float(x)


def _vec(x, name: str) -> tuple[float, float, float]:
    """Three real numbers as a tuple of floats; `TypeError`/`ValueError` naming `name`."""
    try:
        values = tuple(x)
    except TypeError:
        raise TypeError(f"{name}: expected 3 real numbers, got {type(x).__name__} {x!r}") from None
    if len(values) != 3:
        raise ValueError(f"{name}: expected 3 numbers, got {len(values)}: {values}")
    a, b, c = (_real(v, name) for v in values)
    return a, b, c
