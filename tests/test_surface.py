"""`BSplineSurface.evaluate` / `.normal` against scipy NdBSpline, geomdl and closed forms."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import shapes
from bsjax.basis import BSplineSurface, clamped_knots
from tests.helpers import check_grad, random_knots, random_surface
from tests.oracles import geomdl_surface, knots_with_repeats, ndbspline_surface, tolerance

R, S = 9, 7  # non-square control net, the same for every degree pair (few compiles)
ORDERS = [(0, 0), (1, 0), (0, 1), (2, 0), (0, 2), (1, 1)]


@eqx.filter_jit
def _all_orders(surface, u, v):
    return [surface.evaluate(u, v, a, b) for a, b in ORDERS]


# Eager `evaluate` compiles every primitive for each new shape (seconds each on a busy CPU), so
# most tests go through these jitted wrappers; jit == eager is asserted once below.
_points = eqx.filter_jit(lambda surface, u, v: surface.evaluate(u, v))


def _surface(rng, k, l, kind="random", weights=False, periodic_v=False):
    tu = {"random": random_knots, "repeated": knots_with_repeats}[kind](rng, R, k)
    tv = None if periodic_v else random_knots(rng, S, l)
    ctrl = rng.normal(size=(R, S, 3))
    w = rng.uniform(0.5, 2.0, (R, S)) if weights else None
    return BSplineSurface(ctrl, tu, tv, k, l, periodic_v=periodic_v, weights=w)


def _params(rng, surface, count=40):
    """Random (u, v) plus corners, u = 1 / v = 1 exactly, and the knot values themselves."""
    ku = np.unique(np.asarray(surface.knots_u))
    kv = np.unique(np.asarray(surface.knots_v)) if surface.knots_v is not None else np.linspace(0, 1, 5)
    u = np.concatenate([ku, [1.0, 1.0, 0.0], rng.uniform(0, 1, count)])
    v = np.concatenate([rng.choice(kv, len(ku)), [1.0, 0.0, 1.0], rng.uniform(0, 1, count)])
    pad = max(2 * count, len(u)) - len(u)  # a fixed size whatever the knots: pad with random pairs
    return np.concatenate([u, rng.uniform(0, 1, pad)]), np.concatenate([v, rng.uniform(0, 1, pad)])


@pytest.mark.parametrize("k, l", [(1, 2), (2, 3), (3, 3), (4, 1), (5, 2), (3, 5)])
@pytest.mark.parametrize("kind", ["random", "repeated"])
def test_evaluate_matches_ndbspline(k, l, kind):
    rng = np.random.default_rng(10 * k + l)
    surface = _surface(rng, k, l, kind)
    u, v = _params(rng, surface)
    for (a, b), got in zip(ORDERS, _all_orders(surface, u, v)):
        ref = ndbspline_surface(surface, u, v, a, b)
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref), err_msg=str((a, b)))


@pytest.mark.parametrize("k, l", [(2, 3), (3, 2)])
def test_nurbs_matches_homogeneous_reference(k, l):
    rng = np.random.default_rng(100 + k)
    surface = _surface(rng, k, l, weights=True)
    u, v = _params(rng, surface)
    for (a, b), got in zip(ORDERS, _all_orders(surface, u, v)):
        ref = ndbspline_surface(surface, u, v, a, b)
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref), err_msg=str((a, b)))


@pytest.mark.parametrize("weights", [False, True])
def test_evaluate_matches_geomdl(weights):
    rng = np.random.default_rng(7)
    surface = _surface(rng, 3, 2, weights=weights)
    g = geomdl_surface(surface)
    u, v = _params(rng, surface, 10)
    got = _all_orders(surface, u, v)
    for i in range(len(u)):
        skl = g.derivatives(float(u[i]), float(v[i]), order=2)
        for (a, b), values in zip(ORDERS, got):
            ref = np.asarray(skl[a][b])
            np.testing.assert_allclose(
                values[i], ref, rtol=0, atol=tolerance(ref, 1e-11), err_msg=str((a, b))
            )


def test_periodic_surface_matches_ndbspline_and_closes():
    rng = np.random.default_rng(3)
    surface = _surface(rng, 3, 3, periodic_v=True)
    u, v = _params(rng, surface)
    for (a, b), got in zip(ORDERS, _all_orders(surface, u, v)):
        ref = ndbspline_surface(surface, u, v, a, b)
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref), err_msg=str((a, b)))
    # C² closure across the seam v = 0 ≡ v = 1.
    zeros, ones = np.zeros_like(u), np.ones_like(u)
    for a, b in zip(_all_orders(surface, u, zeros), _all_orders(surface, u, ones)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_evaluate_keeps_parameter_shape():
    surface = random_surface(np.random.default_rng(0), 6, 5, 3, 2)
    u = jnp.linspace(0, 1, 12).reshape(3, 4)
    out = surface.evaluate(u, u.T.reshape(3, 4))  # eager
    assert out.shape == (3, 4, 3)
    ref = ndbspline_surface(surface, np.asarray(u), np.asarray(u.T.reshape(3, 4)))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_points(surface, u, u.T.reshape(3, 4)), out, rtol=0, atol=1e-14)
    point = _points(surface, jnp.asarray(0.5), jnp.asarray(0.25))
    assert point.shape == (3,)
    np.testing.assert_allclose(point, ndbspline_surface(surface, 0.5, 0.25), rtol=0, atol=1e-12)


def test_corners_interpolate_corner_control_points():
    surface = _surface(np.random.default_rng(1), 3, 2, weights=True)
    corners = _points(surface, jnp.array([0.0, 0.0, 1.0, 1.0]), jnp.array([0.0, 1.0, 0.0, 1.0]))
    np.testing.assert_allclose(corners, np.asarray(surface.ctrl)[[0, 0, -1, -1], [0, -1, 0, -1]], atol=1e-13)


# --- normals -----------------------------------------------------------------------------------
@eqx.filter_jit
def _normal(surface, u, v):
    return surface.normal(u, v)


def test_normal_is_unit_cross_product_of_tangents():
    rng = np.random.default_rng(5)
    surface = _surface(rng, 3, 2, weights=True)
    u, v = _params(rng, surface)
    n = np.asarray(_normal(surface, u, v))
    t_u = ndbspline_surface(surface, u, v, 1, 0)
    t_v = ndbspline_surface(surface, u, v, 0, 1)
    ref = np.cross(t_u, t_v)
    ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
    np.testing.assert_allclose(n, ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-13)
    np.testing.assert_allclose(np.sum(n * t_u, -1), 0.0, atol=1e-10 * np.abs(t_u).max())
    np.testing.assert_allclose(np.sum(n * t_v, -1), 0.0, atol=1e-10 * np.abs(t_v).max())


def test_sphere_normals_point_outward_including_poles():
    surface = shapes.sphere()
    g = jnp.linspace(0.0, 1.0, 21)
    u, v = jnp.meshgrid(g, g, indexing="ij")
    n = np.asarray(_normal(surface, u, v))
    p = np.asarray(_points(surface, u, v))
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    radial = p / np.linalg.norm(p, axis=-1, keepdims=True)
    assert np.all(np.sum(n * radial, -1) > 0.9)
    # The poles are blunt cone tips (the second control ring sits lower than the pole): the
    # limit normal along each meridian tilts a little off the axis but points up / down.
    assert np.all(n[0, :, 2] > 0.95) and np.all(n[-1, :, 2] < -0.95)


def test_teardrop_normals_finite_at_poles_and_grad_finite():
    surface = shapes.teardrop()
    v = jnp.linspace(0.0, 1.0, 9)
    for u0, sign in ((0.0, 1.0), (1.0, -1.0)):
        n = np.asarray(_normal(surface, jnp.full_like(v, u0), v))
        assert np.all(np.isfinite(n))
        np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
        assert np.all(sign * n[:, 2] > 0), n  # the tip normal points up, the bottom one down
    # Away from the poles the normal is T_u × T_v / |·|.
    u = jnp.full_like(v, 0.4)
    ref = np.cross(ndbspline_surface(surface, u, v, 1, 0), ndbspline_surface(surface, u, v, 0, 1))
    np.testing.assert_allclose(
        _normal(surface, u, v), ref / np.linalg.norm(ref, axis=-1, keepdims=True), atol=1e-12
    )
    # Gradient of a normal component w.r.t. the control net, exactly at the pole, is finite.
    g = jax.jit(jax.grad(lambda c: surface.with_ctrl(c).normal(jnp.array(0.0), jnp.array(0.3))[2]))(
        surface.ctrl
    )
    assert np.all(np.isfinite(np.asarray(g)))


# --- jit, vmap, grad, dtype --------------------------------------------------------------------
def test_jit_and_vmap_over_control_nets_equal_loop():
    rng = np.random.default_rng(11)
    surface = _surface(rng, 3, 2, weights=True)
    u, v = _params(rng, surface, 8)
    nets = jnp.asarray(rng.normal(size=(4, R, S, 3)))
    single = jax.jit(lambda c: surface.with_ctrl(c).evaluate(u, v, 1, 1))
    batched = jax.jit(jax.vmap(single))(nets)
    for b in range(4):
        loop = single(nets[b])
        np.testing.assert_allclose(batched[b], loop, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            batched[b],
            ndbspline_surface(surface.with_ctrl(nets[b]), u, v, 1, 1),
            rtol=0,
            atol=tolerance(loop),
        )


def test_grad_wrt_control_points_weights_and_parameters():
    rng = np.random.default_rng(12)
    surface = _surface(rng, 3, 2, weights=True)
    u, v = (jnp.asarray(x) for x in _params(rng, surface, 6))
    probe = jnp.asarray(rng.normal(size=(len(u), 3)))

    def loss(s, uu=u, vv=v):
        return jnp.sum(s.evaluate(uu, vv) * probe) + jnp.sum(s.normal(uu, vv) * probe)

    check_grad(jax.jit(lambda c: loss(eqx.tree_at(lambda s: s.ctrl, surface, c))), surface.ctrl)
    points_only = jax.jit(
        lambda w: jnp.sum(eqx.tree_at(lambda s: s.weights, surface, w).evaluate(u, v) * probe)
    )
    check_grad(points_only, surface.weights)
    inner = (jnp.asarray(rng.uniform(0.05, 0.95, 6)), jnp.asarray(rng.uniform(0.05, 0.95, 6)))
    probe6 = probe[:6]

    def point_loss(uv):
        return jnp.sum(surface.evaluate(uv[0], uv[1]) * probe6)

    g = check_grad(jax.jit(point_loss), jnp.stack(inner))
    # d/du Σ probe·S = probe·S_u: the analytic parametric gradient is the derivative surface.
    s_u = ndbspline_surface(surface, *map(np.asarray, inner), 1, 0)
    np.testing.assert_allclose(g[0], np.sum(s_u * np.asarray(probe6), -1), rtol=1e-10, atol=1e-12)


def test_grad_wrt_parameters_on_polynomial_surface():
    rng = np.random.default_rng(13)
    surface = _surface(rng, 4, 3)
    uv = jnp.asarray(rng.uniform(0.05, 0.95, (2, 6)))
    probe = jnp.asarray(rng.normal(size=(6, 3)))
    g = check_grad(jax.jit(lambda x: jnp.sum(surface.evaluate(x[0], x[1], 0, 1) * probe)), uv)
    s_uv = ndbspline_surface(surface, *np.asarray(uv), 1, 1)
    np.testing.assert_allclose(g[0], np.sum(s_uv * np.asarray(probe), -1), rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("weights", [False, True])
def test_float32_stays_float32(weights):
    rng = np.random.default_rng(14)
    s64 = _surface(rng, 3, 2, weights=weights)
    s32 = BSplineSurface(
        np.asarray(s64.ctrl, np.float32),
        np.asarray(s64.knots_u, np.float32),
        clamped_knots(S, 2),
        3,
        2,
        weights=None if s64.weights is None else np.asarray(s64.weights, np.float32),
    )
    assert s32.ctrl.dtype == s32.knots_u.dtype == s32.knots_v.dtype == jnp.float32
    u = np.linspace(0, 1, 7, dtype=np.float32)
    out, normal = _points(s32, u, u[::-1]), _normal(s32, u, u[::-1])
    assert out.dtype == normal.dtype == jnp.float32
    ref = ndbspline_surface(s32, u, u[::-1])
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5)


def test_with_ctrl_keeps_basis_and_checks_shape():
    surface = _surface(np.random.default_rng(15), 3, 2, weights=True)
    moved = surface.with_ctrl(surface.ctrl + 1.0)
    assert moved.degree_u == 3 and moved.weights is not None
    np.testing.assert_allclose(moved.evaluate(0.3, 0.6), surface.evaluate(0.3, 0.6) + 1.0, atol=1e-13)
    with pytest.raises(ValueError, match="ctrl"):
        surface.with_ctrl(surface.ctrl[:-1])
