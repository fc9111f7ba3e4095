"""A face hierarchy for `TriangleMesh`: exact closest points and inside tests that visit only
the faces near each query point.

The tree is built once per mesh on the host (numpy): faces are split recursively at the median
of their centroids along the longest axis into a complete binary tree of `2^depth` leaves of
`leaf_size` faces (a short leaf repeats one of its own faces, which changes neither a box nor a
minimum). Only this topology is stored; the leaf boxes are recomputed from the current
vertices on every query (O(F), cheap), so a moved or deformed mesh stays exact.

A query (Ericson, *Real-Time Collision Detection*, §6.3 "bounding volume hierarchy traversal",
here best-first over the leaves and batched so it runs as vector code, all shapes static):

1. the points to search (all, or those marked `active`) in Morton-ordered tiles of `TILE`;
   the squared gap between each tile's box and each leaf box; each tile's `NEAREST` leaves of
   least gap (`top_k`);
2. best-first: chunks of `PAIRS_PER_STEP` (tile, leaf) pairs in rank-major order (every
   tile's nearest leaf first) have their faces tested exactly against the tile's points
   (`_d2`, with per-face quantities computed once), each point keeping its least squared
   distance; a tile is finished when its next leaf lies beyond its bound (the largest of its
   points' distances so far), which only tightens;
3. every remaining (tile, leaf) pair within the tile's bound, in index order (few or none), so
   the result is always exact — no capacity to overflow, pruning costs time, never correctness.

The nearest face is the one of least squared distance, ties going to the lowest face index (as
an `argmin` over all faces in order). The inside test uses the angle-weighted pseudo-normal of
the nearest feature (Bærentzen & Aanæs, *Signed distance computation using the angle weighted
pseudonormal*, 2005): for a closed, consistently oriented manifold mesh, `x` is inside exactly
when `(x − c) · n < 0` with `c` the closest point and `n` the pseudo-normal of the face, edge or
vertex `c` lies on — the same answer as the winding number (Jacobson et al. 2013), whose value
is an integer on such meshes, at the cost of the nearest-face search.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _safe
from bsjax.collide._triangles import ROWS, _d2, _face_table

LEAF_SIZE = 8  # faces per leaf (the target; a leaf holds ⌈F / 2^depth⌉)
TILE = 16  # query points per tile
PAIRS_PER_STEP = 512  # (tile, leaf) pairs tested exactly per step
NEAREST = 32  # leaves per tile taken best-first (the rest in index order)
CHUNK = 32  # points a step of the dense reference
TIE = 64  # faces within this many ulps of the least squared distance are tied


class FaceTree(eqx.Module):
    """The topology of a face hierarchy and of the mesh's edges (host-built, see module doc).

    **Fields:** `leaf_faces (2^depth, leaf_size)` int: face indices of each leaf, in tree order;
    `neighbours (F, 3)` int: the face across edge `(v_i, v_{i+1})` of each face (itself where
    the mesh is open there); `depth` (static): levels below the root; `closed` (static): every
    edge is shared by exactly two faces with opposite directions (the pseudo-normal sign test
    is exact), and the mesh encloses a positive volume.
    """

    leaf_faces: Int[Array, "leaves size"]
    neighbours: Int[Array, "F 3"]
    depth: int = eqx.field(static=True)
    closed: bool = eqx.field(static=True)


def build_tree(vertices: np.ndarray, faces: np.ndarray, leaf_size: int = LEAF_SIZE) -> FaceTree:
    """The `FaceTree` of a mesh (numpy, host side; vertices `(V, 3)`, faces `(F, 3)` int)."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    n_faces = len(faces)
    depth = max(0, int(np.ceil(np.log2(max(1.0, n_faces / leaf_size)))))
    centroids = vertices[faces].mean(1)
    groups = [np.arange(n_faces)]
    for _ in range(depth):  # median split of every group along its longest centroid extent
        nxt = []
        for g in groups:
            c = centroids[g]
            axis = int(np.argmax(c.max(0) - c.min(0))) if len(g) else 0
            g = g[np.argsort(c[:, axis], kind="stable")]
            half = (len(g) + 1) // 2
            nxt += [g[:half], g[half:]]
        groups = nxt
    size = max(len(g) for g in groups)
    rows = []
    for i, g in enumerate(groups):
        if len(g) == 0:  # only when F < 2^depth: borrow the sibling's first face
            g = groups[i ^ 1][:1]
        rows.append(np.concatenate([g, np.full(size - len(g), g[0])]))
    order = np.stack(rows).astype(np.int32)
    neighbours, closed = _edge_topology(faces)
    if closed:
        tri = vertices[faces]
        closed = bool(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() > 0)
    return FaceTree(jnp.asarray(order), jnp.asarray(neighbours), depth, closed)


def _edge_topology(faces: np.ndarray) -> tuple[np.ndarray, bool]:
    """Face across each directed edge `(v_i, v_{i+1})` and whether the mesh is closed and
    consistently oriented (every directed edge once, its reverse once)."""
    n = len(faces)
    a = faces.reshape(-1)
    b = np.roll(faces, -1, axis=1).reshape(-1)
    owner = np.repeat(np.arange(n), 3)
    key = a * (faces.max() + 1) + b
    rev = b * (faces.max() + 1) + a
    _, counts = np.unique(key, return_counts=True)
    lookup = dict(zip(key.tolist(), owner.tolist()))
    closed = bool(np.all(counts == 1)) and all(r in lookup for r in rev.tolist())
    neighbours = np.array([lookup.get(r, o) for r, o in zip(rev.tolist(), owner.tolist())], np.int32)
    return neighbours.reshape(n, 3), closed


def _leaf_table(table, leaf_faces):
    """Face rows of each leaf `(leaves, ROWS, size)`, gathered a leaf at a time."""
    return table[leaf_faces].transpose(0, 2, 1)


def _tol(dtype):
    return TIE * jnp.finfo(dtype).eps


def _merge(best, face, d2, ids, owner):
    """Fold candidate faces `(d2, ids)` `(M, S)` of points `owner (M,)` (owner `n` drops a row)
    into the running `(best, face)` of the points: the least squared distance, and among faces
    within `TIE` ulps of it the lowest index (rounding must not decide between two faces at the
    same distance, e.g. the two faces of an edge). Rows are reduced first, so the scatters run
    over `M`, not `M · S`."""
    n = best.shape[0]
    tol = _tol(best.dtype)
    big = jnp.iinfo(jnp.int32).max
    step = jax.ops.segment_min(jnp.min(d2, -1), owner, num_segments=n + 1)
    near = d2 <= step[owner][:, None] * (1 + tol)
    row_face = jnp.min(jnp.where(near, ids, big), -1)
    step_face = jax.ops.segment_min(row_face, owner, num_segments=n + 1)[:n]
    step = step[:n]
    better = step < best * (1 - tol)
    tie = ~better & (step <= best * (1 + tol))
    face = jnp.where(better, step_face, jnp.where(tie, jnp.minimum(face, step_face), face))
    return jnp.minimum(best, step), face


def nearest_faces(
    tree: FaceTree,
    vertices: Float[Array, "V 3"],
    faces: Int[Array, "F 3"],
    x: Float[Array, "N 3"],
    active: Bool[Array, " N"] | None = None,
) -> Int[Array, " N"]:
    """Index of the face nearest to each point; not differentiable (module doc).

    **Arguments:** the mesh's `tree`, `vertices (V, 3)`, `faces (F, 3)`; points `x (N, 3)`;
    optional `active (N,)` booleans: only these points are searched (an inactive point's face
    is some face near it, not necessarily the nearest; it costs no search steps).
    **Returns:** face indices `(N,)`: the least squared distance, ties (within `TIE` ulps) to the
    lowest index — `nearest_faces_dense` over every face gives the same.
    """
    vertices, x = jax.lax.stop_gradient(vertices), jax.lax.stop_gradient(x)
    n = x.shape[0]
    if active is None:
        active = jnp.ones(n, bool)
    leaves, size = tree.leaf_faces.shape
    tris = vertices[faces]
    leaf_tris = tris[tree.leaf_faces]  # (leaves, size, 3, 3)
    table = _leaf_table(_face_table(tris), tree.leaf_faces)
    lo, hi = leaf_tris.min((1, 2)), leaf_tris.max((1, 2))  # leaf boxes (leaves, 3)

    best, face = jnp.full(n, jnp.inf, x.dtype), jnp.zeros(n, jnp.int32)
    # 1. the active points in tiles of `TILE` (Morton order, inactive ones last); each tile's
    # leaves ranked by the gap between their box and the tile's box
    tiles = _tiles(x, active)
    tile_active = active[tiles]  # (T, TILE)
    tx = x[tiles]
    tlo = jnp.min(jnp.where(tile_active[..., None], tx, jnp.inf), 1)
    thi = jnp.max(jnp.where(tile_active[..., None], tx, -jnp.inf), 1)
    gap = _box_gap2(tlo, thi, lo, hi)  # (T, leaves); +inf for an idle tile
    n_tiles = tiles.shape[0]
    rows_t = jnp.arange(n_tiles)
    # each tile's `NEAREST` leaves of least gap (float32 keys: `top_k` is fast there; the order
    # only steers the work, which leaves are needed is decided on the float64 gaps)
    ranks = min(NEAREST, leaves)
    order = jax.lax.top_k(-gap.astype(jnp.float32), ranks)[1].astype(jnp.int32)  # (T, ranks)
    sgap = jnp.take_along_axis(gap, order, 1)

    def bound(best):
        return jnp.max(jnp.where(tile_active, _slack(best)[tiles], -jnp.inf), -1)

    def test(tile, leaf, used, best, face):
        """Fold the faces of `(tile, leaf)` pairs `(P,)` (where `used`) into `(best, face)`."""
        who = tiles[tile]  # (P, TILE)
        # the barrier keeps XLA from fusing the gather into every use in `_d2` (which recomputes
        # it per use and compiles for minutes)
        rows, px = jax.lax.optimization_barrier((table[leaf], x[who]))
        q = tuple(rows[:, None, i] for i in range(ROWS))
        d2 = _d2(tuple(px[..., k][..., None] for k in range(3)), q)  # (P, TILE, size)
        d2 = jnp.where(used[:, None, None], d2, jnp.inf)
        owner = jnp.where(used[:, None], who, n).reshape(-1)
        ids = jnp.broadcast_to(tree.leaf_faces[leaf][:, None], d2.shape).reshape(-1, size)
        return _merge(best, face, d2.reshape(-1, size), ids, owner)

    # 2. best-first over the nearest leaves: rank-major chunks (every tile's nearest leaf
    # first), a tile's cursor passing the ranks taken or beyond its bound; every rank of a tile
    # up to its cursor is done (tested, or beyond the bound then and so for good: bounds only
    # tighten)
    def ranked(cursor, best):
        rank = jnp.arange(ranks, dtype=jnp.int32)[:, None]  # (ranks, T): rank-major
        return (rank >= cursor[None, :]) & (sgap.T <= bound(best)[None, :])

    def ranked_done(cursor):
        return (
            jnp.zeros((n_tiles, leaves), bool)
            .at[rows_t[:, None], order]
            .set(jnp.arange(ranks, dtype=jnp.int32)[None] < cursor[:, None])
        )

    # 3. then the rest: every (tile, leaf) pair not done whose box lies within the tile's bound,
    # in index order (usually few or none: the bounds are nearly final after 2). Both phases
    # are one loop whose body tests one chunk of pairs, so the program holds one copy of the
    # distance kernel.
    def rest(done, best):
        return ~done & (gap <= bound(best)[:, None])

    def pending(state):
        cursor, done, best, _ = state
        return jnp.any(ranked(cursor, best)) | jnp.any(rest(done | ranked_done(cursor), best))

    def step(state):
        cursor, done, best, face = state
        todo_a = ranked(cursor, best).reshape(-1)
        first = jnp.any(todo_a)  # phase 2 until its pairs run out, then phase 3
        todo_b = rest(done | ranked_done(cursor), best).reshape(-1)
        slot_a = jnp.nonzero(todo_a, size=PAIRS_PER_STEP, fill_value=0)[0].astype(jnp.int32)
        slot_b = jnp.nonzero(todo_b, size=PAIRS_PER_STEP, fill_value=0)[0].astype(jnp.int32)
        used = jnp.arange(PAIRS_PER_STEP) < jnp.where(first, jnp.sum(todo_a), jnp.sum(todo_b))
        tile_a, rank = slot_a % n_tiles, slot_a // n_tiles
        tile = jnp.where(first, tile_a, slot_b // leaves)
        leaf = jnp.where(first, order[tile_a, rank], slot_b % leaves)
        best, face = test(tile, leaf, used, best, face)
        taken = jnp.where(first & used, rank + 1, 0).astype(jnp.int32)
        cursor = jnp.maximum(cursor, jnp.zeros(n_tiles, jnp.int32).at[tile_a].max(taken))
        done = done | jnp.zeros_like(done).at[tile, leaf].max(~first & used)
        return cursor, done, best, face

    state = (jnp.zeros(n_tiles, jnp.int32), jnp.zeros((n_tiles, leaves), bool), best, face)
    return jax.lax.while_loop(pending, step, state)[3]


def _slack(best):
    """The pruning bound: a box this far may hold a face tied with `best` after rounding."""
    return best * (1 + 1e-9) + jnp.finfo(best.dtype).tiny


def _box_gap2(lo_a, hi_a, lo_b, hi_b):
    """Squared distances `(A, B)` between boxes `[lo_a, hi_a] (A, 3)` and `[lo_b, hi_b] (B, 3)`."""
    total = 0
    for k in range(3):
        e = jnp.maximum(
            jnp.maximum(lo_b[None, :, k] - hi_a[:, None, k], lo_a[:, None, k] - hi_b[None, :, k]), 0
        )
        total = total + e * e
    return total


def _spread(v):
    """The 10 low bits of `v` (uint32) spread to every third bit (one axis of a Morton code)."""
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    return (v | (v << 2)) & 0x09249249


def _tiles(x, active):
    """Point indices `(⌈N / TILE⌉, TILE)` in Morton (Z-curve) order of their coordinates, so a
    tile holds nearby points whatever the input order, the inactive points last; the last tile
    repeats its last point."""
    n = x.shape[0]
    lo = jnp.min(jnp.where(active[:, None], x, jnp.inf), 0)
    hi = jnp.max(jnp.where(active[:, None], x, -jnp.inf), 0)
    lo, hi = jnp.where(jnp.any(active), lo, 0), jnp.where(jnp.any(active), hi, 0)
    span = jnp.maximum(hi - lo, jnp.finfo(x.dtype).tiny)
    q = jnp.clip((x - lo[None]) / span[None] * 1023, 0, 1023).astype(jnp.uint32)
    code = _spread(q[:, 0]) | (_spread(q[:, 1]) << 1) | (_spread(q[:, 2]) << 2)
    code = jnp.where(active, code, jnp.uint32(1 << 30))  # Morton codes have 30 bits
    order = jnp.argsort(code).astype(jnp.int32)
    order = jnp.concatenate([order, jnp.broadcast_to(order[-1:], (-n % TILE,))])
    return order.reshape(-1, TILE)


def _dense(table, x):
    """Nearest face of points `x (M, 3)` over every face (rows `(F, ROWS)` of `_face_table`),
    `(M, F)` at once."""
    d2 = _d2(tuple(x[:, k][:, None] for k in range(3)), tuple(table[None, :, i] for i in range(ROWS)))
    ok = d2 <= jnp.min(d2, -1, keepdims=True) * (1 + _tol(d2.dtype))
    return jnp.argmax(ok, -1).astype(jnp.int32)


def nearest_faces_dense(tris: Float[Array, "F 3 3"], x: Float[Array, "N 3"]) -> Int[Array, " N"]:
    """Nearest face of each point over every face `(F, 3, 3)`, with the tie rule of
    `nearest_faces` (the reference; O(N F), `CHUNK` points at a time)."""
    tris, x = jax.lax.stop_gradient(tris), jax.lax.stop_gradient(x)
    n = x.shape[0]
    pad = -n % CHUNK
    xp = jnp.concatenate([x, jnp.zeros((pad, 3), x.dtype)]).reshape(-1, CHUNK, 3)
    table = _face_table(tris)
    return jax.lax.map(lambda p: _dense(table, p), xp).reshape(-1)[:n]


def pseudo_normal_inside(tree: FaceTree, vertices, faces, x, face, closest, bary) -> Bool[Array, " N"]:
    """Inside test by the angle-weighted pseudo-normal of the feature the closest point lies on
    (Bærentzen & Aanæs 2005): face interior → face normal, edge → sum of its two faces'
    normals, vertex → Σ incident angle × face normal. Needs `tree.closed`.

    **Arguments:** `face (N,)` nearest faces, `closest (N, 3)` closest points, `bary (N, 3)`
    their barycentrics in `face` (`_closest_point_on_triangle`).
    """
    tri = vertices[faces]
    normal = _safe.unit(jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    e = [tri[:, (i + 1) % 3] - tri[:, i] for i in range(3)]
    angle = jnp.stack(
        [
            jnp.arctan2(_safe.norm(jnp.cross(e[i], -e[i - 1])), jnp.sum(e[i] * -e[i - 1], -1))
            for i in range(3)
        ],
        -1,
    )  # corner i between edges to v_{i+1} and from v_{i-1}
    vertex_normal = jax.ops.segment_sum(
        (angle[..., None] * normal[:, None, :]).reshape(-1, 3),
        faces.reshape(-1),
        num_segments=vertices.shape[0],
    )
    zero = bary == 0
    zeros = jnp.sum(zero, -1)
    corner = jnp.argmax(bary, -1)  # the vertex, when two barycentrics are 0
    # the edge opposite the zero barycentric i is (v_{i+1}, v_{i+2}): neighbour slot (i + 1) % 3
    edge = (jnp.argmax(zero, -1) + 1) % 3
    across = tree.neighbours[face, edge]
    pn = jnp.where(
        (zeros >= 2)[:, None],
        vertex_normal[faces[face, corner]],
        jnp.where((zeros == 1)[:, None], normal[face] + normal[across], normal[face]),
    )
    return jnp.sum((x - closest) * pn, -1) < 0
