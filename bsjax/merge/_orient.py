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
    return BSplineSurface(orient_ctrl(surface.ctrl, op), ku, kv, du, dv, pu, pv,
                          orient_ctrl(surface.weights, op))


def _edges(surface: BSplineSurface, count: int = 17, samples: tuple[int, int] = (33, 33)) -> dict:
    """The four boundary curves at `count` parameters, read off the patch's `samples` grid (the
    same blending matrices the merge builds) and resampled linearly."""
    grid = np.asarray(surface.blending(*samples).points(surface.ctrl))
    t = np.linspace(0.0, 1.0, count)

    def resample(curve):
        x = np.linspace(0.0, 1.0, len(curve))
        return np.stack([np.interp(t, x, curve[:, i]) for i in range(3)], -1)

    return {("u", 0): resample(grid[0]), ("u", 1): resample(grid[-1]),
            ("v", 0): resample(grid[:, 0]), ("v", 1): resample(grid[:, -1])}


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


def orient_row(surfaces: list[BSplineSurface], direction: str, samples: tuple[int, int] = (33, 33)) -> list[Orientation]:
    """Orientations that make the `direction = 1` edge of patch i meet the `direction = 0` edge of
    patch i + 1 (same sense along the shared edge), chosen by the smallest mean edge gap.
    The edges are read off each patch's `samples` grid.
    """
    edges = [_edges(s, samples=samples) for s in surfaces]
    pairs = list(itertools.product(ALL, repeat=2))
    gaps = [_gap(_oriented_edge(edges[0], a, direction, 1), _oriented_edge(edges[1], b, direction, 0))
            for a, b in pairs]
    ops = list(pairs[_pick(gaps)])
    for e in edges[2:]:
        prev_end = _oriented_edge(edges[len(ops) - 1], ops[-1], direction, 1)
        ops.append(ALL[_pick([_gap(prev_end, _oriented_edge(e, op, direction, 0)) for op in ALL])])
    return ops
