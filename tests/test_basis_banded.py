"""The span-blocked (banded) evaluation of `Blending` against the dense product `A_u P A_v^T`.

The banded kernel (`_tensor.banded_grid`) must give the dense product's results to 1e-12 in
float64 — points, derivatives up to (2, 2), normals, rational nets, periodic directions, degrees
1–5 — under `jit`, `vmap` and `grad`. The dense reference is the same `Blending` with
`banded=False` (the product used before the band existed) and an independent numpy `einsum`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax.basis import Blending, BSplineSurface, SplineDirection, clamped_knots
from bsjax.basis._tensor import banded_grid, prefer_banded
from tests.helpers import check_grad, raises_both, random_knots


def _surface(rng, r, s, k, l, periodic_u=False, periodic_v=False, weights=False, dtype=np.float64):
    x, y = np.meshgrid(np.linspace(0, 1, r), np.linspace(0, 1, s), indexing="ij")
    ctrl = np.stack([x, y, 0.2 * rng.normal(size=x.shape)], axis=-1).astype(dtype)
    tu = None if periodic_u else random_knots(rng, r, k).astype(dtype)
    tv = None if periodic_v else random_knots(rng, s, l).astype(dtype)
    w = rng.uniform(0.5, 2.0, (r, s)).astype(dtype) if weights else None
    return BSplineSurface(ctrl, tu, tv, k, l, periodic_u, periodic_v, weights=w)


def _dense(b: Blending) -> Blending:
    return dataclasses.replace(b, banded=False)


CASES = [  # (r, s, k, l, periodic_u, periodic_v, rational)
    (7, 6, 1, 2, False, False, False),
    (8, 5, 2, 1, False, False, True),
    (9, 7, 3, 3, False, False, False),
    (8, 9, 4, 2, True, False, False),
    (10, 8, 5, 3, False, True, True),
    (9, 9, 3, 3, True, True, True),
]


@pytest.fixture(params=CASES, ids=lambda c: f"{c[0]}x{c[1]}-k{c[2]}l{c[3]}-p{c[4]:d}{c[5]:d}-w{c[6]:d}")
def case(request):
    r, s, k, l, pu, pv, rational = request.param
    surface = _surface(np.random.default_rng(r * 10 + k), r, s, k, l, pu, pv, rational)
    return surface, surface.blending(17, 13)


def test_band_holds_every_nonzero(case):
    """`a_u` is zero outside `support_u`, and `band_u` holds its values there (all orders)."""
    _, b = case
    a_u, idx, band = np.asarray(b.a_u), np.asarray(b.support_u), np.asarray(b.band_u)
    assert b.banded
    rebuilt = np.zeros_like(a_u)
    for nu in range(a_u.shape[0]):
        np.put_along_axis(rebuilt[nu], idx, band[nu], axis=1)
    np.testing.assert_array_equal(rebuilt, a_u)
    assert np.all(np.diff(np.sort(idx, 1), axis=1) > 0)  # distinct columns, also when wrapped


@pytest.mark.parametrize("nu, nv", [(0, 0), (1, 0), (0, 1), (1, 1), (2, 2)])
def test_derivatives_match_dense(case, nu, nv):
    surface, b = case
    got = np.asarray(b.derivative(surface.ctrl, nu, nv))
    want = np.asarray(_dense(b).derivative(surface.ctrl, nu, nv))
    scale = max(1.0, np.abs(want).max())
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * scale)
    if surface.weights is None:  # an independent reference for the polynomial net
        ref = np.einsum(
            "ai,ijc,bj->abc", np.asarray(b.a_u[nu]), np.asarray(surface.ctrl), np.asarray(b.a_v[nv])
        )
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * scale)


def test_points_normals_and_refit_match_dense(case):
    surface, b = case
    dense = _dense(b)
    for fn in ("points", "normals"):
        got, want = getattr(b, fn)(surface.ctrl), getattr(dense, fn)(surface.ctrl)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    grid = b.points(surface.ctrl)
    np.testing.assert_allclose(b.refit(grid), dense.refit(grid), rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.refit(grid), surface.ctrl, rtol=0, atol=1e-9)


def test_jit_vmap_and_views(case):
    surface, b = case
    rng = np.random.default_rng(3)
    nets = jnp.asarray(surface.ctrl[None] + 0.05 * rng.normal(size=(4, *surface.ctrl.shape)))
    batched = jax.jit(jax.vmap(lambda c: b.points(c)))(nets)
    for i in range(nets.shape[0]):
        np.testing.assert_allclose(batched[i], _dense(b).points(nets[i]), rtol=0, atol=1e-12)
    jitted = jax.jit(lambda bl, c: bl.normals(c))(b, surface.ctrl)
    np.testing.assert_allclose(jitted, _dense(b).normals(surface.ctrl), rtol=0, atol=1e-12)
    view = b.lod(3).window(0.2, 0.9, 0.0, 0.7)
    full = np.asarray(b.points(surface.ctrl))[np.asarray(view.index_u)][:, np.asarray(view.index_v)]
    np.testing.assert_allclose(view.points(surface.ctrl), full, rtol=0, atol=1e-12)


def test_gradients_match_finite_differences(case):
    surface, b = case
    probe = jnp.asarray(np.random.default_rng(4).normal(size=(*b.grid_shape, 3)))
    check_grad(lambda c: jnp.sum(b.derivative(c, 1, 1) * probe), surface.ctrl)
    check_grad(lambda c: jnp.sum(b.normals(c) * probe), surface.ctrl, rtol=1e-4)
    if surface.weights is not None:

        def weighted(w):
            return jnp.sum(eqx_replace_weights(b, w).points(surface.ctrl) * probe)

        check_grad(weighted, surface.weights)


def eqx_replace_weights(b: Blending, w) -> Blending:
    return dataclasses.replace(b, weights=w)


def test_float32_matches_float64():
    rng = np.random.default_rng(5)
    s64 = _surface(rng, 9, 8, 3, 2, weights=True)
    s32 = BSplineSurface.from_directions(
        s64.ctrl.astype(np.float32),
        SplineDirection(s64.knots_u.astype(np.float32), 3),
        SplineDirection(s64.knots_v.astype(np.float32), 2),
        s64.weights.astype(np.float32),
    )
    b32, b64 = s32.blending(21, 19), s64.blending(21, 19)
    assert b32.banded and b32.band_u.dtype == np.float32
    for nu, nv in ((0, 0), (1, 0), (1, 1)):
        got = b32.derivative(s32.ctrl, nu, nv)
        assert got.dtype == np.float32
        want = np.asarray(b64.derivative(s64.ctrl, nu, nv))
        scale = max(1.0, np.abs(want).max())  # float32 rounding, amplified by the quotient rule
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-5 * scale)
        np.testing.assert_allclose(got, _dense(b32).derivative(s32.ctrl, nu, nv), rtol=0, atol=1e-5 * scale)


def test_dense_chosen_when_few_u_samples():
    """`prefer_banded` counts multiply-adds: 2 u-samples against 40 v-samples → the dense order
    `(A_u P) A_v^T` is cheaper, and both kernels give the same grid."""
    assert prefer_banded(82, 82, 20, 20, 3)
    assert not prefer_banded(2, 40, 8, 8, 3)
    rng = np.random.default_rng(6)
    surface = _surface(rng, 8, 8, 3, 3)
    b = surface.blending(2, 40)
    assert not b.banded
    banded = dataclasses.replace(b, banded=True)
    np.testing.assert_allclose(banded.normals(surface.ctrl), b.normals(surface.ctrl), rtol=0, atol=1e-12)


def test_banded_grid_kernel_against_numpy():
    """The kernel alone, on the benchmark's 20×20 bicubic at 82×82 (uniform clamped knots)."""
    rng = np.random.default_rng(7)
    direction = SplineDirection(clamped_knots(20, 3), 3)
    params = jnp.linspace(0.0, 1.0, 82)
    a = np.asarray(direction.matrix(params))
    idx = direction.support(params)
    band = jnp.take_along_axis(jnp.asarray(a), idx, axis=1)
    ctrl = rng.normal(size=(20, 20, 3))
    got = banded_grid(idx, band, jnp.asarray(ctrl), jnp.asarray(a))
    np.testing.assert_allclose(got, np.einsum("ai,ijc,bj->abc", a, ctrl, a), rtol=0, atol=1e-12)


def test_bad_nets_raise_under_jit():
    surface = _surface(np.random.default_rng(8), 7, 6, 3, 2)
    b = surface.blending(11, 9)
    bad = jnp.asarray(surface.ctrl).at[2, 3, 1].set(jnp.nan)
    raises_both(lambda c: b.points(c), bad, match="ctrl")
    raises_both(lambda c: b.derivative(c, 1, 0), bad, match="ctrl")
    raises_both(lambda c: b.normals(c), bad, match="ctrl")
    with pytest.raises(ValueError, match="ctrl"):
        b.points(jnp.zeros((6, 7, 3)))
