"""`bsjax.construct` against closed forms (Coons on z = xy, surfaces of revolution, cones, tori),
scipy's `BSpline` (compatible curves unchanged) and scipy's `Rotation` (revolved end section);
jit / vmap / grad and bad input."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import BSpline
from scipy.spatial.transform import Rotation

from bsjax import construct
from bsjax.basis import BSplineCurve, greville
from tests.helpers import check_grad, raises_both, random_knots

T = np.concatenate([np.linspace(0.0, 1.0, 21), np.random.default_rng(7).uniform(0, 1, 20)])
CIRCLE_SQUARE = np.array(
    [[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]], float
)
CIRCLE_WEIGHTS = np.array([1, 2**-0.5] * 4 + [1])
CIRCLE_KNOTS = np.array([0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1])


def _curve(rng, n=6, k=3, d=3, weights=False):
    w = rng.uniform(0.5, 2.0, n) if weights else None
    return BSplineCurve(rng.normal(size=(n, d)), random_knots(rng, n, k), k, weights=w)


def _scipy_points(curve, t):
    """The curve at `t` by scipy's `BSpline` (homogeneous coordinates when rational)."""
    ctrl = np.asarray(curve.ctrl)
    if curve.weights is None:
        return BSpline(np.asarray(curve.knots), ctrl, curve.degree)(t)
    w = np.asarray(curve.weights)
    h = BSpline(np.asarray(curve.knots), np.concatenate([ctrl * w[:, None], w[:, None]], 1), curve.degree)(t)
    return h[:, :-1] / h[:, -1:]


def _circle(radius, height, center=(0.0, 0.0)):
    """The exact rational circle of `radius` at z = `height` about (center, z)."""
    xy = CIRCLE_SQUARE * radius + np.asarray(center)
    ctrl = np.concatenate([xy, np.full((9, 1), height)], axis=1)
    return BSplineCurve(ctrl, CIRCLE_KNOTS, 2, weights=CIRCLE_WEIGHTS)


def _grid(surface, m=9, n=7):
    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, n), indexing="ij")
    return u, v, np.asarray(surface.evaluate(u, v))


# --- compatible ----------------------------------------------------------------------------------
def test_compatible_leaves_each_curve_unchanged():
    rng, d = np.random.default_rng(2), 2
    curves = [_curve(rng, 5, 1, d), _curve(rng, 7, 3, d, weights=True), _curve(rng, 6, 2, d)]
    out = construct.compatible(curves)
    assert [c.degree for c in out] == [3, 3, 3]
    for c in out[1:]:
        np.testing.assert_array_equal(np.asarray(c.knots), np.asarray(out[0].knots))
    for old, new in zip(curves, out):
        assert (new.weights is None) == (old.weights is None)
        np.testing.assert_allclose(_scipy_points(new, T), _scipy_points(old, T), atol=1e-12, rtol=0)
    # every knot of every input survives with at least its (elevated) multiplicity
    knots = np.asarray(out[0].knots)
    for old in curves:
        for value in np.unique(np.asarray(old.knots)):
            own = np.count_nonzero(np.asarray(old.knots) == value) + 3 - old.degree
            assert np.count_nonzero(knots == value) >= min(own, 4)


def test_compatible_under_jit_and_grad():
    rng = np.random.default_rng(1)
    a, b = _curve(rng, 5, 2), _curve(rng, 6, 3)
    ref = construct.compatible([a, b])
    # knots closed over (concrete): control points traced
    jitted = jax.jit(lambda p: construct.compatible([a.with_ctrl(p), b])[0].ctrl)(a.ctrl)
    np.testing.assert_allclose(jitted, ref[0].ctrl, atol=1e-13)
    check_grad(
        lambda p: jnp.sum(construct.compatible([a.with_ctrl(p), b])[0].evaluate(T) ** 2), a.ctrl, n_dirs=2
    )
    # curves as jit arguments (traced knots): fine when already compatible, refused otherwise
    same = jax.jit(lambda c0, c1: construct.compatible([c0, c1])[1].ctrl)(ref[0], ref[1])
    np.testing.assert_allclose(same, ref[1].ctrl, atol=1e-13)
    with pytest.raises(ValueError, match="outside jit"):
        jax.jit(lambda c0, c1: construct.compatible([c0, c1])[1].ctrl)(a, b)
    other = BSplineCurve(ref[1].ctrl, np.sort(np.asarray(ref[1].knots)) ** 1.5, 3)
    with pytest.raises(Exception, match="knot vector of the first curve"):
        jax.block_until_ready(jax.jit(lambda c0, c1: construct.compatible([c0, c1])[1].ctrl)(ref[0], other))


def test_compatible_periodic_curves_and_bad_input():
    rng = np.random.default_rng(2)
    closed = [BSplineCurve(rng.normal(size=(6, 3)), None, 3, periodic=True) for _ in range(2)]
    out = construct.compatible(closed)
    assert out[0].periodic and np.allclose(out[1].ctrl, closed[1].ctrl)
    # closed sections give a surface closed in u that passes through them
    surface = construct.loft([closed[0], closed[1].with_ctrl(np.asarray(closed[1].ctrl) + [0.0, 0.0, 3.0])])
    assert surface.periodic_u and surface.degree_v == 1
    np.testing.assert_allclose(surface.evaluate(T, np.zeros_like(T)), closed[0].evaluate(T), atol=1e-12)
    with pytest.raises(ValueError, match=r"curves\[1\]: expected periodic curves"):
        construct.compatible([closed[0], _curve(rng)])
    with pytest.raises(ValueError, match=r"curves\[1\]: expected dimension 3"):
        construct.compatible([_curve(rng, d=3), _curve(rng, d=2)])
    with pytest.raises(TypeError, match=r"curves\[0\]: expected a BSplineCurve"):
        construct.compatible([np.zeros((4, 3))])  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="curves: expected at least 1"):
        construct.compatible([])


# --- ruled and extrude -----------------------------------------------------------------------------
@pytest.mark.parametrize("weights", [False, True])
def test_ruled_samples_lie_on_the_segments(weights):
    rng = np.random.default_rng(3)
    c0, c1 = _curve(rng, 5, 2, weights=weights), _curve(rng, 7, 3, d=2, weights=weights)
    surface = construct.ruled(c0, c1)
    assert surface.degree_v == 1 and surface.shape[1] == 2
    u, v, s = _grid(surface)
    p0 = _scipy_points(c0, u[:, 0])[:, None]
    p1 = np.concatenate([_scipy_points(c1, u[:, 0]), np.zeros((u.shape[0], 1))], 1)[:, None]
    np.testing.assert_allclose(s[:, 0], p0[:, 0], atol=1e-12)
    np.testing.assert_allclose(s[:, -1], p1[:, 0], atol=1e-12)
    # on the segment: s = p0 + λ (p1 − p0) with λ in [0, 1] (λ = v when polynomial)
    lam = np.sum((s - p0) * (p1 - p0), -1) / np.sum((p1 - p0) ** 2, -1)
    np.testing.assert_allclose(s, p0 + lam[..., None] * (p1 - p0), atol=1e-12)
    assert lam.min() > -1e-12 and lam.max() < 1 + 1e-12
    if not weights:
        np.testing.assert_allclose(lam, v, atol=1e-12)


@pytest.mark.parametrize("weights", [False, True])
def test_extrude_is_curve_plus_v_vector(weights):
    rng = np.random.default_rng(4)
    curve = _curve(rng, 6, 3, weights=weights)
    vector = np.array([0.3, -1.0, 2.0])
    u, v, s = _grid(construct.extrude(curve, vector))
    expected = _scipy_points(curve, u.ravel()).reshape(u.shape + (3,)) + v[..., None] * vector
    np.testing.assert_allclose(s, expected, atol=1e-12)


def test_extrude_planar_curve_at_z0_and_grad():
    rng = np.random.default_rng(5)
    curve = _curve(rng, 5, 2, d=2)
    u, v, s = _grid(construct.extrude(curve, [0.0, 0.0, 1.5]))
    np.testing.assert_allclose(s[..., 2], 1.5 * v, atol=1e-14)
    np.testing.assert_allclose(
        s[..., :2], _scipy_points(curve, u.ravel()).reshape(u.shape + (2,)), atol=1e-12
    )
    check_grad(
        lambda w: jnp.sum(construct.extrude(curve, w).evaluate(u, v) ** 3),
        jnp.array([0.1, 0.2, 1.0]),
        n_dirs=2,
    )


# --- revolve ---------------------------------------------------------------------------------------
def _axis_frame(point, direction, x):
    """Distance from the axis and height along it of points `x (..., 3)`."""
    a = direction / np.linalg.norm(direction)
    rel = x - point
    height = rel @ a
    return np.linalg.norm(rel - height[..., None] * a, axis=-1), height


@pytest.mark.parametrize("weights", [False, True])
def test_revolve_keeps_distance_and_height_and_closes(weights):
    rng = np.random.default_rng(6)
    profile = _curve(rng, 6, 3, weights=weights)
    point, direction = np.array([0.5, -0.2, 0.1]), np.array([1.0, 2.0, -0.5])
    surface = construct.revolve(profile, point, direction)
    assert surface.shape == (6, 9) and surface.degree_v == 2
    np.testing.assert_allclose(np.asarray(surface.knots_v), CIRCLE_KNOTS)
    u, _, s = _grid(surface)
    radius, height = _axis_frame(point, direction, s)
    ref_radius, ref_height = _axis_frame(point, direction, _scipy_points(profile, u[:, 0]))
    np.testing.assert_allclose(radius, np.broadcast_to(ref_radius[:, None], radius.shape), atol=1e-12)
    np.testing.assert_allclose(height, np.broadcast_to(ref_height[:, None], height.shape), atol=1e-12)
    np.testing.assert_allclose(s[:, 0], s[:, -1], atol=1e-12)  # closed
    np.testing.assert_allclose(s[:, 0], _scipy_points(profile, u[:, 0]), atol=1e-12)


@pytest.mark.parametrize(("angle", "n_v"), [(math.pi / 3, 3), (math.pi, 5), (4.0, 7)])
def test_revolve_partial_angle_uses_fewest_arcs_and_ends_rotated(angle, n_v):
    rng = np.random.default_rng(8)
    profile = _curve(rng, 5, 2)
    point, direction = np.array([0.0, 1.0, 0.0]), np.array([0.2, 0.1, 1.0])
    surface = construct.revolve(profile, point, direction, angle)
    assert surface.shape == (5, n_v)
    t = np.linspace(0, 1, 13)
    rotation = Rotation.from_rotvec(angle * direction / np.linalg.norm(direction))
    expected = rotation.apply(_scipy_points(profile, t) - point) + point
    np.testing.assert_allclose(surface.evaluate(t, np.ones_like(t)), expected, atol=1e-12)
    half = Rotation.from_rotvec(0.5 * angle * direction / np.linalg.norm(direction))
    mid = half.apply(_scipy_points(profile, t) - point) + point
    np.testing.assert_allclose(surface.evaluate(t, np.full_like(t, 0.5)), mid, atol=1e-12)


def test_revolve_planar_profile_circle_is_a_torus():
    big, small = 2.0, 0.5
    tube = BSplineCurve(CIRCLE_SQUARE * small + [big, 0.0], CIRCLE_KNOTS, 2, weights=CIRCLE_WEIGHTS)
    point, direction = np.array([1.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])
    surface = construct.revolve(tube, point, direction)
    _, _, s = _grid(surface)
    radius, height = _axis_frame(point, direction, s)
    np.testing.assert_allclose(np.hypot(radius - big, height), small, atol=1e-12)
    # the planar profile's x axis is the coordinate axis least aligned with the axis (here x)
    np.testing.assert_allclose(s[0, 0], point + [big + small, 0.0, 0.0], atol=1e-14)


def test_revolve_jit_vmap_grad():
    rng = np.random.default_rng(9)
    profile = _curve(rng, 5, 3)
    u, v = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 6), indexing="ij")

    def f(ctrl, angle=2 * math.pi):
        return construct.revolve(profile.with_ctrl(ctrl), [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], angle).evaluate(
            u, v
        )

    ref = f(profile.ctrl)
    np.testing.assert_allclose(jax.jit(f)(profile.ctrl), ref, atol=1e-13)
    batch = profile.ctrl[None] + 0.1 * jnp.asarray(rng.normal(size=(3, 5, 3)))
    np.testing.assert_allclose(jax.vmap(f)(batch)[1], f(batch[1]), atol=1e-13)
    check_grad(lambda p: jnp.sum(jnp.sin(f(p))), profile.ctrl, n_dirs=2)
    # a traced angle uses 4 arcs (a concrete 2.5 rad uses 2): the same surface, another v-parametrisation
    traced = jax.jit(lambda a: construct.revolve(profile, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], a))(2.5)
    concrete = construct.revolve(profile, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], 2.5)
    assert (traced.shape[1], concrete.shape[1]) == (9, 5)
    t = np.linspace(0, 1, 9)
    np.testing.assert_allclose(
        traced.evaluate(t, np.ones_like(t)), concrete.evaluate(t, np.ones_like(t)), atol=1e-12
    )
    check_grad(jax.jit(lambda a: jnp.sum(jnp.sin(f(profile.ctrl, a)))), jnp.asarray(2.5), n_dirs=2)
    axis_grad = jax.grad(
        lambda a: jnp.sum(construct.revolve(profile, [0.0, 0.0, 0.0], a).evaluate(u, v) ** 2)
    )(jnp.array([0.0, 1.0, 1.0]))
    assert bool(jnp.all(jnp.isfinite(axis_grad)))


def test_revolve_bad_input():
    rng = np.random.default_rng(10)
    profile = _curve(rng, 5, 2)
    o = np.zeros(3)
    raises_both(
        lambda a: construct.revolve(profile, o, a), np.zeros(3), match="axis_dir: expected a finite nonzero"
    )
    raises_both(lambda a: construct.revolve(profile, o, a), np.array([0.0, np.nan, 1.0]), match="axis_dir")
    raises_both(
        lambda p: construct.revolve(profile, p, [0.0, 0, 1]), np.array([np.inf, 0, 0]), match="axis_point"
    )
    for bad in (0.0, -1.0, 7.0, np.nan):
        raises_both(
            lambda ang: construct.revolve(profile, o, [0.0, 0, 1], ang),
            np.float64(bad),
            match=r"angle: expected",
        )
    with pytest.raises(ValueError, match="axis_dir: expected trailing dimension 3"):
        construct.revolve(profile, o, [0.0, 1.0])
    with pytest.raises(TypeError, match="profile: expected a BSplineCurve"):
        construct.revolve(np.zeros((4, 3)), o, [0.0, 0, 1])  # pyright: ignore[reportArgumentType]


# --- coons -----------------------------------------------------------------------------------------
def _linear_curve(rng, n, k, start, end):
    """A degree-k curve with random knots tracing the segment start → end at uniform speed
    (control points at the Greville abscissae: linear precision)."""
    knots = random_knots(rng, n, k)
    s = greville(knots, k)[:, None]
    return BSplineCurve((1 - s) * np.asarray(start) + s * np.asarray(end), knots, k)


def test_coons_reproduces_hyperbolic_paraboloid():
    rng = np.random.default_rng(11)
    bottom = _linear_curve(rng, 5, 3, [0, 0, 0], [1, 0, 0])
    top = _linear_curve(rng, 4, 2, [0, 1, 0], [1, 1, 1])
    left = _linear_curve(rng, 6, 3, [0, 0, 0], [0, 1, 0])
    right = _linear_curve(rng, 3, 1, [1, 0, 0], [1, 1, 1])
    surface = construct.coons(bottom, top, left, right)
    u, v = rng.uniform(0, 1, (2, 50))
    expected = np.stack([u, v, u * v], -1)
    np.testing.assert_allclose(surface.evaluate(u, v), expected, atol=1e-12)


def _boundaries(rng):
    """Four random curves (different degrees, knots) meeting at the corners of a curved patch."""
    corners = {
        "00": rng.normal(size=3),
        "10": rng.normal(size=3),
        "01": rng.normal(size=3),
        "11": rng.normal(size=3),
    }

    def curve(n, k, a, b):
        ctrl = rng.normal(size=(n, 3))
        ctrl[0], ctrl[-1] = corners[a], corners[b]
        return BSplineCurve(ctrl, random_knots(rng, n, k), k)

    return curve(6, 3, "00", "10"), curve(4, 2, "01", "11"), curve(5, 3, "00", "01"), curve(5, 2, "10", "11")


def test_coons_interpolates_four_random_boundaries():
    rng = np.random.default_rng(12)
    bottom, top, left, right = _boundaries(rng)
    surface = construct.coons(bottom, top, left, right)
    t, zero, one = T, np.zeros_like(T), np.ones_like(T)
    np.testing.assert_allclose(surface.evaluate(t, zero), _scipy_points(bottom, t), atol=1e-12)
    np.testing.assert_allclose(surface.evaluate(t, one), _scipy_points(top, t), atol=1e-12)
    np.testing.assert_allclose(surface.evaluate(zero, t), _scipy_points(left, t), atol=1e-12)
    np.testing.assert_allclose(surface.evaluate(one, t), _scipy_points(right, t), atol=1e-12)
    # the Coons formula itself at interior points
    u, v = rng.uniform(0, 1, (2, 30))
    b, tp = _scipy_points(bottom, u), _scipy_points(top, u)
    lf, rt = _scipy_points(left, v), _scipy_points(right, v)
    p00, p10, p01, p11 = (np.asarray(c.ctrl)[i] for c, i in ((bottom, 0), (bottom, -1), (top, 0), (top, -1)))
    u_, v_ = u[:, None], v[:, None]
    bilinear = (1 - u_) * (1 - v_) * p00 + u_ * (1 - v_) * p10 + (1 - u_) * v_ * p01 + u_ * v_ * p11
    expected = (1 - v_) * b + v_ * tp + (1 - u_) * lf + u_ * rt - bilinear
    np.testing.assert_allclose(surface.evaluate(u, v), expected, atol=1e-12)


def test_coons_jit_vmap_grad():
    rng = np.random.default_rng(13)
    bottom, top, left, right = _boundaries(rng)
    u, v = rng.uniform(0, 1, (2, 20))

    def f(interior):  # move the top curve's interior control points only (corners stay matched)
        ctrl = jnp.asarray(top.ctrl).at[1:-1].set(interior)
        return construct.coons(bottom, top.with_ctrl(ctrl), left, right).evaluate(u, v)

    x = jnp.asarray(top.ctrl)[1:-1]
    np.testing.assert_allclose(jax.jit(f)(x), f(x), atol=1e-13)
    batch = x[None] + jnp.asarray(rng.normal(size=(3, 2, 3)))
    np.testing.assert_allclose(jax.vmap(f)(batch)[2], f(batch[2]), atol=1e-13)
    check_grad(lambda p: jnp.sum(jnp.cos(f(p))), x, n_dirs=2)


def test_coons_bad_input():
    rng = np.random.default_rng(14)
    bottom, top, left, right = _boundaries(rng)
    moved = np.asarray(top.ctrl).copy()
    moved[-1] += 1e-3
    raises_both(
        lambda p: construct.coons(bottom, top.with_ctrl(p), left, right), moved, match="coons corners"
    )
    construct.coons(bottom, top.with_ctrl(moved), left, right, tol=1.0)  # within a loose tolerance
    weighted = BSplineCurve(bottom.ctrl, bottom.knots, bottom.degree, weights=np.ones(bottom.n_ctrl))
    with pytest.raises(ValueError, match="c_bottom: expected a polynomial curve"):
        construct.coons(weighted, top, left, right)
    with pytest.raises(TypeError, match="c_left: expected a BSplineCurve"):
        construct.coons(bottom, top, None, right)  # pyright: ignore[reportArgumentType]


# --- loft ------------------------------------------------------------------------------------------
def _chord_params(curves):
    """Averaged chord-length parameters of compatible sections (The NURBS Book eq. 10.8), numpy."""
    pts = np.stack([np.asarray(c.ctrl) for c in curves], 1)  # (n, K, d)
    steps = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    cum = np.concatenate([np.zeros((pts.shape[0], 1)), np.cumsum(steps, 1)], 1)
    return (cum / cum[:, -1:]).mean(0)


@pytest.mark.parametrize(("degree", "ruled"), [(3, False), (3, True)])
def test_loft_interpolates_sections_at_their_parameters(degree, ruled):
    rng = np.random.default_rng(15)
    sections = [_curve(rng, 5 + i % 2, 2 + i % 2) for i in range(5)]
    for i, s in enumerate(sections):  # stack the sections along z
        sections[i] = s.with_ctrl(np.asarray(s.ctrl) + [0.0, 0.0, 2.0 * i])
    surface = construct.loft(sections, degree=degree, ruled=ruled)
    q = 1 if ruled else degree
    assert surface.degree_v == q and surface.shape[1] == 5
    params = _chord_params(construct.compatible(sections))
    knots = np.concatenate(
        [np.zeros(q + 1), [params[j : j + q].mean() for j in range(1, 5 - q)], np.ones(q + 1)]
    )
    np.testing.assert_allclose(np.asarray(surface.knots_v), knots, atol=1e-14)
    for section, vk in zip(sections, params):
        np.testing.assert_allclose(
            surface.evaluate(T, np.full_like(T, vk)), _scipy_points(section, T), atol=1e-11
        )


@pytest.mark.parametrize("ruled", [True, False])
def test_loft_of_coaxial_circles_lies_on_the_cone(ruled):
    heights = np.array([0.0, 1.0, 3.0])
    circles = [_circle(1.0 + 0.5 * z, z) for z in heights]
    surface = construct.loft(circles, ruled=ruled)
    assert surface.weights is not None and surface.degree_v == (1 if ruled else 2)
    _, _, s = _grid(surface)
    np.testing.assert_allclose(np.hypot(s[..., 0], s[..., 1]), 1.0 + 0.5 * s[..., 2], atol=1e-12)
    assert s[..., 2].min() > -1e-12 and s[..., 2].max() < 3 + 1e-12


def test_loft_grad_and_bad_input():
    rng = np.random.default_rng(16)
    sections = [_circle(1.0 + 0.2 * i, float(i), center=rng.normal(size=2) * 0.1) for i in range(3)]
    u, v = rng.uniform(0, 1, (2, 10))

    def f(ctrl):
        return construct.loft([sections[0], sections[1].with_ctrl(ctrl), sections[2]]).evaluate(u, v)

    np.testing.assert_allclose(jax.jit(f)(sections[1].ctrl), f(sections[1].ctrl), atol=1e-13)
    check_grad(lambda p: jnp.sum(jnp.sin(f(p))), sections[1].ctrl, n_dirs=2)
    same = np.asarray(sections[0].ctrl)
    raises_both(f, same, match="curves: expected distinct consecutive sections")
    with pytest.raises(ValueError, match="curves: expected at least 2"):
        construct.loft(sections[:1])
    with pytest.raises(ValueError, match="degree: expected an int >= 1"):
        construct.loft(sections, degree=0)
    with pytest.raises(TypeError, match="curves: expected a sequence"):
        construct.loft(sections[0])  # pyright: ignore[reportArgumentType]


# --- ruled jit / vmap / grad / bad input --------------------------------------------------------------
def test_ruled_jit_vmap_grad_and_bad_input():
    rng = np.random.default_rng(17)
    c0, c1 = _curve(rng, 5, 2), _curve(rng, 6, 3, weights=True)
    u, v = rng.uniform(0, 1, (2, 15))

    def f(ctrl):
        return construct.ruled(c0.with_ctrl(ctrl), c1).evaluate(u, v)

    np.testing.assert_allclose(jax.jit(f)(c0.ctrl), f(c0.ctrl), atol=1e-13)
    batch = c0.ctrl[None] + 0.1 * jnp.asarray(rng.normal(size=(4, 5, 3)))
    np.testing.assert_allclose(jax.vmap(f)(batch)[3], f(batch[3]), atol=1e-13)
    check_grad(lambda p: jnp.sum(jnp.sin(f(p))), c0.ctrl, n_dirs=2)
    with pytest.raises(TypeError, match="c1: expected a BSplineCurve"):
        construct.ruled(c0, np.zeros((3, 3)))  # pyright: ignore[reportArgumentType]
    closed = BSplineCurve(rng.normal(size=(5, 3)), None, 2, periodic=True)
    with pytest.raises(ValueError, match="c1: expected periodic curves"):
        construct.ruled(closed, c0)


def test_extrude_bad_input():
    rng = np.random.default_rng(18)
    curve = _curve(rng, 4, 2)
    raises_both(lambda w: construct.extrude(curve, w), np.zeros(3), match="vector: expected a finite nonzero")
    raises_both(lambda w: construct.extrude(curve, w), np.array([1.0, np.nan, 0]), match="vector")
    with pytest.raises(ValueError, match="vector: expected an array with 1"):
        construct.extrude(curve, np.zeros((2, 3)))
