"""Rows to drop where patches intersect (thesis §4.4.1).

The thesis asks the collision detector for the colliding region and discards the sample rows
from it to the patch's end, so the combined grid `M` stays rectangular. Two contact tests:
`method="collide"` (default) uses `bsjax.collide.surface_contacts` on the patches' blending
grids (triangle–triangle intersection after the sphere hierarchy: the exact intersection
curve); `method="dense"` is a plain distance test between the two sample grids (a k-d tree),
where a sample is "in contact" when a sample of the other patch lies within the grid spacing —
cheaper to compile, and it also catches patches that overlap without crossing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bsjax import _checks
from bsjax._declared import declared
from bsjax.basis import BSplineSurface


def _spacing(points: np.ndarray) -> float:
    du = np.linalg.norm(np.diff(points, axis=0), axis=-1)
    dv = np.linalg.norm(np.diff(points, axis=1), axis=-1)
    return float(max(du.max(), dv.max()))


def contact_masks(a: BSplineSurface, b: BSplineSurface, samples: int = 82, tolerance: float | None = None):
    """Boolean `(samples, samples)` masks of the samples of `a` and `b` within `tolerance` of the
    other patch's samples (default: the larger sample spacing of the two grids)."""
    pa = np.asarray(a.blending(samples, samples).points(a.ctrl))
    pb = np.asarray(b.blending(samples, samples).points(b.ctrl))
    tol = tolerance if tolerance is not None else max(_spacing(pa), _spacing(pb))
    from scipy.spatial import cKDTree  # here: importing scipy.spatial takes tenths of a second

    da, _ = cKDTree(pb.reshape(-1, 3)).query(pa.reshape(-1, 3))
    db, _ = cKDTree(pa.reshape(-1, 3)).query(pb.reshape(-1, 3))
    return da.reshape(pa.shape[:2]) <= tol, db.reshape(pb.shape[:2]) <= tol


def collide_masks(a: BSplineSurface, b: BSplineSurface, samples: int = 82, capacities=(8192, 32768)):
    """Contact masks of the two sample grids from `bsjax.collide.surface_contacts` (its sphere
    hierarchy; every triangle pair for grids of at most 24² samples, where that is cheaper).
    Crossing patches meet along a whole curve, so the query starts with room for 8192
    candidate cell pairs and retries with more when it overflows."""
    from bsjax.collide import surface_contacts

    method = "dense" if samples <= 24 else "hierarchy"
    for capacity in capacities:
        result = surface_contacts(
            a.blending(samples, samples),
            a.ctrl,
            b.blending(samples, samples),
            b.ctrl,
            method=method,
            capacity=capacity,
        )
        if not bool(result.overflow):
            return np.asarray(result.mask_a), np.asarray(result.mask_b)
    raise ValueError(
        f"overlap: expected the collision query to fit its capacity ({capacities[-1]} cell pairs), "
        "got an overflow; use method='dense'"
    )


_TOUCH = 2  # contact confined to this many rows either side of the seam is touching, kept


@declared
def overlap_trims(
    surfaces: Sequence[BSplineSurface],
    direction: str,
    samples: int = 82,
    tolerance: float | None = None,
    method: str = "collide",
):
    """Per-patch `(lo, hi)` windows along `direction` that leave out the intersecting rows.

    For each seam, the first patch keeps the rows before its first contact row and the second
    patch the rows after its last contact row; patches with no contact, or whose contacts lie
    only in the two rows either side of the seam (they just touch), are kept whole.
    `method`: `"collide"` (bsjax.collide) or `"dense"` (distance test, `tolerance`).
    """
    if method not in ("collide", "dense"):
        raise ValueError(f"method: expected 'collide' or 'dense', got {method!r}")
    if direction not in ("u", "v"):
        _checks.fail("direction", "'u' or 'v'", repr(direction))
    axis = 0 if direction == "u" else 1
    params = np.linspace(0.0, 1.0, samples)
    step = params[1]
    trims = [[0.0, 1.0] for _ in surfaces]
    for i in range(len(surfaces) - 1):
        if method == "collide":
            mask_a, mask_b = collide_masks(surfaces[i], surfaces[i + 1], samples)
        else:
            mask_a, mask_b = contact_masks(surfaces[i], surfaces[i + 1], samples, tolerance)
        rows_a = np.nonzero(mask_a.any(axis=1 - axis))[0]
        rows_b = np.nonzero(mask_b.any(axis=1 - axis))[0]
        if rows_a.size and rows_b.size and rows_a.min() >= samples - _TOUCH and rows_b.max() < _TOUCH:
            continue  # the patches only touch along the seam: neighbours, not an intersection
        if rows_a.size:
            trims[i][1] = min(trims[i][1], params[rows_a.min()] - 0.5 * step)
        if rows_b.size:
            trims[i + 1][0] = max(trims[i + 1][0], params[rows_b.max()] + 0.5 * step)
    for i, (lo, hi) in enumerate(trims):
        if hi - lo < 4 * step:
            raise ValueError(
                f"overlap: expected patches that keep some rows after dropping the "
                f"intersecting ones, got patch {i} with only [{lo:.3f}, {hi:.3f}] left"
            )
    return [tuple(t) for t in trims]


def grid_overlap_windows(
    rows, samples: tuple[int, int] = (82, 82), tolerance: float | None = None, method: str = "collide"
):
    """Kept windows `(u0, u1, v0, v1)` of a grid of (oriented) patches that leave out the rows
    where vertical neighbours intersect and the columns where horizontal ones do (§4.4.1).

    Each column of patches is a row along u and each row of patches a row along v for
    `overlap_trims`; a row of patches keeps the u-rows that all its patches keep (the largest
    start, the smallest end), a column the common v-columns, so the combined grid stays
    rectangular. **Returns:** rows of `(u0, u1, v0, v1)`, as `plan_grid`'s `trim`.
    """
    R, C = len(rows), len(rows[0])
    m, n = samples
    u_win = [[0.0, 1.0] for _ in range(R)]
    v_win = [[0.0, 1.0] for _ in range(C)]
    if R > 1:
        for c in range(C):
            for r, (lo, hi) in enumerate(overlap_trims([row[c] for row in rows], "u", m, tolerance, method)):
                u_win[r] = [max(u_win[r][0], lo), min(u_win[r][1], hi)]
    if C > 1:
        for r in range(R):
            for c, (lo, hi) in enumerate(overlap_trims(rows[r], "v", n, tolerance, method)):
                v_win[c] = [max(v_win[c][0], lo), min(v_win[c][1], hi)]
    return [[(*u_win[r], *v_win[c]) for c in range(C)] for r in range(R)]
