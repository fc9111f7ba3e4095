"""Property-based tests (hypothesis) on degrees, knot vectors, parameters and net shapes.

Sizes are drawn from small fixed sets: every new shape costs a compile, and the properties
(partition of unity, non-negativity, band width, scipy agreement, refit round trip) do not
depend on the size.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bsjax.basis import BSplineSurface, blending_matrix, periodic_blending_matrix
from tests.oracles import ndbspline_surface, periodic_reference, scipy_matrix, tolerance

N_CTRL, M_PARAMS = 10, 32
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
blending = jax.jit(blending_matrix, static_argnames=("degree", "nu"))
periodic = jax.jit(periodic_blending_matrix, static_argnames=("n_ctrl", "degree", "nu"))


@st.composite
def knot_vectors(draw, n_ctrl=N_CTRL):
    """(degree, clamped knots on [0, 1]) with repeated interior knots (multiplicity ≤ degree)."""
    degree = draw(st.integers(1, 5))
    n_interior = n_ctrl - degree - 1
    grid = draw(st.lists(st.integers(1, 19), min_size=n_interior, max_size=n_interior))
    values, counts = np.unique(np.asarray(grid, dtype=np.float64) / 20, return_counts=True)
    if counts.size and counts.max() > degree:  # cap the multiplicity, refill with fresh values
        free = [x for x in np.arange(1, 20) / 20 if x not in values]
        values = np.concatenate([values, free[: int(np.sum(counts - np.minimum(counts, degree)))]])
        counts = np.concatenate([np.minimum(counts, degree), np.ones(len(values) - len(counts), int)])
    interior = np.sort(np.repeat(values, counts))
    return degree, np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


params = st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=M_PARAMS - 2, max_size=M_PARAMS - 2).map(
    lambda x: np.asarray([0.0, 1.0] + x)
)


@SETTINGS
@given(knot_vectors(), params)
def test_partition_of_unity_nonnegative_banded(degree_knots, x):
    degree, knots = degree_knots
    a = np.asarray(blending(knots, degree, x))
    np.testing.assert_allclose(a.sum(1), 1.0, rtol=0, atol=1e-13)
    assert a.min() >= -1e-15
    assert np.all((a != 0).sum(1) <= degree + 1)
    # the non-zeros of a row are contiguous (band structure)
    for row in a != 0:
        idx = np.nonzero(row)[0]
        assert idx[-1] - idx[0] + 1 == len(idx)


@SETTINGS
@given(knot_vectors(), params, st.integers(0, 2))
def test_scipy_agreement(degree_knots, x, nu):
    degree, knots = degree_knots
    ref = scipy_matrix(knots, degree, x, nu)
    np.testing.assert_allclose(blending(knots, degree, x, nu=nu), ref, rtol=0, atol=tolerance(ref, 1e-11))


@SETTINGS
@given(st.integers(1, 5), st.integers(6, 9), params, st.integers(0, 2))
def test_periodic_properties(degree, n_ctrl, x, nu):
    # Dyadic parameters keep the oracle's `(n u − i + k) mod n` exact: for u = 1 − 2⁻⁵³ it would
    # round n u + k up to an integer and take the derivative of the wrong side of the knot.
    x = np.round(x * 2.0**20) / 2.0**20
    a = np.asarray(periodic(n_ctrl, degree, x, nu=nu))
    ref = periodic_reference(n_ctrl, degree, x, nu)
    np.testing.assert_allclose(a, ref, rtol=0, atol=tolerance(ref, 1e-11))
    np.testing.assert_allclose(a.sum(1), 1.0 if nu == 0 else 0.0, rtol=0, atol=tolerance(a, 1e-12))
    if nu == 0:
        assert a.min() >= -1e-15


@eqx.filter_jit
def _grid_and_back(b, ctrl):
    pts = b.points(ctrl)
    return pts, (None if b.refit_u is None else b.refit(pts))


def _knots_with_sampled_spans(rng, n_ctrl: int, degree: int) -> np.ndarray:
    """Random clamped knots whose every span is at least half the mean span long, so 24 samples
    put one in each and the blending matrix has full column rank (Schoenberg–Whitney); freely
    drawn knots can crowd three into 0.004, leaving spans with no sample (a rank-deficient
    matrix the refit rightly refuses)."""
    inner = n_ctrl - degree - 1
    jitter = rng.uniform(-0.25, 0.25, inner) / (inner + 1)
    interior = np.linspace(0.0, 1.0, inner + 2)[1:-1] + jitter
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from([(4, 6), (7, 5)]),  # non-square nets
    st.integers(1, 3),
    st.integers(1, 3),
    st.booleans(),
    st.booleans(),
    st.integers(0, 2**31 - 1),
)
def test_surface_grid_matches_scipy_and_refits(shape, k, l, periodic_v, rational, seed):
    r, s = shape
    rng = np.random.default_rng(seed)
    tu = _knots_with_sampled_spans(rng, r, k)
    tv = None if periodic_v else _knots_with_sampled_spans(rng, s, l)
    surface = BSplineSurface(
        rng.normal(size=(r, s, 3)),
        tu,
        tv,
        k,
        l,
        periodic_v=periodic_v,
        weights=rng.uniform(0.5, 2.0, (r, s)) if rational else None,
    )
    # Greville-like parameters in u keep the refit well posed; v is sampled on a fine grid.
    b = surface.blending(params_u=np.linspace(0, 1, 24), params_v=np.linspace(0, 1, 24, endpoint=False))
    pts, back = _grid_and_back(b, surface.ctrl)
    u, v = np.meshgrid(np.asarray(b.params_u), np.asarray(b.params_v), indexing="ij")
    np.testing.assert_allclose(pts, ndbspline_surface(surface, u, v), rtol=0, atol=1e-12)
    sigma = np.linalg.svd(np.asarray(b.a_u[0]), compute_uv=False).min()
    if sigma > 1e-3:  # the random knots left no knot span without samples
        np.testing.assert_allclose(back, surface.ctrl, rtol=0, atol=1e-9)
    if sigma < 1e-12:  # rank-deficient: no stored inverse, and refit refuses
        assert back is None
    assert jnp.all(jnp.isfinite(b.normals(surface.ctrl)))
