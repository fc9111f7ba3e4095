"""Orientation of patches before a merge: which edges meet, and the flip/transpose that puts them
in place (thesis §4.3.1: the patches are "moved closer together and allowed to touch").

An orientation is `(transpose, flip_u, flip_v)`: swap u and v first, then reverse u and/or v.
Each is an exact reparametrisation, applied to the control net (differentiably) and the knots.
"""

from __future__ import annotations

import itertools
import weakref
from collections import OrderedDict

import jax.numpy as jnp
import numpy as np

from bsjax import _boundary, _checks
from bsjax._declared import declared
from bsjax.basis import BSplineSurface, SplineDirection

Orientation = tuple[bool, bool, bool]
IDENTITY: Orientation = (False, False, False)
# identity first, so that ties (symmetric patches) keep the patch as given
ALL: tuple[Orientation, ...] = tuple(itertools.product((False, True), repeat=3))  # pyright: ignore[reportAssignmentType]


def orient_ctrl(x, op: Orientation):
    """Apply orientation `op` to an `(r, s, …)` array (control net or weights)."""
    transpose, flip_u, flip_v = op
    if x is None:
        return None
    if transpose:
        x = jnp.swapaxes(x, 0, 1)
    if flip_u:
        x = x[::-1]
    if flip_v:
        x = x[:, ::-1]
    return x


def _flip(direction: SplineDirection) -> SplineDirection:
    """The direction reversed, `t → 1 − t` (a periodic basis is its own reverse up to a shift of
    the control points; periodic patches are not merged)."""
    if direction.periodic:
        return direction
    return SplineDirection(1.0 - direction.knots[::-1], direction.degree)


@declared
def orient_surface(surface: BSplineSurface, op: Orientation) -> BSplineSurface:
    """`surface` reparametrised by `op` (same geometry): `op = (transpose, flip_u, flip_v)`."""
    if not (isinstance(op, tuple) and len(op) == 3 and all(isinstance(b, (bool, np.bool_)) for b in op)):
        _checks.fail("op", "an orientation (transpose, flip_u, flip_v) of three bools", repr(op))
    if op == IDENTITY:
        return surface
    transpose, flip_u, flip_v = op
    du, dv = surface.direction_u, surface.direction_v
    if transpose:
        du, dv = dv, du
    du = _flip(du) if flip_u else du
    dv = _flip(dv) if flip_v else dv
    return BSplineSurface.from_directions(
        orient_ctrl(surface.ctrl, op), du, dv, orient_ctrl(surface.weights, op)
    )


_EDGE_POINTS = 17


def _edge_curves(surfaces: tuple[BSplineSurface, ...], count: int) -> tuple[np.ndarray, ...]:
    """The four boundary curves `u = 0`, `u = 1`, `v = 0`, `v = 1` of every patch, `(4, count, 3)`
    each at `count` equally spaced parameters, on the host (numpy, concrete patches): the blending
    matrices of the two ends and of the parameters contracted with the homogeneous net `[w P, w]`
    (thesis eq. 3.6), so planning an orientation compiles nothing."""
    t, ends = np.linspace(0.0, 1.0, count), np.array([0.0, 1.0])
    curves = []
    for s in surfaces:
        net = np.asarray(s.ctrl, np.float64)
        if s.weights is not None:
            w = np.asarray(s.weights, np.float64)[..., None]
            net = np.concatenate([net * w, w], -1)
        basis = lambda d, x: np.asarray(d.matrix(x), np.float64)
        grid = lambda a_u, a_v: np.einsum("ai,ijc,bj->abc", a_u, net, a_v)
        u_edges = grid(basis(s.direction_u, ends), basis(s.direction_v, t))  # (2, c, d)
        v_edges = grid(basis(s.direction_u, t), basis(s.direction_v, ends))  # (c, 2, d)
        h = np.concatenate([u_edges, v_edges.transpose(1, 0, 2)])
        curves.append(h if s.weights is None else h[..., :-1] / h[..., -1:])
    return tuple(curves)


def _edges(surface: BSplineSurface, count: int = _EDGE_POINTS) -> dict:
    """The four boundary curves of `surface` at `count` parameters, keyed `(direction, end)`."""
    return _edge_dicts([surface], count)[0]


class _EdgeMemo:
    """The edges last read from the same surface objects: surfaces (and their arrays) are
    immutable, so the same objects have the same edges — a repeated `merge` of the same patches
    skips the probe. Held by weak reference; `bsjax.clear_caches()` empties it."""

    size = 64

    def __init__(self):
        self.entries: OrderedDict = OrderedDict()

    def get(self, surfaces, count):
        hit = self.entries.get((tuple(map(id, surfaces)), count))
        if hit is not None and all(ref() is s for ref, s in zip(hit[0], surfaces)):
            return hit[1]
        return None

    def put(self, surfaces, count, edges):
        self.entries[(tuple(map(id, surfaces)), count)] = (tuple(weakref.ref(s) for s in surfaces), edges)
        if len(self.entries) > self.size:
            self.entries.popitem(last=False)

    def clear_cache(self) -> None:
        self.entries.clear()


_MEMO = _EdgeMemo()
_boundary.register(_MEMO)


def _edge_dicts(surfaces, count: int = _EDGE_POINTS) -> list[dict]:
    surfaces = tuple(surfaces)
    edges = _MEMO.get(surfaces, count)
    if edges is None:
        keys = (("u", 0), ("u", 1), ("v", 0), ("v", 1))
        edges = [dict(zip(keys, np.asarray(c, np.float64))) for c in _edge_curves(surfaces, count)]
        if _checks.is_concrete([s.ctrl for s in surfaces]):
            _MEMO.put(surfaces, count, edges)
    return edges


def _oriented_edge(edges: dict, op: Orientation, direction: str, end: int) -> np.ndarray:
    """The `direction = end` edge of the patch reoriented by `op`, from the original's edges."""
    transpose, flip_u, flip_v = op
    flip_here, flip_along = (flip_u, flip_v) if direction == "u" else (flip_v, flip_u)
    own = direction if not transpose else ("v" if direction == "u" else "u")
    curve = edges[(own, 1 - end if flip_here else end)]
    return curve[::-1] if flip_along else curve


def _all_oriented(edges: dict, direction: str, end: int) -> np.ndarray:
    """`(8, c, 3)`: the `direction = end` edge under each orientation of `ALL`."""
    return np.stack([_oriented_edge(edges, op, direction, end) for op in ALL])


def _gaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean distances between every edge of `a (p, c, 3)` and of `b (q, c, 3)`: `(p, q)`."""
    return np.mean(np.linalg.norm(a[:, None] - b[None], axis=-1), axis=-1)


def _pick(gaps: list[float]) -> int:
    """Index of the smallest gap; the earliest of near-ties (identity wins on symmetric input)."""
    g = np.asarray(gaps)
    return int(np.argmax(g <= g.min() + 1e-9 * (1.0 + abs(g.min()))))


def orient_row(surfaces: list[BSplineSurface], direction: str, samples=None) -> list[Orientation]:
    """Orientations that make the `direction = 1` edge of patch i meet the `direction = 0` edge of
    patch i + 1 (same sense along the shared edge), chosen by the smallest mean edge gap.
    The edges are evaluated at 17 parameters (one compiled call for all patches; `samples` is
    accepted for compatibility and unused).
    """
    del samples
    patches = tuple(surfaces)
    known = _MEMO.get(patches, ("row", direction))
    if known is not None:
        return list(known)
    ops = _orient_row(patches, direction)
    if _checks.is_concrete([s.ctrl for s in patches]):
        _MEMO.put(patches, ("row", direction), tuple(ops))
    return ops


def _orient_row(surfaces, direction: str) -> list[Orientation]:
    edges = _edge_dicts(surfaces)
    gaps = _gaps(_all_oriented(edges[0], direction, 1), _all_oriented(edges[1], direction, 0))
    pairs = list(itertools.product(ALL, repeat=2))  # row-major over (first, second): as gaps.ravel()
    ops = list(pairs[_pick(list(gaps.ravel()))])
    for e in edges[2:]:
        prev_end = _oriented_edge(edges[len(ops) - 1], ops[-1], direction, 1)
        ops.append(ALL[_pick(list(_gaps(prev_end[None], _all_oriented(e, direction, 0))[0]))])
    return ops


@declared
def orient_grid(rows: list[list[BSplineSurface]], samples=None) -> list[list[Orientation]]:
    """Orientations of an `R × C` grid of patches (thesis §4.4.3) so that patch `(i, j)`'s `u = 1`
    edge meets `(i+1, j)`'s `u = 0` edge and its `v = 1` edge meets `(i, j+1)`'s `v = 0` edge.

    The corner patch and its two neighbours are chosen together (8³ combinations, the smallest
    sum of the two mean edge gaps); every further patch, in row-major order, takes the
    orientation whose `u = 0` / `v = 0` edges best meet the already placed patch above / to
    the left. A single row or column is `orient_row`. Ties keep the patch as given. `samples` is
    accepted for compatibility and unused (the edges are evaluated exactly).
    """
    del samples
    R, C = len(rows), len(rows[0])
    surfaces = tuple(s for row in rows for s in row)
    known = _MEMO.get(surfaces, ("grid", R, C))
    if known is not None:
        return [list(row) for row in known]
    ops = _orient_grid(rows, R, C)
    if _checks.is_concrete([s.ctrl for s in surfaces]):
        _MEMO.put(surfaces, ("grid", R, C), tuple(tuple(row) for row in ops))
    return ops


def _orient_grid(rows, R: int, C: int) -> list[list[Orientation]]:
    if R == 1:
        return [orient_row(rows[0], "v")]
    if C == 1:
        return [[op] for op in orient_row([row[0] for row in rows], "u")]
    flat = _edge_dicts([s for row in rows for s in row])
    edges = [flat[i * C : (i + 1) * C] for i in range(R)]

    def cost(i, j, ops):
        """Gaps of the 8 orientations of patch (i, j) to its placed neighbours above and left."""
        total = np.zeros(len(ALL))
        if i > 0:
            above = _oriented_edge(edges[i - 1][j], ops[i - 1][j], "u", 1)
            total += _gaps(above[None], _all_oriented(edges[i][j], "u", 0))[0]
        if j > 0:
            left = _oriented_edge(edges[i][j - 1], ops[i][j - 1], "v", 1)
            total += _gaps(left[None], _all_oriented(edges[i][j], "v", 0))[0]
        return total

    # triples (a, b, c) of the corner and its neighbours in itertools.product order: a·64 + b·8 + c
    right = _gaps(_all_oriented(edges[0][0], "v", 1), _all_oriented(edges[0][1], "v", 0))
    below = _gaps(_all_oriented(edges[0][0], "u", 1), _all_oriented(edges[1][0], "u", 0))
    corner = (right[:, :, None] + below[:, None, :]).ravel()
    a, b, c = list(itertools.product(ALL, repeat=3))[_pick(list(corner))]
    ops: list[list] = [[None] * C for _ in range(R)]
    ops[0][0], ops[0][1], ops[1][0] = a, b, c
    for i in range(R):
        for j in range(C):
            if ops[i][j] is None:
                ops[i][j] = ALL[_pick(list(cost(i, j, ops)))]
    return ops
