"""Knot vectors, basis functions and blending matrices against scipy and closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import BSpline

from bsjax.basis import (
    SplineDirection,
    basis_functions,
    blending_matrix,
    clamped_knots,
    greville,
    periodic_blending_matrix,
    periodic_knots,
)
from tests.helpers import check_grad, random_knots
from tests.oracles import (
    cardinal_bspline,
    knots_with_repeats,
    periodic_reference,
    scipy_matrix,
    tolerance,
)

DEGREES = [1, 2, 3, 4, 5]
# Fixed sizes: eager blending_matrix compiles every primitive anew for each new shape, so the
# tests share a few shapes and call the jitted wrappers below (eager == jit is tested once).
N_CTRL, M_PARAMS, N_PERIODIC = 12, 48, 8
blending = jax.jit(blending_matrix, static_argnames=("degree", "nu"))
periodic = jax.jit(periodic_blending_matrix, static_argnames=("n_ctrl", "degree", "nu"))


def _params(rng, knots, m=M_PARAMS):
    """`m` sorted parameters: 0, 1, every distinct knot value, the rest random."""
    fixed = np.unique(np.concatenate([[0.0, 1.0], np.asarray(knots)]))
    return np.sort(np.concatenate([fixed, rng.uniform(0, 1, m - len(fixed))]))


@pytest.mark.parametrize("n_ctrl, degree", [(2, 1), (5, 2), (7, 3), (11, 4), (6, 5)])
def test_clamped_knots_closed_form(n_ctrl, degree):
    knots = np.asarray(clamped_knots(n_ctrl, degree))
    interior = np.arange(1, n_ctrl - degree) / (n_ctrl - degree)
    expected = np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])
    assert knots.shape == (n_ctrl + degree + 1,)
    np.testing.assert_allclose(knots, expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("kind", ["random", "repeated", "uniform"])
def test_blending_matches_scipy_design_matrix(degree, kind):
    rng = np.random.default_rng(degree)
    n_ctrl = N_CTRL
    knots = {
        "random": random_knots(rng, n_ctrl, degree),
        "repeated": knots_with_repeats(rng, n_ctrl, degree),
        "uniform": np.asarray(clamped_knots(n_ctrl, degree)),
    }[kind]
    x = _params(rng, knots)
    a = np.asarray(blending(knots, degree, x))
    ref = scipy_matrix(knots, degree, x)
    assert a.shape == (len(x), n_ctrl)
    np.testing.assert_allclose(a, ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("nu", [1, 2])
def test_derivative_blending_matches_scipy_derivative(degree, nu):
    """Simple knots: scipy's `BSpline(...).derivative(nu)` spline of the identity coefficients."""
    rng = np.random.default_rng(10 + degree)
    n_ctrl = N_CTRL
    knots = random_knots(rng, n_ctrl, degree)
    x = _params(rng, knots)
    a = np.asarray(blending(knots, degree, x, nu=nu))
    if nu > degree:  # scipy refuses; the derivative of a piecewise-linear basis is 0 a.e.
        ref = np.zeros((len(x), n_ctrl))
        x = x[~np.isin(x, knots)]
        a = np.asarray(blending(knots, degree, x, nu=nu))
        ref = ref[: len(x)]
    else:
        ref = BSpline(knots, np.eye(n_ctrl), degree).derivative(nu)(x)
    np.testing.assert_allclose(a, ref, rtol=0, atol=tolerance(ref))


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("nu", [1, 2, 3])
def test_derivative_blending_repeated_knots(degree, nu):
    """Repeated interior knots: right-continuous derivatives as scipy's `__call__(x, nu)`."""
    rng = np.random.default_rng(20 + degree)
    n_ctrl = N_CTRL
    knots = knots_with_repeats(rng, n_ctrl, degree)
    x = _params(rng, knots)
    a = np.asarray(blending(knots, degree, x, nu=nu))
    ref = scipy_matrix(knots, degree, x, nu)
    np.testing.assert_allclose(a, ref, rtol=0, atol=tolerance(ref))


@pytest.mark.parametrize("degree", DEGREES)
def test_derivative_above_degree_is_zero(degree):
    knots = np.asarray(clamped_knots(N_CTRL, degree))
    a = blending(knots, degree, np.linspace(0, 1, M_PARAMS), nu=degree + 1)
    assert a.shape == (M_PARAMS, N_CTRL)
    assert float(jnp.max(jnp.abs(a))) == 0.0


@pytest.mark.parametrize("degree", DEGREES)
def test_partition_of_unity_and_band(degree):
    rng = np.random.default_rng(30 + degree)
    knots = knots_with_repeats(rng, N_CTRL, degree)
    x = _params(rng, knots)
    a = np.asarray(blending(knots, degree, x))
    np.testing.assert_allclose(a.sum(1), 1.0, rtol=0, atol=1e-13)
    assert a.min() >= -1e-15
    assert np.all((np.abs(a) > 0).sum(1) <= degree + 1)
    for nu in (1, 2):
        d = np.asarray(blending(knots, degree, x, nu=nu))
        np.testing.assert_allclose(d.sum(1), 0.0, rtol=0, atol=tolerance(d))


def test_end_rows_interpolate_end_points():
    """Clamped: row at u = 0 is e_0 and the row at u = 1 exactly is e_{n−1}."""
    for degree in DEGREES:
        knots = np.asarray(clamped_knots(N_CTRL, degree))
        a = np.asarray(blending(knots, degree, np.linspace(0.0, 1.0, M_PARAMS)))
        np.testing.assert_array_equal(a[[0, -1]], np.eye(N_CTRL)[[0, -1]])


@pytest.mark.parametrize("degree", [1, 3, 5])
def test_basis_functions_single_parameter_and_jit(degree):
    rng = np.random.default_rng(40 + degree)
    knots = jnp.asarray(random_knots(rng, N_CTRL, degree))
    f = jax.jit(basis_functions, static_argnums=(1, 3))
    for t in (0.0, 1.0, float(knots[degree + 1]), 0.37):
        for nu in (0, 1, 2):
            got = np.asarray(f(knots, degree, jnp.asarray(t), nu))
            ref = scipy_matrix(knots, degree, [t], nu)[0]
            np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref))


@pytest.mark.parametrize("degree", [2, 3])
def test_blending_grad_wrt_params(degree):
    """d/du of the row sum weighted by a fixed vector equals the nu=1 matrix (and FD)."""
    rng = np.random.default_rng(50 + degree)
    knots = random_knots(rng, N_CTRL, degree)
    x = jnp.asarray(rng.uniform(0.05, 0.95, M_PARAMS))
    c = jnp.asarray(rng.normal(size=N_CTRL))

    @jax.jit
    def f(p):
        return jnp.sum(blending_matrix(knots, degree, p) @ c)

    g = check_grad(f, x)
    np.testing.assert_allclose(g, scipy_matrix(knots, degree, x, 1) @ np.asarray(c), rtol=1e-10, atol=1e-12)


def test_blending_vmap_over_parameter_sets():
    knots = jnp.asarray(clamped_knots(N_CTRL, 3))
    params = jnp.asarray(np.random.default_rng(0).uniform(0, 1, (4, M_PARAMS)))
    batched = jax.jit(jax.vmap(lambda p: blending_matrix(knots, 3, p)))(params)
    for b in range(4):
        np.testing.assert_allclose(batched[b], scipy_matrix(knots, 3, params[b]), rtol=0, atol=1e-12)


# --- periodic (closed) basis -------------------------------------------------------------------
@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("nu", [0, 1, 2])
def test_periodic_matches_closed_form_eq_3_3(degree, nu):
    n_ctrl = N_PERIODIC
    rng = np.random.default_rng(60 + degree)
    x = np.concatenate([np.arange(n_ctrl) / n_ctrl, rng.uniform(0, 1, M_PARAMS - n_ctrl - 1), [1.0 - 1e-9]])
    a = np.asarray(periodic(n_ctrl, degree, x, nu=nu))
    ref = periodic_reference(n_ctrl, degree, x, nu)
    np.testing.assert_allclose(a, ref, rtol=0, atol=tolerance(ref, 1e-11 if nu else 1e-12))


def test_uniform_cubic_closed_form_is_the_textbook_one():
    """Sanity of the oracle: the uniform cubic pieces (1/6)[t³, −3t³+3t²+3t+1, 3t³−6t²+4, (1−t)³]."""
    t = np.linspace(0, 1, 11)[:-1]
    pieces = [t**3, -3 * t**3 + 3 * t**2 + 3 * t + 1, 3 * t**3 - 6 * t**2 + 4, (1 - t) ** 3]
    for j, piece in enumerate(pieces):
        np.testing.assert_allclose(cardinal_bspline(t + j, 3), piece / 6, atol=1e-15)


@pytest.mark.parametrize("degree", DEGREES)
def test_periodic_rows_are_cyclic_shifts(degree):
    n_ctrl = N_PERIODIC
    rng = np.random.default_rng(70 + degree)
    u0 = rng.uniform(0, 1 / n_ctrl, M_PARAMS)
    base = np.asarray(periodic(n_ctrl, degree, u0))
    for j in range(1, n_ctrl + 1):
        shifted = np.asarray(periodic(n_ctrl, degree, u0 + j / n_ctrl))
        np.testing.assert_allclose(shifted, np.roll(base, j, axis=1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(base.sum(1), 1.0, atol=1e-13)


@pytest.mark.parametrize("n_ctrl", [4, N_PERIODIC])
def test_periodic_cubic_row_at_knot(n_ctrl):
    a = np.asarray(periodic(n_ctrl, 3, np.arange(n_ctrl + 1) / n_ctrl))
    pattern = np.zeros(n_ctrl)
    pattern[:3] = [1 / 6, 2 / 3, 1 / 6]
    for j, row in enumerate(a):
        shifts = [np.abs(row - np.roll(pattern, q)).max() for q in range(n_ctrl)]
        assert min(shifts) < 1e-14, (j, row)
    np.testing.assert_allclose(a[-1], a[0], atol=1e-14)  # u = 1 is u = 0 on a closed curve


@pytest.mark.parametrize("degree", [2, 3, 5])
def test_periodic_matches_scipy_periodic_spline(degree):
    """scipy `BSpline(..., extrapolate='periodic')` with wrapped coefficients."""
    n_ctrl = N_PERIODIC
    rng = np.random.default_rng(80 + degree)
    t = (np.arange(n_ctrl + 2 * degree + 1) - degree) / n_ctrl
    wrap = np.eye(n_ctrl)[np.arange(n_ctrl + degree) % n_ctrl]
    spline = BSpline(t, wrap, degree, extrapolate="periodic")
    x = rng.uniform(-0.5, 1.5, M_PARAMS)
    for nu in (0, 1, 2):
        ref = spline(x, nu=nu)
        got = np.asarray(periodic(n_ctrl, degree, x, nu=nu))
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref))


def test_periodic_knots_and_spline_direction():
    n, k = N_PERIODIC, 3
    np.testing.assert_allclose(periodic_knots(n, k), (np.arange(n + 2 * k + 1) - k) / n, atol=1e-15)
    x = np.linspace(0, 1, M_PARAMS)
    eager = periodic_blending_matrix(n, k, x)
    closed = SplineDirection.closed(n, k)
    assert (closed.periodic, closed.n_ctrl, closed.degree, closed.knots) == (True, n, k, None)
    np.testing.assert_allclose(closed.matrix(jnp.asarray(x)), eager, rtol=0, atol=1e-15)
    np.testing.assert_allclose(periodic(n, k, x), eager, rtol=0, atol=1e-15)
    knots = clamped_knots(N_CTRL, k)
    eager = blending_matrix(knots, k, x, 1)
    clamped = SplineDirection(knots, k)
    assert (clamped.periodic, clamped.n_ctrl) == (False, N_CTRL)
    np.testing.assert_allclose(clamped.matrices(jnp.asarray(x), (0, 1))[1], eager, rtol=0, atol=1e-13)
    np.testing.assert_allclose(blending(knots, k, x, nu=1), eager, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(SplineDirection.uniform(N_CTRL, k).knots, knots)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: SplineDirection([0, 0, 0.5, 1, 1], 3), "degree"),
        (lambda: SplineDirection([0, 0, 0.7, 0.5, 1, 1], 1), "knots: expected a non-decreasing"),
        (lambda: SplineDirection([0, 0, 0.5, 1, 2], 1), "knots: expected a clamped"),
        (lambda: SplineDirection([0, 0, 1], 1, periodic=True), "None for a periodic"),
        (lambda: SplineDirection(None, 3, n_ctrl=3, periodic=True), "degree"),
        (lambda: SplineDirection(None, 3), "knots: expected a knot vector"),
        (lambda: SplineDirection.closed(2.5, 1), "n_ctrl"),
    ],
)
def test_spline_direction_errors(make, match):
    with pytest.raises((ValueError, TypeError), match=match):
        make()


def test_spline_direction_checks_hold_under_jit():
    """A decreasing knot vector raises the same error eagerly and inside the caller's jit."""
    from tests.helpers import raises_both

    bad = jnp.asarray([0.0, 0.0, 0.7, 0.5, 1.0, 1.0])
    raises_both(lambda t: SplineDirection(t, 1).knots, bad, match="knots: expected a non-decreasing")
    outside = jnp.asarray([0.2, 1.5])
    raises_both(lambda x: blending_matrix(clamped_knots(5, 2), 2, x), outside, match="params: expected")


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_greville_closed_form(degree):
    rng = np.random.default_rng(90 + degree)
    knots = random_knots(rng, degree + 6, degree)
    ref = [np.mean(knots[i + 1 : i + degree + 1]) for i in range(degree + 6)]
    np.testing.assert_allclose(greville(knots, degree), ref, atol=1e-15)
    # Greville abscissae reproduce the identity: Σ_i g_i B_i(u) = u (linear precision).
    x = np.linspace(0, 1, 17)
    np.testing.assert_allclose(scipy_matrix(knots, degree, x) @ greville(knots, degree), x, atol=1e-13)


@pytest.mark.parametrize("periodic", [False, True])
def test_float32_in_float32_out(periodic):
    x = np.linspace(0, 1, M_PARAMS, dtype=np.float32)
    if periodic:
        a = periodic_blending_matrix(N_PERIODIC, 3, x)
        ref = periodic_reference(N_PERIODIC, 3, x)
    else:
        knots = np.asarray(clamped_knots(N_CTRL, 3), dtype=np.float32)
        a = blending_matrix(knots, 3, x)
        ref = scipy_matrix(knots, 3, x)
    assert a.dtype == jnp.float32
    np.testing.assert_allclose(a, ref, rtol=0, atol=1e-6)
    assert clamped_knots(6, 3, dtype=jnp.float32).dtype == jnp.float32
