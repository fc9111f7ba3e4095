"""Level-of-detail sphere hierarchy over the sample grid and its tessellation (thesis §3.3.3.4–5).

Level 0 holds one sphere per grid cell: the sphere through three corners (both ends of the
longer diagonal and one other corner), so the fourth lies inside (thesis Fig. 3.6). A level-L
block covers 3^L × 3^L cells: its centre is the three-point sphere of its corners on the
intermittent rows and columns (every 3^L-th row of the blending matrices, `Blending.lod`), and
its radius is grown until it encloses its nine children — so every block sphere encloses the
triangles of its cells and pruning never loses a contact.

The pair traversal is the thesis's alternating refinement with static shapes: a fixed-capacity
list of candidate (block_a, block_b) pairs; each step splits the blocks of one surface into
their 3 × 3 children, keeps the pairs whose spheres intersect (compacted without a scatter) and
reports overflow when more than `capacity` pairs intersect. The steps are one `lax.fori_loop`
over the levels concatenated into one table (`level_table`, `schedule`), so the program holds
one step whatever the hierarchy's depth.

`sphere_hierarchy`, `cell_triangles` and `grid_mesh` are compiled at the public boundary
(`bsjax._boundary.compiled`); the queries call their private kernels, and `traverse`,
`candidate_triangles`, `block_order`, `levels_for`, `level_table` and `schedule` are kernels
of those queries.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax.collide import _soa

BRANCH = 3


def three_point_sphere(p00, p10, p01, p11):
    """Centre of the circle through the longer diagonal's ends and one more corner (thesis §3.3.3.4).

    Corners `(..., 3)` each; returns `(..., 3)`. The arithmetic is `_three_point_sphere`'s (one
    implementation, per component)."""
    return _soa.stack(_three_point_sphere(*(_soa.split(p) for p in (p00, p10, p01, p11))))


def _corners(points):
    return points[:-1, :-1], points[1:, :-1], points[:-1, 1:], points[1:, 1:]


def levels_for(cells: int) -> int:
    """Number of refinement levels so that one top block covers `cells` cells."""
    return max(0, math.ceil(math.log(max(cells, 1), BRANCH) - 1e-12))


def block_order(levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid (row, column) of each position in the base-3 interleaved ("block-major") order.

    In this order the 9 children of block q of the next coarser level are positions 9q … 9q+8,
    at every level — so refinement is `9 q + child` and a level is a reshape of the one below.
    """
    size = BRANCH**levels
    rows, cols = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    shape = (BRANCH,) * (2 * levels)
    order = [ax for k in range(levels) for ax in (k, levels + k)]

    def reorder(a):
        return a.reshape(shape).transpose(order).reshape(-1) if levels else a.reshape(-1)

    return reorder(rows), reorder(cols)


def _grid(points, name: str = "points"):
    """A floating `(m, n, 3)` sample grid with m, n ≥ 2 and finite entries."""
    _checks.check_real(points, name)
    points = jnp.asarray(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        points = points.astype(jnp.result_type(float))
    _checks.check_ndim(points, name, 3, last=3)
    if points.shape[0] < 2 or points.shape[1] < 2:
        _checks.fail(name, "a grid of at least 2 x 2 samples", f"shape {points.shape}")
    return _checks.finite(points, name)


@compiled
def sphere_hierarchy(points: Float[Array, "m n 3"], levels: int) -> list[tuple[Array, Array]]:
    """Bounding spheres of every level, `[(centers (3, N_l), radii (N_l,)) for l = 0..levels]`.

    **Arguments:** a sample grid `points (m, n, 3)` (m, n ≥ 2, finite); `levels` (static int
    ≥ 0; `levels_for(max(m, n) − 1)` makes one top block cover the grid).

    **Returns:** `N_l = 9^(levels − l)` blocks per level in block-major order (`block_order`);
    padding blocks beyond the grid have radius −∞ and never intersect anything. Level 0: the
    three-point sphere of each cell; level L: the three-point sphere of the block's corners
    grown to enclose its nine children (thesis §3.3.3.4, Fig. 3.6).
    """
    levels = _checks.check_count(levels, "levels", minimum=0)
    return _sphere_hierarchy(_grid(points), levels)


def _sphere_hierarchy(points, levels: int):
    """The kernel of `sphere_hierarchy` (no checks): `_sphere_hierarchies` of one grid."""
    return _sphere_hierarchies(((points, levels),))[0]


def _corner_indices(m: int, n: int, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """`(index (4, N), valid (N,))` over every block of every level (level 0 first, each
    block-major): the flat grid indices of its corners p00, p10, p01, p11 — on the intermittent
    rows and columns of `Blending.lod` — and whether it covers a cell of the grid (padding
    blocks beyond the grid do not)."""
    index, valid = [], []
    for level in range(levels + 1):
        step, count = BRANCH**level, BRANCH ** (levels - level)
        iu = np.minimum(np.arange(count + 1) * step, m - 1)
        iv = np.minimum(np.arange(count + 1) * step, n - 1)
        rows, cols = block_order(levels - level)
        index.append([iu[rows + a] * n + iv[cols + b] for a, b in ((0, 0), (1, 0), (0, 1), (1, 1))])
        valid.append((rows * step < m - 1) & (cols * step < n - 1))
    return np.concatenate([np.asarray(i) for i in index], axis=1), np.concatenate(valid)


def _sphere_hierarchies(grids):
    """`sphere_hierarchy` of several grids `((points (m, n, 3), levels), …)` of one dtype.

    Every block of every level and grid gathers its corner samples (one static index table into
    the grids' concatenated samples) and takes its centre in one `_three_point_sphere` over all
    of them, one coordinate at a time (`collide._soa`, so XLA fuses it into one loop); the radii
    then go level by level: a cell's encloses its corners, a block's its nine children
    (`bsjax._safe.norm`'s arithmetic). One program section for all levels and grids instead of
    one per level and grid (half `surface_contacts`' program).
    """
    dtype = grids[0][0].dtype
    if any(points.dtype != dtype for points, _ in grids):  # mixed precision: each in its own
        return [h for grid in grids for h in _sphere_hierarchies((grid,))]
    tables, masks, start = [], [], 0
    for points, levels in grids:
        index, valid = _corner_indices(points.shape[0], points.shape[1], levels)
        tables.append(index + start)
        masks.append(valid)
        start += points.shape[0] * points.shape[1]
    flat = jnp.concatenate([points.reshape(-1, 3) for points, _ in grids])
    index, valid = np.concatenate(tables, axis=1).astype(np.int32), np.concatenate(masks)
    gathered = flat[jnp.asarray(index)]  # (4, all blocks, 3): one gather, one index table
    corners = [_soa.split(gathered[k]) for k in range(4)]
    centres = _three_point_sphere(*corners)  # 3 × (all blocks,)
    neg = jnp.array(-jnp.inf, dtype)
    out, start = [], 0
    for _, levels in grids:
        spheres, radii = [], None
        for level in range(levels + 1):
            size = BRANCH ** (2 * (levels - level))
            c = tuple(x[start : start + size] for x in centres)
            if level == 0:
                ends = [tuple(x[start : start + size] for x in corner) for corner in corners]
                radius = functools.reduce(jnp.maximum, [_soa.norm(_soa.sub(p, c)) for p in ends])
            else:
                child_c = tuple(x.reshape(-1, BRANCH * BRANCH) for x in spheres[-1][0])
                child_r = radii.reshape(-1, BRANCH * BRANCH)
                to_child = _soa.sub(child_c, tuple(x[:, None] for x in c))
                radius = jnp.max(_soa.norm(to_child) + child_r, axis=1)
            radii = jnp.where(jnp.asarray(valid[start : start + size]), radius, neg)
            spheres.append((c, radii))
            start += size
        out.append([(jnp.stack(c), r) for c, r in spheres])
    return out


def _three_point_sphere(p00, p10, p01, p11):
    """`three_point_sphere` of corners given as `collide._soa` component tuples (same arithmetic).

    The terms every component shares are computed once (`lax.optimization_barrier`): fused
    freely, XLA on CPU would recompute them in the loop of each component.
    """
    d_main, d_anti = _soa.sub(p11, p00), _soa.sub(p10, p01)
    long_main = _soa.dot(d_main, d_main) >= _soa.dot(d_anti, d_anti)
    a = _soa.where(long_main, p00, p10)
    b = _soa.where(long_main, p11, p01)
    c = _soa.where(long_main, p10, p00)
    u, v = _soa.sub(b, a), _soa.sub(c, a)
    w = _soa.cross(u, v)
    ww, uu, vv = _soa.dot(w, w), _soa.dot(u, u), _soa.dot(v, v)
    ok = ww > jnp.finfo(ww.dtype).eps * uu * vv
    den = 2 * jnp.where(ok, ww, 1)
    a, b, u, v, w, uu, vv, den, ok = jax.lax.optimization_barrier((a, b, u, v, w, uu, vv, den, ok))
    vw, wu = _soa.cross(v, w), _soa.cross(w, u)
    centre = tuple(
        jnp.where(ok, ai + (uu * vwi + vv * wui) / den, 0.5 * (ai + bi))
        for ai, bi, vwi, wui in zip(a, b, vw, wu)
    )
    return jax.lax.optimization_barrier(centre)


@compiled
def cell_triangles(points: Float[Array, "m n 3"]) -> tuple[Array, Array]:
    """Two triangles per grid cell, split along the shorter diagonal (the thesis drops the longest side).

    **Arguments:** a sample grid `points (m, n, 3)` (m, n ≥ 2, finite).

    **Returns:** `(triangles (m−1, n−1, 2, 3, 3), vertex indices (m−1, n−1, 2, 3))` into the
    flattened `(m·n)` grid; triangles are counter-clockwise in (u, v), so their normals follow
    `T_u × T_v` (thesis §3.3.3.5).
    """
    return _cell_triangles(_grid(points))


def _cell_triangles(points):
    """The kernel of `cell_triangles` (no checks)."""
    m, n = points.shape[:2]
    idx = np.arange(m * n).reshape(m, n)
    i00, i10, i01, i11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    p00, p10, p01, p11 = _corners(points)
    main_short = jnp.sum((p11 - p00) ** 2, -1) <= jnp.sum((p10 - p01) ** 2, -1)
    split_main = np.stack([np.stack([i00, i10, i11], -1), np.stack([i00, i11, i01], -1)], -2)
    split_anti = np.stack([np.stack([i00, i10, i01], -1), np.stack([i10, i11, i01], -1)], -2)
    faces = jnp.where(main_short[..., None, None], jnp.asarray(split_main), jnp.asarray(split_anti))
    return points.reshape(-1, 3)[faces], faces


def candidate_triangles(points: Float[Array, "m n 3"], cells: Int[Array, "K 2"]) -> tuple[Array, Array]:
    """`cell_triangles` of the listed cells only: `(triangles (K, 2, 3, 3), vertex indices (K, 2, 3))`."""
    n = points.shape[1]
    i, j = cells[:, 0], cells[:, 1]
    i00, i10, i01, i11 = i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1
    flat = points.reshape(-1, 3)
    p00, p10, p01, p11 = flat[i00], flat[i10], flat[i01], flat[i11]
    # squared diagonals one component at a time (fused; a sum over a trailing 3 is its own loop)
    squared = lambda d: d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    main_short = squared(p11 - p00) <= squared(p10 - p01)
    split_main = jnp.stack([jnp.stack([i00, i10, i11], -1), jnp.stack([i00, i11, i01], -1)], -2)
    split_anti = jnp.stack([jnp.stack([i00, i10, i01], -1), jnp.stack([i10, i11, i01], -1)], -2)
    faces = jnp.where(main_short[:, None, None], split_main, split_anti)
    return flat[faces], faces


@compiled
def grid_mesh(points: Float[Array, "m n 3"]) -> tuple[Float[Array, "V 3"], Int[Array, "F 3"]]:
    """The triangle mesh of a sample grid: `(vertices (m·n, 3), faces (2(m−1)(n−1), 3))`.

    **Arguments:** `points (m, n, 3)` (m, n ≥ 2, finite). Each cell is split along its shorter
    diagonal (`cell_triangles`); faces are counter-clockwise in (u, v).
    """
    points = _grid(points)
    _, faces = _cell_triangles(points)
    return points.reshape(-1, 3), faces.reshape(-1, 3)


def _overlap(ca, ra, cb, rb):
    both = (ra >= 0) & (rb >= 0)  # padding blocks have radius -inf
    d2 = (ca[0] - cb[0]) ** 2 + (ca[1] - cb[1]) ** 2 + (ca[2] - cb[2]) ** 2
    return both & (d2 <= jnp.where(both, ra + rb, 0) ** 2)


def _compact(hit, size):
    """Positions of the first `size` True entries of `(P, 9)` `hit`, without a scatter.

    A cumulative count per parent and a binary search find each output's parent, then its
    rank among the parent's hits picks the child. **Returns:** `(parent, child, valid)`.
    """
    counts = hit.sum(1, dtype=jnp.int32)
    ends = jnp.cumsum(counts)
    j = jnp.arange(size, dtype=jnp.int32)
    parent = jnp.minimum(jnp.searchsorted(ends, j, side="right", method="scan"), hit.shape[0] - 1)
    parent = parent.astype(jnp.int32)
    rank = j - (ends[parent] - counts[parent])
    cum = jnp.cumsum(hit[parent], 1, dtype=jnp.int32)
    child = jnp.argmax(cum > rank[:, None], 1).astype(jnp.int32)
    return parent, child, j < ends[-1]


def level_table(levels, axes) -> tuple[tuple[Array, ...], Array]:
    """Per-level arrays concatenated along their block axis, and where each level starts.

    **Arguments:** `levels`, a list over levels of tuples of arrays (`sphere_hierarchy`'s
    `(centres (3, N_l), radii (N_l,))`, `collide._flat.normal_cones`' `(axes (N_l, 3), half
    angles (N_l,))`); `axes`, the block axis of each array of the tuple.

    **Returns:** `(arrays, offsets)`: each array concatenated over the levels, and
    `offsets (L + 2,)` int32 — block `q` of level `l` is entry `offsets[l] + q`, so a loop can
    index a level chosen at run time.
    """
    sizes = [level[0].shape[axes[0]] for level in levels]
    offsets = jnp.asarray(np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32))
    arrays = tuple(jnp.concatenate([level[k] for level in levels], axis) for k, axis in enumerate(axes))
    return arrays, offsets


def schedule(levels_a: int, levels_b: int) -> np.ndarray:
    """The alternating refinement order: one row `(level_a, level_b, refine_a)` per step.

    Levels are those of the pair before the step; the surfaces take turns, starting with `a`,
    and one that reached its cells leaves the remaining steps to the other (thesis §3.3.3.4).
    """
    rows, turn_a = [], True
    while levels_a > 0 or levels_b > 0:
        refine_a = (turn_a and levels_a > 0) or levels_b == 0
        rows.append((levels_a, levels_b, int(refine_a)))
        levels_a, levels_b = levels_a - refine_a, levels_b - (not refine_a)
        turn_a = not turn_a
    return np.asarray(rows, np.int32).reshape(-1, 3)


class FlatPairs(NamedTuple):
    """Candidate pairs the traversal set aside as flat (`collide.flat`), a fixed-capacity list:
    block `ia (F,)` at level `la (F,)` of surface a against block `ib` at `lb` of b; `valid (F,)`."""

    la: Int[Array, " F"]
    ia: Int[Array, " F"]
    lb: Int[Array, " F"]
    ib: Int[Array, " F"]
    valid: Bool[Array, " F"]


def _set_aside(pairs: FlatPairs, count, take, la, ia, lb, ib) -> tuple[FlatPairs, Array]:
    """Append the candidates `take (C,)` to the flat list (those past its capacity are dropped:
    the returned running `count` then exceeds the capacity, which the caller reports)."""
    size = pairs.valid.shape[0]
    slot = jnp.where(take, count + jnp.cumsum(take, dtype=jnp.int32) - 1, size)
    put = lambda field, value: field.at[slot].set(value, mode="drop")
    full = lambda x: jnp.broadcast_to(x, take.shape)
    pairs = FlatPairs(
        put(pairs.la, full(la)),
        put(pairs.ia, ia),
        put(pairs.lb, full(lb)),
        put(pairs.ib, ib),
        put(pairs.valid, take),
    )
    return pairs, count + take.sum(dtype=jnp.int32)


def traverse(levels_a, levels_b, capacity: int, flat=None):
    """Alternating refinement of candidate pairs down to cell pairs (thesis §3.3.3.4).

    **Arguments:** the sphere levels of both surfaces (`sphere_hierarchy`); `capacity` (static);
    `flat`: `None`, or `flat(la, lb, ia, ib, valid) → is_flat` (levels and blocks as arrays,
    e.g. a partial of `collide._flat.flat_pairs`) to take flat pairs of blocks (both at level
    ≥ 1) out of the refinement; they are resolved by the caller.

    One `lax.fori_loop` over the steps of `schedule`: every step holds `C = min(capacity,
    9^(La + Lb))` candidate pairs, splits the blocks of one surface into their 3 × 3 children
    (the levels live in one `level_table`, indexed by the step's level) and keeps the pairs whose
    spheres intersect; one program body whatever the depth.

    **Returns:** `(leaf_a (C,), leaf_b (C,), valid (C,), overflow, count, flat_pairs)`:
    block-major leaf indices of candidate cell pairs whose spheres intersect, whether some step
    (or the flat list) held more than `C`, the last step's number of intersecting pairs, and the
    `FlatPairs (C,)` set aside (`None` without `flat`).
    """
    top_a, top_b = len(levels_a) - 1, len(levels_b) - 1
    (centres_a, radii_a), off_a = level_table(levels_a, (1, 0))
    (centres_b, radii_b), off_b = level_table(levels_b, (1, 0))
    size = min(capacity, BRANCH ** (2 * (top_a + top_b)))
    first = _overlap(
        levels_a[top_a][0][:, :1], levels_a[top_a][1][:1], levels_b[top_b][0][:, :1], levels_b[top_b][1][:1]
    )
    zeros = jnp.zeros(size, jnp.int32)
    valid = jnp.zeros(size, bool).at[0].set(first[0])
    pairs = None if flat is None else FlatPairs(zeros, zeros, zeros, zeros, jnp.zeros(size, bool))
    state = (
        zeros,
        zeros,
        valid,
        jnp.zeros((), bool),
        valid.sum(dtype=jnp.int32),
        pairs,
        jnp.zeros((), jnp.int32),
    )
    steps = jnp.asarray(schedule(top_a, top_b))
    kids = jnp.arange(BRANCH * BRANCH, dtype=jnp.int32)[None, :]

    def step(s, state):
        ia, ib, valid, overflow, _, pairs, flat_count = state
        la, lb, a_side = steps[s, 0], steps[s, 1], steps[s, 2]
        refine_a = a_side == 1
        if flat is not None:
            take = flat(la, lb, ia, ib, valid) & (la > 0) & (lb > 0)
            pairs, flat_count = _set_aside(pairs, flat_count, take, la, ia, lb, ib)
            valid = valid & ~take
        ja = jnp.where(refine_a, ia[:, None] * 9 + kids, ia[:, None])  # (C, 9) children of one side
        jb = jnp.where(refine_a, ib[:, None], ib[:, None] * 9 + kids)
        ka = off_a[la - a_side] + ja
        kb = off_b[lb - (1 - a_side)] + jb
        hit = valid[:, None] & _overlap(centres_a[:, ka], radii_a[ka], centres_b[:, kb], radii_b[kb])
        count = hit.sum(dtype=jnp.int32)
        parent, child, valid = _compact(hit, size)
        return (
            ja[parent, child],
            jb[parent, child],
            valid,
            overflow | (count > size),
            count,
            pairs,
            flat_count,
        )

    if len(steps):
        state = jax.lax.fori_loop(0, len(steps), step, state)
    ia, ib, valid, overflow, count, pairs, flat_count = state
    if pairs is not None:
        overflow = overflow | (flat_count > size)
    return ia, ib, valid, overflow, count, pairs
