"""Triangle–triangle overlap and point–triangle distance, branch-free and batched.

The fast path is Guigue & Devillers (2003), "Fast and robust triangle-triangle overlap test
using orientation predicates": only signs of 3×3 determinants are used, so with exactly
representable inputs (e.g. small integers) every decision is exact. Guigue–Devillers assumes
non-degenerate, non-coplanar triangles; pairs that are coplanar or contain a zero-area triangle
go to a robust edge-based test (two closed triangles meet iff an edge of one meets the other),
run under `lax.cond` only when a batch contains such a pair.

`triangles_intersect` and `closest_point_on_triangle` are compiled at the public boundary
(`bsjax._boundary.compiled`); the queries call their private kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _orient3d(a, b, c, d):
    """`(a − d) · ((b − d) × (c − d))`: > 0 when d is below the plane of ccw (a, b, c)."""
    return _dot(a - d, jnp.cross(b - d, c - d))


def _orient2d(a, b, c):
    """`(b − a) × (c − a)` in 2-D: > 0 when c is left of a→b."""
    u, v = b - a, c - a
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _canonical(d0, d1, d2):
    """Guigue–Devillers case table: rotation and swap that isolate the lone vertex.

    **Returns:** `(rot, swap, coplanar)`, rot ∈ {0, 1, 2} (vertex order (p,q,r), (q,r,p),
    (r,p,q)), swap: reverse the orientation of the *other* triangle, coplanar: all distances 0.
    """
    pos, neg = d0 > 0, d0 < 0
    conds = [
        pos & (d1 > 0),
        pos & (d2 > 0),
        pos,
        neg & (d1 < 0),
        neg & (d2 < 0),
        neg,
        (d1 < 0) & (d2 >= 0),
        d1 < 0,
        (d1 > 0) & (d2 > 0),
        d1 > 0,
        d2 > 0,
        d2 < 0,
    ]
    rot = jnp.select(conds, [2, 1, 0, 2, 1, 0, 1, 0, 0, 1, 2, 2], default=0)
    swap = jnp.select(conds, [1, 1, 0, 0, 0, 1, 1, 0, 1, 0, 0, 1], default=0)
    coplanar = (d0 == 0) & (d1 == 0) & (d2 == 0)
    return rot, swap, coplanar


# Structure-of-arrays helpers: a vector is a tuple (x, y, z) of same-shape arrays, which lets
# XLA fuse the whole test into one elementwise loop (a trailing axis of size 3 does not).


def _v(t, i):
    return (t[..., i, 0], t[..., i, 1], t[..., i, 2])


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _sdot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


ROWS = 32  # per-face quantities of `_prep`


def _prep(a, b, c):
    """Per-face quantities of `_d2` (each a 3-tuple of component arrays, or a scalar array):
    `a, b, c`; the edges `ab, bc, ca`; `m = ac × n`, `k = n × ab` with `n = ab × ac`; `n`;
    `1 / |n|²` (0 for a degenerate face); `|n|²`; `1 / |edge|²` (0 for a point edge) — 32
    arrays, computed once per face so a point-face test does no division."""
    ab, bc, ca = _sub(b, a), _sub(c, b), _sub(a, c)
    ac = _sub(c, a)
    n = _cross(ab, ac)
    nn = _sdot(n, n)
    inv = lambda v: jnp.where(v > 0, 1 / jnp.where(v > 0, v, 1), 0)
    return (*a, *b, *c, *ab, *bc, *ca, *_cross(ac, n), *_cross(n, ab), *n, inv(nn), nn) + tuple(
        inv(_sdot(e, e)) for e in (ab, bc, ca)
    )


def _d2(x, q):
    """Squared distance of points `x` (3-tuple of arrays) to faces `q` (the 32 arrays of
    `_prep`, broadcasting with `x`): the distance to the plane, `(ap · n)² / |n|²`, where the
    projection falls inside the face (barycentrics `v = ap · (ac × n) / |n|²`,
    `w = ap · (n × ab) / |n|²` in [0, 1] with `v + w ≤ 1`, tested without dividing), else the
    least distance to the three edges (Ericson, *Real-Time Collision Detection*, §5.1.5). Only
    the searches use it (the face hierarchy of `TriangleMesh`, the grid searches of
    `_contact` and `_penetration`): `_closest_point_on_triangle` gives the exact point of the
    chosen face, and the two agree to a few ulps."""
    a, b, c, ab, bc, ca, m, k, n = (q[3 * i : 3 * i + 3] for i in range(9))
    inv_nn, nn, inv_e = q[27], q[28], q[29:]
    ap = _sub(x, a)
    v, w = _sdot(ap, m), _sdot(ap, k)
    inside = (nn > 0) & (v >= 0) & (w >= 0) & (v + w <= nn)
    h = _sdot(ap, n)
    edge = None
    for p, d, inv in ((a, ab, inv_e[0]), (b, bc, inv_e[1]), (c, ca, inv_e[2])):
        xp = ap if p is a else _sub(x, p)
        t = jnp.clip(_sdot(xp, d) * inv, 0, 1)
        r = _sub(xp, tuple(t * di for di in d))
        e2 = _sdot(r, r)
        edge = e2 if edge is None else jnp.minimum(edge, e2)
    return jnp.where(inside, h * h * inv_nn, edge)


def _face_table(tris):
    """`_prep` of every face `tris (F, 3, 3)` as rows `(F, ROWS)`."""
    return jnp.stack(_prep(*(tuple(tris[:, v, k] for k in range(3)) for v in range(3))), -1)


def _nearest_face(y, table, index=None, valid=None):
    """Index of the face nearest to the point `y (3,)` among the rows `index` (default: all;
    those marked `valid`) of `table (T, ROWS)` (`_face_table`), and its squared distance (`_d2`:
    a decision only — the chosen face's point comes from `_closest_point_on_triangle`). The
    rows are gathered as one block (one gather, not one per quantity)."""
    faces = table if index is None else table[index]
    d2 = _d2((y[0], y[1], y[2]), tuple(faces[:, r] for r in range(faces.shape[1])))
    if valid is not None:
        d2 = jnp.where(valid, d2, jnp.inf)
    k = jnp.argmin(d2)
    return k, d2[k]


def _pick(cond, a, b):
    return tuple(jnp.where(cond, x, y) for x, y in zip(a, b))


def _rotate(rot, v0, v1, v2):
    """Vertex order (v0,v1,v2), (v1,v2,v0) or (v2,v0,v1) for rot = 0, 1, 2."""
    first = _pick(rot == 0, v0, _pick(rot == 1, v1, v2))
    second = _pick(rot == 0, v1, _pick(rot == 1, v2, v0))
    third = _pick(rot == 0, v2, _pick(rot == 1, v0, v1))
    return first, second, third


def _snap(dists, n, offsets):
    """Round plane distances below their floating-point error bound to exactly 0.

    A vertex within rounding error of the other triangle's plane is *on* it; without this an
    edge lying in that plane gets random-sign distances (~1e-16) and a wrong case. The bound
    `16 ε |n| |offset|` is far below 1 for small-integer inputs, which stay exact.
    """
    nn = jnp.sqrt(_sdot(n, n))
    eps = 16 * jnp.finfo(nn.dtype).eps
    return [jnp.where(jnp.abs(d) <= eps * nn * jnp.sqrt(_sdot(o, o)), 0, d) for d, o in zip(dists, offsets)]


def _plane_tests(t1, t2):
    """First step of Guigue–Devillers for `(N, 3, 3)` pairs: the snapped signed distances of each
    triangle's vertices to the other's plane, `(d1 (3 × (N,)), d2 (3 × (N,)))`, and whether a
    plane normal is exactly zero (a degenerate triangle: the robust test decides)."""
    p1, q1, r1 = _v(t1, 0), _v(t1, 1), _v(t1, 2)
    p2, q2, r2 = _v(t2, 0), _v(t2, 1), _v(t2, 2)
    n2 = _cross(_sub(p2, r2), _sub(q2, r2))
    d1 = _snap([_sdot(_sub(x, r2), n2) for x in (p1, q1, r1)], n2, [_sub(x, r2) for x in (p1, q1, r1)])
    n1 = _cross(_sub(q1, p1), _sub(r1, p1))
    d2 = _snap([_sdot(_sub(x, r1), n1) for x in (p2, q2, r2)], n1, [_sub(x, r1) for x in (p2, q2, r2)])
    zero = lambda n: (n[0] == 0) & (n[1] == 0) & (n[2] == 0)
    return d1, d2, zero(n1) | zero(n2)


def _separated(d):
    """All three distances strictly on one side of the plane."""
    return (d[0] * d[1] > 0) & (d[0] * d[2] > 0)


def _guigue_devillers(t1, t2, planes=None):
    """Fast overlap test for `(N, 3, 3)` pairs; returns (overlap, needs_robust_test).

    `planes`: the pairs' `_plane_tests`, when the caller has them already."""
    d1, d2, degenerate = _plane_tests(t1, t2) if planes is None else planes
    p1, q1, r1 = _v(t1, 0), _v(t1, 1), _v(t1, 2)
    p2, q2, r2 = _v(t2, 0), _v(t2, 1), _v(t2, 2)
    sep1, sep2 = _separated(d1), _separated(d2)
    rot1, swap1, cop1 = _canonical(*d1)
    a1 = _rotate(rot1, p1, q1, r1)
    s1 = swap1 == 1
    a2 = (p2, _pick(s1, r2, q2), _pick(s1, q2, r2))
    e2 = (d2[0], jnp.where(s1, d2[2], d2[1]), jnp.where(s1, d2[1], d2[2]))
    rot2, swap2, cop2 = _canonical(*e2)
    b2 = _rotate(rot2, *a2)
    s2 = swap2 == 1
    b1 = (a1[0], _pick(s2, a1[2], a1[1]), _pick(s2, a1[1], a1[2]))
    fail1 = _sdot(_sub(b2[1], b1[1]), _cross(_sub(b2[0], b1[1]), _sub(b1[0], b1[1]))) > 0
    fail2 = _sdot(_sub(b2[2], b1[0]), _cross(_sub(b2[0], b1[0]), _sub(b1[2], b1[0]))) > 0
    overlap = ~sep1 & ~sep2 & ~fail1 & ~fail2
    robust = ~sep1 & ~sep2 & (cop1 | cop2 | degenerate)
    return overlap & ~robust, robust


# --- robust path ---------------------------------------------------------------------------


def _sign(x):
    return jnp.sign(x)


def _segments_2d(a, b, c, d):
    """Closed 2-D segments [a, b] and [c, d] meet (exact orientation predicates)."""
    o1, o2 = _sign(_orient2d(a, b, c)), _sign(_orient2d(a, b, d))
    o3, o4 = _sign(_orient2d(c, d, a)), _sign(_orient2d(c, d, b))
    collinear = (o1 == 0) & (o2 == 0) & (o3 == 0) & (o4 == 0)
    lo1, hi1 = jnp.minimum(a, b), jnp.maximum(a, b)
    lo2, hi2 = jnp.minimum(c, d), jnp.maximum(c, d)
    boxes = jnp.all((lo1 <= hi2) & (lo2 <= hi1), -1)
    general = (o1 * o2 <= 0) & (o3 * o4 <= 0)
    return jnp.where(collinear, boxes, general)


def _segment_triangle_2d(a, b, p, q, r):
    """Closed 2-D segment meets closed (possibly degenerate) triangle."""
    edges = _segments_2d(a, b, p, q) | _segments_2d(a, b, q, r) | _segments_2d(a, b, r, p)
    s1, s2, s3 = _sign(_orient2d(p, q, a)), _sign(_orient2d(q, r, a)), _sign(_orient2d(r, p, a))
    area = _orient2d(p, q, r)
    inside = (area != 0) & (((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0)))
    return edges | inside


def _segment_triangle_3d(a, b, tri):
    """Closed segment [a, b] meets closed triangle, exactly for exact inputs.

    Transversal case: the segment straddles the triangle's plane and the Plücker volumes of the
    line with the three edges agree in sign. Coplanar (or degenerate-triangle) case: the sets
    meet iff their projections onto all three coordinate planes meet (one of the projections is
    injective on the common plane, and every projection of a meeting pair meets).
    """
    p, q, r = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    n = jnp.cross(q - p, r - p)
    degenerate = jnp.all(n == 0, -1)
    eps = 16 * jnp.finfo(n.dtype).eps
    nn = jnp.sqrt(_dot(n, n))
    da, db = _dot(a - p, n), _dot(b - p, n)
    da = jnp.where(jnp.abs(da) <= eps * nn * jnp.sqrt(_dot(a - p, a - p)), 0, da)
    db = jnp.where(jnp.abs(db) <= eps * nn * jnp.sqrt(_dot(b - p, b - p)), 0, db)
    s1, s2, s3 = _sign(_orient3d(a, b, p, q)), _sign(_orient3d(a, b, q, r)), _sign(_orient3d(a, b, r, p))
    through = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    flat = (da == 0) & (db == 0)
    crossing = ~degenerate & ~flat & (_sign(da) * _sign(db) <= 0) & through
    in_plane = jnp.where(
        degenerate,
        (_orient3d(a, b, p, q) == 0) & (_orient3d(a, b, p, r) == 0) & (_orient3d(a, b, q, r) == 0),
        flat,
    )
    # the three coordinate-plane projections, stacked on a leading axis
    keep = ([1, 2], [0, 2], [0, 1])
    proj = lambda x: jnp.stack([x[..., k] for k in keep])
    projected = jnp.all(_segment_triangle_2d(proj(a), proj(b), proj(p), proj(q), proj(r)), 0)
    return crossing | (in_plane & projected)


def _robust(t1, t2):
    """Edge-based exact test for any pair, including coplanar and zero-area triangles."""
    nxt = np.array([1, 2, 0])
    # six (segment, triangle) problems per pair, stacked on a leading axis
    a = jnp.concatenate([jnp.moveaxis(t1, -2, 0), jnp.moveaxis(t2, -2, 0)])
    b = jnp.concatenate([jnp.moveaxis(t1[..., nxt, :], -2, 0), jnp.moveaxis(t2[..., nxt, :], -2, 0)])
    tri = jnp.concatenate([jnp.broadcast_to(t2, (3,) + t2.shape), jnp.broadcast_to(t1, (3,) + t1.shape)])
    return jnp.any(_segment_triangle_3d(a, b, tri), 0)


def _floating(x, name: str):
    _checks.check_real(x, name)
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))


@compiled
def triangles_intersect(t1: Float[Array, "... 3 3"], t2: Float[Array, "... 3 3"]) -> Bool[Array, "..."]:
    """Whether closed triangles `t1` and `t2` share at least one point.

    **Arguments:** `t1`, `t2`: `(..., 3, 3)` triangles (3 vertices × xyz, finite) whose batch
    shapes broadcast; touching counts as intersecting.

    **Returns:** `(...)` bool.

    Guigue & Devillers, *Fast and robust triangle-triangle overlap test using orientation
    predicates* (2003); coplanar and degenerate (zero-area, segment or point) triangles are
    handled by an exact edge-based test that runs only when the batch holds such a pair
    (`lax.cond`). Jittable and vmappable.
    """
    t1, t2 = _floating(t1, "t1"), _floating(t2, "t2")
    dtype = jnp.result_type(t1.dtype, t2.dtype)
    if t1.shape[-2:] != (3, 3) or t2.shape[-2:] != (3, 3):
        raise ValueError(f"t1, t2: expected arrays of shape (..., 3, 3), got {t1.shape} and {t2.shape}")
    batch = _broadcast(t1.shape[:-2], t2.shape[:-2], "t1, t2")
    t1 = _checks.finite(jnp.broadcast_to(t1.astype(dtype), batch + (3, 3)), "t1")
    t2 = _checks.finite(jnp.broadcast_to(t2.astype(dtype), batch + (3, 3)), "t2")
    return _triangles_intersect(t1, t2)


def _triangles_intersect(t1, t2):
    """The kernel of `triangles_intersect` (no checks; batch shapes that broadcast)."""
    t1, t2 = jnp.broadcast_arrays(t1, t2)
    batch = t1.shape[:-2]
    return _intersect_flat(t1.reshape(-1, 3, 3), t2.reshape(-1, 3, 3)).reshape(batch)


def _broadcast(a, b, name: str) -> tuple[int, ...]:
    try:
        return tuple(np.broadcast_shapes(a, b))
    except ValueError:
        raise ValueError(_checks.message(name, "batch shapes that broadcast", f"{a} and {b}")) from None


def _intersect_flat(f1, f2, active=None, planes=None):
    """`triangles_intersect` of flat batches; `active (N,)`: the pairs that matter — the others
    give False and never trigger the exact test; `planes`: their `_plane_tests`, if known."""
    fast, robust = _guigue_devillers(f1, f2, planes)
    if active is not None:
        fast, robust = fast & active, robust & active
    exact = jax.lax.cond(jnp.any(robust), lambda: _robust(f1, f2), lambda: jnp.zeros(f1.shape[:1], bool))
    return jnp.where(robust, exact, fast)


_LIVE_SHARE = 4  # pairs that survive the plane tests are finished N / 4 at a time


def candidate_pairs_intersect(t1, t2, active):
    """`triangles_intersect(t1, t2) & active` for `(..., 3, 3)` batches that broadcast, where
    inactive pairs (padding of a fixed-capacity candidate list) cost no exact test.

    Most candidate pairs of two sampled surfaces are separated by one triangle's plane (the
    first test of Guigue & Devillers): the plane tests run on every pair, and the rest of the
    test only on the pairs that survive them, gathered `N / 4` at a time (slots from a running
    count, in a `lax.while_loop` that runs once in the usual case). The gathered pairs reuse the plane
    distances computed for all, so the answer is the one of the test on every pair.
    """
    batch = jnp.broadcast_shapes(t1.shape[:-2], t2.shape[:-2], active.shape)
    size1, size2 = int(np.prod(t1.shape[:-2])), int(np.prod(t2.shape[:-2]))
    # each pair's row in the flattened t1 and t2, so that only gathered pairs are copied (iotas
    # in the program, not index tables baked into it as constants)
    row1 = jnp.broadcast_to(jnp.arange(size1, dtype=jnp.int32).reshape(t1.shape[:-2]), batch).reshape(-1)
    row2 = jnp.broadcast_to(jnp.arange(size2, dtype=jnp.int32).reshape(t2.shape[:-2]), batch).reshape(-1)
    t1, t2 = t1.reshape(-1, 3, 3), t2.reshape(-1, 3, 3)
    active = jnp.broadcast_to(active, batch).reshape(-1)
    f1, f2 = t1[row1], t2[row2]
    planes = _plane_tests(f1, f2)
    live = active & ~_separated(planes[0]) & ~_separated(planes[1])
    n = live.shape[0]
    slots = n // _LIVE_SHARE
    if slots < 64:
        return _intersect_flat(f1, f2, live, planes).reshape(batch)
    position = jnp.cumsum(live, dtype=jnp.int32) - 1  # rank of each live pair
    chunk = position // slots  # the round that finishes it
    rounds = (position[-1] + slots) // slots
    pair = jnp.arange(n, dtype=jnp.int32)

    def finish(carry):
        c, hits = carry
        mine = live & (chunk == c)
        slot = position - c * slots
        # this round's pairs into their slots (unused slots: n), and each pair's answer back
        # from its slot by a gather
        k = jnp.full(slots, n, jnp.int32).at[jnp.where(mine, slot, slots)].set(pair, mode="drop")
        ok = k < n
        k = jnp.minimum(k, n - 1)
        sub_planes = jax.tree_util.tree_map(lambda x: x[k], planes)
        hit = _intersect_flat(t1[row1[k]], t2[row2[k]], ok, sub_planes)
        return c + 1, jnp.where(mine, hit[jnp.clip(slot, 0, slots - 1)], hits)

    _, hits = jax.lax.while_loop(lambda carry: carry[0] < rounds, finish, (0, jnp.zeros(n, bool)))
    return hits.reshape(batch)


@compiled
def closest_point_on_triangle(x: Float[Array, "... 3"], tri: Float[Array, "... 3 3"]) -> tuple[Array, Array]:
    """Closest point of triangle `tri` to `x` and its barycentric coordinates.

    **Arguments:** points `x (..., 3)` and triangles `tri (..., 3, 3)` (finite) whose batch
    shapes broadcast.

    **Returns:** `(point (..., 3), bary (..., 3))`, `point = Σ_k bary_k tri_k`.

    Ericson, *Real-Time Collision Detection* §5.1.5 (Voronoi regions), branch-free; degenerate
    triangles fall into an edge or vertex region.
    """
    x, tri = _floating(x, "x"), _floating(tri, "tri")
    if x.ndim < 1 or x.shape[-1] != 3:
        _checks.fail("x", "shape (..., 3)", f"shape {x.shape}")
    if tri.ndim < 2 or tri.shape[-2:] != (3, 3):
        _checks.fail("tri", "shape (..., 3, 3)", f"shape {tri.shape}")
    batch = _broadcast(x.shape[:-1], tri.shape[:-2], "x, tri")
    dtype = jnp.result_type(x.dtype, tri.dtype)
    x = _checks.finite(jnp.broadcast_to(x.astype(dtype), batch + (3,)), "x")
    tri = _checks.finite(jnp.broadcast_to(tri.astype(dtype), batch + (3, 3)), "tri")
    return _closest_point_on_triangle(x, tri)


def _closest_on_segment(x, p, q):
    """Closest point of segment [p, q] to x and its parameter t ∈ [0, 1] (a point for p = q)."""
    d = q - p
    t = jnp.clip(_safe.ratio(_dot(x - p, d), _dot(d, d)), 0, 1)
    return p + t[..., None] * d, t


def _closest_point_on_triangle(x, tri):
    """The kernel of `closest_point_on_triangle` (no checks; `x`, `tri` of one batch shape).

    The projection onto the plane where it falls inside the triangle, else the nearest of the
    three edges' closest points. Unlike the region table of Ericson §5.1.5, no decision rests
    on an exact cancellation (which fused multiply-adds break under `jit` for zero-area
    triangles), so degenerate triangles are exact too.
    """
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    ab, ac, ap = b - a, c - a, x - a
    n = jnp.cross(ab, ac)
    nn = _dot(n, n)
    v = _safe.ratio(_dot(jnp.cross(ap, ac), n), nn)
    w = _safe.ratio(_dot(jnp.cross(ab, ap), n), nn)
    inside = (nn > 0) & (v >= 0) & (w >= 0) & (v + w <= 1)
    face = a + v[..., None] * ab + w[..., None] * ac
    on_ab, t_ab = _closest_on_segment(x, a, b)
    on_bc, t_bc = _closest_on_segment(x, b, c)
    on_ca, t_ca = _closest_on_segment(x, c, a)
    d_ab, d_bc, d_ca = (_dot(x - q, x - q) for q in (on_ab, on_bc, on_ca))
    zero = jnp.zeros_like(t_ab)
    edge_bary = jnp.where(
        ((d_ab <= d_bc) & (d_ab <= d_ca))[..., None],
        jnp.stack([1 - t_ab, t_ab, zero], -1),
        jnp.where(
            (d_bc <= d_ca)[..., None],
            jnp.stack([zero, 1 - t_bc, t_bc], -1),
            jnp.stack([t_ca, zero, 1 - t_ca], -1),
        ),
    )
    edge = jnp.where(
        ((d_ab <= d_bc) & (d_ab <= d_ca))[..., None],
        on_ab,
        jnp.where((d_bc <= d_ca)[..., None], on_bc, on_ca),
    )
    bary = jnp.where(inside[..., None], jnp.stack([1 - v - w, v, w], -1), edge_bary)
    return jnp.where(inside[..., None], face, edge), bary
