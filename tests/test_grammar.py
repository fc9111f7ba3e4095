"""bsjax.grammar: characteristic points, symbol strings, Leyton's grammar, measures, operators.

References: closed forms of exact rational ellipses and circles, scipy (BSpline derivatives,
complete and incomplete elliptic integrals, root finding), an independent brute-force
enumeration of symbol strings, and the thesis's count of 21 shapes (§7.1).
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.interpolate as si
import scipy.optimize as so
import scipy.special as sp

from bsjax import grammar
from bsjax.basis import BSplineCurve, clamped_knots
from tests.helpers import raises_both

W = np.sqrt(0.5)
QUARTERS = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]


def ellipse_ctrl(a, b):
    return np.array([[a, 0], [a, b], [0, b], [-a, b], [-a, 0], [-a, -b], [0, -b], [a, -b], [a, 0]], float)


def ellipse(a=2.0, b=1.0, clockwise=False):
    """The exact rational quadratic ellipse x = a cos θ, y = b sin θ (9 control points)."""
    ctrl = ellipse_ctrl(a, b)
    weights = np.array([1, W, 1, W, 1, W, 1, W, 1])
    if clockwise:
        ctrl = ctrl * np.array([1.0, -1.0])
    return BSplineCurve(ctrl, QUARTERS, 2, weights=weights)


def peanut(n=24):
    """A periodic cubic peanut: two indentations, "M+0m-0M+0m-0"."""
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1 + 0.6 * np.cos(2 * th)
    return BSplineCurve(np.c_[r * np.cos(th), 0.7 * r * np.sin(th)], None, 3, periodic=True)


def s_curve():
    """An open clamped cubic with inflections and extrema in the interior."""
    x = np.linspace(0, 4, 8)
    y = np.array([0, 1.2, 0.4, -0.9, -0.2, 1.1, 0.3, 0.8])
    return BSplineCurve(np.c_[x, y], clamped_knots(8, 3), 3)


def ellipse_kappa(a, b, theta):
    return a * b / (a**2 * np.sin(theta) ** 2 + b**2 * np.cos(theta) ** 2) ** 1.5


# --- characteristic points --------------------------------------------------------------------
@pytest.mark.parametrize("a, b", [(2.0, 1.0), (1.5, 0.6)])
def test_ellipse_extrema_at_axis_ends(a, b):
    points = grammar.characteristic_points(ellipse(a, b), closed=True)
    n = int(points.count)
    assert n == 4 and not bool(points.overflow)
    assert points.symbols() == ["M+", "m+", "M+", "m+"]
    np.testing.assert_allclose(points.params[:n], [0, 0.25, 0.5, 0.75], atol=1e-9)
    np.testing.assert_allclose(points.curvature[:n], [a / b**2, b / a**2] * 2, rtol=1e-12)


def test_closed_rule_and_clockwise_ellipse():
    assert grammar.is_closed(ellipse()) and grammar.is_closed(peanut())
    assert not grammar.is_closed(s_curve())
    assert grammar.symbols(ellipse()) == "M+m+M+m+"
    assert grammar.symbols(ellipse(clockwise=True)) == "M+m+M+m+"  # read counter-clockwise


def test_circle_has_no_characteristic_points():
    circle = ellipse(1.3, 1.3)
    assert int(grammar.characteristic_points(circle, closed=True).count) == 0
    assert grammar.symbols(circle) == ""  # constant curvature: the empty string


def _scipy_reference(curve, n=40001):
    """Parameters of κ sign changes and κ' sign changes of a polynomial clamped curve (scipy)."""
    spline = si.BSpline(np.asarray(curve.knots), np.asarray(curve.ctrl), curve.degree)
    t = np.linspace(0, 1, n)
    d1, d2, d3 = spline(t, 1), spline(t, 2), spline(t, 3)
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    speed2 = np.sum(d1 * d1, axis=1)
    slope = (d1[:, 0] * d3[:, 1] - d1[:, 1] * d3[:, 0]) * speed2 - 3 * cross * np.sum(d1 * d2, axis=1)
    zeros = t[1:][np.diff(np.sign(cross)) != 0]
    extrema = t[1:][np.diff(np.sign(slope)) != 0]
    return np.sort(np.concatenate([zeros, extrema])), cross


def test_open_curve_points_match_scipy():
    curve = s_curve()
    points = grammar.characteristic_points(curve)
    n = int(points.count)
    expected, _ = _scipy_reference(curve)
    assert n == len(expected)
    np.testing.assert_allclose(points.params[:n], expected, atol=5e-5)
    kappa = np.asarray(curve.curvature(points.params[:n]))
    np.testing.assert_allclose(points.curvature[:n], kappa, atol=1e-12)
    assert grammar.is_valid(grammar.symbols(curve), closed=False)


def test_peanut_and_invariance():
    base = peanut()
    assert grammar.symbols(base) == "M+0m-0M+0m-0"
    ctrl = np.asarray(base.ctrl)
    rot = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    moved = BSplineCurve(3.0 * ctrl @ rot.T + np.array([5.0, -2.0]), None, 3, periodic=True)
    shifted = BSplineCurve(np.roll(ctrl, 5, axis=0), None, 3, periodic=True)
    mirrored = BSplineCurve(ctrl * np.array([-1.0, 1.0]), None, 3, periodic=True)
    for curve in (moved, shifted, mirrored):
        assert grammar.symbols(curve) == "M+0m-0M+0m-0"


def test_interpolation_ripple_is_merged():
    th = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    curve = BSplineCurve(np.c_[2 * np.cos(th), np.sin(th)], None, 3, periodic=True)
    raw = grammar.characteristic_points(curve)
    assert int(raw.count) > 4  # the spline's own ripple
    assert grammar.symbols(curve) == "M+m+M+m+"
    assert int(grammar.simplify(raw).count) == 4


def test_overflow_flag():
    points = grammar.characteristic_points(peanut(), capacity=3)
    assert bool(points.overflow) and int(points.count) == 3
    with pytest.raises(ValueError, match="capacity"):
        grammar.symbols(peanut(), capacity=3)


def _closed_points(curve):
    return grammar.characteristic_points(curve, closed=True)


def test_jit_and_vmap():
    curve = ellipse()
    eager = grammar.characteristic_points(curve, closed=True)
    jitted = jax.jit(_closed_points)(curve)  # the program test_bad_input's NaN net raises in
    np.testing.assert_allclose(jitted.params, eager.params, atol=1e-14)
    batch = jax.vmap(lambda ctrl: grammar.characteristic_points(curve.with_ctrl(ctrl), closed=True))(
        jnp.stack([ellipse_ctrl(2.0, 1.0), ellipse_ctrl(1.0, 3.0)])
    )
    np.testing.assert_allclose(batch.curvature[:, :4], [[2, 0.25] * 2, [1 / 9, 3] * 2], rtol=1e-12)
    with pytest.raises(TypeError, match="closed"):
        jax.jit(grammar.characteristic_points)(curve)


def test_bad_input():
    curve = ellipse()
    space = BSplineCurve(np.c_[ellipse_ctrl(2, 1), np.zeros(9)], QUARTERS, 2)
    with pytest.raises(ValueError, match="curve: expected a planar curve"):
        grammar.characteristic_points(space)
    with pytest.raises(ValueError, match="curve: expected a planar curve"):
        grammar.measures(space)
    with pytest.raises(TypeError, match="capacity"):
        grammar.characteristic_points(curve, capacity=2.5)  # type: ignore[arg-type]

    def nan_measures(ctrl):
        return grammar.measures(eqx_set_ctrl(curve, ctrl), closed=True).tension

    def nan_parameters(ctrl):
        points = grammar.characteristic_points(curve, closed=True)
        return grammar.point_parameters(eqx_set_ctrl(curve, ctrl), points).d_left

    nan = ellipse_ctrl(2, 1)
    nan[3, 1] = np.nan
    # the whole curve as the argument: under jit, the program of test_jit_and_vmap
    raises_both(_closed_points, eqx_set_ctrl(curve, jnp.asarray(nan)), match="curve.ctrl: expected finite")
    for fn in (nan_measures, nan_parameters):
        raises_both(fn, jnp.asarray(nan), match="curve.ctrl: expected finite")


def eqx_set_ctrl(curve, ctrl):
    return eqx.tree_at(lambda c: c.ctrl, curve, ctrl)


# --- the grammar ------------------------------------------------------------------------------
def test_validity_rules():
    assert grammar.is_valid("M+m+M+m+")
    assert grammar.is_valid("M+0m-0M+0m-0")
    assert grammar.is_valid("m+M+m+M+")  # a rotation
    assert grammar.is_valid("")  # a circle
    assert not grammar.is_valid("M+m+")  # one M+ only
    assert not grammar.is_valid("M+M+m+m+")  # no alternation
    assert not grammar.is_valid("M+m-M+m-")  # opposite signs need a 0
    assert not grammar.is_valid("M+0m+M+m+")  # no 0 between equal signs
    assert not grammar.is_valid("M+m+M-m-")  # M- next to m+
    assert grammar.is_valid("0M+m+M+0", closed=False)
    assert not grammar.is_valid("0m+M+", closed=False)
    with pytest.raises(ValueError, match="name: expected a string of the symbols"):
        grammar.is_valid("M+x")


def _brute_force(max_extrema):
    """Every cyclic sequence of extrema (any of the four, no alternation assumed) with a 0 put
    wherever the sign changes, accepted by `is_valid`, counted modulo rotation and reversal by
    explicit orbits — independent of `canonical` and of `enumerate_shapes`'s construction."""
    seen, shapes = set(), 0
    for length in range(1, max_extrema + 1):
        for extrema in itertools.product(["M+", "m+", "M-", "m-"], repeat=length):
            seq = []
            for k, e in enumerate(extrema):
                seq.append(e)
                if e[1] != extrema[(k + 1) % length][1]:
                    seq.append("0")
            seq = tuple(seq)
            if seq in seen or not grammar.is_valid("".join(seq)):
                continue
            seen |= {tuple(s[r:] + s[:r]) for s in (seq, seq[::-1]) for r in range(len(seq))}
            shapes += 1
    return shapes


def test_enumeration_reproduces_the_thesis_count():
    assert len(grammar.enumerate_shapes(4)) == 3
    assert len(grammar.enumerate_shapes(6)) == 9
    shapes = grammar.enumerate_shapes(8)
    assert (
        len(shapes) == 21 == _brute_force(8)
    )  # "exactly twenty one different shapes, having a maximum of eight extrema"
    assert "M+m+M+m+" in shapes and "M+0m-0M+0m-0" in shapes
    assert all(grammar.is_valid(s) and grammar.canonical(s) == s for s in shapes)


def test_canonical_invariant_under_rotation_and_reversal():
    for name in grammar.enumerate_shapes(8):
        seq = grammar.tokens(name)
        for r in range(len(seq)):
            rotated = seq[r:] + seq[:r]
            assert grammar.canonical("".join(rotated)) == name
            assert grammar.canonical("".join(rotated[::-1])) == name
    assert grammar.canonical("0m-0M+", closed=False) == grammar.canonical("m-0M+0", closed=False)


@pytest.mark.parametrize("rule", sorted(grammar.RULES))
def test_rules_map_valid_to_valid_and_invert(rule):
    lhs, rhs = grammar.RULES[rule]
    applied = 0
    for name in grammar.enumerate_shapes(8):
        seq = grammar.tokens(name)
        for i, symbol in enumerate(seq):
            if symbol != lhs:
                continue
            out = grammar.apply_rule(name, rule, i)
            assert grammar.is_valid(out), (name, rule, i, out)
            assert grammar.tokens(out)[i : i + 3] == list(rhs)
            assert grammar.apply_inverse(out, rule, i) == name
            applied += 1
    assert applied > 0
    with pytest.raises(ValueError, match="index"):
        grammar.apply_rule("M+m+M+m+", rule, 2 if lhs != "M+" else 1)


def test_rule_examples_and_errors():
    assert grammar.apply_rule("M+m+M+m+", "Cm+", 1) == "M+0m-0M+m+"
    assert grammar.apply_rule("M+m+M+m+", "BM+", 0) == "M+m+M+m+M+m+"
    assert grammar.apply_inverse("0m-0M+m+M+", "Cm+", 0) == "m+M+m+M+"
    assert grammar.apply_inverse("m-0M+m+M+0", "Cm+", 5) == "m+M+m+M+"  # over the seam
    with pytest.raises(ValueError, match="rule: expected one of"):
        grammar.apply_rule("M+m+M+m+", "CM+", 0)
    with pytest.raises(ValueError, match="max_extrema"):
        grammar.enumerate_shapes(0)


# --- measures and quantitative parameters --------------------------------------------------------
def test_ellipse_measures_closed_forms():
    a, b = 2.0, 1.0
    m = grammar.measures(ellipse(a, b))
    length = 4 * a * sp.ellipe(1 - b**2 / a**2)
    np.testing.assert_allclose(float(m.length), length, rtol=1e-12)
    np.testing.assert_allclose(float(m.kappa_max), a / b**2, rtol=1e-12)
    np.testing.assert_allclose(float(m.softness), b**2 / a, rtol=1e-12)
    spread = a / b**2 - b / a**2
    np.testing.assert_allclose(float(m.tension), spread * length / (2 * np.pi), rtol=1e-10)
    np.testing.assert_allclose(float(m.tension), 2.698438, atol=1e-6)
    np.testing.assert_allclose(float(m.acceleration), spread / (length / 4), rtol=1e-10)
    np.testing.assert_allclose(float(m.flatness), 1 - b / a, atol=1e-6)
    np.testing.assert_allclose(float(m.convexity), np.pi / 4, atol=1e-6)


def test_arc_and_line_measures():
    semi = BSplineCurve(
        [[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0.0]], [0, 0, 0, 0.5, 0.5, 1, 1, 1], 2, weights=[1, W, 1, W, 1]
    )
    m = grammar.measures(semi)
    np.testing.assert_allclose([float(m.flatness), float(m.convexity)], [0.5, np.pi / 4], atol=1e-9)
    np.testing.assert_allclose([float(m.tension), float(m.softness)], [0.0, 1.0], atol=1e-9)
    flipped = grammar.measures(semi.with_ctrl(np.asarray(semi.ctrl) * np.array([1.0, -1.0])))
    np.testing.assert_allclose(float(flipped.convexity), -np.pi / 4, atol=1e-9)  # turns right
    line = BSplineCurve([[0, 0], [1, 0.5], [2, 1.0], [3, 1.5], [4, 2.0]], [0, 0, 0, 0.3, 0.6, 1, 1, 1], 2)
    m = grammar.measures(line, closed=False)
    assert float(m.flatness) == pytest.approx(1.0) and float(m.softness) > 1e12  # κ ≈ 0: unbounded


def test_point_parameters_of_ellipse():
    a, b = 2.0, 1.0
    curve = ellipse(a, b)
    params = grammar.point_parameters(curve, grammar.characteristic_points(curve, closed=True))
    quarter = a * sp.ellipe(1 - b**2 / a**2)
    np.testing.assert_allclose(params.d_left[:4], quarter, rtol=1e-10)
    np.testing.assert_allclose(params.dk_right[:4], a / b**2 - b / a**2, rtol=1e-12)
    # range of the M+ at θ = 0: arc length to where κ = (κ_max + κ_min) / 2
    half = 0.5 * (a / b**2 + b / a**2)
    theta = float(so.brentq(lambda th: ellipse_kappa(a, b, th) - half, 0, np.pi / 2))  # type: ignore[arg-type]
    # arc length of (a cos θ, b sin θ) from 0 to θ: a E(θ | 1 − b²/a²) read from the minor axis
    s = a * (sp.ellipeinc(np.pi / 2, 1 - b**2 / a**2) - sp.ellipeinc(np.pi / 2 - theta, 1 - b**2 / a**2))
    np.testing.assert_allclose(params.range_right[0], s, rtol=1e-8)
    np.testing.assert_allclose(params.range_right[0] + params.range_left[1], quarter, rtol=1e-10)
    assert np.all(np.asarray(params.symmetric())[:4])
    assert np.all(np.asarray(params.redundant_extrema(quarter * 1.01))[:4])
    assert not np.any(np.asarray(params.redundant_extrema(quarter * 0.99)))
    assert not np.any(np.asarray(params.small_visibility(1.0, 1.0)))
    assert np.all(np.asarray(params.sharp_corner(2.1 * quarter, 1.0))[:4])


# --- operators ------------------------------------------------------------------------------------
def approx_ellipse(n=16):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return BSplineCurve(np.c_[2 * np.cos(th), np.sin(th)], None, 3, periodic=True)


def _points_of(curve, closed=None):
    points = grammar.simplify(grammar.characteristic_points(curve, closed))
    return np.asarray(points.params)[: int(points.count)], points.symbols()


def test_continuation_reports_the_string_it_produced():
    curve = approx_ellipse()
    t, kinds = _points_of(curve)
    i = kinds.index("m+")
    result = grammar.continuation(curve, i, 0.8)
    assert result.before == "M+m+M+m+" and result.status == 0
    assert result.after == grammar.symbols(result.curve)  # what it produced, not the intention
    assert "m-" in result.after  # the squashing became an indentation (Cm+: m+ → 0m-0)
    neighbours = jnp.asarray([t[i - 1], t[(i + 1) % len(t)]])
    np.testing.assert_allclose(result.curve.evaluate(neighbours), curve.evaluate(neighbours), atol=1e-12)
    moved = np.asarray(result.curve.evaluate(t[i]) - curve.evaluate(t[i]))
    assert np.linalg.norm(moved) == pytest.approx(0.8, rel=1e-9)
    assert result.dof_needed == 6  # the drag and two blocked points, two coordinates each
    with pytest.raises(ValueError, match="index: expected a point of kind m\\+ or M-"):
        grammar.continuation(curve, kinds.index("M+"), 0.5)
    with pytest.raises(ValueError, match="amount"):
        grammar.bifurcation(curve, i, -1.0)


def test_sharpen_tension_straighten():
    curve = approx_ellipse()
    t, kinds = _points_of(curve)
    top = kinds.index("M+")
    sharp = grammar.sharpen(curve, top, 0.2)
    assert sharp.status == 0 and sharp.dof_needed == 10
    assert sharp.after == grammar.symbols(sharp.curve)
    assert float(sharp.curve.curvature(t[top])) > float(curve.curvature(t[top]))
    fixed = jnp.asarray([t[top - 1], t[(top + 1) % len(t)]])
    for nu in (0, 1):
        np.testing.assert_allclose(sharp.curve.evaluate(fixed, nu), curve.evaluate(fixed, nu), atol=1e-10)
    low = kinds.index("m+")
    flat = grammar.tension(curve, low, 1.0)
    assert abs(float(flat.curve.curvature(t[low]))) < 1e-9  # κ driven to 0
    assert flat.after == grammar.symbols(flat.curve)
    line = grammar.straighten(curve, low, 1.0)
    a, b, p = np.asarray(line.curve.evaluate(jnp.asarray([t[low - 1], t[(low + 1) % len(t)], t[low]])))
    u, w = b - a, p - a
    assert abs(u[0] * w[1] - u[1] * w[0]) < 1e-10  # on the chord of its neighbours


def test_open_curve_operators():
    curve = s_curve()
    before = grammar.measures(curve, closed=False)
    convex = grammar.convexify(curve, 0.5)
    assert convex.after == grammar.symbols(convex.curve, closed=False)
    assert float(grammar.measures(convex.curve, closed=False).convexity) > float(before.convexity)
    ends = jnp.asarray([0.0, 1.0])
    np.testing.assert_allclose(convex.curve.evaluate(ends), curve.evaluate(ends), atol=1e-12)
    fast = grammar.accelerate(curve, 0.5)
    np.testing.assert_allclose(fast.curve.evaluate(1.0, 1), 1.5 * curve.evaluate(1.0, 1), rtol=1e-10)
    np.testing.assert_allclose(fast.curve.evaluate(0.0, 1), curve.evaluate(0.0, 1), rtol=1e-10)
    _, kinds = _points_of(curve, False)
    i = next(k for k, s in enumerate(kinds) if s != "0")
    soft = grammar.soften(curve, i, 0.05)
    assert soft.dof_needed == 14  # §7.5: 2 end positions, neighbours' positions and tangents, the drag
    assert soft.after == grammar.symbols(soft.curve, closed=False)
