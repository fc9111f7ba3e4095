"""Point-set deviation of a merged surface from the originals (thesis Appendix A, Table A.1).

Like a CAD "point set deviation": dense samples of the original patches are projected onto the
merged surface (closest point, not same parameter) and the distances summarised.
"""

from __future__ import annotations

from typing import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks
from bsjax.basis import BSplineSurface


def _gauss_newton_step(surface: BSplineSurface, points, uv):
    """One clamped Gauss–Newton step on `|S(u, v) − x|²` for every point (2×2 normal equations)."""
    u, v = uv[:, 0], uv[:, 1]
    r = surface.evaluate(u, v) - points
    su, sv = surface.evaluate(u, v, 1, 0), surface.evaluate(u, v, 0, 1)
    a, b, c = jnp.sum(su * su, -1), jnp.sum(su * sv, -1), jnp.sum(sv * sv, -1)
    g0, g1 = jnp.sum(su * r, -1), jnp.sum(sv * r, -1)
    eps = jnp.finfo(uv.dtype).eps
    damp = 1e3 * eps * (a + c) + jnp.finfo(uv.dtype).tiny
    a, c = a + damp, c + damp
    det = a * c - b * b
    safe = det > eps * (a * c)
    det = jnp.where(safe, det, 1.0)  # double where: a degenerate point (pole) does not move
    du = jnp.where(safe, -(c * g0 - b * g1) / det, 0.0)
    dv = jnp.where(safe, -(a * g1 - b * g0) / det, 0.0)
    return jnp.clip(uv + jnp.stack([du, dv], -1), 0.0, 1.0)


def project(surface: BSplineSurface, points: Float[Array, "N 3"], uv0: Float[Array, "N 2"],
            steps: int = 8) -> Float[Array, "N 2"]:
    """Closest-point parameters of `points` on `surface`, from starting guesses `uv0`.

    Gauss–Newton on `|S(u,v) − x|²` (the 2×2 system `J^T J δ = −J^T r` per point, closed form),
    clamped to [0, 1]², `steps` iterations; the better of the start and the result is kept, so a
    step can never make a point worse. Jittable and batched over points.
    """
    uv = jax.lax.fori_loop(0, steps, lambda _, x: _gauss_newton_step(surface, points, x), uv0)
    d0 = jnp.sum((surface.evaluate(uv0[:, 0], uv0[:, 1]) - points) ** 2, -1)
    d1 = jnp.sum((surface.evaluate(uv[:, 0], uv[:, 1]) - points) ** 2, -1)
    return jnp.where((d1 <= d0)[:, None], uv, uv0)


_project_jit = eqx.filter_jit(project)


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
def _closest(surface: BSplineSurface, points, grid, steps: int):
    cu, cv = (x.reshape(-1) for x in jnp.meshgrid(grid, grid, indexing="ij"))
    idx = _nearest(points, surface.evaluate(cu, cv))
    uv = project(surface, points, jnp.stack([cu[idx], cv[idx]], -1), steps)
    return uv, jnp.linalg.norm(surface.evaluate(uv[:, 0], uv[:, 1]) - points, axis=-1)


def closest_parameters(surface: BSplineSurface, points, candidates: int | None = None, steps: int = 8):
    """Global closest points on `surface`: the best of a `candidates²` parameter grid (default
    `4·max(r, s) + 1`, 33…129), then `project`. **Returns:** `(uv (N, 2), distances (N,))`."""
    pts = jnp.asarray(points, surface.ctrl.dtype).reshape(-1, 3)
    g = candidates or _candidate_count(surface)
    return _closest(surface, pts, jnp.linspace(0.0, 1.0, g, dtype=pts.dtype), steps)


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
        return {"total points": self.n_points, "close points": self.n_within, "average": self.mean,
                "median": self.median, "std": self.std, "max": self.max}


def deviation(originals: Sequence[BSplineSurface] | BSplineSurface, merged: BSplineSurface,
              samples: int = 101, tolerance: float = 0.1, candidates: int | None = None,
              windows=None) -> Deviation:
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
        n_points=int(alld.size), n_within=int(np.sum(alld <= tolerance)), mean=float(alld.mean()),
        median=float(np.median(alld)), std=float(alld.std()), max=float(alld.max()),
        tolerance=float(tolerance), distances=tuple(np.asarray(d) for d in dists),
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
    image = ax.imshow(strip, origin="lower", cmap="viridis", vmin=0.0, vmax=max(report.max, 1e-12),
                      aspect="auto")
    ax.figure.colorbar(image, ax=ax, label="distance")
    ax.set_xlabel("patch samples (u, patch after patch)")
    ax.set_ylabel("v samples")
    ax.set_title(title or f"mean {report.mean:.4g}, max {report.max:.4g}")
    return ax
