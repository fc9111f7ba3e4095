"""Input validation shared by every public constructor and function.

Structure errors (ndim, lengths, counts) are checked on shapes, which are always known, even
under `jit`. Value checks (finite, monotone, positive) run only on concrete arrays: inside a
trace the values are unknown, and callers use `eqx.error_if` where a value check must survive
`jit`.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np


def is_concrete(x: Any) -> bool:
    """True when `x` holds values (not a tracer), so value checks can run on it."""
    return not isinstance(x, jax.core.Tracer)


def fail(name: str, expected: str, got: Any) -> None:
    """Raise the project's standard `ValueError`: argument name, what was expected, what came."""
    raise ValueError(f"{name}: expected {expected}, got {got}")


def check_ndim(x: Any, name: str, ndim: int, last: int | None = None) -> None:
    """`x` must have `ndim` dimensions (and a trailing size `last` when given)."""
    shape = np.shape(x)
    if len(shape) != ndim:
        fail(name, f"an array with {ndim} dimension(s)", f"shape {shape}")
    if last is not None and shape[-1] != last:
        fail(name, f"trailing dimension {last}", f"shape {shape}")


def check_finite(x: Any, name: str) -> None:
    """All entries of a concrete `x` must be finite."""
    if is_concrete(x) and not np.all(np.isfinite(np.asarray(x))):
        fail(name, "finite values", "NaN or inf")


def check_positive(x: Any, name: str, strict: bool = True) -> None:
    """All entries of a concrete `x` must be > 0 (or ≥ 0 when `strict=False`)."""
    if not is_concrete(x):
        return
    a = np.asarray(x)
    sign = "> 0" if strict else ">= 0"
    if not np.all(np.isfinite(a)):
        fail(name, f"finite values {sign}", "NaN or inf")
    if np.any(a <= 0) if strict else np.any(a < 0):
        fail(name, f"finite values {sign}", f"min {np.min(a)}")


def check_degree(degree: Any, name: str, n_ctrl: int | None = None, n_name: str = "") -> None:
    """`degree` must be an int ≥ 1 and smaller than the number of control points."""
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
        raise TypeError(f"{name}: expected an int, got {type(degree).__name__}")
    if degree < 1:
        fail(name, "a degree >= 1", degree)
    if n_ctrl is not None and degree >= n_ctrl:
        fail(name, f"a degree smaller than the {n_ctrl} control points along {n_name}", degree)


def check_monotone(x: Any, name: str) -> None:
    """A concrete 1-D `x` must be finite and non-decreasing."""
    if not is_concrete(x):
        return
    t = np.asarray(x, dtype=np.float64)
    check_finite(t, name)
    if np.any(np.diff(t) < 0):
        fail(name, "a non-decreasing knot vector", f"a decrease at index {int(np.argmax(np.diff(t) < 0))}")


def check_range(x: Any, name: str, lo: float, hi: float) -> None:
    """All entries of a concrete `x` must lie in `[lo, hi]`."""
    if is_concrete(x):
        a = np.asarray(x, dtype=np.float64)
        if a.size and (a.min() < lo or a.max() > hi):
            fail(name, f"values in [{lo}, {hi}]", f"[{a.min()}, {a.max()}]")


def check_knots(knots: Any, degree: int, n_ctrl: int, name: str) -> None:
    """A clamped, non-decreasing knot vector of length `n_ctrl + degree + 1` on [0, 1]."""
    check_ndim(knots, name, 1)
    if len(knots) != n_ctrl + degree + 1:
        fail(name, f"length n_ctrl + degree + 1 = {n_ctrl + degree + 1}", len(knots))
    if not is_concrete(knots):
        return
    check_monotone(knots, name)
    t = np.asarray(knots, dtype=np.float64)
    if np.any(t[: degree + 1] != t[0]) or np.any(t[-degree - 1 :] != t[-1]):
        fail(name, f"a clamped knot vector ({degree + 1} equal knots at each end)", t.tolist())
    if t[0] != 0.0 or t[-1] != 1.0:
        fail(name, "a knot vector on [0, 1]", f"[{t[0]}, {t[-1]}]")
    interior = np.unique(t[degree + 1 : -degree - 1], return_counts=True)[1]
    if interior.size and interior.max() > degree:
        fail(name, f"interior knot multiplicity <= degree {degree}", int(interior.max()))
