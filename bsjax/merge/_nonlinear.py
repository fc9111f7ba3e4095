"""Nonlinear refit with parameter correction — beyond the thesis (SPEC §4).

The linear merge (eq. 3.7) assigns every sample a fixed parameter: patch i's grid scaled into
its knot segment. When the patches have unequal edge lengths or dissimilar curvature those
parameters are poor, and the least-squares surface is pulled along the seam. Here the sample
parameters are corrected too (Hoschek's parameter correction): alternately project every sample
onto the current surface (closest point, Gauss–Newton) and solve the linear least-squares
problem for the control net at the corrected parameters (QR / SVD through `lstsq`). Each half
step lowers `Σ |S(u_a, v_a) − x_a|²`, the squared point-to-surface distance of the samples,
which is what the deviation report measures. Seam knots are kept, so the continuity is kept.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from bsjax.basis import BSplineSurface
from bsjax.merge._deviation import project


def collocation(surface: BSplineSurface, uv: Float[Array, "N 2"]) -> Float[Array, "N rs"]:
    """Rows `B_i(u_a) B_j(v_a)` of the scattered-data least-squares system, `(N, r·s)`."""
    bu = surface.rows("u", uv[:, 0])
    bv = surface.rows("v", uv[:, 1])
    return (bu[:, :, None] * bv[:, None, :]).reshape(uv.shape[0], -1)


def fit_scattered(surface: BSplineSurface, uv, points) -> Float[Array, "r s 3"]:
    """Least-squares control net of `surface`'s basis through `points` at parameters `uv`."""
    k = collocation(surface, uv)
    sol = jnp.linalg.lstsq(k, points)[0]
    return sol.reshape(surface.shape + (3,))


@eqx.filter_jit
def _correct(surface: BSplineSurface, points, uv, steps: int):
    uv = project(surface, points, uv, steps)
    return surface.with_ctrl(fit_scattered(surface, uv, points)), uv


def refine(layout, ctrls, iterations: int = 6, steps: int = 4) -> Float[Array, "r s 3"]:
    """Merged control net with parameter correction, starting from the linear merge.

    **Arguments:**
    - `layout`: a `MergeLayout` from `plan`/`plan_grid`.
    - `ctrls`: the input control nets, as for `layout.apply`.
    - `iterations`: projection + refit rounds; `steps`: Gauss–Newton steps per projection.

    **Returns:** `(r, s, 3)` control net on the layout's merged basis.
    """
    points = layout.points(ctrls)
    m, n = points.shape[:2]
    pu, pv = layout.merged.params_u, layout.merged.params_v
    uv = jnp.stack(jnp.meshgrid(pu, pv, indexing="ij"), -1).reshape(-1, 2)
    flat = points.reshape(-1, 3)
    surface = layout.surface(layout.merged.refit(points))
    for _ in range(iterations):
        surface, uv = _correct(surface, flat, uv, steps)
    return surface.ctrl
