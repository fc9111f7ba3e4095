"""Point-set deviation of a merged surface from the originals (thesis Appendix A, Table A.1).

Like a CAD "point set deviation": dense samples of the original patches are projected onto the
merged surface (closest point, not same parameter) and the distances summarised.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bsjax import _checks
from bsjax.basis import BSplineSurface
from bsjax.merge._project import ProjectionSolver, closest_points


def _nearest(points, candidates, chunk: int = 256):
    """Index of the nearest candidate for every point, in chunks so memory stays `chunk × G`."""
    n = points.shape[0]
    pad = (-n) % chunk
    padded = jnp.concatenate([points, jnp.zeros((pad, 3), points.dtype)]).reshape(-1, chunk, 3)
    c2 = jnp.sum(candidates**2, -1)

    def one(block):
        return jnp.argmin(c2[None, :] - 2.0 * block @ candidates.T, axis=1)

    return jax.lax.map(one, padded).reshape(-1)[:n]


def _candidate_count(surface: BSplineSurface) -> int:
    return int(np.clip(4 * max(surface.shape) + 1, 33, 129))


@eqx.filter_jit
def _closest(surface: BSplineSurface, points, grid, solver: ProjectionSolver):
    cu, cv = (x.reshape(-1) for x in jnp.meshgrid(grid, grid, indexing="ij"))
    idx = _nearest(points, surface.evaluate(cu, cv))
    proj = closest_points(surface, points, jnp.stack([cu[idx], cv[idx]], -1), solver)
    return proj.params, proj.distances


def closest_parameters(surface: BSplineSurface, points, candidates: int | None = None, steps: int = 8):
    """Global closest points on `surface`: the best of a `candidates²` parameter grid (default
    `4·max(r, s) + 1`, 33…129), then `closest_points` (optimistix Gauss–Newton, at most `steps`
    steps). **Returns:** `(uv (N, 2), distances (N,))`."""
    pts = jnp.asarray(points, surface.ctrl.dtype).reshape(-1, 3)
    g = candidates or _candidate_count(surface)
    return _closest(
        surface, pts, jnp.linspace(0.0, 1.0, g, dtype=pts.dtype), ProjectionSolver(max_steps=steps)
    )


@eqx.filter_jit
def _sample(surface: BSplineSurface, pu, pv):
    u, v = jnp.meshgrid(pu, pv, indexing="ij")
    return surface.evaluate(u, v)


class Deviation(eqx.Module):
    """Point-set deviation report (thesis Table A.1 columns).

    **Fields:** `n_points` (total points), `n_within` (points within `tolerance`), `mean`,
    `median`, `std`, `max` distances, `tolerance`, and `distances`: one `(m, n)` array per
    original patch (for heat maps).
    """

    n_points: int
    n_within: int
    mean: float
    median: float
    std: float
    max: float
    tolerance: float
    distances: tuple[np.ndarray, ...]

    def row(self) -> dict:
        """The summary as a dict (for tables and JSON)."""
        return {
            "total points": self.n_points,
            "close points": self.n_within,
            "average": self.mean,
            "median": self.median,
            "std": self.std,
            "max": self.max,
        }


def deviation(
    originals: Sequence[BSplineSurface] | BSplineSurface,
    merged: BSplineSurface,
    samples: int = 101,
    tolerance: float = 0.1,
    candidates: int | None = None,
    windows=None,
) -> Deviation:
    """Deviation of `merged` from the `originals` by closest-point projection (thesis App. A).

    **Arguments:**
    - `originals`: the input patch(es); each is sampled on a `samples × samples` grid (the
      thesis uses 101², i.e. 20402 points for two patches).
    - `merged`: the merged surface.
    - `tolerance`: distance under which a point counts as "close" (same units as the geometry).
    - `candidates`: size of the merged surface's starting grid (default `4·max(r, s) + 1`).
    - `windows`: per original `None` or `(u0, u1, v0, v1)`: sample only that parameter window
      (the kept part of a trimmed or intersecting patch).

    **Returns:** a `Deviation`.
    """
    if isinstance(originals, BSplineSurface):
        originals = [originals]
    if not isinstance(merged, BSplineSurface):
        raise TypeError(f"merged: expected a BSplineSurface, got {type(merged).__name__}")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 2:
        _checks.fail("samples", "an int >= 2", samples)
    _checks.check_positive(tolerance, "tolerance")
    windows = [None] * len(originals) if windows is None else list(windows)
    if len(windows) != len(originals):
        _checks.fail("windows", f"{len(originals)} entries (one per original)", len(windows))
    dists = []
    for i, (s, w) in enumerate(zip(originals, windows)):
        if not isinstance(s, BSplineSurface):
            raise TypeError(f"originals[{i}]: expected a BSplineSurface, got {type(s).__name__}")
        u0, u1, v0, v1 = (0.0, 1.0, 0.0, 1.0) if w is None else map(float, w)
        pu = np.linspace(u0, u1, samples)
        pv = np.linspace(v0, v1, samples)
        pts = _sample(s, jnp.asarray(pu, s.ctrl.dtype), jnp.asarray(pv, s.ctrl.dtype))
        _, d = closest_parameters(merged, pts.astype(merged.ctrl.dtype).reshape(-1, 3), candidates)
        dists.append(np.asarray(d).reshape(samples, samples))
    return summarize(dists, tolerance)


def summarize(dists: Sequence[np.ndarray], tolerance: float) -> Deviation:
    """Summary statistics of per-patch distance grids."""
    alld = np.concatenate([np.ravel(d) for d in dists])
    return Deviation(
        n_points=int(alld.size),
        n_within=int(np.sum(alld <= tolerance)),
        mean=float(alld.mean()),
        median=float(np.median(alld)),
        std=float(alld.std()),
        max=float(alld.max()),
        tolerance=float(tolerance),
        distances=tuple(np.asarray(d) for d in dists),
    )


def plot_deviation(report: Deviation, ax=None, title: str | None = None):
    """Heat map of the deviation, one panel strip per original patch side by side (matplotlib).

    **Returns:** the matplotlib `Axes`.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(2.4 * len(report.distances) + 1.2, 2.6))
    gap = np.full((report.distances[0].shape[0] // 20 + 1, report.distances[0].shape[1]), np.nan)
    parts = [p for d in report.distances for p in (gap, d)][1:]
    strip = np.concatenate(parts, axis=0).T
    image = ax.imshow(
        strip, origin="lower", cmap="viridis", vmin=0.0, vmax=max(report.max, 1e-12), aspect="auto"
    )
    ax.figure.colorbar(image, ax=ax, label="distance")
    ax.set_xlabel("patch samples (u, patch after patch)")
    ax.set_ylabel("v samples")
    ax.set_title(title or f"mean {report.mean:.4g}, max {report.max:.4g}")
    return ax
