"""Knot vectors of a merged surface (thesis §4.3.3, §4.4.2, §6.3.1.3).

All functions here work on concrete knot vectors (NumPy, float64): knot vectors fix the static
layout of a merge and are decided once, outside `jit`.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np

from bsjax import _checks
from bsjax._declared import declared
from bsjax.basis import clamped_knots

CROSS_MODES = ("average", "uniform")


def _host(knots, name: str) -> np.ndarray:
    """A concrete knot vector as float64 NumPy (knot vectors fix array sizes: planned on the host)."""
    if isinstance(knots, jax.core.Tracer):
        raise TypeError(
            f"{name}: expected a concrete knot vector (knot rules are planned on the host, outside "
            "jit), got a traced array"
        )
    _checks.check_real(knots, name)
    return np.asarray(knots, dtype=np.float64)


def _as_knots(knots, degree: int, name: str) -> np.ndarray:
    """A concrete clamped knot vector on [0, 1] of at least `degree + 1` control points."""
    t = _host(knots, name)
    _checks.check_ndim(t, name, 1)
    if len(t) < 2 * (degree + 1):
        _checks.fail(
            name, f"a clamped knot vector of at least 2 (degree + 1) = {2 * (degree + 1)} knots", len(t)
        )
    _checks.clamped_knots(t, degree, len(t) - degree - 1, name)
    return t


def _interior(t: np.ndarray, degree: int) -> np.ndarray:
    return t[degree + 1 : len(t) - degree - 1]


def _seam_knots(left: float, seam: float, right: float, degree: int, continuity: int) -> np.ndarray:
    """The knots at one seam: `degree − continuity` copies of the seam value plus `continuity`
    replacements placed between the seam and its neighbours (thesis §4.3.3: "the other multiple
    knots are changed by averaging them with their neighbouring knots"). The first replacement
    goes left, the next right, and so on; one replacement on a side is the plain average.
    """
    n_left = (continuity + 1) // 2
    n_right = continuity - n_left
    lefts = left + (seam - left) * np.arange(1, n_left + 1) / (n_left + 1)
    rights = seam + (right - seam) * np.arange(1, n_right + 1) / (n_right + 1)
    return np.concatenate([lefts, np.full(degree - continuity, seam), rights])


def _check_continuity(continuity, degree: int, name: str = "continuity") -> int:
    if isinstance(continuity, bool) or not isinstance(continuity, (int, np.integer)):
        raise TypeError(f"{name}: expected an int, got {type(continuity).__name__}")
    if not 0 <= continuity < degree:
        _checks.fail(
            name, f"an int in 0..{degree - 1} (below the degree {degree} in the merge direction)", continuity
        )
    return int(continuity)


def combine_knots(
    knot_list: Sequence, degree: int, continuity: int | Sequence[int], bounds: Sequence[float] | None = None
) -> np.ndarray:
    """Join N clamped knot vectors of one degree along the merge direction (thesis §4.3.3, §4.4.3).

    Vector i is scaled into `[bounds[i], bounds[i+1]]` (default: equal segments `i/N`); at each
    seam `degree − continuity` knots are kept and `continuity` are moved next to the seam, so the
    result has `Σ r_i − (N − 1) + degree + 1` knots, i.e. `r = Σ r_i − (N − 1)` control points.
    """
    n = len(knot_list)
    if n < 1:
        _checks.fail("knot_list", "at least one knot vector", n)
    ts = [_as_knots(t, degree, f"knots[{i}]") for i, t in enumerate(knot_list)]
    cs = [continuity] * (n - 1) if np.ndim(continuity) == 0 else list(continuity)
    if len(cs) != n - 1:
        _checks.fail("continuity", f"one int or {n - 1} ints (one per seam)", len(cs))
    cs = [_check_continuity(c, degree) for c in cs]
    b = np.linspace(0.0, 1.0, n + 1) if bounds is None else np.asarray(bounds, dtype=np.float64)
    if b.shape != (n + 1,) or b[0] != 0.0 or b[-1] != 1.0 or np.any(np.diff(b) <= 0):
        _checks.fail("bounds", f"{n + 1} increasing values from 0 to 1", b.tolist())
    scaled = [b[i] + (b[i + 1] - b[i]) * _interior(t, degree) for i, t in enumerate(ts)]
    parts = [np.zeros(degree + 1)]
    for i in range(n):
        parts.append(scaled[i])
        if i < n - 1:
            left = scaled[i][-1] if scaled[i].size else b[i]
            right = scaled[i + 1][0] if scaled[i + 1].size else b[i + 2]
            parts.append(_seam_knots(left, b[i + 1], right, degree, cs[i]))
    parts.append(np.ones(degree + 1))
    return np.concatenate(parts)


@declared
def merge_knots(knots_a, knots_b, degree: int, continuity: int) -> np.ndarray:
    """Merged knot vector of two patches joined in one direction (thesis §4.3.3).

    **Arguments:**
    - `knots_a`, `knots_b`: clamped knot vectors on [0, 1] of the first and second patch, both
      of degree `degree` (bring degrees together first, see `common_degree`).
    - `degree`: k ≥ 1, the merged degree in this direction.
    - `continuity`: c in `0..k−1`, the continuity C^c asked for at the seam.

    **Returns:** `(len(knots_a) + len(knots_b) − k − 2,)` float64: `knots_a` scaled into
    [0, ½], `knots_b` into [½, 1]; at ½, `k − c` equal knots (C⁰: k, C^{k−1}: one), the other `c`
    replaced by averages with the neighbouring knots so the count stays `r = r_a + r_b − 1`.

    Thesis example (cubic, C²): `[0,0,0,0,.2138,.4959,.7262,1,1,1,1]` and
    `[0,0,0,0,.1215,.2512,.3689,.5047,.7283,.8631,1,1,1,1]` give
    `[0,0,0,0,.1069,.2480,.3631,.4316,.5,.5304,.5608,.6256,.6845,.7524,.8642,.9316,1,1,1,1]`.
    """
    _checks.check_degree(degree, "degree")
    pair = [_as_knots(knots_a, degree, "knots_a"), _as_knots(knots_b, degree, "knots_b")]
    return combine_knots(pair, degree, continuity)


def average_knots(knots_a, knots_b) -> np.ndarray:
    """Element-wise average of two knot vectors of equal length (thesis §6.3.1.3).

    `U = (U1 + U2) / 2`, used across the merge direction so neither patch's knots dominate.
    """
    a, b = _host(knots_a, "knots_a"), _host(knots_b, "knots_b")
    _checks.check_ndim(a, "knots_a", 1)
    _checks.check_ndim(b, "knots_b", 1)
    if a.shape != b.shape:
        _checks.fail("knots_b", f"the length of knots_a ({len(a)})", len(b))
    a, b = _checks.monotone(a, "knots_a"), _checks.monotone(b, "knots_b")
    return 0.5 * (a + b)


def check_cross(value, name: str) -> None:
    """`value` must be one of `CROSS_MODES` (the rule across the merge direction; each public
    caller names its own argument: `cross_knots=`, `cross=`, `mode=`)."""
    if not isinstance(value, str) or value not in CROSS_MODES:
        _checks.fail(name, f"one of {CROSS_MODES}", repr(value))


@declared
def cross_knots(knot_list: Sequence, degree: int, n_ctrl: int, mode: str = "average") -> np.ndarray:
    """Knot vector across the merge direction for `n_ctrl` control points (thesis §4.3.3, §6.3.1.3).

    `mode="uniform"`: the clamped uniform vector. `mode="average"`: the element-wise average of
    the vectors with `n_ctrl` control points; when their counts differ, the merged knot set — the
    interior knots of all vectors pooled and `n_ctrl − degree − 1` of them picked at evenly
    spaced quantiles, so the distribution of the knots survives.
    """
    check_cross(mode, "mode")
    _checks.check_degree(degree, "degree")
    n_ctrl = _checks.check_count(n_ctrl, "n_ctrl", degree + 1)
    if mode == "uniform":
        return np.asarray(clamped_knots(n_ctrl, degree, np.float64))
    if not isinstance(knot_list, (list, tuple)):
        _checks.fail("knot_list", "a list of knot vectors", type(knot_list).__name__)
    ts = [_as_knots(t, degree, f"knot_list[{i}]") for i, t in enumerate(knot_list)]
    if not ts:
        _checks.fail("knot_list", "at least one knot vector", "none")
    full = [t for t in ts if len(t) == n_ctrl + degree + 1]
    if len(full) == len(ts):
        return np.mean(np.stack(full), axis=0)
    pooled = np.sort(np.concatenate([_interior(t, degree) for t in ts]))
    n_int = n_ctrl - degree - 1
    if pooled.size == 0 or n_int <= 0:
        return np.asarray(clamped_knots(n_ctrl, degree, np.float64))
    interior = np.quantile(pooled, np.arange(1, n_int + 1) / (n_int + 1))
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def window_knots(knots, degree: int, lo: float, hi: float) -> np.ndarray:
    """Knots of the part `[lo, hi]` of a patch, rescaled to [0, 1] (kept region of a trimmed patch)."""
    t = _host(knots, "knots")
    inner = _interior(t, degree)
    inner = inner[(inner > lo) & (inner < hi)]
    return np.concatenate([np.zeros(degree + 1), (inner - lo) / (hi - lo), np.ones(degree + 1)])
