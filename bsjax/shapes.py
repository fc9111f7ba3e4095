"""Built-in shapes: the thesis's teardrop and spoon (bowl + handle), and simple test surfaces.

Units are metres (the spoon is about 18 cm long), so the physics presets apply directly.
"""

from __future__ import annotations

import numpy as np

from bsjax import _checks
from bsjax._declared import declared
from bsjax.basis import BSplineSurface, clamped_knots

__all__ = ["plate", "sphere", "spoon_bowl", "spoon_handle", "teardrop"]


def _float(value, name: str) -> float:
    """A real scalar as a Python float (a clear TypeError otherwise)."""
    _checks.check_real(value, name)
    if np.ndim(value) != 0 or not isinstance(value, (int, float, np.integer, np.floating)):
        _checks.fail(name, "a real number", repr(value))
    return float(value)


# Radius gain of a uniform periodic cubic: on a regular N-gon of radius R the curve passes at
# R (2/3 + cos(2π/N)/3) at the knots; dividing by it puts the curve close to the circle.
def _ring_gain(n: int) -> float:
    return 2.0 / 3.0 + np.cos(2.0 * np.pi / n) / 3.0


def _revolve(profile: np.ndarray, n_around: int, dtype=None) -> BSplineSurface:
    """Closed-in-v surface of revolution about z from a `(r, 2)` profile of (radius, z) rows."""
    theta = 2.0 * np.pi * np.arange(n_around) / n_around
    rho = profile[:, :1] / _ring_gain(n_around)
    z = np.repeat(profile[:, 1:], n_around, axis=1)
    ctrl = np.stack([rho * np.cos(theta), rho * np.sin(theta), z], axis=-1)
    r = len(profile)
    return BSplineSurface(
        ctrl.astype(dtype or np.float64), clamped_knots(r, 3, dtype), None, 3, 3, periodic_v=True
    )


def teardrop(dtype=None) -> BSplineSurface:
    """The thesis's teardrop (Fig. 6.4): 8×8 bicubic, closed in v, poles at both ends of u.

    Height 2 (z from −1 to 1), pointed at the top (u = 0), round at the bottom (u = 1).
    """
    profile = np.array(
        [
            [0.0, 1.0],
            [0.12, 0.8],
            [0.38, 0.45],
            [0.62, 0.0],
            [0.7, -0.45],
            [0.52, -0.85],
            [0.2, -1.0],
            [0.0, -1.0],
        ]
    )
    return _revolve(profile, 8, dtype)


@declared
def sphere(radius: float = 1.0, n_rows: int = 8, n_around: int = 8, dtype=None) -> BSplineSurface:
    """An approximate sphere: closed in v, poles at u = 0 (top) and u = 1 (bottom); `radius`
    finite > 0, `n_rows`, `n_around` ints ≥ 4."""
    _checks.positive(_float(radius, "radius"), "radius")
    _checks.check_count(n_rows, "n_rows", minimum=4)
    _checks.check_count(n_around, "n_around", minimum=4)
    phi = np.linspace(0.0, np.pi, n_rows)
    # Pull the profile polygon outwards so the cubic curve lies near the circle.
    profile = np.stack([np.sin(phi) * 1.08, np.cos(phi) * 1.02], axis=-1) * radius
    profile[0, 0] = profile[-1, 0] = 0.0
    return _revolve(profile, n_around, dtype)


@declared
def plate(r: int = 8, s: int = 8, size: float = 1.0, degree: int = 3, dtype=None) -> BSplineSurface:
    """A flat square plate `[0, size]²` at z = 0 (normal +z), `r × s` control points (ints
    > `degree`), `size` finite > 0."""
    _checks.check_degree(degree, "degree")
    _checks.check_count(r, "r", minimum=degree + 1)
    _checks.check_count(s, "s", minimum=degree + 1)
    _checks.positive(_float(size, "size"), "size")
    x, y = np.meshgrid(np.linspace(0, size, r), np.linspace(0, size, s), indexing="ij")
    ctrl = np.stack([x, y, np.zeros_like(x)], axis=-1).astype(dtype or np.float64)
    return BSplineSurface(
        ctrl, clamped_knots(r, degree, dtype), clamped_knots(s, degree, dtype), degree, degree
    )


def spoon_handle(dtype=None) -> BSplineSurface:
    """Spoon handle: a 12 cm strip, 1.2 cm wide, gently curved up, 8×8 bicubic.

    u runs from the free end (x = −0.12) to the neck (x = 0), where it meets `spoon_bowl`'s
    u = 0 edge exactly.
    """
    x, y = np.meshgrid(np.linspace(-0.12, 0.0, 8), 0.006 * np.linspace(-1, 1, 8), indexing="ij")
    z = 0.008 * (x / 0.12) ** 2 + 0.0015 * (1 - (y / 0.006) ** 2)
    z = z - z[-1:, :]  # the neck row lies at z = 0, like the bowl's first row
    ctrl = np.stack([x, y, z], axis=-1).astype(dtype or np.float64)
    return BSplineSurface(ctrl, clamped_knots(8, 3, dtype), clamped_knots(8, 3, dtype), 3, 3)


def spoon_bowl(dtype=None) -> BSplineSurface:
    """Spoon bowl: a 6 cm long, 4.4 cm wide, 1.2 cm deep dish, 8×8 bicubic.

    u runs from the neck (x = 0, half-width 6 mm, z = 0) to the tip; v across the bowl.
    """
    u = np.linspace(0.0, 1.0, 8)
    half = 0.006 + 0.016 * np.sin(np.pi * u * 0.8) ** 0.7 * (1 - 0.5 * u**4)
    x = 0.06 * u
    t = np.linspace(-1.0, 1.0, 8)
    y = half[:, None] * t[None, :]
    depth = 0.012 * np.sin(np.pi * np.clip(u * 1.05, 0, 1)) ** 1.2
    z = -depth[:, None] * (1 - t[None, :] ** 2)
    ctrl = np.stack([np.repeat(x[:, None], 8, 1), y, z], axis=-1).astype(dtype or np.float64)
    return BSplineSurface(ctrl, clamped_knots(8, 3, dtype), clamped_knots(8, 3, dtype), 3, 3)
