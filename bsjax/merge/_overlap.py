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

import numpy as np
from scipy.spatial import cKDTree

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
    da, _ = cKDTree(pb.reshape(-1, 3)).query(pa.reshape(-1, 3))
    db, _ = cKDTree(pa.reshape(-1, 3)).query(pb.reshape(-1, 3))
    return da.reshape(pa.shape[:2]) <= tol, db.reshape(pb.shape[:2]) <= tol


def collide_masks(a: BSplineSurface, b: BSplineSurface, samples: int = 82):
    """Contact masks of the two sample grids from `bsjax.collide.surface_contacts` (its sphere
    hierarchy; every triangle pair for grids of at most 24² samples, where that is cheaper)."""
    from bsjax.collide import surface_contacts

    result = surface_contacts(a.blending(samples, samples), a.ctrl, b.blending(samples, samples), b.ctrl,
                              method="dense" if samples <= 24 else "hierarchy")
    if bool(result.overflow):
        raise ValueError("overlap: expected the collision query to fit its capacity, got an overflow; "
                         "use method='dense'")
    return np.asarray(result.mask_a), np.asarray(result.mask_b)


def overlap_trims(surfaces, direction: str, samples: int = 82, tolerance: float | None = None,
                  method: str = "collide"):
    """Per-patch `(lo, hi)` windows along `direction` that leave out the intersecting rows.

    For each seam, the first patch keeps the rows before its first contact row and the second
    patch the rows after its last contact row; patches with no contact are kept whole.
    `method`: `"collide"` (bsjax.collide) or `"dense"` (distance test, `tolerance`).
    """
    if method not in ("collide", "dense"):
        raise ValueError(f"method: expected 'collide' or 'dense', got {method!r}")
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
        if rows_a.size:
            trims[i][1] = min(trims[i][1], params[rows_a.min()] - 0.5 * step)
        if rows_b.size:
            trims[i + 1][0] = max(trims[i + 1][0], params[rows_b.max()] + 0.5 * step)
    for i, (lo, hi) in enumerate(trims):
        if hi - lo < 4 * step:
            raise ValueError(f"overlap: expected patches that keep some rows after dropping the "
                             f"intersecting ones, got patch {i} with only [{lo:.3f}, {hi:.3f}] left")
    return [tuple(t) for t in trims]
