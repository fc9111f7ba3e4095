"""bsjax.sketch against independent references: scipy's design matrix (normal equations with
fixed ends), geomdl's approximation, closed forms (regular polygons, L/square strokes, rays)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import BSpline

from bsjax import collide, sketch
from bsjax.basis import BSplineCurve, clamped_knots
from tests.helpers import check_grad, raises_both

N, N_CTRL = 40, 8  # one stroke shape for the fit tests (one compilation)


def wavy(rng, n=N, d=2, noise=1e-3):
    t = np.linspace(0.0, 1.0, n)
    cols = [np.cos(3 * t), np.sin(2 * t), 0.5 * t**2][:d]
    return np.stack(cols, 1) + noise * rng.normal(size=(n, d))


def reference_fit(points, n_ctrl, degree, fix_ends):
    """Chord-length parameters, averaged knots (NURBS Book eqs. 9.68–9.69) and the normal
    equations built from scipy's design matrix (eq. 4-22), in numpy."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    t = np.concatenate([[0.0], np.cumsum(steps)]) / steps.sum()
    m1 = len(points)
    d = m1 / (n_ctrl - degree)
    inner = []
    for j in range(1, n_ctrl - degree):
        i = int(j * d)
        a = j * d - i
        inner.append((1 - a) * t[i - 1] + a * t[i])
    knots = np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])
    n_mat = BSpline.design_matrix(t, knots, degree).toarray()
    if not fix_ends:
        return np.linalg.solve(n_mat.T @ n_mat, n_mat.T @ points), knots
    q = points[1:-1] - np.outer(n_mat[1:-1, 0], points[0]) - np.outer(n_mat[1:-1, -1], points[-1])
    a = n_mat[1:-1, 1:-1]
    inner_ctrl = np.linalg.solve(a.T @ a, a.T @ q)
    return np.vstack([points[0], inner_ctrl, points[-1]]), knots


@pytest.mark.parametrize("fix_ends", [True, False])
def test_fit_equals_normal_equations_of_scipy_design_matrix(fix_ends):
    points = wavy(np.random.default_rng(0))
    fit = sketch.fit_curve(points, N_CTRL, fix_ends=fix_ends)
    ctrl, knots = reference_fit(points, N_CTRL, 3, fix_ends)
    np.testing.assert_allclose(np.asarray(fit.curve.knots), knots, atol=1e-12)
    np.testing.assert_allclose(np.asarray(fit.curve.ctrl), ctrl, atol=1e-10)
    spline = BSpline(knots, ctrl, 3)
    np.testing.assert_allclose(
        np.asarray(fit.residuals), np.linalg.norm(spline(np.asarray(fit.params)) - points, axis=1), atol=1e-10
    )
    if fix_ends:  # the ends are interpolated exactly
        np.testing.assert_allclose(np.asarray(fit.curve.evaluate(jnp.array([0.0, 1.0]))), points[[0, -1]])


def test_fit_error_comparable_to_geomdl():
    from geomdl import fitting

    points = wavy(np.random.default_rng(1), d=3, noise=2e-3)
    ours = sketch.fit_curve(points, N_CTRL)
    theirs = fitting.approximate_curve(points.tolist(), 3, ctrlpts_size=N_CTRL)
    dense_t = np.linspace(0, 1, 2001)
    dense = np.asarray(theirs.evaluate_list(dense_t.tolist()))
    theirs_err = np.min(np.linalg.norm(points[:, None] - dense[None], axis=2), axis=1).max()
    ours_dense = np.asarray(ours.curve.evaluate(dense_t))
    ours_err = np.min(np.linalg.norm(points[:, None] - ours_dense[None], axis=2), axis=1).max()
    assert ours_err <= 1.5 * theirs_err
    assert ours_err < 0.05  # and both are real fits of the stroke


def test_fit_jit_vmap_grad():
    rng = np.random.default_rng(2)
    points = jnp.asarray(wavy(rng))
    direct = sketch.fit_curve(points, N_CTRL).curve.ctrl
    jitted = jax.jit(lambda p: sketch.fit_curve(p, N_CTRL).curve.ctrl)(points)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(direct), atol=1e-12)
    batch = jnp.stack([points, points + 0.1])
    mapped = jax.vmap(lambda p: sketch.fit_curve(p, N_CTRL).curve.ctrl)(batch)
    np.testing.assert_allclose(np.asarray(mapped[1]), np.asarray(direct) + 0.1, atol=1e-10)
    check_grad(lambda p: jnp.sum(sketch.fit_curve(p, N_CTRL).curve.ctrl ** 2), points, rtol=1e-4)


def test_features_regular_polygon_closed_form():
    r, n = 2.0, 24
    th = np.linspace(0, np.pi, n)  # samples on a half circle: a regular polygon's vertices
    points = r * np.stack([np.cos(th), np.sin(th)], 1)
    f = sketch.features(points, np.linspace(0, 3, n))
    h = 2 * r * np.sin(np.pi / (2 * (n - 1)))  # chord
    turn = np.pi / (n - 1)
    assert float(f.length) == pytest.approx((n - 1) * h, rel=1e-12)
    np.testing.assert_allclose(np.asarray(f.turning[1:-1]), turn, rtol=1e-10)
    # eq. 4-1 with k = 2: 4 turns over 4 chords (samples far enough from the ends)
    np.testing.assert_allclose(np.asarray(f.curvature[2:-3]), turn / h, rtol=1e-10)
    np.testing.assert_allclose(
        np.asarray(f.speed[1:-1]), 2 * r * np.sin(turn) / (2 * 3 / (n - 1)), rtol=1e-10
    )
    assert float(f.mean_speed) == pytest.approx((n - 1) * h / 3, rel=1e-12)


def l_stroke(n=25, slow=True):
    a = np.linspace(0, 1, n)
    points = np.concatenate([np.stack([a, 0 * a], 1), np.stack([np.ones(n - 1), a[1:]], 1)])
    dt = np.ones(2 * n - 2)
    if slow:  # the pen slows down around the corner (sample n - 1)
        dt[n - 5 : n + 3] = 6.0
    return points, np.concatenate([[0.0], np.cumsum(dt)])


def test_corners_of_l_and_square_strokes_not_of_a_circle():
    points, times = l_stroke()
    assert np.flatnonzero(np.asarray(sketch.corners(points, times))).tolist() == [24]
    # the same geometry drawn at constant speed: no slow-down, so no corner with times …
    steady = np.arange(len(points), dtype=float)
    assert not np.asarray(sketch.corners(points, steady)).any()
    # … but curvature alone (no times) still finds it
    assert np.flatnonzero(np.asarray(sketch.corners(points))).tolist() == [24]
    a = np.linspace(0, 1, 13)[:-1]
    sq = np.concatenate(
        [np.stack([a, 0 * a], 1), np.stack([1 + 0 * a, a], 1), np.stack([1 - a, 1 + 0 * a], 1)]
    )
    sq = np.concatenate([sq, [[0.0, 1.0]]])
    assert np.flatnonzero(np.asarray(sketch.corners(sq))).tolist() == [12, 24]
    th = np.linspace(0, 2 * np.pi, 49)
    noise = 1e-3 * np.random.default_rng(3).normal(size=(49, 2))
    circle = np.stack([np.cos(th), np.sin(th)], 1) + noise
    assert not np.asarray(sketch.corners(circle, np.linspace(0, 1, 49))).any()


def test_resample_keeps_ends_and_corners_and_thins_a_noisy_stroke():
    rng = np.random.default_rng(4)
    points, times = l_stroke(60)
    noisy = 100 * points + 0.2 * rng.normal(size=points.shape)  # "pixels"
    out = sketch.resample(noisy, times)
    assert out.index[0] == 0 and out.index[-1] == len(noisy) - 1
    assert 5 < len(out.index) < len(noisy) / 2
    assert np.all(np.diff(out.index) > 0)
    np.testing.assert_array_equal(out.points, noisy[out.index])
    np.testing.assert_array_equal(out.times, times[out.index])
    corner = np.flatnonzero(np.asarray(sketch.corners(noisy, times)))
    assert set(corner.tolist()) <= set(out.index.tolist())
    # eqs. 4-2 / 4-3 step by step (numpy): slow → index step round(2 S/S_avg + 0.5), fast → spacing 7 S/S_avg
    f = sketch.features(noisy, times)
    rel = np.asarray(f.speed) / float(f.mean_speed)
    forced = set(corner.tolist()) | {len(noisy) - 1}
    for i, j in zip(out.index[:-1], out.index[1:]):
        if j in forced:
            continue
        if rel[i] < 1.0:
            assert j - i == max(1, int(np.floor(2 * rel[i] + 1.0)))
        else:
            assert np.linalg.norm(noisy[j] - noisy[i]) >= 7 * rel[i]
            assert np.linalg.norm(noisy[j - 1] - noisy[i]) < 7 * rel[i] or j - 1 == i
    # a larger unit (coarser pixels) keeps fewer samples
    assert len(sketch.resample(noisy, times, unit=3.0).index) < len(out.index)


def test_fit_stroke_splits_at_the_corner_with_fewest_control_points():
    points, times = l_stroke()
    tol = 1e-3
    curves = sketch.fit_stroke(points, times, tol=tol)
    assert len(curves) == 2
    np.testing.assert_allclose(np.asarray(curves[0].evaluate(1.0)), [1.0, 0.0], atol=1e-12)  # C0 join
    np.testing.assert_allclose(np.asarray(curves[1].evaluate(0.0)), [1.0, 0.0], atol=1e-12)
    for curve, piece in zip(curves, (points[:25], points[24:])):
        dense = np.asarray(curve.evaluate(np.linspace(0, 1, 20001)))
        err = np.min(np.linalg.norm(piece[:, None] - dense[None], axis=2), axis=1).max()
        assert err <= tol  # (dense sampling adds at most 1/40000 to the distance)
        assert curve.n_ctrl == 4  # a straight piece needs only one cubic segment


def straight(n=10):
    x = np.linspace(0, 1, n)
    return BSplineCurve(np.stack([x, 0 * x], 1), clamped_knots(n, 3), 3)


def bump_stroke():
    s = np.linspace(0.3, 0.7, 8)
    return BSplineCurve(np.stack([s, 0.1 * np.sin(np.pi * (s - 0.3) / 0.4)], 1), clamped_knots(8, 3), 3)


def test_oversketch_scale_zero_one_and_outside_the_span():
    curve, stroke = straight(), bump_stroke()
    t = np.linspace(0, 1, 401)
    old = np.asarray(curve.evaluate(t))
    zero = sketch.oversketch(curve, stroke, 0.0)
    np.testing.assert_allclose(np.asarray(zero.curve.evaluate(t)), old, atol=1e-12)
    one = sketch.oversketch(curve, stroke, 1.0)
    assert 0.0 <= one.start < 0.3 and 0.7 < one.end <= 1.0
    new = np.asarray(one.curve.evaluate(t))
    outside = (t < one.start) | (t > one.end)
    np.testing.assert_allclose(new[outside], old[outside], atol=1e-12)
    inner = np.asarray(stroke.evaluate(np.linspace(0.05, 0.95, 40)))
    assert np.min(np.linalg.norm(inner[:, None] - new[None], axis=2), axis=1).max() < 2e-3
    half = np.asarray(sketch.oversketch(curve, stroke, 0.5).curve.evaluate(t))
    np.testing.assert_allclose(half, 0.5 * (old + new), atol=1e-12)  # eq. 4-23 is linear in scale


def test_oversketch_closed_curve():
    n = 12
    th = 2 * np.pi * np.arange(n) / n
    loop = BSplineCurve(np.stack([np.cos(th), np.sin(th)], 1), None, 3, periodic=True)
    a = np.linspace(0.2, 1.0, 8)
    stroke = BSplineCurve(np.stack([1.2 * np.cos(a), 1.2 * np.sin(a)], 1), clamped_knots(8, 3), 3)
    t = np.linspace(0, 1, 400)
    zero = np.asarray(sketch.oversketch(loop, stroke, 0.0).curve.evaluate(t))
    # the same closed curve, clamped at a seam moved by whole control points: C0(t) = C(t + k/n)
    shifted = [np.asarray(loop.evaluate(np.mod(t + k / n, 1.0))) for k in range(n)]
    assert min(np.abs(zero - s).max() for s in shifted) < 1e-12
    edited = sketch.oversketch(loop, stroke, 1.0).curve
    np.testing.assert_allclose(np.asarray(edited.evaluate(0.0)), np.asarray(edited.evaluate(1.0)), atol=1e-12)
    inner = np.asarray(stroke.evaluate(np.linspace(0.1, 0.9, 30)))
    dense = np.asarray(edited.evaluate(t))
    assert np.min(np.linalg.norm(inner[:, None] - dense[None], axis=2), axis=1).max() < 1e-2


def test_unproject_lands_on_plane_and_camera_ray():
    eye, target, up = np.array([0.3, -5.0, 1.0]), np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, 1.0])
    fov, aspect = 0.8, 1.5
    camera = sketch.Camera(eye, target, up, fov, aspect)
    plane = collide.Plane([0.0, 0.2, 0.0], [0.1, 1.0, 0.2])
    xy = np.array([[0.5, 0.5], [0.1, 0.9], [0.7, 0.2]])
    x = np.asarray(sketch.unproject(xy, camera, plane))
    n = np.array([0.1, 1.0, 0.2]) / np.linalg.norm([0.1, 1.0, 0.2])
    np.testing.assert_allclose((x - [0.0, 0.2, 0.0]) @ n, 0.0, atol=1e-12)
    # the look-at frame in numpy: pixel (x, y) ↦ f + (2x−1) tan(fov/2) aspect r + (2y−1) tan(fov/2) u
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, up) / np.linalg.norm(np.cross(f, up))
    u = np.cross(r, f)
    h = np.tan(fov / 2)
    rays = f + (2 * xy[:, :1] - 1) * h * aspect * r + (2 * xy[:, 1:] - 1) * h * u
    np.testing.assert_allclose(np.cross(x - eye, rays), 0.0, atol=1e-12)
    assert np.all(np.sum((x - eye) * rays, axis=1) > 0)
    # batched shape and the user's jit
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 1, 2)), -1)
    assert sketch.unproject(grid, camera, plane).shape == (2, 3, 3)
    np.testing.assert_allclose(np.asarray(jax.jit(sketch.unproject)(xy, camera, plane)), x, atol=1e-12)


# --- bad input ----------------------------------------------------------------------------------
def test_bad_strokes():
    points = wavy(np.random.default_rng(5))
    with pytest.raises(ValueError, match="points: expected at least 2 samples"):
        sketch.fit_curve(points[:1], 2, 1)
    with pytest.raises(ValueError, match="n_ctrl: expected at most the 5 stroke samples"):
        sketch.fit_curve(points[:5], 8)
    with pytest.raises(
        ValueError, match="params: expected one of 'chord', 'centripetal', 'uniform', got 'arc'"
    ):
        sketch.fit_curve(points, N_CTRL, params="arc")
    with pytest.raises(ValueError, match="points: expected at least 3 samples"):
        sketch.features(points[:2])
    with pytest.raises(ValueError, match="points: expected stroke samples of dimension 2 or 3"):
        sketch.features(np.zeros((5, 4)))
    bad = points.copy()
    bad[3, 1] = np.nan
    raises_both(lambda p: sketch.fit_curve(p, N_CTRL).curve.ctrl, bad, match="points: expected finite")
    raises_both(lambda p: sketch.fit_curve(p, N_CTRL).curve.ctrl, 0 * points, match="nonzero length")
    raises_both(lambda p: sketch.features(p).length, bad, match="points: expected finite")
    times = np.linspace(0, 1, N)[::-1].copy()
    raises_both(lambda p, t: sketch.corners(p, t), points, times, match="times: expected strictly increasing")
    raises_both(lambda p, c: sketch.corners(p, None, 2, c), points, -1.0, match="curvature_factor: expected")


def test_bad_oversketch_and_unproject():
    with pytest.raises(ValueError, match=r"scale: expected values in \[0.0, 1.0\]"):
        sketch.oversketch(straight(), bump_stroke(), 1.5)
    with pytest.raises(TypeError, match="stroke_curve: expected a BSplineCurve"):
        sketch.oversketch(straight(), np.zeros((4, 2)))  # type: ignore[arg-type]
    camera = sketch.Camera([0.0, -5.0, 0.0], [0.0, 0.0, 0.0])
    side = collide.Plane([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])  # contains the view direction
    raises_both(
        lambda xy: sketch.unproject(xy, camera, side),
        np.array([[0.5, 0.5]]),
        match="window_xy: expected points",
    )
    plane = collide.Plane([0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    raises_both(lambda xy: sketch.unproject(xy, camera, plane), np.array([[np.nan, 0.5]]), match="finite")
    with pytest.raises(ValueError, match="fov: expected an angle"):
        sketch.Camera([0.0, -5.0, 0.0], [0.0, 0.0, 0.0], fov=4.0)
