"""Jitted wrappers of the foundation's builders, so that plan-time work (blending matrices of
every patch and of the merged grid, edge and deviation evaluations) compiles once per direction
shape instead of dispatching hundreds of small eager operations.

`blending` builds exactly what `BSplineSurface.blending` builds (same `Blending` fields, the
matrices from `bsjax.basis.blending_matrix`), but compiles one kernel per (knot count, degree,
sample count) of a *direction*, so the v matrices of a u-merge are shared by every patch and
the merged surface.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp

from bsjax._blending import _ORDERS, Blending
from bsjax.basis import blending_matrix


@partial(jax.jit, static_argnums=1)
def _direction(knots, degree: int, params):
    a = jnp.stack([blending_matrix(knots, degree, params, nu) for nu in range(_ORDERS)])
    pinv = jnp.linalg.pinv(a[0]) if a.shape[1] >= a.shape[2] else None
    return a, pinv


def blending(surface, m: int = 82, n: int = 82, params_u=None, params_v=None) -> Blending:
    """`surface.blending(m, n, params_u, params_v)` for an open (clamped) surface, compiled once
    per direction shape."""
    if surface.periodic_u or surface.periodic_v:
        return surface.blending(m, n, params_u, params_v)
    dtype = surface.ctrl.dtype
    pu = jnp.linspace(0.0, 1.0, m, dtype=dtype) if params_u is None else jnp.asarray(params_u, dtype)
    pv = jnp.linspace(0.0, 1.0, n, dtype=dtype) if params_v is None else jnp.asarray(params_v, dtype)
    a_u, refit_u = _direction(surface.knots_u, surface.degree_u, pu)
    a_v, refit_v = _direction(surface.knots_v, surface.degree_v, pv)
    return Blending(
        params_u=pu, params_v=pv, a_u=a_u, a_v=a_v, refit_u=refit_u, refit_v=refit_v,
        weights=surface.weights, knots_u=surface.knots_u, knots_v=surface.knots_v,
        index_u=jnp.arange(len(pu)), index_v=jnp.arange(len(pv)),
        degree_u=surface.degree_u, degree_v=surface.degree_v,
    )


@eqx.filter_jit
def evaluate(surface, u, v, nu: int = 0, nv: int = 0):
    """`surface.evaluate(u, v, nu, nv)`, compiled once per shape."""
    return surface.evaluate(u, v, nu, nv)
