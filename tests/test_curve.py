"""`BSplineCurve` / `CurveBlending` against scipy's `BSpline`, closed forms (the rational circle,
a parabola's curvature), `make_lsq_spline`, and the surface's own iso-lines."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import BSpline, make_lsq_spline

import bsjax
from bsjax.basis import BSplineCurve, BSplineSurface, CurveBlending, SplineDirection, clamped_knots
from tests.helpers import check_grad, raises_both, random_knots, random_surface

T = np.concatenate([np.linspace(0.0, 1.0, 41), np.random.default_rng(99).uniform(0, 1, 40)])


def _tol(ref, scale=1e-12):
    return scale * max(1.0, float(np.abs(ref).max()))


def _random_curve(rng, n=7, k=3, d=3, weights=False, periodic=False):
    ctrl = rng.normal(size=(n, d))
    w = rng.uniform(0.5, 2.0, n) if weights else None
    knots = None if periodic else random_knots(rng, n, k)
    return BSplineCurve(ctrl, knots, k, periodic=periodic, weights=w)


def _scipy(curve):
    """scipy's `BSpline` of the curve (homogeneous coordinates when rational); periodic curves
    as the unclamped uniform knots `(j − k)/n` over the wrapped control points."""
    n, k = curve.n_ctrl, curve.degree
    ctrl = np.asarray(curve.ctrl)
    if curve.weights is not None:
        w = np.asarray(curve.weights)
        ctrl = np.concatenate([ctrl * w[:, None], w[:, None]], axis=1)
    if curve.periodic:
        return BSpline((np.arange(n + 2 * k + 1) - k) / n, ctrl[np.arange(n + k) % n], k)
    return BSpline(np.asarray(curve.knots), ctrl, k)


def _reference(curve, t, nu):
    """Derivative `nu` from scipy; rational: the quotient rule written out (NURBS Book eq. 4.8)."""
    t = np.asarray(t) % 1.0 if curve.periodic else np.asarray(t)
    spline = _scipy(curve)
    if curve.weights is None:
        return spline(t, nu)
    h = [spline(t, j) for j in range(nu + 1)]
    a, w = [x[:, :-1] for x in h], [x[:, -1:] for x in h]
    c0 = a[0] / w[0]
    if nu == 0:
        return c0
    c1 = (a[1] - w[1] * c0) / w[0]
    if nu == 1:
        return c1
    return (a[2] - 2 * w[1] * c1 - w[2] * c0) / w[0]


# --- evaluation ------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("d", [2, 3])
def test_evaluate_matches_scipy(k, d):
    rng = np.random.default_rng(10 * k + d)
    curve = _random_curve(rng, n=k + 5, k=k, d=d)
    t = np.concatenate([T, np.asarray(curve.knots)])  # the knots themselves (span ends) too
    for nu in range(3):
        ref = _reference(curve, t, nu)
        got = np.asarray(curve.evaluate(t, nu))
        assert got.shape == (t.size, d)
        np.testing.assert_allclose(got, ref, rtol=0, atol=_tol(ref))


def test_repeated_interior_knots_match_scipy():
    rng = np.random.default_rng(5)
    knots = np.array([0, 0, 0, 0, 0.3, 0.3, 0.3, 0.6, 0.8, 0.8, 1, 1, 1, 1.0])
    curve = BSplineCurve(rng.normal(size=(10, 3)), knots, 3)
    for nu in range(3):
        ref = _reference(curve, T, nu)
        np.testing.assert_allclose(curve.evaluate(T, nu), ref, rtol=0, atol=_tol(ref))


@pytest.mark.parametrize("k, d", [(1, 2), (2, 3), (3, 2), (4, 3)])
def test_periodic_matches_scipy_with_wrapped_net(k, d):
    rng = np.random.default_rng(20 + k)
    curve = _random_curve(rng, n=k + 4, k=k, d=d, periodic=True)
    t = np.concatenate([T, [-0.25, 1.3, 2.0]])  # taken modulo 1
    for nu in range(min(3, k)):  # a degree-1 closed curve has no second derivative inside spans
        ref = _reference(curve, t, nu)
        np.testing.assert_allclose(curve.evaluate(t, nu), ref, rtol=0, atol=_tol(ref))
    # closed: the curve and its derivatives (k − 1 of them continuous) meet at the seam
    for nu in range(min(k, 3)):
        end = np.asarray(curve.evaluate(0.0, nu))
        np.testing.assert_allclose(curve.evaluate(1.0, nu), end, rtol=0, atol=_tol(end, 1e-11))


@pytest.mark.parametrize("d, periodic", [(2, False), (3, False), (3, True)])
def test_rational_derivatives_match_the_quotient_rule(d, periodic):
    rng = np.random.default_rng(30 + d + periodic)
    curve = _random_curve(rng, n=8, k=3, d=d, weights=True, periodic=periodic)
    for nu in range(3):
        ref = _reference(curve, T, nu)
        np.testing.assert_allclose(curve.evaluate(T, nu), ref, rtol=0, atol=_tol(ref))


def _circle(radius=1.0, clockwise=False):
    """The 9-point rational quadratic circle (The NURBS Book Ex. 7.2)."""
    p = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]], float)
    if clockwise:
        p[:, 1] *= -1
    w = np.array([1, 2**-0.5] * 4 + [1])
    knots = np.array([0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1])
    return BSplineCurve(radius * p, knots, 2, weights=w)


def test_rational_quadratic_circle_is_exact():
    circle = _circle()
    t = np.linspace(0, 1, 1001)
    p = np.asarray(circle.evaluate(t))
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 1.0, rtol=0, atol=1e-12)
    angle = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    assert np.all(np.diff(angle) > 0) and abs(angle[-1] - angle[0] - 2 * np.pi) < 1e-12
    d1, d2 = np.asarray(circle.evaluate(t, 1)), np.asarray(circle.evaluate(t, 2))
    np.testing.assert_allclose(np.sum(p * d1, axis=1), 0.0, atol=1e-11)  # tangent ⟂ radius
    speed2 = np.sum(d1 * d1, axis=1)  # |C|² = 1 twice differentiated: C·C'' = −|C'|²
    np.testing.assert_allclose(np.sum(p * d2, axis=1), -speed2, atol=1e-10 * speed2.max())
    # a 3-D circle (z = 1 plane) is a rational curve of the same weights
    lifted = BSplineCurve(np.c_[circle.ctrl, np.ones(9)], circle.knots, 2, weights=circle.weights)
    q = np.asarray(lifted.evaluate(t))
    np.testing.assert_allclose(np.linalg.norm(q[:, :2], axis=1), 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q[:, 2], 1.0, rtol=0, atol=1e-15)


# --- curvature -------------------------------------------------------------------------------
@pytest.mark.parametrize("radius", [0.5, 1.0, 3.0])
def test_circle_curvature_is_one_over_radius_with_the_travel_sign(radius):
    t = np.linspace(0, 1, 257)
    np.testing.assert_allclose(_circle(radius).curvature(t), 1 / radius, rtol=1e-12)
    np.testing.assert_allclose(_circle(radius, clockwise=True).curvature(t), -1 / radius, rtol=1e-12)
    lifted = _circle(radius)
    lifted = BSplineCurve(np.c_[lifted.ctrl, np.zeros(9)], lifted.knots, 2, weights=lifted.weights)
    np.testing.assert_allclose(lifted.curvature(t), 1 / radius, rtol=1e-12)  # unsigned in space


def test_parabola_turns_left():
    """`y = x²` travelled towards +x turns left: κ = 2 / (1 + 4x²)^{3/2} > 0; backwards κ < 0."""
    ctrl = np.array([[-1.0, 1.0], [0.0, -1.0], [1.0, 1.0]])  # Bézier: x = 2t − 1, y = x²
    t = np.linspace(0, 1, 33)
    x = 2 * t - 1
    kappa = 2 / (1 + 4 * x**2) ** 1.5
    np.testing.assert_allclose(BSplineCurve(ctrl, clamped_knots(3, 2), 2).curvature(t), kappa, rtol=1e-13)
    back = BSplineCurve(ctrl[::-1], clamped_knots(3, 2), 2).curvature(t)
    np.testing.assert_allclose(back, -kappa[::-1], rtol=1e-13)


@pytest.mark.parametrize("d", [2, 3])
def test_curvature_matches_scipy_derivatives(d):
    rng = np.random.default_rng(40 + d)
    curve = _random_curve(rng, n=9, k=4, d=d)
    d1, d2 = _reference(curve, T, 1), _reference(curve, T, 2)
    if d == 2:
        ref = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.linalg.norm(d1, axis=1) ** 3
    else:
        ref = np.linalg.norm(np.cross(d1, d2), axis=1) / np.linalg.norm(d1, axis=1) ** 3
    np.testing.assert_allclose(curve.curvature(T), ref, rtol=1e-9, atol=1e-12)


def test_curvature_is_zero_and_finite_where_the_speed_vanishes():
    """A line with a repeated control point has zero speed at that point: κ = 0, gradient finite."""
    ctrl = jnp.asarray([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    curve = BSplineCurve(ctrl, clamped_knots(3, 2), 2)
    assert float(curve.curvature(0.0)) == 0.0
    g = jax.grad(lambda c: curve.with_ctrl(c).curvature(0.0))(ctrl)
    assert bool(jnp.all(jnp.isfinite(g)))


# --- blending --------------------------------------------------------------------------------
@pytest.mark.parametrize("weights, periodic", [(False, False), (True, False), (False, True)])
def test_blending_agrees_with_evaluate_and_refit_recovers_the_net(weights, periodic):
    rng = np.random.default_rng(50 + 2 * weights + periodic)
    curve = _random_curve(rng, n=9, k=3, d=3, weights=weights, periodic=periodic)
    b = curve.blending(40)
    assert isinstance(b, CurveBlending) and b.a.shape == (3, 40, 9) and bool(b.full_rank)
    t = np.linspace(0, 1, 40)
    for nu in range(3):
        ref = _reference(curve, t, nu)
        np.testing.assert_allclose(b.derivative(curve.ctrl, nu), ref, rtol=0, atol=_tol(ref))
    np.testing.assert_allclose(b.points(curve.ctrl), _reference(curve, t, 0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.refit(b.points(curve.ctrl)), curve.ctrl, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(b.curve(curve.ctrl).weights, curve.weights)


def test_refit_is_scipy_least_squares_spline():
    """Noisy samples: the stored pseudo-inverse gives scipy `make_lsq_spline`'s coefficients."""
    rng = np.random.default_rng(60)
    curve = _random_curve(rng, n=8, k=3, d=2)
    params = np.sort(np.r_[0.0, rng.uniform(0, 1, 48), 1.0])
    points = np.asarray(curve.evaluate(params)) + 0.01 * rng.normal(size=(50, 2))
    fit = make_lsq_spline(params, points, np.asarray(curve.knots), k=3)
    got = curve.blending(params=params).refit(points)
    np.testing.assert_allclose(got, fit.c, rtol=0, atol=1e-10)


def test_refit_needs_enough_samples():
    curve = _random_curve(np.random.default_rng(0), n=8)
    few = curve.blending(5)
    assert few.refit_matrix is None
    with pytest.raises(ValueError, match="refit"):
        few.refit(np.zeros((5, 3)))
    seam = BSplineCurve(np.random.default_rng(1).normal(size=(6, 2)), None, 3, periodic=True)
    doubled = seam.blending(params=np.array([0.0, 0.1, 0.2, 0.3, 0.4, 1.0, 2.0]))  # 5 distinct
    assert not bool(doubled.full_rank)
    with pytest.raises(ValueError, match="rank"):
        doubled.refit(np.zeros((7, 2)))


# --- iso-curves --------------------------------------------------------------------------------
@pytest.mark.parametrize("weights", [False, True])
@pytest.mark.parametrize("direction", ["u", "v"])
def test_iso_curve_is_the_surface_iso_line(weights, direction):
    rng = np.random.default_rng(70 + weights)
    surface = random_surface(rng, 6, 5, 3, 2, weights=weights)
    t = np.linspace(0, 1, 37)
    for value in (0.0, 0.37, 1.0):
        curve = surface.iso_curve(direction, value)
        assert curve.degree == (surface.degree_v if direction == "u" else surface.degree_u)
        assert (curve.weights is None) == (not weights)
        fixed = np.full_like(t, value)
        u, v = (fixed, t) if direction == "u" else (t, fixed)
        for nu in range(3):
            ref = np.asarray(surface.evaluate(u, v, *((0, nu) if direction == "u" else (nu, 0))))
            np.testing.assert_allclose(curve.evaluate(t, nu), ref, rtol=0, atol=_tol(ref))


def test_iso_curve_of_a_closed_direction_is_closed():
    rng = np.random.default_rng(75)
    surface = BSplineSurface(rng.normal(size=(6, 7, 3)), random_knots(rng, 6, 3), None, 3, 2, periodic_v=True)
    curve = surface.iso_curve("u", 0.6)
    assert curve.periodic and curve.knots is None
    t = np.linspace(0, 1, 29)
    np.testing.assert_allclose(curve.evaluate(t), surface.evaluate(np.full_like(t, 0.6), t), atol=1e-12)
    raises_both(lambda x: surface.iso_curve("u", x).ctrl, jnp.asarray(1.5), match="value")


# --- jit, vmap, grad -------------------------------------------------------------------------
def test_jit_vmap_and_grad():
    rng = np.random.default_rng(80)
    curve = _random_curve(rng, n=7, k=3, d=3, weights=True)
    t = jnp.asarray(T[:20])
    jitted = jax.jit(lambda c, x: c.evaluate(x, 1))(curve, t)
    np.testing.assert_allclose(jitted, curve.evaluate(t, 1), rtol=0, atol=1e-14)
    batch = jax.vmap(lambda c: curve.with_ctrl(c).evaluate(t))(jnp.stack([curve.ctrl, 2 * curve.ctrl]))
    np.testing.assert_allclose(batch[1], 2 * np.asarray(curve.evaluate(t)), rtol=1e-13)
    rows = jax.vmap(curve.evaluate)(t.reshape(4, 5))
    np.testing.assert_allclose(rows.reshape(20, 3), curve.evaluate(t), rtol=0, atol=1e-15)

    def loss_ctrl(c):
        return jnp.sum(curve.with_ctrl(c).evaluate(t) ** 2) + jnp.sum(curve.with_ctrl(c).curvature(t))

    check_grad(loss_ctrl, curve.ctrl)
    check_grad(
        lambda w: jnp.sum(BSplineCurve.from_direction(curve.ctrl, curve.direction, w).evaluate(t, 2)),
        curve.weights,
    )
    # d/dt C(t) is the first derivative the curve reports (inside the domain; ends: see below)
    g = jax.grad(lambda x: jnp.sum(curve.evaluate(x)[..., 0]))(t[1:])
    np.testing.assert_allclose(g, curve.evaluate(t[1:], 1)[:, 0], rtol=1e-12, atol=1e-12)
    check_grad(lambda x: jnp.sum(curve.curvature(x)), t[1:-1])
    # refit inside a caller's jit, differentiable in the points
    b = curve.blending(30)
    check_grad(lambda p: jnp.sum(b.refit(p) ** 2), b.points(curve.ctrl))


def test_grad_in_t_at_the_domain_ends():
    curve = _random_curve(np.random.default_rng(81), n=7, k=3, d=2)
    ends = jnp.asarray([0.0, 1.0])
    g = jax.grad(lambda x: jnp.sum(curve.evaluate(x)[..., 0]))(ends)
    np.testing.assert_allclose(g, curve.evaluate(ends, 1)[:, 0], rtol=1e-12)


def test_from_direction_with_ctrl_and_exports():
    direction = SplineDirection.uniform(6, 3)
    curve = BSplineCurve.from_direction(np.zeros((6, 2)), direction)
    assert (curve.n_ctrl, curve.degree, curve.dim, curve.periodic) == (6, 3, 2, False)
    assert bsjax.BSplineCurve is BSplineCurve and bsjax.CurveBlending is CurveBlending
    moved = curve.with_ctrl(np.ones((6, 2)))
    np.testing.assert_allclose(moved.evaluate(np.linspace(0, 1, 5)), 1.0, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="ctrl"):
        curve.with_ctrl(np.ones((5, 2)))


# --- bad input -------------------------------------------------------------------------------
KNOTS = clamped_knots(5, 3)
CTRL = np.random.default_rng(90).normal(size=(5, 3))


@pytest.mark.parametrize(
    "ctrl, match",
    [
        (np.zeros((5, 4)), "ctrl: expected control points of dimension d = 2 or 3"),
        (np.zeros((5,)), "ctrl: expected an array with 2 dimension"),
        (np.zeros((4, 3)), "knots: expected length"),
        (np.zeros((5, 1)), "ctrl: expected control points of dimension"),
    ],
)
def test_bad_ctrl_shape_names_ctrl(ctrl, match):
    raises_both(lambda c: BSplineCurve(c, KNOTS, 3).ctrl, ctrl, match=match)


@pytest.mark.parametrize(
    "knots, match",
    [
        (np.array([0, 0, 0, 0, 0.7, 0.5, 1, 1, 1.0]), "knots: expected a non-decreasing"),
        (np.array([0, 0, 0, 0.1, 0.5, 1, 1, 1, 1.0]), "knots: expected a clamped knot vector"),
        (np.array([0, 0, 0, 0, 0.5, 1, 1, 1, 2.0]), "knots: expected a clamped knot vector"),
        (np.array([0, 0, 0, 0, np.nan, 1, 1, 1, 1.0]), "knots: expected finite"),
    ],
)
def test_bad_knots_name_knots(knots, match):
    raises_both(lambda t: BSplineCurve(CTRL, t, 3).direction.knots, knots, match=match)


def test_bad_degree_periodic_and_weights():
    with pytest.raises(ValueError, match="degree: expected a degree smaller than the 5 control points"):
        BSplineCurve(CTRL, np.r_[np.zeros(6), np.ones(5)], 5)
    with pytest.raises(ValueError, match="degree: expected a degree smaller"):
        BSplineCurve(CTRL, None, 5, periodic=True)
    with pytest.raises(TypeError, match="degree: expected an int"):
        BSplineCurve(CTRL, KNOTS, 3.0)
    with pytest.raises(ValueError, match="knots: expected None for a periodic"):
        BSplineCurve(CTRL, KNOTS, 3, periodic=True)
    with pytest.raises(ValueError, match="weights: expected shape"):
        BSplineCurve(CTRL, KNOTS, 3, weights=np.ones(4))
    raises_both(
        lambda w: BSplineCurve(CTRL, KNOTS, 3, weights=w).weights,
        np.array([1.0, 1.0, 0.0, 1.0, 1.0]),
        match="weights: expected finite values > 0",
    )
    raises_both(
        lambda c: BSplineCurve(c, KNOTS, 3).ctrl,
        np.where(CTRL > 1, np.inf, CTRL),
        match="ctrl: expected finite",
    )


def test_bad_parameters_and_orders():
    curve = BSplineCurve(CTRL, KNOTS, 3)
    raises_both(
        lambda t: curve.evaluate(t), np.array([0.2, 1.5]), match=r"t: expected values in \[0.0, 1.0\]"
    )
    raises_both(lambda t: curve.evaluate(t), np.array([-1e-9]), match="t: expected values in")
    raises_both(lambda t: curve.curvature(t), np.array([np.nan]), match="t: expected values in")
    raises_both(lambda t: curve.blending(params=t).a, np.array([0.0, 0.5, 2.0]), match="params: expected")
    closed = BSplineCurve(CTRL, None, 3, periodic=True)
    raises_both(lambda t: closed.evaluate(t), np.array([0.2, np.inf]), match="t: expected finite")
    for nu in (3, -1):
        with pytest.raises(ValueError, match="nu: expected a derivative order in 0..2"):
            curve.evaluate(0.5, nu)
    for nu in (1.0, True):  # not an int: a TypeError
        with pytest.raises(TypeError, match="nu: expected an int"):
            curve.evaluate(0.5, nu)
    b = curve.blending(20)
    with pytest.raises(ValueError, match="nu: expected a derivative order"):
        b.derivative(CTRL, 3)
    raises_both(lambda c: b.points(c), np.zeros((6, 3)), match=r"ctrl: expected shape \(5, d\)")
    raises_both(lambda p: b.refit(p), np.full((20, 3), np.nan), match="points: expected finite")
    raises_both(lambda p: b.refit(p), np.zeros((19, 3)), match=r"points: expected shape \(20, d\)")
    with pytest.raises(TypeError, match="t: expected real"):
        curve.evaluate(np.array([0.5 + 0j]))
    with pytest.raises(ValueError, match="m: expected an int >= 2"):
        curve.blending(1)


def test_iso_curve_argument_errors():
    surface = random_surface(np.random.default_rng(95), 5, 4, 3, 2)
    with pytest.raises(ValueError, match="direction: expected 'u' or 'v'"):
        surface.iso_curve("w", 0.5)
    with pytest.raises(ValueError, match="value: expected an array with 0 dimension"):
        surface.iso_curve("u", np.array([0.5, 0.6]))
    raises_both(
        lambda x: surface.iso_curve("v", x).ctrl, jnp.asarray(-0.1), match=r"value: expected values in \[0"
    )


def test_float32_curve_stays_float32():
    rng = np.random.default_rng(96)
    c64 = _random_curve(rng, n=7, k=3, d=2, weights=True)
    c32 = BSplineCurve(
        np.asarray(c64.ctrl, np.float32),
        np.asarray(c64.knots, np.float32),
        3,
        weights=np.float32(c64.weights),
    )
    t = np.linspace(0, 1, 25, dtype=np.float32)
    for nu in range(3):
        got = c32.evaluate(t, nu)
        ref = np.asarray(c64.evaluate(t.astype(np.float64), nu))
        assert got.dtype == jnp.float32
        np.testing.assert_allclose(got, ref, rtol=0, atol=_tol(ref, 1e-4))
    assert c32.curvature(t).dtype == jnp.float32 and c32.blending(9).a.dtype == jnp.float32
