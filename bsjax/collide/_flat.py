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

The traversal sets flat pairs aside in a fixed-capacity list (`hierarchy.FlatPairs`), whatever
their level; after it, every cell of every flat pair is tested in one fixed-shape pass: the
pairs' cells laid out one after another in `flat_slots` slots (a block's cells are consecutive
leaves in block-major order), each against the other block's precomputed plane and slab
(`block_planes`). More cells than slots is reported as overflow, as more candidates than the
capacity is.

These are kernels of `surface_contacts` (compiled there), called inside its trace.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _safe
from bsjax.collide import _soa
from bsjax.collide._hierarchy import BRANCH, block_order, level_table


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


class BlockPlanes(NamedTuple):
    """Every block of every level of one surface as a plane slab, in one `level_table`.

    **Fields:** `axis (B, 3)`, `half (B,)`: the block's normal cone (`normal_cones`); `quad
    (B, 4, 3)`: its corners on the intermittent rows, in quad order 00, 10, 11, 01; `level (B,)`:
    the plane through the quad's centre along `axis`; `lo (B,)`, `hi (B,)`: the range of its
    cells' corners about that plane (its slab); `offsets (L + 2,)`: where each level starts.
    Per leaf cell `(9^L,)`, block-major: `corners (9^L, 4)` vertex indices, `present`.
    """

    axis: Array
    half: Array
    quad: Array
    level: Array
    lo: Array
    hi: Array
    offsets: Array
    corners: Array
    present: Array


def block_planes(points: Float[Array, "m n 3"], levels: int) -> BlockPlanes:
    """The `BlockPlanes` of a sample grid's hierarchy of `levels` levels (no gradient: a pruning
    decision and a contact mask)."""
    points = jax.lax.stop_gradient(points)
    m, n = points.shape[:2]
    rows, cols = block_order(levels)
    present = jnp.asarray((rows < m - 1) & (cols < n - 1))
    cells = np.stack([np.minimum(rows, m - 2), np.minimum(cols, n - 2)], -1).astype(np.int32)
    corners = _cell_corners(points, jnp.asarray(cells))
    x = points.reshape(-1, 3)[corners]  # (9^L, 4, 3)
    per_level = []
    for lv, (axis, half) in enumerate(normal_cones(points, levels)):
        blocks = BRANCH ** (2 * (levels - lv))
        quad = _block_quad(points, levels, lv)
        level = jnp.sum(quad.mean(-2) * axis, -1)
        dy = jnp.einsum("bpjc,bc->bpj", x.reshape(blocks, -1, 4, 3), axis) - level[:, None, None]
        inside = present.reshape(blocks, -1)[..., None]
        lo = jnp.min(jnp.where(inside, dy, jnp.inf), (1, 2))
        hi = jnp.max(jnp.where(inside, dy, -jnp.inf), (1, 2))
        per_level.append((axis, half, quad, level, lo, hi))
    arrays, offsets = level_table(per_level, (0,) * 6)
    return BlockPlanes(*arrays, offsets, corners, present)


def flat_pairs(planes_a: BlockPlanes, planes_b: BlockPlanes, flat_angle: float, la, lb, ia, ib, valid):
    """Which candidate pairs `(ia at level la, ib at level lb)` are flat pairs (see module doc);
    the levels may be traced (`hierarchy.traverse`'s loop)."""
    qa, qb = planes_a.offsets[la] + ia, planes_b.offsets[lb] + ib
    parallel = jnp.abs(jnp.sum(planes_a.axis[qa] * planes_b.axis[qb], -1)) >= np.cos(flat_angle)
    return valid & (planes_a.half[qa] <= flat_angle) & (planes_b.half[qb] <= flat_angle) & parallel


def _cell_corners(points, cells):
    """Flat vertex indices `(..., 4)` of cells (row, column), corners in quad order 00, 10, 11, 01."""
    n = points.shape[1]
    i, j = cells[..., 0], cells[..., 1]
    return jnp.stack([i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1], -1)


def _block_quad(points, levels: int, level: int):
    """Every block's corners on the intermittent rows, `(9^(levels − level), 4, 3)` in quad
    order, block-major (one gather with a static index table)."""
    m, n = points.shape[:2]
    rows, cols = block_order(levels - level)
    step = BRANCH**level
    r, c = rows * step, cols * step
    r1, c1 = np.minimum(r + step, m - 1), np.minimum(c + step, n - 1)
    index = np.stack([r * n + c, r1 * n + c, r1 * n + c1, r * n + c1], -1).astype(np.int32)
    return points.reshape(-1, 3)[jnp.asarray(index)]


def _over_quad(x, quad, normal):
    """Which points project along `normal` inside the convex quad, `(K, P)`: points `x`, corners
    `quad` and `normal` as `collide._soa` component tuples of `(K, P)`, `(K, 4)` and `(K,)`.

    Side of edge i: `n · (e_i × (x − q_i)) = (n × e_i) · x − (n × e_i) · q_i` (one product per
    point and edge); inside when all four sides agree, up to a rounding tolerance.
    """
    edges = tuple(jnp.roll(c, -1, axis=-1) - c for c in quad)  # (K, 4) each
    inward = _soa.cross(tuple(c[:, None] for c in normal), edges)
    offset = _soa.dot(inward, quad)
    side = _soa.dot(tuple(c[:, :, None] for c in x), tuple(c[:, None, :] for c in inward)) - offset[:, None]
    scale = jnp.max(_soa.dot(edges, edges), -1)
    tol = (64 * jnp.finfo(scale.dtype).eps * scale)[:, None, None]
    return jnp.all(side >= -tol, -1) | jnp.all(side <= tol, -1)


def _saturating_cumsum(counts, limit: int):
    """`cumsum(counts)` of non-negative ints with every partial sum capped at `limit` (int32-safe)."""
    return jax.lax.associative_scan(lambda a, b: jnp.minimum(a + b, limit), jnp.minimum(counts, limit))


def _cells_of_pairs(
    points, own: BlockPlanes, level, block, other: BlockPlanes, other_level, other_block, valid, slots: int
):
    """The cells of one side of every flat pair, each against the other block's slab.

    The pairs' cells are laid out one after another in `slots` slots (a block of level `l`
    covers the `9^l` consecutive leaves from `block · 9^l`, block-major); each slot finds its
    pair by a binary search over the running cell count. A cell is in contact when its corners
    straddle the other block's slab and a corner or its centre lies over the other block's quad.

    **Returns:** `(hit (S,), leaf (S,), pair (S,), found (F,), overflow)`: whether each slot's
    cell is in contact, its leaf and pair, whether each pair found a contact cell, and whether
    the pairs hold more than `slots` cells.
    """
    per = jnp.where(valid, BRANCH ** (2 * level), 0)
    ends = _saturating_cumsum(per, slots + 1)  # exact below the cap
    starts = jnp.concatenate([jnp.zeros(1, ends.dtype), ends[:-1]])
    j = jnp.arange(slots, dtype=jnp.int32)
    pair = jnp.searchsorted(ends, j, side="right", method="scan")
    pair = jnp.minimum(pair, valid.shape[0] - 1).astype(jnp.int32)
    live = j < ends[-1]
    leaf = jnp.where(live, block[pair] * BRANCH ** (2 * level[pair]) + j - starts[pair], 0)
    x = tuple(c.reshape(-1)[own.corners[leaf]] for c in _soa.split(points))  # (S, 4) each
    q = other.offsets[other_level[pair]] + other_block[pair]
    axis = _soa.split(other.axis[q])
    dx = _soa.dot(x, tuple(c[:, None] for c in axis)) - other.level[q][:, None]
    straddle = (jnp.min(dx, -1) <= other.hi[q]) & (jnp.max(dx, -1) >= other.lo[q])
    probe = tuple(jnp.concatenate([c, c.mean(-1, keepdims=True)], -1) for c in x)  # corners and centre
    over = jnp.any(_over_quad(probe, _soa.split(other.quad[q]), axis), -1)
    hit = live & own.present[leaf] & straddle & over
    # a pair's slots are consecutive: it found a cell when the running hit count grew over them
    seen = jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(hit, dtype=jnp.int32)])
    found = seen[jnp.minimum(ends, slots)] > seen[jnp.minimum(starts, slots)]
    return hit, leaf, pair, found, ends[-1] > slots


def flat_slots(capacity: int, levels: int) -> int:
    """Cell slots of one side of the flat pairs: 4 per leaf cell (a cell's block meets a few of
    the other surface's blocks) plus 8 per candidate, at most every pair's whole block."""
    leaves = BRANCH ** (2 * levels)
    return min(capacity * leaves, 4 * leaves + 8 * capacity)


def _vertices_of_cells(cell_hit, levels: int, shape):
    """Grid vertices `(m, n)` of the cells that hit, from block-major leaf flags `(9^L,)`."""
    m, n = shape
    rows, cols = block_order(levels)
    leaf_of = np.zeros((BRANCH**levels,) * 2, np.int32)
    leaf_of[rows, cols] = np.arange(rows.size)
    cells = jnp.pad(cell_hit[jnp.asarray(leaf_of[: m - 1, : n - 1])], 1)  # (m + 1, n + 1)
    return cells[:-1, :-1] | cells[1:, :-1] | cells[:-1, 1:] | cells[1:, 1:]


def resolve_flat_pairs(
    pa, planes_a: BlockPlanes, pb, planes_b: BlockPlanes, pairs, slots_a: int, slots_b: int
):
    """Contact vertices of the flat pairs, each block against the other's plane (module doc).

    **Arguments:** sample grids `pa (ma, na, 3)`, `pb` and their `block_planes`; `pairs`, the
    traversal's `hierarchy.FlatPairs (F,)`; the static cell slots of each side (`flat_slots`).

    **Returns:** `(mask_a (ma, na), mask_b (mb, nb), pairs in contact (), overflow ())`: a pair is
    in contact when both sides found contact cells; the vertices of those cells are marked.
    """
    pa, pb = jax.lax.stop_gradient(pa), jax.lax.stop_gradient(pb)
    hit_a, leaf_a, pair_a, found_a, over_a = _cells_of_pairs(
        pa, planes_a, pairs.la, pairs.ia, planes_b, pairs.lb, pairs.ib, pairs.valid, slots_a
    )
    hit_b, leaf_b, pair_b, found_b, over_b = _cells_of_pairs(
        pb, planes_b, pairs.lb, pairs.ib, planes_a, pairs.la, pairs.ia, pairs.valid, slots_b
    )
    both = pairs.valid & found_a & found_b

    def mask(points, planes, hit, leaf, pair):
        cell_hit = jnp.zeros(planes.present.shape, bool).at[leaf].max(hit & both[pair])
        return _vertices_of_cells(cell_hit, _levels(planes), points.shape[:2])

    return (
        mask(pa, planes_a, hit_a, leaf_a, pair_a),
        mask(pb, planes_b, hit_b, leaf_b, pair_b),
        both.sum(dtype=jnp.int32),
        over_a | over_b,
    )


def _levels(planes: BlockPlanes) -> int:
    return planes.offsets.shape[0] - 2
