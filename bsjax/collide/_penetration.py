"""Per-sample penetration depth and contact normal between two deformable B-spline surfaces.

Penetration is measured by **closest point** (surface–surface contact, thesis ch. 3; the
distributed-spring depth of Gao & Gibson, *Haptic B-spline surface sculpting with
a shaped tool of implicit surface*, §3.2, with the other surface in place of the tool). For surfaces
X and Y (first A against B, then B against A):

- `x_i` is sample i of X (its blending's `(m, n)` grid); `c_i` the closest point of Y's sampled
  tessellation (two triangles per cell, as `hierarchy.grid_mesh`), found per sample (vmapped
  over X's samples) with the point tool's certified nearest-triangle search
  (`contact._nearest_on_grid`: the triangles of the cells around the nearest sample, certified
  when no other cell's corner ball comes closer, else every triangle). The search decides the
  triangle only (no gradient); the foot point on it, its barycentric weights and everything
  after are differentiable. Where two triangles are equally near (a foot on a shared edge)
  either may be reported; the foot point, depth and normal are the same.
- `n_Y(c_i)` is Y's unit normal at `c_i`: Y's sample normals (`contact.points_normals`)
  interpolated with the barycentric weights of `c_i` and normalised (`_safe.unit`).
- The signed distance is `s_i = (x_i − c_i)·n_Y(c_i)`. Sample i of X penetrates Y when
  `s_i < 0`, `|x_i − c_i| ≤ reach` and `c_i` is interior to Y: not a foot point on Y's open
  boundary. The foot lies on the open boundary when every vertex of its triangle with a
  positive barycentric weight lies on one boundary side (first or last row or column of Y's
  grid) and is open there (a point beyond a plate's edge projects onto the edge: its foot is
  clamped there). A side is not open at a sample that coincides with the opposite side's
  sample (a closed direction's seam, sampled twice by the default grid `linspace(0, 1, n)`, or
  a clamped net closed on itself) or with its neighbour along the side (a pole); coincidence is
  within 1 % of the grid's spacing across the side there (the distance to the sample one row
  in) — loose enough for a deformed body's refit surface, whose pole and seam samples drift
  apart by rounding-sized amounts — and at least `√ε` times the extent of Y's samples. So
  samples beyond a plate's edge, or farther than `reach` behind it, never count.
- Where sample i penetrates: depth `d_i = −s_i`, normal `n_Y(c_i)` (the direction that pushes X
  out of Y); elsewhere depth 0 and normal 0.

`reach` is the deepest penetration counted (e.g. the thinner body's thickness): an open
surface has no inside, so without it every sample anywhere behind the other surface would be
in contact. The distance `|x_i − c_i|` (≥ `|s_i|`) is compared with it, which lets the search
skip samples whose lower bound already exceeds `reach` (their `faces`/`bary` are then a nearby
triangle's, not necessarily the nearest's; they are never in contact).

A broad phase first certifies, with the control hulls (`broad.hulls_apart` with margin `reach`),
that no sample of either surface lies within `reach` of the other; then the narrow phase is
skipped (`lax.cond`) and both results are empty (`faces` 0, `bary` `(1, 0, 0)`).

Cost, for a searched grid of V samples: per searching sample the nearest sample is found among
every 5th row and column and then the 11 × 11 samples around it (not among all V), the 50
triangles of the 5 × 5 cells around it are searched, and the certificate bounds the 400 cells
of the 4 × 4 tiles of 5 × 5 cells around them one by one and every other tile by one ball —
about `V / 25` balls, not V. Both directions run as the two steps of one `lax.map` (one
program whatever the grids' shapes); only uncertified samples within `reach` pay for a search
of every triangle. Grids of at most 200 triangles (11 × 11 samples, no more than the samples
scanned around the nearest one) are searched whole instead: every sample against every
triangle, exact without a certificate, and a program a fraction of the size (an 8 × 8 pair:
the first call of a two-body scene 2.1 → 1.5 s, a step 2.4× faster).

`surface_penetration` is compiled at the public boundary (`bsjax._boundary.compiled`): the
blendings' arrays, the nets and `reach` are traced (a new `reach` does not recompile); the
blendings' static fields select a compilation.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled, host_cache
from bsjax.collide import _soa
from bsjax.collide._broad import _hulls_apart, unless_apart
from bsjax.collide._contact import _BLOCK, _CORNERS, _checked_net, points_normals
from bsjax.collide._hierarchy import _cell_triangles
from bsjax.collide._triangles import _closest_point_on_triangle, _face_table, _nearest_face


class Penetration(eqx.Module):
    """Penetration of the samples of one surface X into the other surface Y (module docstring).

    **Fields:**
    - `depth (m, n)`: `d_i = −s_i ≥ 0` where in contact, 0 elsewhere.
    - `normals (m, n, 3)`: unit contact normal `n_Y(c_i)` that pushes X out of Y where in
      contact, zeros elsewhere.
    - `mask (m, n)`: samples of X in contact.
    - `faces (m, n, 3)`: Y's sample indices (flat, row-major into Y's `(m_Y, n_Y)` grid) of the
      triangle holding the foot point `c_i`.
    - `bary (m, n, 3)`: barycentric weights of `c_i` on that triangle (≥ 0, sum 1): a force
      `f_i` on sample i of X is balanced exactly by `−bary_ik f_i` on Y's sample `faces_ik`.
    """

    depth: Float[Array, "m n"]
    normals: Float[Array, "m n 3"]
    mask: Bool[Array, "m n"]
    faces: Int[Array, "m n 3"]
    bary: Float[Array, "m n 3"]


@compiled
def surface_penetration(
    blending_a, ctrl_a: Float[Array, "ra sa 3"], blending_b, ctrl_b: Float[Array, "rb sb 3"], *, reach
) -> tuple[Penetration, Penetration]:
    """Per-sample penetration of two surfaces into each other, by closest point (module docstring).

    **Arguments:**
    - `blending_a`, `blending_b`: the surfaces' `Blending`s (sample grids of at least 2 × 2).
    - `ctrl_a (ra, sa, 3)`, `ctrl_b (rb, sb, 3)`: their control nets (finite; differentiable).
    - `reach` (keyword, required): the deepest penetration counted, e.g. the thinner body's
      thickness; a finite scalar > 0 (traced).

    **Returns:** `(a against b, b against a)`: the `Penetration` of A's samples `(m_a, n_a)`
    into B and of B's samples `(m_b, n_b)` into A (the second copy of a seam sample never in
    contact: `Blending.counted`). The depth is the distributed-spring depth of
    Gao & Gibson, *Haptic B-spline surface sculpting with a shaped tool of implicit surface*,
    §3.2, measured to the other surface's tessellation; jittable, vmappable and differentiable
    in both nets (the foot triangle is a decision, the depth and normal along it are not).
    """
    ctrl_a = _checked_net(blending_a, ctrl_a, "ctrl_a", "blending_a")
    ctrl_b = _checked_net(blending_b, ctrl_b, "ctrl_b", "blending_b")
    for blending, name in ((blending_a, "blending_a"), (blending_b, "blending_b")):
        if min(blending.grid_shape) < 2:
            _checks.fail(name, "a sample grid of at least 2 x 2", f"grid {tuple(blending.grid_shape)}")
    dtype = jnp.promote_types(ctrl_a.dtype, ctrl_b.dtype)
    ctrl_a, ctrl_b = ctrl_a.astype(dtype), ctrl_b.astype(dtype)
    reach = _checked_reach(reach, dtype)
    apart = _hulls_apart(ctrl_a.reshape(-1, 3), ctrl_b.reshape(-1, 3), reach)  # a decision
    pa, na = points_normals(blending_a, ctrl_a)
    pb, nb = points_normals(blending_b, ctrl_b)
    ab, ba = _both_sides(pa, na, pb, nb, reach, apart)
    return _counted(ab, blending_a.counted), _counted(ba, blending_b.counted)


def _counted(pen: Penetration, counted) -> Penetration:
    """`pen` with the second copy of each seam sample out of contact (`Blending.counted`): a
    closed surface's seam pushes once (its reaction still reaches the other surface's copies)."""
    return eqx.tree_at(
        lambda p: (p.depth, p.normals, p.mask),
        pen,
        (jnp.where(counted, pen.depth, 0), jnp.where(counted[..., None], pen.normals, 0), pen.mask & counted),
    )


def _checked_reach(reach, dtype):
    """`reach` as a finite scalar > 0 of `dtype` (structure now, value at run time too)."""
    _checks.check_real(reach, "reach")
    if np.shape(reach) != ():
        _checks.fail("reach", "a scalar", f"shape {np.shape(reach)}")
    return _checks.positive(jnp.asarray(reach).astype(dtype), "reach")


_TILE = _BLOCK - 1  # cells per side of a tile (the searched block's size)
# a grid of at most this many triangles is searched whole, every sample against every triangle:
# no more than the `(2·_TILE + 1)²` samples that the tiled search scans around the nearest one
_EXHAUSTIVE = 2 * (2 * _TILE) ** 2
_COINCIDE = 1e-2  # samples closer than this fraction of the spacing across a side coincide


class _Layout(NamedTuple):
    """Static index tables of the two searches (`_both_sides`), built on the host from the shapes.

    Side 0 is A's samples searching B's grid, side 1 B's samples searching A's. Flat lists
    concatenate both searched grids (B's, then A's): vertices (`vert_offset (2,)` where each
    grid starts, `vert_side (V,)`), cells (`cell_corners (C, 4)`: vertices p00, p10, p01, p11)
    and tiles of `_TILE × _TILE` cells (`tile_verts (G, (_TILE+1)²)`: every vertex of the tile,
    padded by repetition; `tile_corners (G, 4)`). The searching samples concatenate A's and
    B's (`sample_count (2,)`). Each `stack` entry `(2, K)` gathers one side's own entries of a
    flat list (vertices, cells, tiles, triangles, the coarse vertices of every `_TILE`-th row
    and column, samples) into one row per side, padded to the longer side; `valid` marks the
    real ones, `rows`/`cols` their grid positions; `dims (2, 2)` is each searched grid's `(p, q)`.

    The boundary tables, per vertex and side (first row, last row, first column, last column):
    `on_side (V, 4)` whether the vertex lies on that side; `rim (V, 4, 4)` the opposite side's
    vertex, the vertex's two neighbours along the side (one repeated at an end) and its
    neighbour one row or column in (the vertex itself where it is not on the side).
    """

    dims: np.ndarray
    vert_offset: np.ndarray
    vert_side: np.ndarray
    cell_corners: np.ndarray
    tile_verts: np.ndarray
    tile_corners: np.ndarray
    sample_count: np.ndarray
    stack: dict
    valid: dict
    rows: dict
    cols: dict
    on_side: np.ndarray
    rim: np.ndarray


def _every(count: int, step: int) -> np.ndarray:
    """`0, step, 2·step, …` and the last index `count − 1` (as `Blending.lod`)."""
    idx = np.arange(0, count, step)
    return idx if idx[-1] == count - 1 else np.append(idx, count - 1)


def _stack(lists) -> tuple[np.ndarray, np.ndarray]:
    """`(index (2, K), valid (2, K))`: two index lists as rows padded with their first entry."""
    width = max(len(x) for x in lists)
    index = np.stack([np.concatenate([x, np.full(width - len(x), x[0])]) for x in lists])
    valid = np.arange(width)[None, :] < np.array([len(x) for x in lists])[:, None]
    return index.astype(np.int32), valid


@host_cache()
def _layout(shape_b: tuple[int, int], shape_a: tuple[int, int]) -> _Layout:
    """The `_Layout` of the searched grids `(p, q)` of B and A."""
    dims = np.array([shape_b, shape_a], np.int32)
    verts = dims[:, 0] * dims[:, 1]
    offset = np.array([0, verts[0]])
    total = int(verts.sum())
    rim = np.repeat(np.arange(total)[:, None, None], 4, 1).repeat(4, 2)
    on_side = np.zeros((total, 4), bool)
    cell_corners, tile_verts, tile_corners = [], [], []
    lists = {k: [] for k in ("vert", "cell", "tile", "tri", "coarse", "sample")}
    rows, cols = {"tile": [], "coarse": []}, {"tile": [], "coarse": []}
    for side, (p, q) in enumerate(dims):
        idx = np.arange(p * q).reshape(p, q) + offset[side]
        cell_start, tile_start = sum(len(c) for c in cell_corners), sum(len(t) for t in tile_verts)
        cell_corners.append(np.stack([idx[a, b].reshape(-1) for a, b in _CORNERS], 1))
        lists["vert"].append(idx.reshape(-1))
        lists["cell"].append(cell_start + np.arange((p - 1) * (q - 1)))
        lists["tri"].append(2 * cell_start + np.arange(2 * (p - 1) * (q - 1)))
        tu, tv = -(-(p - 1) // _TILE), -(-(q - 1) // _TILE)
        tiles = []
        for a in range(tu):
            for b in range(tv):
                r = np.arange(a * _TILE, min((a + 1) * _TILE, p - 1) + 1)
                c = np.arange(b * _TILE, min((b + 1) * _TILE, q - 1) + 1)
                block = idx[np.ix_(r, c)].reshape(-1)
                tiles.append(np.concatenate([block, np.full((_TILE + 1) ** 2 - block.size, block[0])]))
                tile_corners.append([idx[r[0], c[0]], idx[r[-1], c[0]], idx[r[0], c[-1]], idx[r[-1], c[-1]]])
        tile_verts.append(np.array(tiles))
        lists["tile"].append(tile_start + np.arange(tu * tv))
        rows["tile"].append(np.repeat(np.arange(tu), tv))
        cols["tile"].append(np.tile(np.arange(tv), tu))
        coarse_r, coarse_c = np.meshgrid(_every(p, _TILE), _every(q, _TILE), indexing="ij")
        lists["coarse"].append(idx[coarse_r, coarse_c].reshape(-1))
        rows["coarse"].append(coarse_r.reshape(-1))
        cols["coarse"].append(coarse_c.reshape(-1))
        lines = (
            (idx[0], idx[-1], idx[1]),
            (idx[-1], idx[0], idx[-2]),
            (idx[:, 0], idx[:, -1], idx[:, 1]),
            (idx[:, -1], idx[:, 0], idx[:, -2]),
        )
        for k, (line, opposite, inward) in enumerate(lines):
            before = np.concatenate([line[1:2], line[:-1]])  # at an end: the one neighbour twice
            after = np.concatenate([line[1:], line[-2:-1]])
            rim[line, k] = np.stack([opposite, before, after, inward], 1)
            on_side[line, k] = True
    lists["sample"] = [np.arange(verts[1]), verts[1] + np.arange(verts[0])]  # A's samples, then B's
    stacked = {k: _stack(v) for k, v in lists.items()}
    return _Layout(
        dims=dims,
        vert_offset=offset.astype(np.int32),
        vert_side=np.repeat(np.arange(2, dtype=np.int32), verts),
        cell_corners=np.concatenate(cell_corners).astype(np.int32),
        tile_verts=np.concatenate(tile_verts).astype(np.int32),
        tile_corners=np.array(tile_corners, np.int32),
        sample_count=verts[::-1].astype(np.int32),
        stack={k: v[0] for k, v in stacked.items()},
        valid={k: v[1] for k, v in stacked.items()},
        rows={k: _stack(v)[0] for k, v in rows.items()},
        cols={k: _stack(v)[0] for k, v in cols.items()},
        on_side=on_side,
        rim=rim.astype(np.int32),
    )


def _both_sides(pa, na, pb, nb, reach, apart) -> tuple[Penetration, Penetration]:
    """A's samples against B's tessellation and B's against A's (module docstring): one search
    program for both sides (`_foot_triangles`, skipped by `lax.cond` when the broad phase
    certified the surfaces `apart`), then the differentiable foot points, normals and depths
    of all samples at once.

    The `lax.cond` holds the search only, on values without gradient: differentiating the
    result linearises no branch of it (JAX linearises each branch of a `cond` with a tangent
    twice). Apart, every sample's foot is taken on a placeholder triangle of its searched grid's
    first cell (so the foot point and its derivative stay finite), out of contact, and reported
    empty (`faces` 0, `bary` `(1, 0, 0)`)."""
    lay = _layout(tuple(pb.shape[:2]), tuple(pa.shape[:2]))
    x = jnp.concatenate([pa.reshape(-1, 3), pb.reshape(-1, 3)])  # the searching samples
    verts = jnp.concatenate([pb.reshape(-1, 3), pa.reshape(-1, 3)])  # the searched grids
    vert_normals = jnp.concatenate([nb.reshape(-1, 3), na.reshape(-1, 3)])
    grids = (jax.lax.stop_gradient(pb), jax.lax.stop_gradient(pa))
    fixed = jax.lax.stop_gradient(verts)
    own = np.repeat(lay.vert_offset, lay.sample_count)[:, None]  # where each sample's searched grid starts
    row = np.repeat(lay.dims[:, 1], lay.sample_count)[:, None]  # its searched grid's row length
    first = own + np.array([0, 1, 0]) + np.array([0, 0, 1]) * row  # that grid's first triangle
    y, near = jax.lax.stop_gradient(x), jax.lax.stop_gradient(reach)
    face = unless_apart(
        apart,
        lambda: _foot_triangles(y, fixed, grids, lay, near),
        empty=lambda out: jnp.asarray(first, out.dtype),
    )
    closest, bary = _closest_point_on_triangle(x, verts[face])  # (N, 3), (N, 3): differentiable
    normal = _safe.unit(jnp.sum(bary[..., None] * vert_normals[face], axis=1))
    offset = x - closest
    s = _safe.dot(offset, normal)
    open_sides = _open_sides(fixed, grids, lay)[face]  # (N, 3, 4)
    on_boundary = jnp.any(jnp.all(open_sides | ~(bary > 0)[..., None], axis=1), axis=-1)
    mask = (s < 0) & (_safe.norm(offset) <= reach) & ~on_boundary & ~apart
    depth = jnp.where(mask, -s, 0)
    normal = jnp.where(mask[:, None], normal, 0)
    split = int(lay.sample_count[0])
    face = jnp.where(apart, 0, face - jnp.asarray(own))
    bary = jnp.where(apart, jnp.asarray([1, 0, 0], bary.dtype), bary)

    def side(rows: slice, shape) -> Penetration:
        m, n = shape
        return Penetration(
            depth=depth[rows].reshape(m, n),
            normals=normal[rows].reshape(m, n, 3),
            mask=mask[rows].reshape(m, n),
            faces=face[rows].reshape(m, n, 3),
            bary=bary[rows].reshape(m, n, 3),
        )

    return side(slice(None, split), pa.shape[:2]), side(slice(split, None), pb.shape[:2])


def _foot_triangles(x, verts, grids, lay: _Layout, reach) -> Int[Array, "N 3"]:
    """Vertex indices `(N, 3)` into `verts` of the triangle nearest to each searching sample
    `x (N, 3)` in its side's grid (no gradient: a decision).

    The search of `contact._nearest_on_grid` per sample (`_search_side`), with the corner balls
    of the cells (centre: corner mean, radius: farthest corner) and of tiles of `_TILE × _TILE`
    cells (centre: corner mean, radius: farthest vertex) computed once for all samples, and
    the triangles of `hierarchy._cell_triangles`; grids of at most `_EXHAUSTIVE` triangles
    (padded) are searched whole (`_nearest_of_all` per sample). The two sides are the two steps
    of a `lax.map` over rows padded to one shape: one program for both, whatever the grids' shapes.
    """
    tris, faces = [], []
    for side, grid in enumerate(grids):
        t, f = _cell_triangles(grid)
        tris.append(t.reshape(-1, 3, 3))
        faces.append(f.reshape(-1, 3).astype(jnp.int32) + int(lay.vert_offset[side]))
    # the triangles as the per-face quantities of `_triangles._d2`, one row per face: `(T, ROWS)`
    table, faces = _face_table(jnp.concatenate(tris)), jnp.concatenate(faces)
    st, valid = lay.stack, lay.valid
    every_face = dict(table=table[st["tri"]], faces=faces[st["tri"]], tri_valid=jnp.asarray(valid["tri"]))
    if st["tri"].shape[1] <= _EXHAUSTIVE:  # small grids: every triangle, no certificate needed
        found = jax.lax.map(
            lambda g: jax.vmap(lambda y: _nearest_of_all(g, y))(g["x"]), {**every_face, "x": x[st["sample"]]}
        )
        return _unstack(found, lay)

    def balls(corners, members):
        """Centres (mean of 4 corners) and radii (farthest member vertex) of vertex groups."""
        centre = sum(verts[corners[:, c]] for c in range(4)) * 0.25
        d = _soa.split(verts[members] - centre[:, None])
        return centre, jnp.sqrt(jnp.max(_soa.dot(d, d), axis=1))

    cell_centre, cell_radius = balls(lay.cell_corners, lay.cell_corners)
    tile_centre, tile_radius = balls(lay.tile_corners, lay.tile_verts)
    per_side = dict(
        dims=jnp.asarray(lay.dims),
        verts=verts[st["vert"]],
        cell_centre=cell_centre[st["cell"]],
        cell_radius=cell_radius[st["cell"]],
        tile_centre=tile_centre[st["tile"]],
        tile_radius=tile_radius[st["tile"]],
        tile_valid=jnp.asarray(valid["tile"]),
        tile_row=jnp.asarray(lay.rows["tile"]),
        tile_col=jnp.asarray(lay.cols["tile"]),
        coarse=verts[st["coarse"]],
        coarse_valid=jnp.asarray(valid["coarse"]),
        coarse_row=jnp.asarray(lay.rows["coarse"]),
        coarse_col=jnp.asarray(lay.cols["coarse"]),
        **every_face,
        x=x[st["sample"]],
    )
    return _unstack(jax.lax.map(lambda g: _search_side(g, reach), per_side), lay)


def _unstack(found: Int[Array, "2 N_max 3"], lay: _Layout) -> Int[Array, "N 3"]:
    """The two sides' rows of `found` without their padding, A's samples then B's."""
    count = lay.sample_count
    return jnp.concatenate([found[0, : count[0]], found[1, : count[1]]])


def _nearest_of_all(g: dict, y) -> Int[Array, " 3"]:
    """The vertex indices of the triangle nearest to `y (3,)` among every triangle of one side's
    grid (the rows of `_foot_triangles`)."""
    return g["faces"][_nearest_face(y, g["table"], valid=g["tri_valid"])[0]]


def _search_side(g: dict, reach) -> Int[Array, "N 3"]:
    """One side of `_foot_triangles`: the nearest triangles `(N, 3)` of the samples `g["x"]`
    in one grid of `g["dims"] = (p, q)` (the padded rows of `_foot_triangles`).

    Per sample (`vmap`): the nearest vertex (the nearest of every `_TILE`-th row and column,
    then the nearest in the `(2·_TILE + 1)²` vertices around it), the triangles of the
    `_BLOCK × _BLOCK` samples around it (`contact._nearest_on_grid`), and its certificate: no
    unsearched cell comes closer than the triangle found — bounded by the corner balls of the
    cells of the 4 × 4 tiles around the block (which hold every cell within `_TILE` cells of
    it) and by the balls of the other tiles.
    A sample is searched again over every triangle (one such sample after the other, a
    `fori_loop` over just those) when some ball comes within `min(found distance, reach)`: only
    then can a nearer triangle lie within `reach` (a sample whose nearer triangles all lie
    beyond `reach` is out of contact whichever of them it reports).
    """
    p, q = g["dims"][0], g["dims"][1]
    coarse, verts = _soa.split(g["coarse"]), g["verts"]
    window = np.arange(-_TILE, _TILE + 1, dtype=np.int32)
    steps, pattern = np.arange(_BLOCK - 1, dtype=np.int32), np.arange(4 * _TILE, dtype=np.int32)

    def within(centre, radius, y, dist, other):
        """Whether some ball of `other` comes within `dist` of `y` (squares: no root per ball)."""
        d = _soa.sub(_soa.split(centre), y)
        return jnp.any(other & (_soa.dot(d, d) <= (dist + radius) ** 2))

    def local(y):
        d = _soa.sub(coarse, y)
        k = jnp.argmin(jnp.where(g["coarse_valid"], _soa.dot(d, d), jnp.inf))
        r = jnp.clip(g["coarse_row"][k] + window, 0, p - 1)[:, None]
        c = jnp.clip(g["coarse_col"][k] + window, 0, q - 1)[None, :]
        around = (r * q + c).reshape(-1)
        d = _soa.split(verts[around] - y[None])
        near = around[jnp.argmin(_soa.dot(d, d))]
        i0 = jnp.clip(near // q - _BLOCK // 2, 0, jnp.maximum(p - _BLOCK, 0))
        j0 = jnp.clip(near % q - _BLOCK // 2, 0, jnp.maximum(q - _BLOCK, 0))
        rows = jnp.minimum(i0 + steps, p - 2)[:, None, None]
        cols = jnp.minimum(j0 + steps, q - 2)[None, :, None]
        index = (2 * (rows * (q - 1) + cols) + np.arange(2, dtype=np.int32).reshape(1, 1, 2)).reshape(
            -1
        )  # `_cell_triangles` order
        k, d2 = _nearest_face(y, g["table"], index)
        dist = _safe.sqrt(d2)
        # the cells of the 4 × 4 tiles around the block one by one, every other tile as a whole
        ti, tj = jnp.maximum(i0 - _TILE, 0) // _TILE, jnp.maximum(j0 - _TILE, 0) // _TILE
        row_hit = (g["tile_row"] >= ti) & (g["tile_row"] < ti + 4)
        other_tiles = g["tile_valid"] & ~(row_hit & (g["tile_col"] >= tj) & (g["tile_col"] < tj + 4))
        cr = jnp.minimum(ti * _TILE + pattern, p - 2)[:, None]
        cc = jnp.minimum(tj * _TILE + pattern, q - 2)[None, :]
        unsearched = ~((cr >= i0) & (cr < i0 + _BLOCK - 1) & (cc >= j0) & (cc < j0 + _BLOCK - 1))
        cells = (cr * (q - 1) + cc).reshape(-1)
        tiles = (g["tile_centre"], g["tile_radius"])
        near_cells = (g["cell_centre"][cells], g["cell_radius"][cells])
        unsearched = unsearched.reshape(-1)
        bound = jnp.minimum(dist, reach)
        return g["faces"][index[k]], within(*tiles, y, bound, other_tiles) | within(
            *near_cells, y, bound, unsearched
        )

    face, needed = jax.vmap(local)(g["x"])
    order = jnp.nonzero(needed, size=needed.shape[0], fill_value=0)[0]

    def every(i, face):
        j = order[i]
        return face.at[j].set(_nearest_of_all(g, g["x"][j]))

    return jax.lax.fori_loop(0, jnp.sum(needed, dtype=jnp.int32), every, face)


def _open_sides(verts, grids, lay: _Layout) -> Bool[Array, "V 4"]:
    """Whether each vertex of the searched grids lies on the open side first row, last row,
    first column, last column of its grid: a sample that coincides with the opposite side's
    sample (a seam) or with a neighbour along the side (a pole) is not open (module docstring).
    Coincidence: every coordinate within `_COINCIDE` times the distance to the vertex's
    neighbour one row in (the grid's local spacing across the side), and at least `√ε` times
    the grid's extent."""
    eps = jnp.finfo(verts.dtype).eps
    ext_b, ext_a = (jnp.max(jnp.max(g, axis=(0, 1)) - jnp.min(g, axis=(0, 1))) for g in grids)
    # a select, not a gather: XLA fuses a gather's operand into it, every reduction per element
    floor = jnp.sqrt(eps) * jnp.where(jnp.asarray(lay.vert_side == 0), ext_b, ext_a)[:, None, None]
    chebyshev = jnp.max(jnp.abs(verts[lay.rim] - verts[:, None, None, :]), axis=-1)  # (V, 4, 4)
    tol = jnp.maximum(floor, _COINCIDE * chebyshev[..., 3:])
    closed = jnp.any(chebyshev[..., :3] <= tol, axis=-1)
    return jnp.asarray(lay.on_side) & ~closed
