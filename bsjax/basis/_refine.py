"""Knot insertion, degree elevation (exact) and degree reduction (least squares).

One mechanism serves all three: a change of basis in one direction. When the new spline space
contains the old one (insertion, elevation), the matrix `T` with `B_old = B_new T` is found
exactly by collocation at more parameters than basis functions, and the new control net is
`T P` (in homogeneous coordinates for NURBS). For reduction the same solve is a least-squares
approximation, and its error is measured and returned.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from bsjax import _checks
from bsjax.basis import _tensor
from bsjax.basis._direction import SplineDirection
from bsjax.basis._knots import greville
from bsjax.basis._surface import BSplineSurface


def insert_knots(surface: BSplineSurface, direction: str, values) -> BSplineSurface:
    """Insert knot `values` in `direction` ('u' or 'v'); the surface is unchanged (NURBS Book §5.2)."""
    knots, degree, _ = _direction(surface, direction, "insert_knots")
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if np.any(~np.isfinite(values)) or np.any((values <= 0) | (values >= 1)):
        _checks.fail("values", "knot values strictly inside (0, 1)", values.tolist())
    new = np.sort(np.concatenate([knots, values]))
    SplineDirection(new, degree, name="values (resulting knot vector)")
    return _rebase(surface, direction, new, degree)[0]


def elevate_degree(surface: BSplineSurface, direction: str, times: int = 1) -> BSplineSurface:
    """Raise the degree in `direction` by `times`, geometry unchanged (NURBS Book §5.5).

    Every distinct knot gains `times` in multiplicity, so continuity is kept exactly.
    """
    knots, degree, _ = _direction(surface, direction, "elevate_degree")
    _check_times(times)
    values, counts = np.unique(knots, return_counts=True)
    new = np.repeat(values, counts + times)
    return _rebase(surface, direction, new, degree + times)[0]


def reduce_degree(surface: BSplineSurface, direction: str, times: int = 1) -> tuple[BSplineSurface, float]:
    """Lower the degree in `direction` by `times` as a least-squares approximation.

    The end multiplicities drop by `times` (so the control count drops by `times`, thesis §4.3);
    interior knots are kept, their multiplicity capped at the new degree.

    **Returns:** `(surface, max_error)`: the reduced surface and the largest distance between
    the two surfaces over a dense sample grid.
    """
    knots, degree, _ = _direction(surface, direction, "reduce_degree")
    _check_times(times)
    if degree - times < 1:
        _checks.fail("times", f"at most {degree - 1} (degree {degree} cannot go below 1)", times)
    new_degree = degree - times
    values, counts = np.unique(knots, return_counts=True)
    counts = np.minimum(counts, new_degree)
    counts[0] = counts[-1] = new_degree + 1
    return _rebase(surface, direction, np.repeat(values, counts), new_degree)


def _direction(surface, direction, caller):
    if direction not in ("u", "v"):
        _checks.fail("direction", "'u' or 'v'", repr(direction))
    d = surface.direction(direction)
    if d.periodic:
        _checks.fail(f"{caller}: direction", "a clamped direction (the periodic basis is uniform)", direction)
    return np.asarray(d.knots, dtype=np.float64), d.degree, d.n_ctrl


def _check_times(times):
    if isinstance(times, bool) or not isinstance(times, (int, np.integer)) or times < 1:
        _checks.fail("times", "an int >= 1", times)


def _rebase(surface, direction, new_knots, new_degree):
    """Re-express `surface` in the basis (new_knots, new_degree) along `direction`: the change of
    basis `T` with `B_old ≈ B_new T` by least-squares collocation (exact when the new space
    contains the old), applied to the (homogeneous) control net."""
    old = surface.direction(direction)
    new = SplineDirection(new_knots, new_degree)
    t = np.unique(np.concatenate([np.linspace(0, 1, 4 * (new.n_ctrl + 1)), greville(new_knots, new_degree)]))
    a_old = np.asarray(old.matrix(jnp.asarray(t, surface.ctrl.dtype)), dtype=np.float64)
    a_new = np.asarray(new.matrix(jnp.asarray(t, surface.ctrl.dtype)), dtype=np.float64)
    transform = np.linalg.lstsq(a_new, a_old, rcond=None)[0]  # (n_new, n_old)
    dtype = surface.ctrl.dtype
    w = surface.weights
    net = _tensor.homogeneous(surface.ctrl, w)
    axis = 0 if direction == "u" else 1
    net = jnp.moveaxis(
        jnp.tensordot(jnp.asarray(transform, dtype), jnp.moveaxis(net, axis, 0), axes=1), 0, axis
    )
    ctrl, weights = (net, None) if w is None else (net[..., :3] / net[..., 3:], net[..., 3])
    directions = {"u": surface.direction_u, "v": surface.direction_v}
    directions[direction] = new.astype(dtype)
    result = BSplineSurface.from_directions(ctrl, directions["u"], directions["v"], weights)
    return result, _max_distance(surface, result)


def _max_distance(a, b, count: int = 64):
    """Largest distance between two surfaces on a common `count × count` parameter grid."""
    g = jnp.linspace(0.0, 1.0, count, dtype=a.ctrl.dtype)
    u, v = jnp.meshgrid(g, g, indexing="ij")
    return float(jnp.max(jnp.linalg.norm(a.evaluate(u, v) - b.evaluate(u, v), axis=-1)))
