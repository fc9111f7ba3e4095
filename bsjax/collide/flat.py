"""Flat-contact pruning of the sphere hierarchy (thesis §3.3.3.4–5).

When two surfaces lie on each other (a plate on a table, a spoon in a bowl) every child sphere
of a candidate pair intersects every neighbour: refinement prunes nothing and the candidate list
grows ninefold per step. The thesis stops refining when every sphere intersects and, before
tessellating, drops the points whose unit normal differs from the previous one by less than δ —
in a flat region those points add no shape.

Here each block of the hierarchy carries a **normal cone** (axis and half-angle bounding the
normals of its triangles). A candidate pair of blocks that are both flat (half-angle ≤ δ) and
parallel within δ is a *flat pair*: it is not refined but resolved at its level by replacing
each block by its plane — the points the δ-pruning would drop. A cell of one block is in
contact when its corners straddle the other block's plane slab (the slab of that block's own
corners, so the flatness tolerance is exact) and it lies over that block's footprint (the
quad of its corners on the intermittent rows). The vertices of contact cells are marked, as the
vertices of intersecting triangles are for the refined pairs.

These are kernels of `surface_contacts` (compiled there), called inside its trace.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _safe
from bsjax.collide.hierarchy import BRANCH, block_order


def _angle(a, b):
    """Angle between unit vectors along the last axis, `arccos` clipped into its domain."""
    return jnp.arccos(jnp.clip(jnp.sum(a * b, -1), -1.0, 1.0))


def normal_cones(points: Float[Array, "m n 3"], levels: int) -> list[tuple[Array, Array]]:
    """Normal cone of every block of every level: `[(axes (N_l, 3), half_angles (N_l,))]`.

    Level 0 is one cone per cell spanning the normals of its two triangles (split along the
    shorter diagonal, as `cell_triangles`); a block's axis is the mean of its children's axes
    and its half-angle `max(θ_child + ∠(axis, axis_child))`, so every triangle normal of the
    block lies in the cone. Zero-area triangles (poles) make their blocks never flat; padding
    blocks beyond the grid are ignored. No gradient: a pruning decision.
    """
    points = jax.lax.stop_gradient(points)
    m, n = points.shape[:2]
    p00, p10, p01, p11 = points[:-1, :-1], points[1:, :-1], points[:-1, 1:], points[1:, 1:]
    main_short = jnp.sum((p11 - p00) ** 2, -1) <= jnp.sum((p10 - p01) ** 2, -1)
    n1 = jnp.where(main_short[..., None], jnp.cross(p10 - p00, p11 - p00), jnp.cross(p10 - p00, p01 - p00))
    n2 = jnp.where(main_short[..., None], jnp.cross(p11 - p00, p01 - p00), jnp.cross(p11 - p10, p01 - p10))
    u1, ok1 = _safe.unit_or_zero(n1)
    u2, ok2 = _safe.unit_or_zero(n2)
    axis, ok = _safe.unit_or_zero(u1 + u2)
    half = jnp.where(ok1 & ok2 & ok, 0.5 * _angle(u1, u2), jnp.inf)
    rows, cols = block_order(levels)
    present = jnp.asarray((rows < m - 1) & (cols < n - 1))
    rr, cc = np.minimum(rows, m - 2), np.minimum(cols, n - 2)
    axis, half = axis[rr, cc], jnp.where(present, half[rr, cc], 0.0)
    out = [(axis, half)]
    for _ in range(levels):
        child_axis = axis.reshape(-1, BRANCH * BRANCH, 3)
        child_half = half.reshape(-1, BRANCH * BRANCH)
        child_present = present.reshape(-1, BRANCH * BRANCH)
        axis, _ = _safe.unit_or_zero(jnp.sum(jnp.where(child_present[..., None], child_axis, 0), 1))
        spread = jnp.where(child_present, child_half + _angle(child_axis, axis[:, None]), 0)
        present = jnp.any(child_present, 1)
        half = jnp.max(spread, 1)
        out.append((axis, half))
    return out


def flat_pairs(cones_a, cones_b, flat_angle: float, la: int, lb: int, ia, ib, valid):
    """Which candidate pairs `(ia at level la, ib at level lb)` are flat pairs (see module doc)."""
    (axis_a, half_a), (axis_b, half_b) = cones_a[la], cones_b[lb]
    a, b = axis_a[ia], axis_b[ib]
    parallel = jnp.abs(jnp.sum(a * b, -1)) >= np.cos(flat_angle)
    return valid & (half_a[ia] <= flat_angle) & (half_b[ib] <= flat_angle) & parallel


def block_cells(levels: int, level: int, shape, blocks) -> tuple[Array, Array]:
    """Cells `(K, 9^level, 2)` (row, column) of blocks `(K,)` and which of them exist."""
    rows, cols = block_order(levels)
    per = BRANCH ** (2 * level)
    leaves = blocks[:, None] * per + jnp.arange(per, dtype=blocks.dtype)[None, :]
    present = jnp.asarray((rows < shape[0] - 1) & (cols < shape[1] - 1))[leaves]
    cells = np.stack([np.minimum(rows, shape[0] - 2), np.minimum(cols, shape[1] - 2)], -1).astype(np.int32)
    return jnp.asarray(cells)[leaves], present


def _cell_corners(points, cells):
    """Flat vertex indices `(..., 4)` of cells (row, column), corners in quad order 00, 10, 11, 01."""
    n = points.shape[1]
    i, j = cells[..., 0], cells[..., 1]
    return jnp.stack([i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1], -1)


def _block_quad(points, levels: int, level: int, blocks):
    """The block's corners on the intermittent rows, `(K, 4, 3)` in quad order."""
    m, n = points.shape[:2]
    rows, cols = block_order(levels - level)
    step = BRANCH**level
    r, c = jnp.asarray(rows)[blocks] * step, jnp.asarray(cols)[blocks] * step
    r1, c1 = jnp.minimum(r + step, m - 1), jnp.minimum(c + step, n - 1)
    return jnp.stack([points[r, c], points[r1, c], points[r1, c1], points[r, c1]], -2)


def _over_quad(x, quad, normal):
    """Which points `x (K, P, 3)` project along `normal (K, 3)` inside the convex quad `(K, 4, 3)`.

    Side of edge i: `n · (e_i × (x − q_i)) = (n × e_i) · x − (n × e_i) · q_i` (one product per
    point and edge); inside when all four sides agree, up to a rounding tolerance.
    """
    edges = jnp.roll(quad, -1, axis=-2) - quad
    inward = jnp.cross(normal[:, None], edges)  # (K, 4, 3)
    offset = jnp.sum(inward * quad, -1)
    side = jnp.einsum("kpc,kec->kpe", x, inward) - offset[:, None]
    scale = jnp.max(_safe.norm(edges), -1) ** 2
    tol = (64 * jnp.finfo(x.dtype).eps * scale)[:, None, None]
    return jnp.all(side >= -tol, -1) | jnp.all(side <= tol, -1)


def _cells_against_plane(x, present, quad, axis, y, slab_present):
    """Which cells (corners `x (K, C, 4, 3)`) straddle the other block's slab — the range of its
    cells' corners `y (K, D, 4, 3)` along its `axis (K, 3)` — over its `quad (K, 4, 3)`."""
    level = jnp.sum(quad.mean(-2) * axis, -1)[:, None, None]  # the plane through the quad's centre
    dy = jnp.einsum("kdjc,kc->kdj", y, axis) - level
    lo = jnp.min(jnp.where(slab_present[..., None], dy, jnp.inf), (1, 2))
    hi = jnp.max(jnp.where(slab_present[..., None], dy, -jnp.inf), (1, 2))
    dx = jnp.einsum("kcjx,kx->kcj", x, axis) - level
    straddle = (jnp.min(dx, -1) <= hi[:, None]) & (jnp.max(dx, -1) >= lo[:, None])
    probe = jnp.concatenate([x, x.mean(-2, keepdims=True)], -2)  # corners and centre
    over = jnp.any(_over_quad(probe.reshape(x.shape[0], -1, 3), quad, axis).reshape(probe.shape[:-1]), -1)
    return present & straddle & over


def resolve_flat_pairs(
    pa, levels_a: int, la: int, ia, pb, levels_b: int, lb: int, ib, flat, cones_a, cones_b
):
    """Contact cells of flat pairs, each block against the other's plane (module doc).

    **Arguments:** sample grids `pa (ma, na, 3)`, `pb`; hierarchy depths and the static levels
    `la`, `lb` of the block indices `ia (K,)`, `ib (K,)`; `flat (K,)` the flat pairs to resolve.

    **Returns:** `(corners_a (K, Ca, 4), hit_a (K, Ca), corners_b (K, Cb, 4), hit_b (K, Cb))`:
    vertex indices of every cell of each block and whether it is in contact.
    """
    pa, pb = jax.lax.stop_gradient(pa), jax.lax.stop_gradient(pb)
    cells_a, present_a = block_cells(levels_a, la, pa.shape, ia)
    cells_b, present_b = block_cells(levels_b, lb, pb.shape, ib)
    corners_a, corners_b = _cell_corners(pa, cells_a), _cell_corners(pb, cells_b)
    quad_a, quad_b = _block_quad(pa, levels_a, la, ia), _block_quad(pb, levels_b, lb, ib)
    axis_a, axis_b = cones_a[la][0][ia], cones_b[lb][0][ib]
    xa, xb = pa.reshape(-1, 3)[corners_a], pb.reshape(-1, 3)[corners_b]
    hit_a = _cells_against_plane(xa, present_a, quad_b, axis_b, xb, present_b)
    hit_b = _cells_against_plane(xb, present_b, quad_a, axis_a, xa, present_a)
    # a pair is in contact only when both sides found contact cells
    both = flat & jnp.any(hit_a, 1) & jnp.any(hit_b, 1)
    return corners_a, hit_a & both[:, None], corners_b, hit_b & both[:, None]
