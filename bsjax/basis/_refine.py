"""Knot insertion, degree elevation (exact) and degree reduction (least squares), for surfaces
(one direction at a time) and curves.

One mechanism serves all three and both kinds of spline: a change of basis along one axis of the
control net. When the new spline space contains the old one (insertion, elevation), the matrix
`T` with `B_old = B_new T` is found exactly by collocation at more parameters than basis
functions, and the new control net is `T P` along that axis (in homogeneous coordinates for
NURBS). For reduction the same solve is a least-squares approximation, and its error is
measured and returned.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from bsjax import _checks
from bsjax._declared import declared
from bsjax.basis import _tensor
from bsjax.basis._curve import BSplineCurve
from bsjax.basis._direction import SplineDirection
from bsjax.basis._knots import greville
from bsjax.basis._surface import BSplineSurface

Spline = BSplineSurface | BSplineCurve


@declared
def insert_knots(spline: Spline, direction=None, values=None) -> Spline:
    """Insert knot `values` (strictly inside (0, 1)); the geometry is unchanged (NURBS Book §5.2).

    Surfaces: `insert_knots(surface, direction, values)` with `direction` 'u' or 'v'.
    Curves: `insert_knots(curve, values)` (no direction).
    **Returns:** the refined surface or curve (one more control point per inserted value).
    """
    direction, values = _curve_args(spline, direction, values, "values", "insert_knots")
    if values is None:
        _checks.fail("values", "knot values to insert", None)
    knots, degree = _clamped(spline, direction, "insert_knots")
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if np.any(~np.isfinite(values)) or np.any((values <= 0) | (values >= 1)):
        _checks.fail("values", "knot values strictly inside (0, 1)", values.tolist())
    new = np.sort(np.concatenate([knots, values]))
    SplineDirection(new, degree, name="values (resulting knot vector)")
    return _rebase(spline, direction, new, degree)


@declared
def elevate_degree(spline: Spline, direction=None, times: int | None = None) -> Spline:
    """Raise the degree by `times` (default 1), geometry unchanged (NURBS Book §5.5).

    Surfaces: `elevate_degree(surface, direction, times=1)`; curves: `elevate_degree(curve, times=1)`.
    Every distinct knot gains `times` in multiplicity, so continuity is kept exactly.
    """
    direction, times = _curve_args(spline, direction, times, "times", "elevate_degree")
    times = 1 if times is None else times
    knots, degree = _clamped(spline, direction, "elevate_degree")
    _check_times(times)
    values, counts = np.unique(knots, return_counts=True)
    new = np.repeat(values, counts + times)
    return _rebase(spline, direction, new, degree + times)


@declared
def reduce_degree(spline: Spline, direction=None, times: int | None = None) -> tuple[Spline, float]:
    """Lower the degree by `times` (default 1) as a least-squares approximation.

    Surfaces: `reduce_degree(surface, direction, times=1)`; curves: `reduce_degree(curve, times=1)`.
    The end multiplicities drop by `times` (so the control count drops by `times`, thesis §4.3);
    interior knots are kept, their multiplicity capped at the new degree.

    **Returns:** `(spline, max_error)`: the reduced surface or curve and the largest distance
    between old and new over a dense sample grid (64 × 64 for surfaces, 1024 for curves).
    """
    direction, times = _curve_args(spline, direction, times, "times", "reduce_degree")
    times = 1 if times is None else times
    knots, degree = _clamped(spline, direction, "reduce_degree")
    _check_times(times)
    if degree - times < 1:
        _checks.fail("times", f"at most {degree - 1} (degree {degree} cannot go below 1)", times)
    new_degree = degree - times
    values, counts = np.unique(knots, return_counts=True)
    counts = np.minimum(counts, new_degree)
    counts[0] = counts[-1] = new_degree + 1
    reduced = _rebase(spline, direction, np.repeat(values, counts), new_degree)
    if direction is None:
        return reduced, _max_curve_distance(spline, reduced)
    return reduced, _max_distance(spline, reduced)


def _curve_args(spline, direction, second, second_name, caller):
    """`(direction, second)`: for a curve the direction is omitted, so a second positional
    argument arrives in `direction`'s place."""
    if isinstance(spline, BSplineCurve):
        if second is not None and direction is not None:
            _checks.fail(f"{caller}: direction", "no direction for a curve", repr(direction))
        return None, direction if second is None else second
    if not isinstance(spline, BSplineSurface):
        _checks.fail(f"{caller}: spline", "a BSplineSurface or a BSplineCurve", type(spline).__name__)
    if direction not in ("u", "v"):
        _checks.fail("direction", "'u' or 'v'", repr(direction))
    return direction, second


def _basis(spline, direction) -> SplineDirection:
    return spline.direction if direction is None else spline.direction(direction)


def _clamped(spline, direction, caller):
    d = _basis(spline, direction)
    if d.periodic:
        where = f"{caller}: direction" if direction is not None else f"{caller}: curve"
        _checks.fail(where, "a clamped direction (the periodic basis is uniform)", direction or "periodic")
    return np.asarray(d.knots, dtype=np.float64), d.degree


def _check_times(times):
    if isinstance(times, bool) or not isinstance(times, (int, np.integer)) or times < 1:
        _checks.fail("times", "an int >= 1", times)


@declared
def change_of_basis(old: SplineDirection, new: SplineDirection) -> np.ndarray:
    """The matrix `T (n_new, n_old)` with `B_old = B_new T`: control points in the basis `old`
    become `T P` in the basis `new` (rational splines: apply it to homogeneous points `[w P, w]`).

    Found by least-squares collocation of both bases at more parameters than basis functions
    (a uniform grid of `4 (n_new + 1)` points and the Greville abscissae of `new`), exact to
    rounding when the space of `new` contains that of `old` — the change of basis behind knot
    insertion and degree elevation (The NURBS Book §§5.2, 5.5, and §10.3 for making sections
    compatible); a least-squares approximation otherwise (degree reduction).

    **Arguments:** `old`, `new`: clamped `SplineDirection`s with concrete knots.
    **Returns:** a float64 numpy array `(new.n_ctrl, old.n_ctrl)`.
    """
    for direction, name in ((old, "old"), (new, "new")):
        if not isinstance(direction, SplineDirection):
            raise TypeError(f"{name}: expected a SplineDirection, got {type(direction).__name__}")
        if direction.periodic:
            _checks.fail(name, "a clamped direction (the periodic basis is uniform)", "periodic")
    grid = np.linspace(0.0, 1.0, 4 * (new.n_ctrl + 1))
    t = np.unique(np.concatenate([grid, np.asarray(greville(new.knots, new.degree), np.float64)]))
    a_old, a_new = old.matrix(t), new.matrix(t)  # on the host (numpy): concrete knots and t
    return np.linalg.lstsq(a_new, a_old, rcond=None)[0]


def _rebase_net(ctrl, weights, transform, axis: int):
    """Apply `transform` along `axis` of the (homogeneous) net: `(ctrl, weights)` in the new basis."""
    net = _tensor.homogeneous(ctrl, weights)
    t = jnp.asarray(transform, ctrl.dtype)
    net = jnp.moveaxis(jnp.tensordot(t, jnp.moveaxis(net, axis, 0), axes=1), 0, axis)
    if weights is None:
        return net, None
    return net[..., :-1] / net[..., -1:], net[..., -1]


def _rebase(spline, direction, new_knots, new_degree):
    """Re-express `spline` in the basis (new_knots, new_degree) along `direction` (the curve's
    only direction when None)."""
    old = _basis(spline, direction)
    dtype = spline.ctrl.dtype
    new = SplineDirection(new_knots, new_degree, dtype=dtype)
    axis = 1 if direction == "v" else 0
    ctrl, weights = _rebase_net(spline.ctrl, spline.weights, change_of_basis(old, new), axis)
    if direction is None:
        return BSplineCurve.from_direction(ctrl, new, weights)
    directions = {"u": spline.direction_u, "v": spline.direction_v, direction: new}
    return BSplineSurface.from_directions(ctrl, directions["u"], directions["v"], weights)


def _max_distance(a, b, count: int = 64):
    """Largest distance between two surfaces on a common `count × count` parameter grid."""
    g = jnp.linspace(0.0, 1.0, count, dtype=a.ctrl.dtype)
    u, v = jnp.meshgrid(g, g, indexing="ij")
    return float(jnp.max(jnp.linalg.norm(a.evaluate(u, v) - b.evaluate(u, v), axis=-1)))


def _max_curve_distance(a, b, count: int = 1024):
    """Largest distance between two curves at `count` common parameters."""
    t = jnp.linspace(0.0, 1.0, count, dtype=a.ctrl.dtype)
    return float(jnp.max(jnp.linalg.norm(a.evaluate(t) - b.evaluate(t), axis=-1)))
