"""`bsjax.plot` draws on plain matplotlib figures: the process's backend and pyplot's figures are
the caller's (a notebook's inline backend must survive a bsjax picture)."""

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")


def test_figure_and_save_leave_the_backend_and_pyplot_alone(tmp_path):
    import matplotlib.pyplot as plt

    from bsjax import plot

    before = matplotlib.get_backend()
    try:
        matplotlib.use("pdf")  # a caller's choice, not Agg
        open_figures = plt.get_fignums()
        fig, (ax,) = plot.figure(1)
        grid = np.stack([*np.meshgrid(np.arange(4.0), np.arange(5.0), indexing="ij"), np.zeros((4, 5))], -1)
        plot.draw_surface(ax, grid, values=grid[..., 0])
        plot.save_figure(fig, tmp_path / "plate.png")
        assert matplotlib.get_backend() == "pdf"
        assert plt.get_fignums() == open_figures  # nothing left in pyplot's registry
        assert (tmp_path / "plate.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        matplotlib.use(before)
