"""`SplineDirection`: one parameter direction of a spline — its knots (or the periodic flag),
degree and control-point count. Surfaces, blending matrices, knot insertion / degree change,
merging and curves all speak in directions, so the basis code exists once."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks
from bsjax._typing import ArrayLike, HostArray
from bsjax.basis._functions import check_order, periodic_rows, periodic_support, rows, support
from bsjax.basis._knots import clamped_knots


class SplineDirection(eqx.Module):
    """The basis of one direction on [0, 1]: clamped non-uniform, or uniform periodic (thesis eq. 3.3).

    **Fields:**
    - `knots`: `(n_ctrl + degree + 1,)` clamped, non-decreasing knots on [0, 1] with interior
      multiplicity ≤ degree; `None` for the periodic direction.
    - `degree` (static): k ≥ 1; `n_ctrl` (static): number of control points > k.
    - `periodic` (static): the uniform closed basis on [0, 1).

    Build with `SplineDirection(knots, degree)`, `SplineDirection.uniform(n_ctrl, degree)` or
    `SplineDirection.closed(n_ctrl, degree)` (alias `periodic`).
    """

    knots: Float[Array, " L"] | None
    degree: int = eqx.field(static=True)
    n_ctrl: int = eqx.field(static=True)
    periodic: bool = eqx.field(static=True)

    def __init__(
        self,
        knots: ArrayLike | None,
        degree: int,
        *,
        n_ctrl: int | None = None,
        periodic: bool = False,
        name: str = "knots",
        dtype=None,
    ):
        if not isinstance(name, str):
            raise TypeError(f"name: expected a str (the knots' name in messages), got {name!r}")
        if not isinstance(periodic, (bool, np.bool_)):
            kind = f"{type(periodic).__name__} {periodic!r}"
            raise TypeError(f"periodic{name[5:]}: expected a bool, got {kind}")
        if periodic:
            if knots is not None:
                _checks.fail(name, "None for a periodic direction (uniform closed basis)", "an array")
            n_ctrl = _checks.check_count(n_ctrl, "n_ctrl", 2)
            _checks.check_degree(
                degree, f"degree{name[5:]}", n_ctrl, f"{name[6:] or 'the direction'} ({n_ctrl})"
            )
            self.knots = None
        else:
            if knots is None:
                _checks.fail(name, "a knot vector for a non-periodic direction", None)
            _checks.check_real(knots, name)  # also when `dtype` is given (the surface's)
            knots = jnp.asarray(knots, dtype or _checks.float_dtype(knots, names=(name,)))
            _checks.check_ndim(knots, name, 1)
            count = knots.shape[0] - int(degree) - 1 if isinstance(degree, (int, np.integer)) else 0
            n_ctrl = count if n_ctrl is None else n_ctrl
            _checks.check_degree(
                degree, f"degree{name[5:]}", n_ctrl, f"{name[6:] or 'the direction'} ({n_ctrl})"
            )
            if n_ctrl != count:
                _checks.fail(name, f"length n_ctrl + degree + 1 = {n_ctrl + degree + 1}", knots.shape[0])
            self.knots = _checks.clamped_knots(knots, int(degree), n_ctrl, name)
        self.degree, self.n_ctrl, self.periodic = int(degree), int(n_ctrl), bool(periodic)

    @classmethod
    def uniform(cls, n_ctrl: int, degree: int, dtype=None) -> SplineDirection:
        """Clamped uniform knots (`clamped_knots`)."""
        return cls(clamped_knots(n_ctrl, degree, dtype), degree)

    @classmethod
    def closed(cls, n_ctrl: int, degree: int) -> SplineDirection:
        """The uniform periodic basis of `n_ctrl` control points (thesis eq. 3.3)."""
        return cls(None, degree, n_ctrl=n_ctrl, periodic=True)

    periodic_basis = closed

    @property
    def domain(self) -> tuple[float, float]:
        """The parameter domain, always `(0.0, 1.0)`."""
        return (0.0, 1.0)

    def matrices(
        self, params: Float[HostArray, " m"], orders: tuple[int, ...] = (0,)
    ) -> Float[Array, "o m n"]:
        """Blending matrices `A^{(nu)}[a, i] = B^{(nu)}_i(params_a)` for each `nu` in `orders`
        (thesis eq. 3.6), `(len(orders), m, n_ctrl)`. A kernel: traceable, no value checks on
        `params` (periodic parameters are taken modulo 1, clamped ones clipped to [0, 1]);
        computed on the host (numpy) when `params` and the knots are concrete."""
        for nu in orders:
            check_order(nu)
        if self.knots is None:
            return _checks.on_device(periodic_rows(self.n_ctrl, self.degree, params, tuple(orders)))
        return _checks.on_device(rows(self._knots_like(params), self.degree, params, tuple(orders)))

    def support(self, params: Float[HostArray, " m"]) -> Int[Array, "m k1"]:
        """Column indices of the `degree + 1` basis functions that can be non-zero at each
        parameter, `(m, degree + 1)` int32 (cyclic for a periodic direction): every other entry
        of the rows of `matrices(params, orders)` is exactly zero, for every derivative order.
        A kernel like `matrices` (The NURBS Book A2.1, span search)."""
        if self.knots is None:
            return _checks.on_device(periodic_support(self.n_ctrl, self.degree, params))
        return _checks.on_device(support(self._knots_like(params), self.degree, params))

    def _knots_like(self, params):
        """The knots in the dtype of `params`, in numpy when both are concrete (the basis is then
        computed on the host: `basis._functions`)."""
        xp = _checks.xp(self.knots, params)
        return xp.asarray(self.knots, dtype=params.dtype)

    def matrix(self, params: Float[HostArray, " m"], nu: int = 0) -> Float[Array, "m n"]:
        """One blending matrix, `(m, n_ctrl)` (see `matrices`)."""
        return self.matrices(params, (nu,))[0]

    def check_params(self, params, name: str):
        """`params` after checking they are finite and, for a clamped direction, in [0, 1]."""
        if self.periodic:
            return _checks.finite(params, name)
        return _checks.in_range(params, name, 0.0, 1.0)

    def astype(self, dtype) -> SplineDirection:
        """The same direction with its knots in `dtype`."""
        if self.knots is None or self.knots.dtype == dtype:
            return self
        return SplineDirection(self.knots.astype(dtype), self.degree)
