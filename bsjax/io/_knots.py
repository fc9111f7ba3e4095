"""A CAD file's knot vector on any domain → bsjax's clamped [0, 1] knots, exactly.

Rhino and OCCT store closed surfaces and curves with unclamped ("periodic") knots, uniform or
not. Such a spline restricted to its domain `[U_p, U_n]` has an exact clamped equivalent: insert
the domain ends as knots (Boehm's single-knot insertion, "The NURBS Book" §5.2, Eq. 5.15) until
each has multiplicity `p`, then drop the control points whose basis functions vanish on the
domain ("The NURBS Book" §12.3, unclamping's inverse). The geometry on the domain is unchanged
(only rounding: one convex combination per inserted knot). The work is in homogeneous
coordinates `[w P, w]`, so rational splines stay exact.
"""

from __future__ import annotations

import numpy as np


def _insert(hom: np.ndarray, knots: np.ndarray, degree: int, value: float) -> tuple[np.ndarray, np.ndarray]:
    """Insert `value` once into `knots` (control points along axis 0 of `hom`)."""
    p = degree
    k = int(np.searchsorted(knots, value, side="right")) - 1  # knots[k] <= value < knots[k + 1]
    s = int(np.sum(knots == value))
    out = np.empty((hom.shape[0] + 1, *hom.shape[1:]), dtype=hom.dtype)
    out[: k - p + 1] = hom[: k - p + 1]
    out[k - s + 1 :] = hom[k - s :]
    for i in range(k - p + 1, k - s + 1):
        a = (value - knots[i]) / (knots[i + p] - knots[i])
        out[i] = a * hom[i] + (1.0 - a) * hom[i - 1]
    return out, np.insert(knots, k + 1, value)


def clamp(hom: np.ndarray, knots: np.ndarray, degree: int, axis: int = 0):
    """Clamp a full knot vector `knots (n + p + 1,)` at its domain ends.

    **Arguments:** `hom`: homogeneous control points with the `n` along `axis`; `knots`: the full
    knot vector (any nondecreasing values outside the domain are fine: they do not affect it).
    **Returns:** `(hom, knots01, domain)`: the clamped control points (same axis), the clamped
    knots mapped onto [0, 1], and the domain `(U_p, U_n)`.
    """
    p, n = degree, hom.shape[axis]
    h, u = np.moveaxis(np.asarray(hom, dtype=np.float64), axis, 0), np.asarray(knots, dtype=np.float64)
    a, b = float(u[p]), float(u[n])
    while np.sum(u == a) < p:
        h, u = _insert(h, u, p, a)
    first = int(np.flatnonzero(u == a)[-1]) - p
    h, u = h[first:], u[first:].copy()
    u[0] = a
    while np.sum(u == b) < p:
        h, u = _insert(h, u, p, b)
    last = int(np.flatnonzero(u == b)[0])  # the basis functions of index >= last vanish on [a, b]
    h, u = h[:last], u[: last + p + 1].copy()
    u[-1] = b
    u01 = (u - a) / (b - a)
    u01[: p + 1], u01[-p - 1 :] = 0.0, 1.0
    return np.moveaxis(h, 0, axis), u01, (a, b)


def is_clamped(knots: np.ndarray, degree: int) -> bool:
    """`knots` (full, `n + p + 1`) start and end with `p + 1` equal values."""
    return bool(np.all(knots[: degree + 1] == knots[0]) and np.all(knots[-degree - 1 :] == knots[-1]))
