"""Point-set deviation of a merged surface from the originals (thesis Appendix A, Table A.1).

Like a CAD "point set deviation": dense samples of the original patches are projected onto the
merged surface (closest point, not same parameter) and the distances summarised.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax._optional import require
from bsjax.basis import BSplineSurface, ProjectionSolver, closest_points


@compiled
def closest_parameters(
    surface: BSplineSurface, points: Float[Array, "N 3"], candidates: int | None = None, steps: int = 8
) -> tuple[Float[Array, "N 2"], Float[Array, " N"]]:
    """Global closest points on `surface`: Gauss–Newton (`closest_points`, at most `steps` steps
    per start) from the nearest samples of a `candidates²` parameter grid (default
    `4·max(r, s) + 1`, 33…129), the best kept. **Returns:** `(uv (N, 2), distances (N,))`."""
    steps = _checks.check_count(steps, "steps")
    pts = jnp.asarray(points, surface.ctrl.dtype).reshape(-1, 3)
    proj = closest_points(surface, pts, None, ProjectionSolver(max_steps=steps), candidates)
    return proj.params, proj.distances


class Deviation(eqx.Module):
    """Point-set deviation report (thesis Table A.1 columns).

    **Fields:** `n_points` (static: total points), `n_within` (points within `tolerance`),
    `mean`, `median`, `std`, `max` distances (0-d arrays), `tolerance` (static), and
    `distances`: one `(m, n)` array per original patch (for heat maps). `row()` gives the
    summary as plain Python numbers.
    """

    n_within: Int[Array, ""]
    mean: Float[Array, ""]
    median: Float[Array, ""]
    std: Float[Array, ""]
    max: Float[Array, ""]
    distances: tuple[Float[Array, "m n"], ...]
    n_points: int = eqx.field(static=True)
    tolerance: float = eqx.field(static=True)

    def row(self) -> dict:
        """The summary as a dict of Python numbers (for tables and JSON)."""
        return {
            "total points": self.n_points,
            "close points": int(self.n_within),
            "average": float(self.mean),
            "median": float(self.median),
            "std": float(self.std),
            "max": float(self.max),
        }


def _window_params(w, samples: int, surface: BSplineSurface):
    """The `samples` parameters per direction of the window `w` (`None`: the whole domain); a
    closed direction sampled all the way round stops short of 1, so its seam counts once."""
    u0, u1, v0, v1 = (0.0, 1.0, 0.0, 1.0) if w is None else w

    def grid(lo, hi, periodic):
        endpoint = not (periodic and hi - lo >= 1.0)
        return jnp.linspace(lo, hi, samples, endpoint=endpoint, dtype=surface.ctrl.dtype)

    return grid(u0, u1, surface.periodic_u), grid(v0, v1, surface.periodic_v)


def _check_windows(windows, count: int):
    windows = [None] * count if windows is None else list(windows)
    if len(windows) != count:
        _checks.fail("windows", f"{count} entries (one per original)", len(windows))
    for i, w in enumerate(windows):
        if w is not None and len(w) != 4:
            _checks.fail(f"windows[{i}]", "None or (u0, u1, v0, v1)", w)
    return windows


@compiled(static=("tolerance",))
def deviation(
    originals: Sequence[BSplineSurface] | BSplineSurface,
    merged: BSplineSurface,
    samples: int = 101,
    tolerance: float = 0.1,
    candidates: int | None = None,
    windows=None,
) -> Deviation:
    """Deviation of `merged` from the `originals` by closest-point projection (thesis App. A).

    Dense samples of the originals are projected onto `merged` (closest point, not same
    parameter: `closest_parameters`, a global multi-start Gauss–Newton search that also finds
    foot points across a seam of a closed surface) and the distances summarised.

    **Arguments:**
    - `originals`: the input patch(es); each is sampled on a `samples × samples` grid (the
      thesis uses 101², i.e. 20402 points for two patches; a closed direction's samples cover
      [0, 1) once, its seam not twice).
    - `merged`: the merged surface.
    - `tolerance`: distance (> 0) under which a point counts as "close" (same units as the
      geometry); static (a new value compiles again).
    - `candidates`: size of the merged surface's starting grid (default `4·max(r, s) + 1`).
    - `windows`: per original `None` or `(u0, u1, v0, v1)`: sample only that parameter window
      (the kept part of a trimmed or intersecting patch).

    **Returns:** a `Deviation` (compiled once per shapes and options; also works inside `jit`).
    """
    if isinstance(originals, BSplineSurface):
        originals = [originals]
    if not isinstance(merged, BSplineSurface):
        raise TypeError(f"merged: expected a BSplineSurface, got {type(merged).__name__}")
    samples = _checks.check_count(samples, "samples", 2)
    if not np.isfinite(tolerance) or tolerance <= 0:  # static: checked while tracing
        _checks.fail("tolerance", "a finite value > 0", tolerance)
    windows = _check_windows(windows, len(originals))
    dtype = merged.ctrl.dtype
    points = []
    for i, (s, w) in enumerate(zip(originals, windows)):
        if not isinstance(s, BSplineSurface):
            raise TypeError(f"originals[{i}]: expected a BSplineSurface, got {type(s).__name__}")
        pu, pv = _window_params(w, samples, s)
        uu, vv = jnp.meshgrid(pu, pv, indexing="ij")
        pts = s.evaluate(uu, vv).astype(dtype)
        points.append(_checks.finite(pts, f"originals[{i}]").reshape(-1, 3))
    # one projection of every original's samples: one search in the program, not one per original
    _, d = closest_parameters(merged, jnp.concatenate(points), candidates)
    return summarize(list(d.reshape(len(points), samples, samples)), tolerance)


def summarize(dists: Sequence[Float[Array, "m n"]], tolerance: float) -> Deviation:
    """Summary statistics of per-patch distance grids (traceable)."""
    alld = jnp.concatenate([jnp.ravel(d) for d in dists])
    return Deviation(
        n_within=jnp.sum(alld <= tolerance),
        mean=jnp.mean(alld),
        median=jnp.median(alld),
        std=jnp.std(alld),
        max=jnp.max(alld),
        distances=tuple(dists),
        n_points=int(alld.size),
        tolerance=float(tolerance),
    )


@declared
def plot_deviation(report: Deviation, ax=None, title: str | None = None):
    """Heat map of the deviation, one panel strip per original patch side by side (matplotlib).

    **Returns:** the matplotlib `Axes`. Needs the `plot` extra.
    """
    plt = require("matplotlib.pyplot", "plot", "bsjax.merge.plot_deviation")

    if ax is None:
        _, ax = plt.subplots(figsize=(2.4 * len(report.distances) + 1.2, 2.6))
    dists = [np.asarray(d) for d in report.distances]
    gap = np.full((dists[0].shape[0] // 20 + 1, dists[0].shape[1]), np.nan)
    parts = [p for d in dists for p in (gap, d)][1:]
    strip = np.concatenate(parts, axis=0).T
    image = ax.imshow(
        strip, origin="lower", cmap="viridis", vmin=0.0, vmax=max(float(report.max), 1e-12), aspect="auto"
    )
    ax.figure.colorbar(image, ax=ax, label="distance")
    ax.set_xlabel("patch samples (u, patch after patch)")
    ax.set_ylabel("v samples")
    ax.set_title(title or f"mean {report.mean:.4g}, max {report.max:.4g}")
    return ax
