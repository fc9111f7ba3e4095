"""`merge` takes a CAD face's trim as a patch's window (issue #17): a face trimmed to a
rectangle (read back from a STEP file) merges exactly as with the explicit window; trims that
are not axis-aligned rectangles are refused naming the patch's entry."""

import numpy as np
import pytest

from bsjax import io
from bsjax import merge as mg
from tests.helpers import random_surface
from tests.test_merge import S, grid_error, split

pytest.importorskip("OCP")


def _rectangle(u0, u1, v0, v1, extra: bool = False):
    corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    if extra:  # collinear points on the sides, as a file's loop split into several edges has
        corners = [(u0, v0), (0.5 * (u0 + u1), v0), (u1, v0), (u1, v1), (u0, v1), (u0, 0.5 * (v0 + v1))]
    return np.array(corners, dtype=np.float64)


def test_a_face_trimmed_to_a_window_merges_as_the_window(tmp_path):
    surface = random_surface(np.random.default_rng(7), 7, 6, 3, 3)
    left, _ = split(surface, "u", 0.6)
    _, right = split(surface, "u", 0.5)
    w = 0.5 / 0.6
    face = io.CadObject(left, "left", trim=io.Trim.from_loops([_rectangle(0.0, w, 0.0, 1.0, True)], [True]))
    read = io.load_all(io.save([face, io.CadObject(right, "right")], tmp_path / "faces.step"), trims=True)
    assert read[0].trim is not None and read[1].trim is None
    np.testing.assert_allclose(read[0].window(), (0.0, w, 0.0, 1.0), rtol=0, atol=1e-12)

    explicit = mg.merge([left, right], "u", 2, samples=(30, S), trim=[(0.0, w), None], orient="as_given")
    from_file = mg.merge([left, right], "u", 2, samples=(30, S), trim=[read[0], read[1]], orient="as_given")
    np.testing.assert_allclose(np.asarray(from_file.ctrl), np.asarray(explicit.ctrl), rtol=0, atol=1e-9)
    assert grid_error(from_file, surface) < 1e-6
    by_trim = mg.merge([left, right], "u", 2, samples=(30, S), trim=[read[0].trim, None], orient="as_given")
    np.testing.assert_allclose(np.asarray(by_trim.ctrl), np.asarray(explicit.ctrl), rtol=0, atol=1e-9)


def test_trims_that_are_not_windows_are_refused():
    surface = random_surface(np.random.default_rng(7), 7, 6, 3, 3)
    left, right = split(surface, "u", 0.5)
    hole = _rectangle(0.4, 0.6, 0.4, 0.6)[::-1]
    holed = io.CadObject(left, trim=io.Trim.from_loops([_rectangle(0, 1, 0, 1), hole], [True, False]))
    with pytest.raises(ValueError, match=r"trim\[0\]: expected an axis-aligned rectangular trim.*1 holes"):
        mg.merge([left, right], "u", 2, samples=S, trim=[holed, None], orient="as_given")
    slanted = io.Trim.from_loops([[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.2, 1.0)]], [True])
    with pytest.raises(ValueError, match=r"trim\[1\]: expected an axis-aligned.*1 of 4 edges off"):
        mg.merge([left, right], "u", 2, samples=S, trim=[None, slanted], orient="as_given")
    ell = io.Trim.from_loops([[(0, 0), (1, 0), (1, 0.5), (0.5, 0.5), (0.5, 1), (0, 1)]], [True])
    with pytest.raises(ValueError, match="2 of 6 edges off"):
        ell.window()
    assert io.CadObject(left).window() == (0.0, 1.0, 0.0, 1.0)
    assert io.Trim.from_loops([_rectangle(0.1, 0.7, 0.2, 0.9, True)], [True]).window() == (0.1, 0.7, 0.2, 0.9)
