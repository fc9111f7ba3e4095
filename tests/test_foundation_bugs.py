"""Failing tests for defects found in the foundation (basis/_surface/_blending); see the report.

Each test states the contract (SPEC §2 / §11, issue 2) that the current code breaks. They are
kept separate so the foundation owner can fix them and move the tests to their home files.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from bsjax.basis import BSplineSurface, basis_functions, blending_matrix, clamped_knots
from tests.helpers import random_surface


def test_rational_evaluate_rejects_bad_derivative_order():
    """SPEC §11: a bad `nu` is a ValueError naming `nu`. The polynomial path does this; the
    NURBS path builds `range(nu + 1)` first and dies with KeyError (nu < 0) / TypeError (float)."""
    surface = random_surface(np.random.default_rng(0), 6, 5, 3, 2, weights=True)
    with pytest.raises(ValueError, match="^nu"):
        surface.evaluate(0.5, 0.5, -1, 0)
    with pytest.raises(ValueError, match="^nu"):
        surface.evaluate(0.5, 0.5, 1.5, 0)
    with pytest.raises(ValueError, match="^nv"):
        surface.evaluate(0.5, 0.5, 0, -1)


def test_blending_matrix_rejects_decreasing_knots():
    """SPEC §11: "non-monotone … knot vectors" → clear error. `blending_matrix` (a public
    contract name) only checks ndim and the degree, so a decreasing vector gives a silent matrix."""
    with pytest.raises(ValueError, match="^knots"):
        blending_matrix(np.array([0.0, 0.0, 0.6, 0.3, 1.0, 1.0]), 1, np.array([0.5]))


def test_periodic_refit_round_trip_with_as_many_samples_as_control_points():
    """SPEC §2: `refit(points(P)) == P` to 1e-10 whenever m ≥ r and n ≥ s. In a closed
    direction the default `linspace(0, 1, n)` samples the seam twice (u = 0 ≡ u = 1), so with
    n == s the stored pseudo-inverse is rank-deficient and the refit is silently wrong (error
    O(1)). Either sample [0, 1) in closed directions or refuse (rank check) in `Blending`."""
    rng = np.random.default_rng(1)
    r, s = 6, 5
    surface = BSplineSurface(rng.normal(size=(r, s, 3)), clamped_knots(r, 3), None, 3, 3, periodic_v=True)
    b = surface.blending(r + 4, s)
    ctrl = jnp.asarray(rng.normal(size=(r, s, 3)))
    try:
        back = b.refit(b.points(ctrl))
    except ValueError as error:  # refusing with a clear message also satisfies the contract
        assert "n" in str(error)
        return
    np.testing.assert_allclose(back, ctrl, rtol=0, atol=1e-10)


def test_basis_functions_rejects_negative_derivative_order():
    """`basis_functions` is public (`basis.__all__`); nu = −1 runs degree + 1 Cox–de Boor steps
    and returns a vector one entry short, silently."""
    knots = clamped_knots(6, 3)
    try:
        out = basis_functions(knots, 3, jnp.asarray(0.5), nu=-1)
    except ValueError as error:
        assert str(error).startswith("nu")
        return
    assert out.shape == (6,), out.shape


def test_blending_params_outside_the_domain_are_refused():
    """SPEC §11 / STYLE ("silent dropping of bad input"): explicit `params_u` outside [0, 1]
    are clipped to the ends without a word; a concrete check (like the finite check next to it)
    would name `params_u` and the range."""
    surface = random_surface(np.random.default_rng(2), 6, 5, 3, 2)
    with pytest.raises(ValueError, match="^params_u"):
        surface.blending(params_u=np.array([-0.5, 0.5, 1.5]), n=9)
