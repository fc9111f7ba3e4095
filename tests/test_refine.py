"""Knot insertion, degree elevation and degree reduction of surfaces and curves against geomdl
and scipy."""

import copy

import numpy as np
import pytest
from geomdl import NURBS as GNURBS
from geomdl import BSpline as GBSpline
from geomdl import helpers as ghelpers
from geomdl import operations
from scipy.interpolate import BSpline

from bsjax.basis import (
    BSplineCurve,
    BSplineSurface,
    clamped_knots,
    elevate_degree,
    insert_knots,
    reduce_degree,
)
from tests.helpers import random_knots
from tests.oracles import geomdl_surface, ndbspline_surface

R, S = 7, 6


def _surface(rng, k=3, l=2, weights=False, r=R, s=S):
    w = rng.uniform(0.5, 2.0, (r, s)) if weights else None
    return BSplineSurface(
        rng.normal(size=(r, s, 3)), random_knots(rng, r, k), random_knots(rng, s, l), k, l, weights=w
    )


def _dense(rng, count=400):
    u = np.concatenate([rng.uniform(0, 1, count), [0.0, 1.0, 1.0, 0.5]])
    v = np.concatenate([rng.uniform(0, 1, count), [1.0, 0.0, 1.0, 0.5]])
    return u, v


def _same_geometry(a, b, rng, atol=1e-12):
    u, v = _dense(rng)
    for nu, nv in ((0, 0), (1, 0), (0, 1)):
        ra, rb = ndbspline_surface(a, u, v, nu, nv), ndbspline_surface(b, u, v, nu, nv)
        np.testing.assert_allclose(rb, ra, rtol=0, atol=atol * max(1.0, np.abs(ra).max()))


def _geomdl_net(g, weights):
    r, s = g.ctrlpts_size_u, g.ctrlpts_size_v
    pts = np.asarray(g.ctrlpts).reshape(r, s, 3)
    w = np.asarray(g.weights).reshape(r, s) if weights else None
    return pts, w


@pytest.mark.parametrize("direction, weights", [("u", False), ("v", True)])
def test_insert_knots_matches_geomdl_and_keeps_geometry(direction, weights):
    rng = np.random.default_rng(1 + weights)
    surface = _surface(rng, weights=weights)
    values = [0.31, 0.77, 0.77]
    refined = insert_knots(surface, direction, values)
    old = np.asarray(getattr(surface, f"knots_{direction}"))
    np.testing.assert_array_equal(
        getattr(refined, f"knots_{direction}"), np.sort(np.concatenate([old, values]))
    )
    assert refined.shape == ((R + 3, S) if direction == "u" else (R, S + 3))
    _same_geometry(surface, refined, rng)
    g = geomdl_surface(surface)
    for value, count in ((0.31, 1), (0.77, 2)):
        g = copy.deepcopy(g)
        operations.insert_knot(
            g,
            [value, None] if direction == "u" else [None, value],
            [count, 0] if direction == "u" else [0, count],
        )
    pts, w = _geomdl_net(g, weights)
    np.testing.assert_allclose(refined.ctrl, pts, rtol=0, atol=1e-12)
    if weights:
        np.testing.assert_allclose(refined.weights, w, rtol=0, atol=1e-12)


@pytest.mark.parametrize("weights, times", [(False, 1), (True, 2)])
def test_elevate_bezier_direction_matches_geomdl(weights, times):
    """u is a single Bézier segment (r = k + 1): the NURBS Book elevation formula, per column."""
    rng = np.random.default_rng(10 + times)
    k = 3
    surface = BSplineSurface(
        rng.normal(size=(k + 1, S, 3)),
        clamped_knots(k + 1, k),
        random_knots(rng, S, 2),
        k,
        2,
        weights=rng.uniform(0.5, 2.0, (k + 1, S)) if weights else None,
    )
    up = elevate_degree(surface, "u", times)
    assert up.degree_u == k + times and up.shape == (k + 1 + times, S)
    w = np.ones((k + 1, S)) if not weights else np.asarray(surface.weights)
    hom = np.concatenate([np.asarray(surface.ctrl) * w[..., None], w[..., None]], -1)
    for j in range(S):
        ref = np.asarray(ghelpers.degree_elevation(k, hom[:, j].tolist(), num=times))
        np.testing.assert_allclose(np.asarray(up.ctrl)[:, j], ref[:, :3] / ref[:, 3:], rtol=0, atol=1e-12)
        if weights:
            np.testing.assert_allclose(np.asarray(up.weights)[:, j], ref[:, 3], rtol=0, atol=1e-12)
    _same_geometry(surface, up, rng)


@pytest.mark.parametrize("direction, weights", [("u", True), ("v", False)])
def test_elevate_degree_keeps_geometry_and_continuity(direction, weights):
    rng = np.random.default_rng(20 + weights)
    surface = _surface(rng, k=2, l=3, weights=weights)
    up = elevate_degree(surface, direction, 2)
    old = np.asarray(getattr(surface, f"knots_{direction}"))
    values, counts = np.unique(old, return_counts=True)
    np.testing.assert_array_equal(getattr(up, f"knots_{direction}"), np.repeat(values, counts + 2))
    assert getattr(up, f"degree_{direction}") == getattr(surface, f"degree_{direction}") + 2
    _same_geometry(surface, up, rng, atol=1e-11)
    # second derivatives, too (the elevated space contains the old one exactly)
    u, v = _dense(rng, 50)
    nu, nv = (2, 0) if direction == "u" else (0, 2)
    ref = ndbspline_surface(surface, u, v, nu, nv)
    np.testing.assert_allclose(
        ndbspline_surface(up, u, v, nu, nv), ref, rtol=0, atol=1e-9 * np.abs(ref).max()
    )


def test_elevated_coefficients_equal_scipy_least_squares_fit():
    """The elevated net is the unique exact representation: scipy's LSQ spline fit finds it too."""
    from scipy.interpolate import make_lsq_spline

    rng = np.random.default_rng(30)
    surface = _surface(rng, k=3, l=2)
    up = elevate_degree(surface, "u")
    x = np.linspace(0, 1, 200)
    for j in (0, S // 2, S - 1):  # a column of the net is a curve in u at a fixed v-index
        column = BSplineSurface(np.asarray(surface.ctrl), surface.knots_u, surface.knots_v, 3, 2)
        samples = ndbspline_surface(column.with_ctrl(_column_only(surface.ctrl, j)), x, np.zeros_like(x))
        fit = make_lsq_spline(x, samples, np.asarray(up.knots_u), k=4)
        np.testing.assert_allclose(np.asarray(up.ctrl)[:, j], fit.c, rtol=0, atol=1e-10)


def _column_only(ctrl, j):
    """A net whose v = 0 boundary curve is column `j` of `ctrl` (so S(u, 0) is that column's curve)."""
    out = np.zeros(np.shape(ctrl))
    out[:, 0] = np.asarray(ctrl)[:, j]
    return out


@pytest.mark.parametrize("direction, weights", [("u", False), ("v", True)])
def test_reduce_after_elevate_is_exact(direction, weights):
    rng = np.random.default_rng(40 + weights)
    surface = _surface(rng, k=3, l=3, weights=weights)
    up = elevate_degree(surface, direction)
    down, err = reduce_degree(up, direction)
    assert getattr(down, f"degree_{direction}") == 3
    assert err < 1e-12
    _same_geometry(surface, down, rng, atol=1e-11)


@pytest.mark.parametrize("direction", ["u", "v"])
def test_reduce_degree_reports_the_measured_error(direction):
    rng = np.random.default_rng(50)
    surface = _surface(rng, k=4, l=4)
    down, err = reduce_degree(surface, direction)
    assert getattr(down, f"degree_{direction}") == 3
    assert down.shape == ((R - 1, S) if direction == "u" else (R, S - 1))  # end multiplicity drops by 1
    g64, g127 = np.linspace(0, 1, 64), np.linspace(0, 1, 127)  # the 127-grid contains the 64-grid

    def deviation(g):
        u, v = np.meshgrid(g, g, indexing="ij")
        return np.linalg.norm(ndbspline_surface(surface, u, v) - ndbspline_surface(down, u, v), axis=-1).max()

    assert err > 1e-4  # a generic quartic is not cubic
    np.testing.assert_allclose(err, deviation(g64), rtol=1e-10)
    assert err <= deviation(g127) * (1 + 1e-12) and deviation(g127) <= 1.5 * err


def test_reduce_twice_and_errors_grow():
    rng = np.random.default_rng(51)
    surface = _surface(rng, k=4, l=2, r=9)
    _, e1 = reduce_degree(surface, "u", 1)
    down2, e2 = reduce_degree(surface, "u", 2)
    assert down2.degree_u == 2 and e2 >= e1 > 0


@pytest.mark.parametrize(
    "call",
    [
        lambda s: insert_knots(s, "w", [0.5]),
        lambda s: elevate_degree(s, "x"),
        lambda s: reduce_degree(s, 0),
    ],
)
def test_bad_direction_names_the_argument(call):
    with pytest.raises(ValueError, match="direction"):
        call(_surface(np.random.default_rng(0)))


def test_refine_argument_errors():
    surface = _surface(np.random.default_rng(0))
    with pytest.raises(ValueError, match="values"):
        insert_knots(surface, "u", [1.0])
    with pytest.raises(ValueError, match="values"):
        insert_knots(surface, "u", [np.nan])
    with pytest.raises(ValueError, match="values"):
        insert_knots(surface, "v", [0.5, 0.5, 0.5])  # multiplicity 3 > degree 2
    with pytest.raises(ValueError, match="times"):
        elevate_degree(surface, "u", 0)
    with pytest.raises(ValueError, match="times"):
        reduce_degree(surface, "v", 2)  # degree 2 cannot go to 0
    closed = BSplineSurface(surface.ctrl, surface.knots_u, None, 3, 2, periodic_v=True)
    with pytest.raises(ValueError, match="direction"):
        insert_knots(closed, "v", [0.5])


# --- curves: the same change of basis along the curve's only axis ------------------------------
def _curve(rng, n=8, k=3, d=3, weights=False):
    w = rng.uniform(0.5, 2.0, n) if weights else None
    return BSplineCurve(rng.normal(size=(n, d)), random_knots(rng, n, k), k, weights=w)


def _scipy_curve(curve, t, nu=0):
    """Points (nu = 0) or the first derivative (nu = 1) from scipy, through homogeneous
    coordinates when rational (independent of bsjax's evaluator)."""
    ctrl, w = np.asarray(curve.ctrl), curve.weights
    if w is None:
        return BSpline(np.asarray(curve.knots), ctrl, curve.degree)(t, nu)
    w = np.asarray(w)
    h = BSpline(np.asarray(curve.knots), np.c_[ctrl * w[:, None], w], curve.degree)
    h0, c0 = h(t), h(t)[:, :-1] / h(t)[:, -1:]
    if nu == 0:
        return c0
    h1 = h(t, 1)
    return (h1[:, :-1] - h1[:, -1:] * c0) / h0[:, -1:]


def _same_curve(a, b, atol=1e-12):
    t = np.concatenate([np.linspace(0, 1, 301), np.random.default_rng(7).uniform(0, 1, 100)])
    for nu in (0, 1):
        ra = _scipy_curve(a, t, nu)
        np.testing.assert_allclose(_scipy_curve(b, t, nu), ra, rtol=0, atol=atol * max(1.0, np.abs(ra).max()))


@pytest.mark.parametrize("d, weights", [(2, False), (3, True)])
def test_curve_insert_knots_matches_geomdl_and_keeps_the_curve(d, weights):
    rng = np.random.default_rng(60 + d)
    curve = _curve(rng, d=d, weights=weights)
    values = [0.31, 0.77, 0.77]
    refined = insert_knots(curve, values)
    assert isinstance(refined, BSplineCurve) and refined.n_ctrl == curve.n_ctrl + 3
    np.testing.assert_array_equal(refined.knots, np.sort(np.r_[np.asarray(curve.knots), values]))
    _same_curve(curve, refined)
    g = GNURBS.Curve() if weights else GBSpline.Curve()
    g.degree = curve.degree
    ctrl = np.asarray(curve.ctrl)
    if weights:
        w = np.asarray(curve.weights)
        g.ctrlptsw = np.c_[ctrl * w[:, None], w].tolist()
    else:
        g.ctrlpts = ctrl.tolist()
    g.knotvector = np.asarray(curve.knots).tolist()
    for value, count in ((0.31, 1), (0.77, 2)):
        operations.insert_knot(g, [value], [count])
    np.testing.assert_allclose(refined.ctrl, np.asarray(g.ctrlpts), rtol=0, atol=1e-12)
    if weights:
        np.testing.assert_allclose(refined.weights, np.asarray(g.weights), rtol=0, atol=1e-12)
    assert insert_knots(curve, values=[0.5]).n_ctrl == curve.n_ctrl + 1  # keyword form


@pytest.mark.parametrize("weights, times", [(False, 1), (True, 2)])
def test_curve_elevate_bezier_matches_geomdl(weights, times):
    rng = np.random.default_rng(70 + times)
    k = 3
    w = rng.uniform(0.5, 2.0, k + 1) if weights else np.ones(k + 1)
    curve = BSplineCurve(
        rng.normal(size=(k + 1, 2)), clamped_knots(k + 1, k), k, weights=w if weights else None
    )
    up = elevate_degree(curve, times)
    assert up.degree == k + times and up.n_ctrl == k + 1 + times
    hom = np.c_[np.asarray(curve.ctrl) * w[:, None], w]
    ref = np.asarray(ghelpers.degree_elevation(k, hom.tolist(), num=times))
    np.testing.assert_allclose(up.ctrl, ref[:, :2] / ref[:, 2:], rtol=0, atol=1e-12)
    if weights:
        np.testing.assert_allclose(up.weights, ref[:, 2], rtol=0, atol=1e-12)
    _same_curve(curve, up)


@pytest.mark.parametrize("d, weights", [(2, True), (3, False)])
def test_curve_elevate_keeps_the_curve_and_reduce_undoes_it(d, weights):
    rng = np.random.default_rng(80 + d)
    curve = _curve(rng, k=2, d=d, weights=weights)
    up = elevate_degree(curve, times=2)
    values, counts = np.unique(np.asarray(curve.knots), return_counts=True)
    np.testing.assert_array_equal(up.knots, np.repeat(values, counts + 2))
    _same_curve(curve, up, atol=1e-11)
    t = np.linspace(0, 1, 50)
    np.testing.assert_allclose(up.evaluate(t, 2), curve.evaluate(t, 2), rtol=0, atol=1e-9)
    down, err = reduce_degree(up, times=2)
    assert down.degree == 2 and err < 1e-12
    _same_curve(curve, down, atol=1e-11)


def test_curve_reduce_degree_reports_the_measured_error():
    rng = np.random.default_rng(90)
    curve = _curve(rng, n=9, k=4)
    down, err = reduce_degree(curve)
    assert down.degree == 3 and down.n_ctrl == 8
    t = np.linspace(0, 1, 4001)
    dense = np.linalg.norm(_scipy_curve(curve, t) - _scipy_curve(down, t), axis=1).max()
    assert 1e-4 < err <= dense * (1 + 1e-12) and dense <= 1.05 * err


def test_curve_refine_argument_errors():
    rng = np.random.default_rng(0)
    curve = _curve(rng)
    with pytest.raises(ValueError, match="no direction for a curve"):
        insert_knots(curve, "u", [0.5])
    with pytest.raises(ValueError, match="values"):
        insert_knots(curve, [1.0])
    with pytest.raises(ValueError, match="values"):
        insert_knots(curve, [0.5, 0.5, 0.5, 0.5])  # multiplicity 4 > degree 3
    with pytest.raises(ValueError, match="times"):
        elevate_degree(curve, 0)
    with pytest.raises(ValueError, match="times"):
        reduce_degree(curve, 3)
    closed = BSplineCurve(curve.ctrl, None, 3, periodic=True)
    with pytest.raises(ValueError, match="insert_knots: curve: expected a clamped direction"):
        insert_knots(closed, [0.5])
    with pytest.raises(TypeError, match="spline: expected a BSplineSurface or a BSplineCurve"):
        elevate_degree(np.zeros((4, 3)))
