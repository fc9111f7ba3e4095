"""matplotlib pictures of surfaces, control nets and per-sample scalar maps (Agg, no screen)."""

from __future__ import annotations

import numpy as np


def figure(n_panels: int, size: float = 4.0):
    """A row of `n_panels` 3-D axes on the Agg backend (works headless)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(size * n_panels, size))
    axes = [fig.add_subplot(1, n_panels, k + 1, projection="3d") for k in range(n_panels)]
    return fig, axes


def draw_surface(ax, points, ctrl=None, values=None, title: str = "", cmap: str = "viridis"):
    """Draw an `(m, n, 3)` sample grid (coloured by `values (m, n)` if given) and its control net."""
    import matplotlib

    p = np.asarray(points)
    colors = None
    if values is not None:
        v = np.asarray(values, dtype=np.float64)
        span = np.ptp(v) or 1.0
        colors = matplotlib.colormaps[cmap]((v - v.min()) / span)
    style = (
        {"facecolors": colors, "shade": False} if colors is not None else {"color": "#8fb3d9", "shade": True}
    )
    ax.plot_surface(
        p[..., 0], p[..., 1], p[..., 2], rstride=1, cstride=1, linewidth=0, antialiased=False, **style
    )
    if ctrl is not None:
        c = np.asarray(ctrl)
        ax.plot_wireframe(c[..., 0], c[..., 1], c[..., 2], color="#c0392b", linewidth=0.6)
        ax.scatter(c[..., 0].ravel(), c[..., 1].ravel(), c[..., 2].ravel(), color="#c0392b", s=4)
    equal_axes(ax, p.reshape(-1, 3))
    ax.set_title(title, fontsize=9)


def equal_axes(ax, xyz):
    """Equal scale on the three axes, fitted to the `(N, 3)` points."""
    lo, hi = xyz.min(0), xyz.max(0)
    centre, half = (lo + hi) / 2, max((hi - lo).max() / 2, 1e-12)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))


def save(fig, path) -> None:
    """Write `fig` to `path` (PNG at 110 dpi, or the format of the extension) and close it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
