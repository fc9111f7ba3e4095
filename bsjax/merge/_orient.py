"""Orientation of patches before a merge: which edges meet, and the flip/transpose that puts them
in place (thesis §4.3.1: the patches are "moved closer together and allowed to touch").

An orientation is `(transpose, flip_u, flip_v)`: swap u and v first, then reverse u and/or v.
Each is an exact reparametrisation, applied to the control net (differentiably) and the knots.
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np

from bsjax.basis import BSplineSurface

Orientation = tuple[bool, bool, bool]
IDENTITY: Orientation = (False, False, False)
# identity first, so that ties (symmetric patches) keep the patch as given
ALL: tuple[Orientation, ...] = tuple(itertools.product((False, True), repeat=3))


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


def _flip_knots(t):
    return None if t is None else 1.0 - t[::-1]


def orient_surface(surface: BSplineSurface, op: Orientation) -> BSplineSurface:
    """`surface` reparametrised by `op` (same geometry)."""
    if op == IDENTITY:
        return surface
    transpose, flip_u, flip_v = op
    ku, kv = surface.knots_u, surface.knots_v
    du, dv, pu, pv = surface.degree_u, surface.degree_v, surface.periodic_u, surface.periodic_v
    if transpose:
        ku, kv, du, dv, pu, pv = kv, ku, dv, du, pv, pu
    ku = _flip_knots(ku) if flip_u else ku
    kv = _flip_knots(kv) if flip_v else kv
    return BSplineSurface(
        orient_ctrl(surface.ctrl, op), ku, kv, du, dv, pu, pv, orient_ctrl(surface.weights, op)
    )


def _edges(surface: BSplineSurface, count: int = 17, samples: tuple[int, int] = (33, 33)) -> dict:
    """The four boundary curves at `count` parameters, read off the patch's `samples` grid (the
    same blending matrices the merge builds) and resampled linearly."""
    grid = np.asarray(surface.blending(*samples).points(surface.ctrl))
    t = np.linspace(0.0, 1.0, count)

    def resample(curve):
        x = np.linspace(0.0, 1.0, len(curve))
        return np.stack([np.interp(t, x, curve[:, i]) for i in range(3)], -1)

    return {
        ("u", 0): resample(grid[0]),
        ("u", 1): resample(grid[-1]),
        ("v", 0): resample(grid[:, 0]),
        ("v", 1): resample(grid[:, -1]),
    }


def _oriented_edge(edges: dict, op: Orientation, direction: str, end: int) -> np.ndarray:
    """The `direction = end` edge of the patch reoriented by `op`, from the original's edges."""
    transpose, flip_u, flip_v = op
    flip_here, flip_along = (flip_u, flip_v) if direction == "u" else (flip_v, flip_u)
    own = direction if not transpose else ("v" if direction == "u" else "u")
    curve = edges[(own, 1 - end if flip_here else end)]
    return curve[::-1] if flip_along else curve


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.linalg.norm(a - b, axis=-1)))


def _pick(gaps: list[float]) -> int:
    """Index of the smallest gap; the earliest of near-ties (identity wins on symmetric input)."""
    g = np.asarray(gaps)
    return int(np.argmax(g <= g.min() + 1e-9 * (1.0 + abs(g.min()))))


def orient_row(
    surfaces: list[BSplineSurface], direction: str, samples: tuple[int, int] = (33, 33)
) -> list[Orientation]:
    """Orientations that make the `direction = 1` edge of patch i meet the `direction = 0` edge of
    patch i + 1 (same sense along the shared edge), chosen by the smallest mean edge gap.
    The edges are read off each patch's `samples` grid.
    """
    edges = [_edges(s, samples=samples) for s in surfaces]
    pairs = list(itertools.product(ALL, repeat=2))
    gaps = [
        _gap(_oriented_edge(edges[0], a, direction, 1), _oriented_edge(edges[1], b, direction, 0))
        for a, b in pairs
    ]
    ops = list(pairs[_pick(gaps)])
    for e in edges[2:]:
        prev_end = _oriented_edge(edges[len(ops) - 1], ops[-1], direction, 1)
        ops.append(ALL[_pick([_gap(prev_end, _oriented_edge(e, op, direction, 0)) for op in ALL])])
    return ops


def orient_grid(
    rows: list[list[BSplineSurface]], samples: tuple[int, int] = (33, 33)
) -> list[list[Orientation]]:
    """Orientations of an `R × C` grid of patches (thesis §4.4.3) so that patch `(i, j)`'s `u = 1`
    edge meets `(i+1, j)`'s `u = 0` edge and its `v = 1` edge meets `(i, j+1)`'s `v = 0` edge.

    The corner patch and its two neighbours are chosen together (8³ combinations, the smallest
    sum of the two mean edge gaps); every further patch, in row-major order, takes the
    orientation whose `u = 0` / `v = 0` edges best meet the already placed patch above / to
    the left. A single row or column is `orient_row`. Ties keep the patch as given.
    """
    R, C = len(rows), len(rows[0])
    if R == 1:
        return [orient_row(rows[0], "v", samples)]
    if C == 1:
        return [[op] for op in orient_row([row[0] for row in rows], "u", samples)]
    edges = [[_edges(s, samples=samples) for s in row] for row in rows]

    def cost(i, j, op, ops):
        total = 0.0
        if i > 0:
            total += _gap(
                _oriented_edge(edges[i - 1][j], ops[i - 1][j], "u", 1),
                _oriented_edge(edges[i][j], op, "u", 0),
            )
        if j > 0:
            total += _gap(
                _oriented_edge(edges[i][j - 1], ops[i][j - 1], "v", 1),
                _oriented_edge(edges[i][j], op, "v", 0),
            )
        return total

    triples = list(itertools.product(ALL, repeat=3))
    corner = [
        _gap(_oriented_edge(edges[0][0], a, "v", 1), _oriented_edge(edges[0][1], b, "v", 0))
        + _gap(_oriented_edge(edges[0][0], a, "u", 1), _oriented_edge(edges[1][0], c, "u", 0))
        for a, b, c in triples
    ]
    a, b, c = triples[_pick(corner)]
    ops: list[list] = [[None] * C for _ in range(R)]
    ops[0][0], ops[0][1], ops[1][0] = a, b, c
    for i in range(R):
        for j in range(C):
            if ops[i][j] is None:
                ops[i][j] = ALL[_pick([cost(i, j, op, ops) for op in ALL])]
    return ops
