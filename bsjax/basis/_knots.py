"""Knot vectors on [0, 1]: clamped uniform, the unclamped uniform vector behind the periodic
basis (thesis eq. 3.3), and Greville abscissae (The NURBS Book eq. 9.8)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks
from bsjax._declared import declared
from bsjax._typing import ArrayLike


def _check_dtype(dtype, name: str = "dtype"):
    if dtype is not None and not jnp.issubdtype(dtype, jnp.floating):
        _checks.fail(name, "a floating dtype (float32 or float64)", jnp.dtype(dtype).name)


@declared
def clamped_knots(n_ctrl: int, degree: int, dtype=None) -> Float[Array, " L"]:
    """Clamped (open) uniform knot vector on [0, 1].

    **Arguments:**
    - `n_ctrl`: number of control points, > `degree`.
    - `degree`: polynomial degree k ≥ 1.
    - `dtype`: a floating dtype (default: JAX's default float).

    **Returns:** `[0]*(k+1) + uniform interior + [1]*(k+1)`, length `n_ctrl + degree + 1`.
    """
    _checks.check_count(n_ctrl, "n_ctrl", 2)
    _checks.check_degree(degree, "degree", n_ctrl, "this direction")
    _check_dtype(dtype)
    interior = np.linspace(0.0, 1.0, n_ctrl - degree + 1)[1:-1]
    knots = np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])
    return jnp.asarray(knots, dtype=dtype or _checks.float_dtype())


@declared
def periodic_knots(n_ctrl: int, degree: int, dtype=None) -> Float[Array, " L"]:
    """The unclamped uniform knot vector behind the periodic basis: `(j − k) / n`, j = 0…n+2k.

    Its `n_ctrl + degree` basis functions cover the domain `[t_k, t_{n+k}] = [0, 1]`; the last
    `degree` of them are the first `degree` again (wrapped), which is thesis eq. 3.3.
    """
    _checks.check_count(n_ctrl, "n_ctrl", 2)
    _checks.check_degree(degree, "degree", n_ctrl, "the periodic direction")
    _check_dtype(dtype)
    j = np.arange(n_ctrl + 2 * degree + 1)
    return jnp.asarray((j - degree) / n_ctrl, dtype=dtype or _checks.float_dtype())


@declared
def greville(knots: ArrayLike, degree: int) -> np.ndarray:
    """Greville abscissae `(t_{i+1} + … + t_{i+k}) / k` (The NURBS Book eq. 9.8), one per control
    point; host-side (numpy), for planning fits."""
    _checks.check_degree(degree, "degree")
    _checks.check_real(knots, "knots")
    t = np.asarray(knots, dtype=np.float64)
    _checks.check_ndim(t, "knots", 1)
    n_ctrl = len(t) - degree - 1
    if n_ctrl < degree + 1:
        _checks.fail("knots", f"at least 2 (degree + 1) = {2 * (degree + 1)} knots", len(t))
    _checks.monotone(t, "knots")
    return np.array([t[i + 1 : i + degree + 1].mean() for i in range(n_ctrl)])
