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
from bsjax.basis import BSplineCurve, clamped_knots, greville
from tests.helpers import check_grad, jit_vmap_grad, raises_both, random_knots

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
    def f(p):
        c = construct.compatible([a.with_ctrl(p), b])[0]
        return c.ctrl, jnp.sum(c.evaluate(T) ** 2)

    # under jit (and vmap), with the gradient: one program; its first element is a's own net
    far = a.ctrl + 0.1 * jnp.asarray(rng.normal(size=(5, 3)))
    (jitted, _), _, _ = jit_vmap_grad(f, a.ctrl, far, reduce=lambda y: y[1])
    np.testing.assert_allclose(jitted[0], ref[0].ctrl, atol=1e-13)
    # curves as jit arguments (traced knots): fine when already compatible, refused otherwise
    second = jax.jit(lambda c0, c1: construct.compatible([c0, c1])[1].ctrl)  # one program for both pairs
    same = second(ref[0], ref[1])
    np.testing.assert_allclose(same, ref[1].ctrl, atol=1e-13)
    with pytest.raises(ValueError, match="outside jit"):
        second(a, b)
    other = BSplineCurve(ref[1].ctrl, np.sort(np.asarray(ref[1].knots)) ** 1.5, 3)
    with pytest.raises(Exception, match="knot vector of the first curve"):
        jax.block_until_ready(second(ref[0], other))


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

    # jit, vmap and the gradient in the control points and the axis direction: one program
    far = (profile.ctrl + 0.1 * jnp.asarray(rng.normal(size=(5, 3))), jnp.array([0.3, 1.0, 0.8]))
    jit_vmap_grad(
        lambda x: construct.revolve(profile.with_ctrl(x[0]), [0.0, 0.0, 0.0], x[1]).evaluate(u, v),
        (profile.ctrl, jnp.array([0.0, 1.0, 1.0])),
        far,
        n_dirs=3,
    )
    # a traced angle uses 4 arcs (a concrete 2.5 rad uses 2): the same surface, another v-parametrisation
    traced = jax.jit(lambda a: construct.revolve(profile, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], a))(2.5)
    concrete = construct.revolve(profile, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], 2.5)
    assert (traced.shape[1], concrete.shape[1]) == (9, 5)
    t = np.linspace(0, 1, 9)
    np.testing.assert_allclose(
        traced.evaluate(t, np.ones_like(t)), concrete.evaluate(t, np.ones_like(t)), atol=1e-12
    )
    check_grad(jax.jit(lambda a: jnp.sum(jnp.sin(f(profile.ctrl, a)))), jnp.asarray(2.5), n_dirs=2)


def test_revolve_bad_input():
    rng = np.random.default_rng(10)
    profile = _curve(rng, 5, 2)
    o = np.zeros(3)

    def by_axis(a):  # one function (one program under jit) for both axis_dir cases
        return construct.revolve(profile, o, a)

    def by_angle(ang):  # one program under jit for the four angles
        return construct.revolve(profile, o, [0.0, 0, 1], ang)

    raises_both(by_axis, np.zeros(3), match="axis_dir: expected a finite nonzero")
    raises_both(by_axis, np.array([0.0, np.nan, 1.0]), match="axis_dir")
    raises_both(
        lambda p: construct.revolve(profile, p, [0.0, 0, 1]), np.array([np.inf, 0, 0]), match="axis_point"
    )
    for bad in (0.0, -1.0, 7.0, np.nan):
        raises_both(by_angle, np.float64(bad), match=r"angle: expected")
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
    far = x + jnp.asarray(rng.normal(size=(2, 3)))
    jit_vmap_grad(f, x, far, reduce=lambda y: jnp.sum(jnp.cos(y)))  # jit, vmap and grad: one program


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

    far = c0.ctrl + 0.1 * jnp.asarray(rng.normal(size=(5, 3)))
    jit_vmap_grad(f, c0.ctrl, far)  # jit, vmap and grad: one program
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


# --- interpolate_grid ------------------------------------------------------------------------------
def _grid_points(rng, m=6, n=5):
    """A non-separable, non-uniformly spaced grid (increasing in both directions)."""
    steps = rng.uniform(0.2, 1.0, (m, n, 3))
    return np.cumsum(steps, axis=0) + np.cumsum(rng.uniform(0.2, 1.0, (m, n, 3)), axis=1)


def _reference_params(points):
    """Averaged chord-length parameters along axis 0 of `(m, n, 3)` (The NURBS Book eq. 9.5)."""
    chords = np.linalg.norm(np.diff(points, axis=0), axis=-1)  # (m-1, n)
    cumulative = np.concatenate([np.zeros((1, points.shape[1])), np.cumsum(chords, axis=0)])
    return (cumulative / cumulative[-1]).mean(axis=1)


def _reference_knots(params, p):
    interior = [params[j : j + p].mean() for j in range(1, len(params) - p)]
    return np.concatenate([np.zeros(p + 1), interior, np.ones(p + 1)])


@pytest.mark.parametrize("degree", [(3, 3), (2, 3)])
def test_interpolate_grid_equals_scipy_interpolation_twice(degree):
    from scipy.interpolate import make_interp_spline

    points = _grid_points(np.random.default_rng(3))
    surface = construct.interpolate_grid(points, degree)
    pu, pv = _reference_params(points), _reference_params(np.swapaxes(points, 0, 1))
    ku, kv = _reference_knots(pu, degree[0]), _reference_knots(pv, degree[1])
    np.testing.assert_allclose(np.asarray(surface.knots_u), ku, atol=1e-14)
    np.testing.assert_allclose(np.asarray(surface.knots_v), kv, atol=1e-14)
    along_u = make_interp_spline(pu, points, k=degree[0], t=ku, axis=0).c
    expected = np.swapaxes(make_interp_spline(pv, along_u, k=degree[1], t=kv, axis=1).c, 0, 1)  # (axis first)
    np.testing.assert_allclose(np.asarray(surface.ctrl), expected, atol=1e-10)
    u, v = np.meshgrid(pu, pv, indexing="ij")
    np.testing.assert_allclose(np.asarray(surface.evaluate(u, v)), points, atol=1e-10)


def test_interpolate_grid_jit_vmap_grad():
    rng = np.random.default_rng(4)
    points = _grid_points(rng, 5, 4)
    u, v = (jnp.asarray(x) for x in rng.uniform(0, 1, (2, 7)))

    def f(p):
        surface = construct.interpolate_grid(p)
        return surface.ctrl, jnp.sum(surface.evaluate(u, v) ** 2)

    # jit, vmap and grad in one program; the batch ends with the grid doubled
    (nets, _), _, _ = jit_vmap_grad(f, points, 2.0 * points, reduce=lambda y: y[1], close={"rtol": 1e-9})
    np.testing.assert_allclose(nets[-1], 2.0 * nets[0], atol=1e-10)  # chord parameters scale-free


def test_interpolate_grid_bad_input():
    points = _grid_points(np.random.default_rng(5), 4, 4)
    with pytest.raises(ValueError, match="points"):
        construct.interpolate_grid(points[:3])  # 3 rows for degree 3
    with pytest.raises(ValueError, match="points"):
        construct.interpolate_grid(points[..., :2])
    with pytest.raises(TypeError, match="degree"):
        construct.interpolate_grid(points, 3)
    holed = points.copy()
    holed[1, 1, 0] = np.nan
    raises_both(lambda p: construct.interpolate_grid(p).ctrl, holed, match="points")
    coincident = points.copy()
    coincident[2] = coincident[1]
    raises_both(lambda p: construct.interpolate_grid(p).ctrl, coincident, match="coincident rows")


# --- sweep -----------------------------------------------------------------------------------------
def _helix_path(turns=1.5, a=2.0, b=0.5, samples=11):
    """A cubic B-spline through samples of the helix `(a cos s, a sin s, b s)`."""
    from scipy.interpolate import make_interp_spline

    s = np.linspace(0, 2 * np.pi * turns, samples)
    spline = make_interp_spline(
        np.linspace(0, 1, samples), np.stack([a * np.cos(s), a * np.sin(s), b * s], 1), k=3
    )
    return BSplineCurve(spline.c, spline.t, 3)


def _planar_circle(radius):
    return BSplineCurve(CIRCLE_SQUARE * radius, CIRCLE_KNOTS, 2, weights=CIRCLE_WEIGHTS)


def _s_path():
    """A planar S-shaped path in z = 0, starting along +x, turning left then right (its inflection
    off the sampled parameters)."""
    ctrl = np.array([[0.0, 0, 0], [1, 0, 0], [2, 1, 0], [3.2, 2, 0], [4, 1, 0], [5, 0, 0], [6, 0, 0]])
    return BSplineCurve(ctrl, clamped_knots(7, 3), 3)


def _scipy_rmf_normals(path, t, start):
    """The rotation-minimising normal by integrating `r' = −(r · T') T` with scipy (an
    independent reference for the double reflection method)."""
    from scipy.integrate import solve_ivp

    knots, ctrl = np.asarray(path.knots), np.asarray(path.ctrl)
    d1, d2 = BSpline(knots, ctrl, path.degree).derivative(1), BSpline(knots, ctrl, path.degree).derivative(2)

    def rhs(x, r):
        c1, c2 = d1(x), d2(x)
        speed = np.linalg.norm(c1)
        tangent = c1 / speed
        dtangent = (c2 - (c2 @ tangent) * tangent) / speed
        return -(r @ dtangent) * tangent

    return solve_ivp(rhs, (0.0, 1.0), start, t_eval=t, rtol=1e-11, atol=1e-12).y.T


def test_sweep_circle_along_helix_is_a_tube_with_rotation_minimising_frames():
    path, radius = _helix_path(), 0.3
    fit = construct.sweep(_planar_circle(radius), path)
    assert 0 < float(fit.max_error) < 2e-3  # the stated fit tolerance for this path
    rng = np.random.default_rng(6)
    u, v = rng.uniform(0, 1, (2, 200))
    points = np.asarray(fit.surface.evaluate(u, v))
    centre = _scipy_points(path, v)
    distance = np.linalg.norm(points - centre, axis=-1)
    assert np.abs(distance - radius).max() <= float(fit.max_error) + 1e-12
    # the sections (v = t_k): exact, in the normal plane, normals = scipy's integrated RMF
    count = fit.surface.shape[1]
    t_k = np.linspace(0, 1, count)
    normals = (np.asarray(fit.surface.evaluate(np.zeros(count), t_k)) - _scipy_points(path, t_k)) / radius
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(normals, _scipy_rmf_normals(path, t_k, normals[0]), atol=1e-6)


def test_sweep_planar_path_rmf_has_no_twist_frenet_flips_fixed_translates():
    path, profile = _s_path(), _planar_circle(0.2)
    count = 9
    t_k = np.linspace(0, 1, count)
    centre = _scipy_points(path, t_k)

    def local_point(frame, u):  # S(u, t_k) − C(t_k): the profile point in the frame
        surface = construct.sweep(profile, path, frame, n_sections=count).surface
        return (np.asarray(surface.evaluate(np.full(count, u), t_k)) - centre) / 0.2

    # default start normal: z (up) for a path in the xy plane; the RMF keeps it (no twist)
    np.testing.assert_allclose(local_point("rmf", 0.0), np.tile([0.0, 0, 1], (count, 1)), atol=1e-12)
    binormal = local_point("frenet", 0.25)  # B = T × N: +z where the path turns left, −z right
    spline = BSpline(np.asarray(path.knots), np.asarray(path.ctrl), 3)
    d1, d2 = spline.derivative(1)(t_k), spline.derivative(2)(t_k)
    turn = np.sign(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert set(turn) == {-1.0, 1.0}  # the Frenet frame flips; the RMF above did not
    np.testing.assert_allclose(binormal, turn[:, None] * [0.0, 0, 1], atol=1e-12)
    fixed = local_point("fixed", 0.25)
    np.testing.assert_allclose(fixed, np.tile(fixed[0], (count, 1)), atol=1e-12)
    # a given start normal (y): the RMF binormal stays z, the normal is z × T(t) (closed form)
    surface = construct.sweep(profile, path, n_sections=count, normal=[0.0, 2.0, 0.0]).surface
    normals = (np.asarray(surface.evaluate(np.zeros(count), t_k)) - centre) / 0.2
    tangents = BSpline(np.asarray(path.knots), np.asarray(path.ctrl), 3).derivative(1)(t_k)
    expected = np.cross([0.0, 0, 1], tangents / np.linalg.norm(tangents, axis=-1, keepdims=True))
    np.testing.assert_allclose(normals, expected, atol=1e-12)


def test_sweep_jit_vmap_grad():
    path, profile = _s_path(), _planar_circle(0.2)
    u, v = (jnp.asarray(x) for x in np.random.default_rng(8).uniform(0, 1, (2, 5)))

    def f(ctrls):
        profile_ctrl, path_ctrl = ctrls
        fit = construct.sweep(profile.with_ctrl(profile_ctrl), path.with_ctrl(path_ctrl), n_sections=6)
        return jnp.sum(fit.surface.evaluate(u, v) ** 2) + fit.max_error

    # jit, vmap and grad (in both curves' control points) in one program; the batch ends with the
    # profile doubled
    _, values, _ = jit_vmap_grad(
        f, (profile.ctrl, path.ctrl), (2.0 * profile.ctrl, path.ctrl), lambda y: y, {"rtol": 1e-12}
    )
    assert values.shape == (2 * 2 + 2,)


def test_sweep_bad_input():
    path, profile = _s_path(), _planar_circle(0.2)
    with pytest.raises(ValueError, match="frame"):
        construct.sweep(profile, path, frame="twisted")
    with pytest.raises(ValueError, match="n_sections"):
        construct.sweep(profile, path, n_sections=1)
    with pytest.raises(TypeError, match="path"):
        construct.sweep(profile, path.ctrl)

    # 9 sections: the eager calls reuse the kernels compiled by the planar-path test above;
    # the path and normal checks share one program under jit
    def rmf(p, n):
        return construct.sweep(profile, path.with_ctrl(p), n_sections=9, normal=n).max_error

    point, up = np.ones((7, 3)), np.array([0.0, 2.0, 0.0])
    raises_both(rmf, point, up, match="path: expected a regular path")
    line = np.linspace([0.0, 0, 0], [1.0, 1, 1], 7)
    raises_both(lambda p: construct.sweep(profile, path.with_ctrl(p), "frenet", 9).max_error, line,
                match="nonzero curvature")  # fmt: skip
    raises_both(rmf, np.asarray(path.ctrl), np.array([1.0, 0, 0]), match="normal")


# --- boundary_rotation -----------------------------------------------------------------------------
_OUTLINE = np.array([[0.0, 0, 0], [1, 0.5, 0], [1.5, 1.5, 0], [0.8, 2.5, 0], [0, 3, 0]])


def test_boundary_rotation_of_mirrored_outlines_is_a_surface_of_revolution():
    left = BSplineCurve(_OUTLINE, clamped_knots(5, 3), 3)
    right = BSplineCurve(_OUTLINE * [-1, 1, 1], clamped_knots(5, 3), 3)
    fit = construct.boundary_rotation(left, right, [0.0, 0.0, 3.0])
    assert float(fit.max_error) < 1e-12
    u, _, points = _grid(fit.surface, 11, 13)
    radius = np.abs(_scipy_points(left, u.ravel())[:, 0]).reshape(u.shape)
    np.testing.assert_allclose(np.hypot(points[..., 0], points[..., 2]), radius, atol=1e-12)
    np.testing.assert_allclose(
        points[..., 1], _scipy_points(left, u.ravel())[:, 1].reshape(u.shape), atol=1e-12
    )
    assert points[5, 3, 2] > 0  # the circles bulge towards +plane_normal at v = ¼


def test_boundary_rotation_general_outlines_circles_through_both():
    rng = np.random.default_rng(9)
    left = BSplineCurve(np.c_[rng.normal(size=(6, 2)) + [2, 0], np.zeros(6)], random_knots(rng, 6, 3), 3)
    right = BSplineCurve(np.c_[rng.normal(size=(5, 2)) - [2, 0], np.zeros(5)], random_knots(rng, 5, 2), 2)
    fit = construct.boundary_rotation(left, right, [0.0, 0.0, 1.0])
    t = np.linspace(0, 1, 17)
    for v, curve in ((0.0, left), (0.5, right), (1.0, left)):
        on_outline = np.asarray(fit.surface.evaluate(t, np.full_like(t, v)))
        np.testing.assert_allclose(on_outline, _scipy_points(curve, t), atol=1e-12)
    # every sample on the circle of centre Q(u), radius |D(u)|, in the plane of D and the normal
    u, v = rng.uniform(0, 1, (2, 300))
    cl, cr = _scipy_points(left, u), _scipy_points(right, u)
    offset = np.asarray(fit.surface.evaluate(u, v)) - (cl + cr) / 2
    half = np.linalg.norm(cl - cr, axis=-1) / 2
    error = float(fit.max_error)
    assert 0 < error < 0.05 * half.max()
    assert np.abs(np.linalg.norm(offset, axis=-1) - half).max() <= error + 1e-12
    in_plane = np.abs(np.einsum("ij,ij->i", offset, np.cross(cl - cr, [0.0, 0, 1]))) / np.linalg.norm(
        cl - cr, axis=-1
    )
    assert in_plane.max() <= 1e-12


def test_boundary_rotation_jit_vmap_grad_and_bad_input():
    left = BSplineCurve(_OUTLINE + [0.2, 0, 0], clamped_knots(5, 3), 3)
    right = BSplineCurve(_OUTLINE * [-1, 1, 1], clamped_knots(5, 3), 3)
    u, v = (jnp.asarray(x) for x in np.random.default_rng(10).uniform(0, 1, (2, 6)))

    def f(ctrl, normal):
        fit = construct.boundary_rotation(left.with_ctrl(ctrl), right, normal)
        return jnp.sum(fit.surface.evaluate(u, v) ** 2) + fit.max_error

    normal = jnp.asarray([0.1, 0.0, 1.0])
    # jit, vmap and grad (control points, normal) in one program; outlines apart: |D| > 0 inside
    ctrl = left.ctrl + 0.1
    _, values, _ = jit_vmap_grad(
        lambda x: f(*x), (ctrl, normal), (ctrl, 2.0 * normal), lambda y: y, {"rtol": 1e-12}
    )
    assert float(values[-1]) == pytest.approx(float(values[0]), rel=1e-12)  # any normal length

    def by_normal(n):  # one program under jit for both bad normals
        return construct.boundary_rotation(left, right, n).max_error

    raises_both(by_normal, np.zeros(3), match="plane_normal")
    raises_both(by_normal, np.array([np.nan, 0, 1.0]), match="plane_normal")
    with pytest.raises(ValueError, match="plane_normal"):
        construct.boundary_rotation(left, right, [0.0, 1.0])
    with pytest.raises(ValueError, match="right: expected a polynomial"):
        construct.boundary_rotation(left, _circle(1.0, 0.0), [0.0, 0.0, 1.0])
    with pytest.raises(TypeError, match="left"):
        construct.boundary_rotation(_OUTLINE, right, [0.0, 0.0, 1.0])


# --- rail_rotation ---------------------------------------------------------------------------------
def _semicircle_profile():
    """The half circle of radius 1 about (0, 0, 1) in the plane x = 0, from (0, 0, 0) to (0, 0, 2)."""
    ctrl = np.array([[0.0, 0, 0], [0, -1, 0], [0, -1, 1], [0, -1, 2], [0, 0, 2]])
    knots = [0, 0, 0, 0.5, 0.5, 1, 1, 1]
    return BSplineCurve(ctrl, knots, 2, weights=np.array([1, 2**-0.5, 1, 2**-0.5, 1]))


def test_rail_rotation_straight_parallel_rails_make_a_cylinder():
    rail_a = BSplineCurve(np.array([[0.0, 0, 0], [3, 0, 0]]), [0, 0, 1, 1], 1)
    rail_b = BSplineCurve(np.array([[0.0, 0, 2], [3, 0, 2]]), [0, 0, 1, 1], 1)
    fit = construct.rail_rotation(rail_a, rail_b, _semicircle_profile(), n_sections=4)
    assert float(fit.max_error) < 1e-12
    _, v, points = _grid(fit.surface, 9, 11)
    np.testing.assert_allclose(np.hypot(points[..., 1], points[..., 2] - 1), 1.0, atol=1e-12)
    np.testing.assert_allclose(points[..., 0], 3 * v, atol=1e-12)
    assert points[..., 1].max() <= 1e-12  # the arc's side kept (y ≤ 0)


def test_rail_rotation_coaxial_circles_revolve_the_profile_and_hold_the_rails():
    rail_a, rail_b = _circle(1.0, 0.0), _circle(0.5, 2.0)
    profile = BSplineCurve(
        np.array([[1.0, 0, 0], [1.3, 0, 0.7], [0.6, 0, 1.4], [0.5, 0, 2]]), clamped_knots(4, 3), 3
    )
    fit = construct.rail_rotation(rail_a, rail_b, profile)
    error = float(fit.max_error)
    assert 0 < error < 5e-3
    rng = np.random.default_rng(11)
    u, v = rng.uniform(0, 1, (2, 200))
    points = np.asarray(fit.surface.evaluate(u, v))
    expected = _scipy_points(profile, u)
    assert np.abs(np.hypot(points[:, 0], points[:, 1]) - expected[:, 0]).max() <= error + 1e-12
    np.testing.assert_allclose(points[:, 2], expected[:, 2], atol=1e-12)  # heights exact
    t_k = np.linspace(0, 1, fit.surface.shape[1])
    for u_end, rail in ((0.0, rail_a), (1.0, rail_b)):
        on_rail = np.asarray(fit.surface.evaluate(np.full_like(t_k, u_end), t_k))
        np.testing.assert_allclose(on_rail, _scipy_points(rail, t_k), atol=1e-12)


def test_rail_rotation_grad_and_bad_input():
    rail_a = BSplineCurve(np.array([[0.0, 0, 0], [1, 0.5, 0], [3, 0, 0]]), [0, 0, 0, 1, 1, 1], 2)
    rail_b = BSplineCurve(np.array([[0.0, 0, 2], [1, 0.2, 2], [3, 0, 2]]), [0, 0, 0, 1, 1, 1], 2)
    profile = _semicircle_profile()
    u, v = (jnp.asarray(x) for x in np.random.default_rng(12).uniform(0, 1, (2, 5)))

    def f(ctrl):
        fit = construct.rail_rotation(rail_a.with_ctrl(ctrl), rail_b, profile, n_sections=5)
        return jnp.sum(fit.surface.evaluate(u, v) ** 2) + fit.max_error

    far = rail_a.ctrl + 0.05 * jnp.asarray(np.random.default_rng(13).normal(size=(3, 3)))
    jit_vmap_grad(f, rail_a.ctrl, far, lambda y: y, {"rtol": 1e-12}, n_dirs=1)  # jit, vmap, grad: one program
    raises_both(lambda p: construct.rail_rotation(rail_a, rail_b.with_ctrl(p), profile, 5).max_error,
                np.asarray(rail_a.ctrl), match="rail_b: expected rails apart")  # fmt: skip
    closed = profile.with_ctrl(np.asarray(profile.ctrl) * [1, 1, 0])
    with pytest.raises(ValueError, match="profile: expected distinct end points"):
        construct.rail_rotation(rail_a, rail_b, closed, 5)
    with pytest.raises(ValueError, match="n_sections"):
        construct.rail_rotation(rail_a, rail_b, profile, 1)


def test_new_knot_values_with_the_same_counts_reuse_the_compilation():
    """The plan (merged knots, change-of-basis matrices) is an input of the compiled kernel: a new
    pair of strokes with other interior knots but the same degree and counts compiles nothing
    new, and the ruled surface is still exact (`S(u, v) = (1 − v) C0(u) + v C1(u)`)."""
    rng = np.random.default_rng(7)

    def stroke(z):
        knots = np.concatenate([[0.0] * 4, np.sort(rng.uniform(0.05, 0.95, 5)), [1.0] * 4])
        ctrl = np.stack([np.linspace(0, 1, 9), 0.1 * rng.normal(size=9), np.full(9, z)], -1)
        return BSplineCurve(ctrl, knots, 3)

    construct._ruled.clear_cache()
    t = np.linspace(0, 1, 11)
    for _ in range(3):
        c0, c1 = stroke(0.0), stroke(1.0)
        surface = construct.ruled(c0, c1)
        for v in (0.0, 0.3, 1.0):
            expected = (1 - v) * _scipy_points(c0, t) + v * _scipy_points(c1, t)
            np.testing.assert_allclose(surface.evaluate(t, np.full_like(t, v)), expected, atol=1e-12)
    (jitted,) = construct._ruled._cache.values()
    assert jitted._cache_size() == 1
