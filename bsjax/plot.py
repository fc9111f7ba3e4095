"""matplotlib pictures of surfaces, control nets and per-sample scalar maps.

Figures are plain `matplotlib.figure.Figure`s, not pyplot's: no backend is selected or switched
(a notebook's inline backend, a GUI session and a headless script alike keep theirs), nothing
is kept in pyplot's registry, and `save_figure` writes through the figure's own canvas (no screen).

Needs the `plot` extra (`pip install 'bsjax[plot]'`); matplotlib is imported by the functions.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bsjax import _checks
from bsjax._declared import declared
from bsjax._optional import require

__all__ = ["draw_surface", "equal_axes", "figure", "save_figure"]


def _grid(x, name: str, shape: tuple | None = None) -> np.ndarray:
    """A finite real `(m, n, 3)` grid (or exactly `shape` when given), as float64 numpy."""
    _checks.check_real(x, name)
    a = np.asarray(x, dtype=np.float64)
    if shape is not None and a.shape != shape:
        _checks.fail(name, f"shape {shape}", a.shape)
    if shape is None and (a.ndim != 3 or a.shape[-1] != 3 or min(a.shape[:2]) < 2):
        _checks.fail(name, "a grid of shape (m, n, 3) with m, n >= 2", a.shape)
    if not np.all(np.isfinite(a)):
        _checks.fail(name, "finite values", "NaN or inf")
    return a


@declared
def figure(n_panels: int, size: float = 4.0):
    """A row of `n_panels` 3-D axes: `(matplotlib.figure.Figure, axes)`, outside pyplot (module
    docstring; works headless, and leaves the process's backend as it is)."""
    n_panels = _checks.check_count(n_panels, "n_panels")
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not (0 < size < 1e3):
        _checks.fail("size", "a panel size in inches in (0, 1000)", size)
    require("matplotlib", "plot", "bsjax.plot.figure")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size * n_panels, size))
    axes = [fig.add_subplot(1, n_panels, k + 1, projection="3d") for k in range(n_panels)]
    return fig, axes


@declared
def draw_surface(ax, points, ctrl=None, values=None, title: str = "", cmap: str = "viridis"):
    """Draw an `(m, n, 3)` sample grid (coloured by `values (m, n)` if given) and its control net.

    Bad input (shapes, NaN/inf, an unknown colour map) raises a `ValueError` naming the argument.
    """
    matplotlib = require("matplotlib", "plot", "bsjax.plot.draw_surface")

    _axes(ax)
    p = _grid(points, "points")
    c = None if ctrl is None else _grid(ctrl, "ctrl")
    colors = None
    if values is not None:
        v = _grid(values, "values", p.shape[:2])
        if cmap not in matplotlib.colormaps:
            _checks.fail("cmap", "a matplotlib colour map name (e.g. 'viridis')", repr(cmap))
        span = np.ptp(v) or 1.0
        colors = matplotlib.colormaps[cmap]((v - v.min()) / span)
    style = (
        {"facecolors": colors, "shade": False} if colors is not None else {"color": "#8fb3d9", "shade": True}
    )
    ax.plot_surface(
        p[..., 0], p[..., 1], p[..., 2], rstride=1, cstride=1, linewidth=0, antialiased=False, **style
    )
    if c is not None:
        ax.plot_wireframe(c[..., 0], c[..., 1], c[..., 2], color="#c0392b", linewidth=0.6)
        ax.scatter(c[..., 0].ravel(), c[..., 1].ravel(), c[..., 2].ravel(), color="#c0392b", s=4)
    equal_axes(ax, p.reshape(-1, 3))
    ax.set_title(title, fontsize=9)


def _axes(ax, name: str = "ax"):
    if not hasattr(ax, "set_xlim"):
        _checks.fail(name, "a matplotlib Axes", type(ax).__name__)
    return ax


def equal_axes(ax, xyz):
    """Equal scale on the three axes, fitted to the `(N, 3)` points (finite)."""
    _axes(ax)
    _checks.check_real(xyz, "xyz")
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or not len(xyz):
        _checks.fail("xyz", "points of shape (N, 3), N >= 1", xyz.shape)
    _checks.finite(xyz, "xyz")
    lo, hi = xyz.min(0), xyz.max(0)
    centre, half = (lo + hi) / 2, max((hi - lo).max() / 2, 1e-12)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))


@declared
def save_figure(fig, path: str | os.PathLike) -> None:
    """Write `fig` to `path` (PNG at 110 dpi, or the format of the extension) and close it.

    A missing folder or an extension matplotlib cannot write raises a `ValueError` naming `path`.
    """
    if not hasattr(fig, "savefig"):
        _checks.fail("fig", "a matplotlib Figure", type(fig).__name__)
    path = Path(path)
    if not path.parent.is_dir():
        _checks.fail("path", "a file in an existing folder", str(path))
    formats = fig.canvas.get_supported_filetypes()
    if path.suffix.lstrip(".").lower() not in formats:
        _checks.fail("path", f"an image extension ({', '.join('.' + f for f in sorted(formats))})", str(path))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    if fig.canvas.manager is not None:  # a pyplot figure (a caller's): released from pyplot's registry
        require("matplotlib.pyplot", "plot", "bsjax.plot.save_figure").close(fig)
