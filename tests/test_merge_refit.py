"""Nonlinear refit (parameter correction, optimistix) and the shared closest-point projection.

References: closed-form foot points on a plane (inside and beyond the edges), the dense
collocation matrix for the banded normal equations, brute-force nearest samples, and the linear
merge's own deviation on the thesis's harder cases (the refit must lower it).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from bsjax import basis
from bsjax import merge as mg
from bsjax.basis import BSplineSurface, clamped_knots, greville
from bsjax.examples import merge_cases as cases
from bsjax.merge import _deviation, _nonlinear
from tests.helpers import random_surface
from tests.oracles import ndbspline_surface


def _plate(r=5, s=4):
    """z = 0 over [0, 2] × [0, 1], x = 2u and y = v exactly (control points at Greville points)."""
    ku, kv = clamped_knots(r, 3), clamped_knots(s, 3)
    x, y = np.meshgrid(2.0 * np.asarray(greville(ku, 3)), np.asarray(greville(kv, 3)), indexing="ij")
    return BSplineSurface(np.stack([x, y, 0.0 * x], -1), ku, kv, 3, 3)


def test_closest_points_plane_and_clamped_edges():
    """Foot points on a plane patch: inside, the orthogonal projection; beyond an edge or corner,
    the nearest boundary point (the clamped parameter slides along the edge)."""
    plate = _plate()
    pts = jnp.asarray([[0.6, 0.3, 0.5], [2.4, 0.7, -0.2], [-0.3, 1.5, 0.1], [1.0, -0.4, 0.0]])
    want_uv = np.array([[0.3, 0.3], [1.0, 0.7], [0.0, 1.0], [0.5, 0.0]])
    want_d = np.array([0.5, np.hypot(0.4, 0.2), np.sqrt(0.09 + 0.25 + 0.01), 0.4])
    start = jnp.full((4, 2), 0.5)
    proj = basis.closest_points(plate, pts, start)
    np.testing.assert_allclose(proj.params, want_uv, atol=1e-9)
    np.testing.assert_allclose(proj.distances, want_d, atol=1e-9)
    assert bool(jnp.all(proj.result == optx.RESULTS.successful))
    np.testing.assert_allclose(basis.project(plate, pts, start), want_uv, atol=1e-9)


def test_closest_points_never_worse_than_start():
    """On a curved random patch from poor starts (0.1 off): every distance is at most the
    start's, and all but a local minimum or two reach the global one (brute force over a dense
    scipy sampling)."""
    s = random_surface(np.random.default_rng(5), 6, 5, 3, 2)
    rng = np.random.default_rng(0)
    uv_true = rng.uniform(0.05, 0.95, (40, 2))
    pts = ndbspline_surface(s, uv_true[:, 0], uv_true[:, 1]) + 0.02 * rng.normal(size=(40, 3))
    start = jnp.asarray(np.clip(uv_true + rng.normal(scale=0.1, size=(40, 2)), 0, 1))
    proj = basis.closest_points(s, jnp.asarray(pts), start)
    d_start = np.linalg.norm(ndbspline_surface(s, *np.asarray(start).T) - pts, axis=-1)
    d_got = np.linalg.norm(ndbspline_surface(s, *np.asarray(proj.params).T) - pts, axis=-1)
    np.testing.assert_allclose(proj.distances, d_got, atol=1e-12)
    assert np.all(d_got <= d_start + 1e-12)
    g = np.linspace(0, 1, 301)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    dense = ndbspline_surface(s, uu.ravel(), vv.ravel())
    brute = np.min(np.linalg.norm(dense[None] - pts[:, None], axis=-1), axis=1)
    assert np.sum(d_got <= brute + 1e-9) >= 38  # the nearest of 90 601 samples, or better


@pytest.mark.parametrize("shape", [(7, 5, 3, 2), (4, 9, 2, 4)])
def test_normal_matrix_matches_dense_collocation(shape):
    r, s, k, l = shape
    surf = random_surface(np.random.default_rng(1), r, s, k, l)
    uv = jnp.asarray(np.random.default_rng(2).uniform(size=(300, 2)))
    # the kernels as one program each (called eagerly, every operation would be its own)
    dense = eqx.filter_jit(_nonlinear.collocation)(surf, uv)
    normal = jax.jit(_nonlinear.normal_matrix, static_argnums=(2, 3))
    banded = normal(surf.rows("u", uv[:, 0]), surf.rows("v", uv[:, 1]), k, l)
    np.testing.assert_allclose(banded, dense.T @ dense, atol=1e-12)
    ctrl, d = eqx.filter_jit(_nonlinear.fit_scattered)(surf, uv, surf.evaluate(uv[:, 0], uv[:, 1]))
    np.testing.assert_allclose(ctrl, surf.ctrl, atol=1e-8)  # points of the basis: exact round trip
    assert float(jnp.max(d)) < 1e-8


def _run(number, continuity, samples=20):
    c = cases.case(number)
    layout = mg.plan(c.patches, c.direction, continuity, samples=samples, orient="as_given", **c.options)
    ctrls = [s.ctrl for s in c.patches]
    linear = layout.surface(layout.apply(ctrls))
    sol = mg.refit(layout, ctrls)
    dev = [mg.deviation(c.originals, x, samples=31) for x in (linear, layout.surface(sol.ctrl))]
    return layout, sol, dev


# the thesis's harder cases: different curvatures (2), different knot vectors and dimensions
# (4), different degrees (6)
@pytest.mark.parametrize("number, continuity", [(2, 2), (4, 0), (6, 2)])
def test_refit_lowers_deviation_on_harder_cases(number, continuity):
    _layout, sol, (linear, refined) = _run(number, continuity)
    assert refined.mean < linear.mean
    assert refined.max <= linear.max * (1 + 1e-3)
    if number == 4:  # unequal edge lengths: the parametrisation was the problem
        assert refined.mean < 0.8 * linear.mean and refined.max < 0.6 * linear.max
    rms = np.asarray(sol.rms)[: int(sol.rounds) + 1]
    assert int(sol.rounds) >= 1 and not np.any(np.isnan(rms))
    assert np.all(np.diff(rms) <= 1e-12 * rms[0])  # each round lowers the sample distance
    uv = np.asarray(sol.params)
    assert uv.min() >= 0.0 and uv.max() <= 1.0


def test_refit_status_and_refine_wrapper():
    """Status: a round budget that runs out is `max_steps_reached`, a loose tolerance settles;
    `refine` is the net of `refit`; the seam knots (continuity) are those of the layout."""
    c = cases.case(4)
    layout = mg.plan(c.patches, "u", 0, samples=20, orient="as_given")
    ctrls = [s.ctrl for s in c.patches]
    full = mg.refit(layout, ctrls, mg.RefitSolver(rtol=0.0))
    assert full.result == optx.RESULTS.max_steps_reached and int(full.rounds) == 8
    loose = mg.refit(layout, ctrls, mg.RefitSolver(rtol=0.5))
    assert loose.result == optx.RESULTS.successful and int(loose.rounds) < 8
    assert float(full.rms[8]) < float(loose.rms[int(loose.rounds)])
    np.testing.assert_allclose(mg.refine(layout, ctrls), mg.refit(layout, ctrls).ctrl, atol=1e-12)
    merged = mg.merge(c.patches, "u", 0, samples=20, orient="as_given", refine=True)
    np.testing.assert_array_equal(merged.knots_u, layout.merged.knots_u)
    with pytest.raises(ValueError, match="rounds"):
        mg.refit(layout, ctrls, mg.RefitSolver(rounds=0))
    with pytest.raises(TypeError, match="solver"):
        mg.refit(layout, ctrls, solver=3)


# --- closed surfaces and seams ----------------------------------------------------------------
def _closed_tube():
    """A clamped bicubic tube closed along u (first and last control rows equal, knots at
    1/4, 1/2, 3/4) and its four Bézier quarters along u (knot insertion by FITPACK)."""
    from tests.test_merge import split

    th = 2 * np.pi * np.arange(7) / 6
    z = np.array([0.0, 1 / 3, 2 / 3, 1.0]) * 2
    ctrl = np.stack(np.broadcast_arrays(np.cos(th)[:, None], np.sin(th)[:, None], z[None, :]), -1)
    tube = BSplineSurface(ctrl, clamped_knots(7, 3), clamped_knots(4, 3), 3, 3)
    q0, rest = split(tube, "u", 0.25)
    q1, rest = split(rest, "u", 1 / 3)
    q2, q3 = split(rest, "u", 0.5)
    return tube, [q0, q1, q2, q3]


def _brute(surface, pts, count=401):
    """Distances to a dense scipy sampling of `surface` (k-d tree) and the sampling's cell size."""
    from scipy.spatial import cKDTree

    g = np.linspace(0, 1, count)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    dense = ndbspline_surface(surface, uu.ravel(), vv.ravel())
    grid = dense.reshape(count, count, 3)
    cell = max(
        np.linalg.norm(np.diff(grid, axis=0), axis=-1).max(),
        np.linalg.norm(np.diff(grid, axis=1), axis=-1).max(),
    )
    return cKDTree(dense).query(pts)[0], cell


def test_deviation_on_a_closed_merge_is_exact():
    """Four quarters of a closed tube merged into one surface whose edges u = 0 and u = 1
    coincide: the merge reproduces the tube (scipy), so every original point lies on it. The
    nearest grid sample of points next to the seam lies across it, where a single domain-clamped
    Gauss–Newton start stays (0.07 away); the multi-start search finds the foot points."""
    tube, quarters = _closed_tube()
    merged = mg.merge(quarters, "u", 2, samples=16, orient="as_given")
    g = np.linspace(0, 1, 23)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    np.testing.assert_allclose(
        ndbspline_surface(merged, uu.ravel(), vv.ravel()),
        ndbspline_surface(tube, uu.ravel(), vv.ravel()),
        atol=1e-12,
    )
    report = mg.deviation(quarters, merged, samples=41)
    assert float(report.max) < 1e-9 and int(report.n_within) == report.n_points == 4 * 41**2
    g = np.linspace(0, 1, 41)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    pts = jnp.concatenate([q.evaluate(uu, vv).reshape(-1, 3) for q in quarters])
    one = basis.closest_points(merged, pts, None, basis.ProjectionSolver(), None, 1)
    assert float(one.distances.max()) > 1e-2  # the single start fails at the seam (the old report)


def test_closest_points_global_matches_brute_force_near_a_seam():
    """Points off the closed tube (±0.1 along the radius) around its seam: the global search's
    distances agree with a brute-force dense projection (within one cell, never above it)."""
    tube, quarters = _closed_tube()
    merged = mg.merge(quarters, "u", 2, samples=16, orient="as_given")
    rng = np.random.default_rng(3)
    u = np.mod(rng.uniform(-0.08, 0.08, 200), 1.0)
    v = rng.uniform(0.0, 1.0, 200)
    on = ndbspline_surface(tube, u, v)
    radial = on * np.array([1.0, 1.0, 0.0])[None]
    pts = on + rng.uniform(-0.1, 0.1, (200, 1)) * radial / np.linalg.norm(radial, axis=-1, keepdims=True)
    proj = basis.closest_points(merged, jnp.asarray(pts))
    brute, cell = _brute(merged, pts)
    d = np.asarray(proj.distances)
    assert np.all(d <= brute + 1e-9) and np.all(d >= brute - cell)
    np.testing.assert_allclose(ndbspline_surface(merged, *np.asarray(proj.params).T), pts, atol=0.11)


def test_closest_points_periodic_crosses_the_seam():
    """On a periodic (closed) direction the iteration wraps: from a start on the far side of the
    seam (u = 0.97) it reaches a foot point at u = 0.02 (brute force over a dense sampling)."""
    rng = np.random.default_rng(2)
    th = 2 * np.pi * np.arange(8) / 8
    ctrl = np.stack(
        np.broadcast_arrays(np.cos(th)[:, None], np.sin(th)[:, None], np.arange(5.0)[None] / 4), -1
    )
    ctrl = ctrl + 0.05 * rng.normal(size=ctrl.shape)
    ring = BSplineSurface(ctrl, None, clamped_knots(5, 3), 3, 3, periodic_u=True)
    u_true = np.array([0.02, 0.98, 0.5])
    v_true = np.array([0.4, 0.6, 0.5])
    pts = ring.evaluate(jnp.asarray(u_true), jnp.asarray(v_true))
    starts = jnp.asarray([[0.97, 0.4], [0.03, 0.6], [0.45, 0.5]])
    proj = basis.closest_points(ring, pts, starts)
    np.testing.assert_allclose(proj.distances, 0.0, atol=1e-9)
    wrapped = np.mod(np.asarray(proj.params[:, 0]) - u_true + 0.5, 1.0) - 0.5
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-7)
    assert bool(jnp.all((proj.params >= 0.0) & (proj.params < 1.0)))
    far = pts + 0.05 * ring.normal(jnp.asarray(u_true), jnp.asarray(v_true))
    g = np.linspace(0, 1, 801, endpoint=False)
    uu, vv = np.meshgrid(g, np.linspace(0, 1, 201), indexing="ij")
    dense = np.asarray(ring.evaluate(jnp.asarray(uu), jnp.asarray(vv))).reshape(-1, 3)
    brute = np.min(np.linalg.norm(dense[None] - np.asarray(far)[:, None], axis=-1), axis=1)
    got = np.asarray(basis.closest_points(ring, far).distances)
    assert np.all(got <= brute + 1e-9) and np.all(got >= brute - 0.02)


def test_projection_bad_input_eager_and_jit():
    from tests.helpers import raises_both

    plate = _plate()
    pts = jnp.asarray([[0.6, 0.3, 0.5], [np.nan, 0.0, 0.0]])
    raises_both(lambda p: basis.closest_points(plate, p, jnp.full((2, 2), 0.5)).params, pts, match="points")
    raises_both(lambda p: basis.project(plate, p), pts, match="points")
    raises_both(lambda p: _deviation.closest_parameters(plate, p)[1], pts, match="points")
    good = pts.at[1, 0].set(0.0)
    raises_both(lambda uv: basis.project(plate, good, uv), jnp.asarray([[0.5, 0.5], [1.5, 0.2]]), match="uv0")
    raises_both(lambda p: basis.closest_points(plate, p[:, :2]).params, good, match="points")
    with pytest.raises(TypeError, match="solver"):
        basis.closest_points(plate, good, None, 3)
