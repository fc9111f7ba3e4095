"""Merging patches (bsjax.merge): knot rules, exact reproduction, continuity, gradients, errors.

References: the thesis's worked knot examples (§4.3.3, §6.3.1.3); scipy's NdBSpline evaluation
of the surface that was cut into the patches (merging the pieces must give it back); closed-form
geometry (planes, creases); finite differences for gradients.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import interpolate

from bsjax import merge as mg
from bsjax.basis import BSplineSurface, clamped_knots, greville
from bsjax.merge import _orient, _overlap
from bsjax.merge._layout import changed_degree_knots
from tests.helpers import check_grad, random_knots, random_surface
from tests.oracles import ndbspline_surface

S = 16  # samples per patch direction: small, and one size so compiled kernels are shared
U1 = [0, 0, 0, 0, 0.2138, 0.4959, 0.7262, 1, 1, 1, 1]
U2 = [0, 0, 0, 0, 0.1215, 0.2512, 0.3689, 0.5047, 0.7283, 0.8631, 1, 1, 1, 1]


def _insert(knots, degree, ctrl, t, times):
    """Insert knot `t` `times` times along axis 0 of `ctrl` with FITPACK (scipy), not bsjax."""
    flat = np.asarray(ctrl).reshape(len(ctrl), -1)
    cols = []
    for j in range(flat.shape[1]):
        tck = (np.asarray(knots, np.float64), flat[:, j], degree)
        for _ in range(times):
            tck = interpolate.insert(t, tck)
        cols.append(np.asarray(tck[1])[: len(tck[0]) - degree - 1])
    return np.asarray(tck[0]), np.stack(cols, -1).reshape((-1,) + np.shape(ctrl)[1:])


def split(surface: BSplineSurface, direction: str, t: float):
    """The two pieces of `surface` on either side of the iso-line `direction = t`, each
    reparametrised to [0, 1] (knot insertion to full multiplicity, NURBS Book §5.3, by FITPACK)."""
    if direction == "v":
        a, b = split(_orient.orient_surface(surface, (True, False, False)), "u", t)
        back = (True, False, False)
        return _orient.orient_surface(a, back), _orient.orient_surface(b, back)
    k = surface.degree_u
    have = int(np.sum(np.isclose(np.asarray(surface.knots_u), t)))
    ku, ctrl = _insert(surface.knots_u, k, surface.ctrl, t, k - have)
    i = int(np.searchsorted(ku, t - 1e-12))
    ka = np.concatenate([ku[:i], [t] * (k + 1)]) / t
    kb = (np.concatenate([[t] * (k + 1), ku[i + k :]]) - t) / (1 - t)
    a = BSplineSurface(ctrl[:i], ka, surface.knots_v, k, surface.degree_v)
    b = BSplineSurface(ctrl[i - 1 :], kb, surface.knots_v, k, surface.degree_v)
    return a, b


def grid_error(merged: BSplineSurface, reference: BSplineSurface, count: int = 23) -> float:
    g = np.linspace(0.0, 1.0, count)
    u, v = np.meshgrid(g, g, indexing="ij")
    ref = ndbspline_surface(reference, u.ravel(), v.ravel())
    got = ndbspline_surface(merged, u.ravel(), v.ravel())
    return float(np.max(np.abs(got - ref)))


def elevated(b: BSplineSurface) -> BSplineSurface:
    """`b` raised to degree 4 in u: the quartic space with every knot one more time contains the
    cubic, so an interpolating scipy fit (make_lsq_spline) of dense samples is exact."""
    k = b.degree_u
    values, counts = np.unique(np.asarray(b.knots_u), return_counts=True)
    t = np.repeat(values, counts + 1)
    x = np.linspace(0, 1, 4 * len(t))
    pts = np.stack(
        [ndbspline_surface(b, x, np.full_like(x, vj)) for vj in np.asarray(greville(b.knots_v, 3))], 1
    )
    rows = interpolate.make_lsq_spline(x, pts.reshape(len(x), -1), t, k + 1).c
    grid = rows.reshape(len(t) - k - 2, -1, 3)
    # columns: the cubic in v is interpolated at its Greville points by the v-basis
    av = interpolate.BSpline.design_matrix(
        np.asarray(greville(b.knots_v, 3)), np.asarray(b.knots_v), 3
    ).toarray()
    ctrl = (
        np.linalg.solve(av, grid.transpose(1, 0, 2).reshape(av.shape[0], -1))
        .reshape(av.shape[0], -1, 3)
        .transpose(1, 0, 2)
    )
    return BSplineSurface(ctrl, t, b.knots_v, k + 1, b.degree_v)


@pytest.fixture(scope="module")
def surface():
    return random_surface(np.random.default_rng(7), 7, 6, 3, 3)


# --- knot vectors ----------------------------------------------------------------------------
def test_merge_knots_thesis_433():
    """Thesis §4.3.3. The printed vectors have two typos: 0.2512 → 0.6256 is missing from both
    (the count must be r1 + r2 − 1 + k + 1 = 20), and 0.4317 should be (0.3631 + 0.5)/2 = 0.4316;
    0.2478 (C⁰) vs 0.2480 (C²) is a rounding slip of 0.24795."""
    c0 = mg.merge_knots(U1, U2, 3, 0)
    c2 = mg.merge_knots(U1, U2, 3, 2)
    thesis_c0 = [
        0,
        0,
        0,
        0,
        0.1069,
        0.2478,
        0.3631,
        0.5,
        0.5,
        0.5,
        0.5608,
        0.6256,
        0.6845,
        0.7524,
        0.8642,
        0.9316,
        1,
        1,
        1,
        1,
    ]
    thesis_c2 = [
        0,
        0,
        0,
        0,
        0.1069,
        0.2480,
        0.3631,
        0.4317,
        0.5,
        0.5304,
        0.5608,
        0.6256,
        0.6845,
        0.7524,
        0.8642,
        0.9316,
        1,
        1,
        1,
        1,
    ]
    assert len(c0) == len(c2) == (7 + 10 - 1) + 3 + 1
    np.testing.assert_allclose(c0, thesis_c0, atol=2e-4)
    np.testing.assert_allclose(c2, thesis_c2, atol=2e-4)
    assert c2[7] == pytest.approx((0.7262 / 2 + 0.5) / 2) and c2[9] == pytest.approx((0.5 + 0.56075) / 2)
    c1 = mg.merge_knots(U1, U2, 3, 1)
    assert np.sum(c1 == 0.5) == 2 and c1[7] == pytest.approx(0.43155)


def test_average_knots_thesis_6313():
    a = [0, 0, 0, 0.25, 0.49, 0.67, 0.75, 0.9, 1, 1, 1]
    b = [0, 0, 0, 0.20, 0.45, 0.61, 0.71, 0.85, 1, 1, 1]
    thesis = [0, 0, 0, 0.22, 0.47, 0.64, 0.73, 0.87, 1, 1, 1]  # printed truncated to 2 decimals
    got = mg.average_knots(a, b)
    np.testing.assert_allclose(np.floor(got * 100 + 1e-9) / 100, thesis)
    with pytest.raises(ValueError, match="knots_b"):
        mg.average_knots(a, b[:-1])


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 5), st.integers(0, 4), st.integers(0, 4), st.integers(0, 10**6))
def test_merge_knots_properties(degree, extra_a, extra_b, seed):
    rng = np.random.default_rng(seed)
    ka = random_knots(rng, degree + 1 + extra_a, degree)
    kb = random_knots(rng, degree + 1 + extra_b, degree)
    for c in range(degree):
        t = mg.merge_knots(ka, kb, degree, c)
        assert len(t) == len(ka) + len(kb) - degree - 2  # r = r_a + r_b − 1
        assert np.all(np.diff(t) >= 0)
        assert np.sum(t == 0.5) == degree - c  # C^c at the seam
        np.testing.assert_allclose(
            t[: degree + 1 + extra_a], np.concatenate([ka[: degree + 1], ka[degree + 1 : -degree - 1] / 2])
        )
        BSplineSurface(
            np.zeros((len(t) - degree - 1, degree + 1, 3)),
            t,
            clamped_knots(degree + 1, degree),
            degree,
            degree,
        )


def test_cross_knots_modes():
    ta, tb = random_knots(np.random.default_rng(1), 6, 3), random_knots(np.random.default_rng(2), 9, 3)
    np.testing.assert_allclose(mg.cross_knots([ta, tb], 3, 9, "uniform"), clamped_knots(9, 3))
    np.testing.assert_allclose(mg.cross_knots([ta, ta], 3, 6), ta)
    merged = mg.cross_knots([ta, tb], 3, 9)
    assert len(merged) == 13 and np.all(np.diff(merged) >= 0)
    inner = merged[4:-4]
    pooled = np.concatenate([ta[4:-4], tb[4:-4]])
    assert pooled.min() <= inner.min() and inner.max() <= pooled.max()
    with pytest.raises(ValueError, match="mode: expected one of"):
        mg.cross_knots([ta], 3, 6, "spline")


# --- merging gives back the surface that was cut -------------------------------------------
@pytest.mark.parametrize("direction", ["u", "v"])
def test_merge_halves_reproduces(surface, direction):
    a, b = split(surface, direction, 0.5)
    for c in (0, 1, 2):  # the original is C² at 0.5: every continuity up to 2 contains it
        merged = mg.merge([a, b], direction, c, samples=S)
        assert merged.shape == (
            (a.shape[0] + b.shape[0] - 1, 6) if direction == "u" else (7, a.shape[1] + b.shape[1] - 1)
        )
        assert grid_error(merged, surface) < 1e-6


def test_merge_auto_orientation(surface):
    a, b = split(surface, "u", 0.5)
    for op in [(False, True, True), (True, False, False), (True, True, False)]:
        turned = _orient.orient_surface(b, op)
        layout = mg.plan([a, turned], "u", 2, samples=S)
        merged = layout.surface(layout.apply([a.ctrl, turned.ctrl]))
        assert grid_error(merged, surface) < 1e-6


def test_oriented_edges_match_evaluation(surface):
    edges = _orient._edges(surface, count=S)
    t = np.linspace(0.0, 1.0, S)
    for op in _orient.ALL:
        s = _orient.orient_surface(surface, op)
        for d in "uv":
            for e in (0, 1):
                uu, vv = (np.full_like(t, e), t) if d == "u" else (t, np.full_like(t, e))
                np.testing.assert_allclose(
                    _orient._oriented_edge(edges, op, d, e), ndbspline_surface(s, uu, vv), atol=1e-12
                )


def test_merge_three_in_a_row_and_grid(surface):
    a, rest = split(surface, "u", 1 / 3)
    b, c = split(rest, "u", 0.5)
    assert grid_error(mg.merge([a, b, c], "u", 2, samples=S), surface) < 1e-6
    top, bottom = split(surface, "u", 0.5)
    rows = [list(split(top, "v", 0.5)), list(split(bottom, "v", 0.5))]
    merged = mg.merge_grid(rows, (2, 1), samples=S)
    assert merged.shape == (top.shape[0] + bottom.shape[0] - 1, rows[0][0].shape[1] + rows[0][1].shape[1] - 1)
    assert grid_error(merged, surface) < 1e-6


def _grid(surface):
    top, bottom = split(surface, "u", 0.5)
    return [list(split(top, "v", 0.5)), list(split(bottom, "v", 0.5))]


def test_merge_grid_orientation(surface):
    """A 2×2 grid with every patch flipped or transposed (the corner too) merges to the same
    surface as the well-oriented grid: `orient_grid` finds the inverse reparametrisations."""
    rows = _grid(surface)
    turns = [[(True, False, True), (True, True, False)], [(False, True, True), (True, True, True)]]
    turned = [[_orient.orient_surface(p, op) for p, op in zip(row, orow)] for row, orow in zip(rows, turns)]
    ops = mg.orient_grid(turned, (S, S))
    for row, orow, trow in zip(rows, ops, turned):
        for p, op, t in zip(row, orow, trow):  # undoing the turn gives back each patch
            np.testing.assert_allclose(_orient.orient_surface(t, op).ctrl, p.ctrl, atol=1e-12)
    reference = mg.merge_grid(rows, 2, samples=S, orient="as_given")
    for orient in ("auto", ops):
        merged = mg.merge_grid(turned, 2, samples=S, orient=orient)
        np.testing.assert_allclose(merged.ctrl, reference.ctrl, atol=1e-10)
        assert grid_error(merged, surface) < 1e-6
    assert grid_error(mg.merge_grid(turned, 2, samples=S, orient="as_given"), surface) > 1e-2
    with pytest.raises(ValueError, match="orient"):
        mg.merge_grid(turned, 2, samples=S, orient=[[(True, False)] * 2] * 2)


def test_merge_grid_trimmed(surface):
    """The lower row of a 2×2 grid starts at u = 0.4 (overlapping the upper row's last tenth);
    trimming its u-window to the part below 0.5 gives back the surface; windows that differ
    along a row are refused."""
    top, _ = split(surface, "u", 0.5)
    _, bottom = split(surface, "u", 0.4)
    rows = [list(split(top, "v", 0.5)), list(split(bottom, "v", 0.5))]
    lo = 0.1 / 0.6
    trim = [[None, None], [(lo, 1.0, 0.0, 1.0)] * 2]
    merged = mg.merge_grid(rows, 2, samples=(37, S), trim=trim, orient="as_given")
    assert grid_error(merged, surface) < 1e-6
    with pytest.raises(ValueError, match="trim"):
        mg.merge_grid(rows, 2, samples=S, trim=[[None, None], [(lo, 1.0, 0.0, 1.0), None]])
    with pytest.raises(ValueError, match="trim"):
        mg.merge_grid(rows, 2, samples=S, trim=[[None, None], [(0.5, 0.2, 0.0, 1.0)] * 2])


def test_merge_grid_overlap_dropped():
    """Upper plates running past x = 1, tilted lower plates crossing them (§4.4.1): the grid
    merge drops the intersecting rows of every column and runs straight through."""
    upper = [_plate(0.0, 1.2, 5, 4, y0=0.0, y1=1.0), _plate(0.0, 1.2, 5, 4, y0=1.0, y1=2.0)]
    lower = [_plate(0.9, 2.0, 5, 4, lambda x, y: 0.5 * (x - 1.0), y0=y0, y1=y0 + 1.0) for y0 in (0.0, 1.0)]
    windows = _overlap.grid_overlap_windows([upper, lower], (S, S), method="dense")
    (u0, u1, v0, v1), (l0, l1, w0, w1) = windows[0][0], windows[1][1]
    assert (u0, v0, v1, w0, w1, l1) == (0.0, 0.0, 1.0, 0.0, 1.0, 1.0)  # the v seam does not cross
    assert 0.6 < u1 < 1.0 / 1.2 and 0.1 / 1.1 < l0 < 0.35
    g = np.linspace(0, 1, 200)
    for overlap, monotone in (("keep", False), ("drop", True)):
        merged = mg.merge_grid([upper, lower], 0, samples=S, overlap=overlap, overlap_method="dense")
        for v in (0.2, 0.7):
            x = ndbspline_surface(merged, g, np.full_like(g, v))[:, 0]
            assert bool(np.all(np.diff(x) > 0)) == monotone


def test_reduction_error(surface):
    """`degrees="reduce"`: the layout reports each patch's loss from lowering its degree — zero for
    a patch left alone and for an exactly elevated cubic, and for a true quartic the largest
    distance to its reduction, checked against scipy sampling of the patch and of
    `reduce_degree`'s result."""
    from bsjax.basis import reduce_degree

    a, b = split(surface, "u", 0.5)
    exact = mg.plan([a, elevated(b)], "u", 2, samples=S, degrees="reduce", orient="as_given")
    assert float(exact.reduction_error[0, 0]) == 0.0 and float(exact.reduction_error[1, 0]) < 1e-9
    rng = np.random.default_rng(4)
    quartic = random_surface(rng, 7, 6, 4, 3)
    quartic = quartic.with_ctrl(quartic.ctrl + jnp.array([1.0, 0.0, 0.0])[None, None])
    layout = mg.plan([a, quartic], "u", 2, samples=S, degrees="reduce", orient="as_given")
    err = float(layout.reduction_error[1, 0])
    reduced, _ = reduce_degree(quartic, "u", 1)
    g = np.linspace(0, 1, S)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    sampled = np.linalg.norm(
        ndbspline_surface(quartic, uu.ravel(), vv.ravel())
        - ndbspline_surface(reduced, uu.ravel(), vv.ravel()),
        axis=-1,
    )
    assert err == pytest.approx(sampled.max(), rel=1e-9) and err > 1e-4
    # the merge cannot beat the lower degree: the merged quartic part deviates at least ~ as much
    merged = layout.surface(layout.apply([a.ctrl, quartic.ctrl]))
    assert mg.deviation([quartic], merged, samples=S).max > 0.5 * err


def test_merge_trimmed_patch(surface):
    """A patch cut at u = 0.6 overlaps its neighbour from 0.5; trimming it at 0.5/0.6 of its own
    parameter range leaves exactly the missing half, and the merge gives back the surface."""
    left, _ = split(surface, "u", 0.6)
    _, right = split(surface, "u", 0.5)
    merged = mg.merge(
        [left, right], "u", 2, samples=(30, S), trim=[(0.0, 0.5 / 0.6), None], orient="as_given"
    )
    assert grid_error(merged, surface) < 1e-6


def test_merge_degree_policies(surface):
    a, b = split(surface, "u", 0.5)
    b_up = elevated(b)
    assert grid_error(b_up, b) < 1e-12
    with pytest.raises(ValueError, match="degrees"):
        mg.merge([a, b_up], "u", 2, samples=S)
    up = mg.merge([a, b_up], "u", 2, samples=S, degrees="elevate")
    assert (up.degree_u, up.degree_v) == (4, 3)
    assert grid_error(up, surface) < 1e-6  # exact elevation keeps the cubic in the space
    down_layout = mg.plan([a, b_up], "u", 2, samples=S, degrees="reduce")
    # the knot rules are the foundation's: elevation adds to every multiplicity; reduction drops
    # the end multiplicities and caps interior ones at the new degree
    np.testing.assert_allclose(
        changed_degree_knots([0, 0, 0, 0, 0.4, 0.4, 0.7, 1, 1, 1, 1], 3, 4),
        [0, 0, 0, 0, 0, 0.4, 0.4, 0.4, 0.7, 0.7, 1, 1, 1, 1, 1],
    )
    t = np.array([0, 0, 0, 0, 0, 0.3, 0.3, 0.6, 1, 1, 1, 1, 1.0])
    np.testing.assert_allclose(changed_degree_knots(t, 4, 2), [0, 0, 0, 0.3, 0.3, 0.6, 1, 1, 1])
    b_down_count = len(changed_degree_knots(b_up.knots_u, 4, 3)) - 4
    assert (down_layout.merged.degree_u, down_layout.merged.ctrl_shape[0]) == (
        3,
        a.shape[0] + b_down_count - 1,
    )
    down = down_layout.surface(down_layout.apply([a.ctrl, b_up.ctrl]))
    assert grid_error(down, surface) < 1e-6


def test_thesis_case6_degrees():
    """6×6 bicubic with an 8×12 patch of degrees 4×5, merged along v (thesis Fig. 4.6/6.14)."""
    rng = np.random.default_rng(3)
    a = random_surface(rng, 6, 6, 3, 3)
    b = random_surface(rng, 8, 12, 4, 5)
    b = b.with_ctrl(b.ctrl + jnp.array([0.0, 1.0, 0.0])[None, None])
    # the merged basis (no matrices needed): elevation raises every knot's multiplicity,
    # 6 ctrl over 3 spans → 6 + 3·d
    k, l, ku, kv = mg.merged_knots([[a, b]], (0, 2), degrees="elevate")
    assert (k, l, len(ku) - k - 1, len(kv) - l - 1) == (4, 5, max(6 + 3, 8), (6 + 3 * 2) + 12 - 1)
    assert np.sum(kv == 0.5) == l - 2  # C² seam
    k, l, ku, kv = mg.merged_knots([[a, b]], (0, 2), degrees="reduce")
    assert (k, l, len(ku) - k - 1, len(kv) - l - 1) == (
        3,
        3,
        max(6, 8 - 1),
        6 + (12 - 2) - 1,
    )  # −d per reduced patch
    with pytest.raises(ValueError, match="degrees"):
        mg.merged_knots([[a, b]], 2)


# --- geometry ------------------------------------------------------------------------------
def _plate(x0, x1, r, s, z=lambda x, y: 0.0 * x, y0=0.0, y1=1.0):
    """A plate over [x0, x1] × [0, 1], control points at the Greville abscissae, so x and y are
    linear in u and v (linear precision) whatever the control counts."""
    ku, kv = clamped_knots(r, 3), clamped_knots(s, 3)
    gu = np.array([np.mean(ku[i + 1 : i + 4]) for i in range(r)])
    gv = np.array([np.mean(kv[j + 1 : j + 4]) for j in range(s)])
    x, y = np.meshgrid(x0 + (x1 - x0) * gu, y0 + (y1 - y0) * gv, indexing="ij")
    return BSplineSurface(np.stack([x, y, z(x, y)], -1), ku, kv, 3, 3)


def test_flat_coplanar_zero_deviation():
    a, b = _plate(0.0, 1.0, 5, 5), _plate(1.0, 2.0, 7, 6)
    for c in (0, 1, 2):
        merged = mg.merge([a, b], "u", c, samples=S)
        assert float(jnp.max(jnp.abs(merged.ctrl[..., 2]))) < 1e-12
        report = mg.deviation([a, b], merged, samples=12, tolerance=1e-6)
        assert report.max < 1e-9 and report.n_within == report.n_points == 2 * 144


@pytest.mark.parametrize("c", [0, 1, 2])
def test_seam_continuity(c):
    """A roof (crease at x = 1): the merged surface's derivatives jump across the seam exactly up
    to the order asked for — C⁰ keeps a kink, C² smooths S_u and S_uu."""
    a = _plate(0.0, 1.0, 5, 4, lambda x, y: 0.4 * x)
    b = _plate(1.0, 2.5, 5, 4, lambda x, y: 0.4 * (2.0 - x))
    merged = mg.merge([a, b], "u", c, samples=S)
    h = 1e-9
    u = np.array([0.5 - h, 0.5 + h])
    v = np.full(2, 0.37)
    jumps = []
    for nu in (1, 2):
        d = ndbspline_surface(merged, u, v, nu, 0)
        jumps.append(float(np.linalg.norm(d[1] - d[0]) / np.linalg.norm(d[0] + d[1])))
    assert (jumps[0] > 0.1) == (c == 0)
    assert (jumps[1] > 0.1) == (c <= 1)
    assert jumps[0] < 1e-6 or c == 0


def test_deviation_closed_form_and_brute_force():
    """Offset plate: every distance is the offset. Roof: the projected distances agree with a
    brute-force nearest point over a dense scipy sampling of the merged surface."""
    a, b = _plate(0.0, 1.0, 5, 5), _plate(1.0, 2.0, 7, 6)
    flat = mg.merge([a, b], "u", 2, samples=S)
    lifted = a.with_ctrl(a.ctrl + jnp.array([0.0, 0.0, 0.3])[None, None])
    report = mg.deviation([lifted], flat, samples=12, tolerance=0.25)
    np.testing.assert_allclose(report.distances[0], 0.3, atol=1e-12)
    assert (report.n_points, report.n_within, report.std) == (144, 0, pytest.approx(0.0, abs=1e-12))

    roof_a = _plate(0.0, 1.0, 5, 4, lambda x, y: 0.4 * x)
    roof_b = _plate(1.0, 2.5, 5, 4, lambda x, y: 0.4 * (2.0 - x))
    merged = mg.merge([roof_a, roof_b], "u", 2, samples=S)
    report = mg.deviation([roof_a, roof_b], merged, samples=12)
    g = np.linspace(0, 1, 401)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    dense = ndbspline_surface(merged, uu.ravel(), vv.ravel())
    cell = np.max(np.linalg.norm(np.diff(dense.reshape(401, 401, 3), axis=0), axis=-1))
    from scipy.spatial import cKDTree

    tree = cKDTree(dense)
    for orig, d in zip([roof_a, roof_b], report.distances):
        x = np.linspace(0, 1, 12)
        xu, xv = np.meshgrid(x, x, indexing="ij")
        brute = tree.query(ndbspline_surface(orig, xu.ravel(), xv.ravel()))[0].reshape(12, 12)
        assert np.all(d <= brute + 1e-9) and np.all(d >= brute - cell)
    assert (
        report.max > 1e-3
        and report.median <= report.max
        and report.mean == pytest.approx(np.mean(np.concatenate([x.ravel() for x in report.distances])))
    )
    assert report.row()["total points"] == 288


@pytest.mark.parametrize("c", [0, 2])
def test_refine_reduces_deviation(c):
    """Edges of unequal length (1 vs 1.4, thesis case 4): parameter correction lowers the
    deviation of the linear merge."""
    bend = lambda x, y: 0.2 * np.sin(3.0 * y)
    a = _plate(0.0, 1.0, 5, 4, bend)
    b = _plate(1.0, 2.5, 5, 4, bend, y0=-0.2, y1=1.2)
    linear = mg.deviation([a, b], mg.merge([a, b], "u", c, samples=S), samples=12)
    corrected = mg.deviation([a, b], mg.merge([a, b], "u", c, samples=S, refine=True), samples=12)
    assert corrected.mean < 0.8 * linear.mean and corrected.max < linear.max


def test_overlap_rows_dropped():
    """A flat patch running past x = 1 and a tilted one crossing it there (thesis §4.4.1)."""
    a = _plate(0.0, 1.2, 5, 4)
    b = _plate(0.9, 2.0, 5, 4, lambda x, y: 0.5 * (x - 1.0))
    (lo_a, hi_a), (lo_b, hi_b) = mg.overlap_trims([a, b], "u", S, method="dense")
    assert lo_a == 0.0 and 0.6 < hi_a < 1.0 / 1.2 and hi_b == 1.0 and 0.1 / 1.1 < lo_b < 0.35
    # bsjax.collide finds the crossing itself (x = 1): the rows just before / after it are kept
    (_, hi_c), (lo_c, _) = mg.overlap_trims([a, b], "u", S, method="collide")
    step = 1.0 / (S - 1)
    assert 1.0 / 1.2 - 2 * step < hi_c < 1.0 / 1.2 and 0.1 / 1.1 < lo_c < 0.1 / 1.1 + 2 * step
    # kept whole, the merged surface folds back on itself (x runs to 1.2, then back to 0.9);
    # with the overlapping rows dropped it runs straight through
    g = np.linspace(0, 1, 200)
    for overlap, monotone in (("keep", False), ("drop", True)):
        merged = mg.merge([a, b], "u", 0, samples=S, overlap=overlap, overlap_method="dense")
        x = ndbspline_surface(merged, g, np.full_like(g, 0.5))[:, 0]
        assert bool(np.all(np.diff(x) > 0)) == monotone
    windows = [(lo_a, hi_a, 0, 1), (lo_b, hi_b, 0, 1)]
    assert mg.deviation([a, b], merged, samples=12, windows=windows).max < 0.05


def test_float32_merge_keeps_dtype():
    a = _plate(0.0, 1.0, 5, 4, lambda x, y: 0.4 * x)
    b = _plate(1.0, 2.5, 5, 4, lambda x, y: 0.4 * (2.0 - x))

    def f32(s):
        return BSplineSurface(
            np.asarray(s.ctrl, np.float32),
            np.asarray(s.knots_u, np.float32),
            np.asarray(s.knots_v, np.float32),
            3,
            3,
        )

    single = mg.merge([f32(a), f32(b)], "u", 2, samples=S)
    double = mg.merge([a, b], "u", 2, samples=S)
    assert single.ctrl.dtype == single.knots_u.dtype == jnp.float32
    np.testing.assert_allclose(single.ctrl, double.ctrl, atol=2e-5)


# --- jit, vmap, grad --------------------------------------------------------------------------
def _apply_fn(layout, ctrls):
    return layout.apply(ctrls)


def _refine_fn(layout, ctrls):
    return mg.refine(layout, ctrls)


# one function object per kernel: jax.jit of it here and in the bad-input checks is one program
_apply = jax.jit(_apply_fn)


def test_layout_jit_vmap_grad(surface):
    a, b = split(surface, "u", 0.5)
    layout = mg.plan([a, b], "u", 2, samples=S)
    eager = layout.apply([a.ctrl, b.ctrl])
    np.testing.assert_allclose(_apply(layout, [a.ctrl, b.ctrl]), eager, atol=1e-12)
    batch = a.ctrl[None] + 0.01 * jnp.asarray(np.random.default_rng(0).normal(size=(3,) + a.ctrl.shape))
    stacked = jax.vmap(lambda p: layout.apply([p, b.ctrl]))(batch)
    for i in range(3):
        np.testing.assert_allclose(stacked[i], layout.apply([batch[i], b.ctrl]), atol=1e-12)
    w = jnp.asarray(np.random.default_rng(1).normal(size=eager.shape))

    def objective(pa):
        return jnp.sum(w * layout.apply([pa, b.ctrl]) ** 2)

    check_grad(objective, a.ctrl)
    check_grad(lambda pb: jnp.sum(jnp.sin(layout.apply([a.ctrl, pb]))), b.ctrl)


# --- bad input -------------------------------------------------------------------------------
def test_bad_input(surface):
    a, b = split(surface, "u", 0.5)
    with pytest.raises(ValueError, match="continuity"):
        mg.merge([a, b], "u", 3, samples=S)
    with pytest.raises(ValueError, match="continuity"):
        mg.merge_knots(U1, U2, 3, -1)
    with pytest.raises(ValueError, match="surfaces"):
        mg.merge([a], "u")
    with pytest.raises(ValueError, match="direction"):
        mg.merge([a, b], "w")
    with pytest.raises(ValueError, match="rows"):
        mg.merge_grid([[a, b], [a]])
    with pytest.raises(ValueError, match="periodic"):
        from bsjax.shapes import teardrop

        mg.merge([a, teardrop()], "u", samples=S)
    with pytest.raises(ValueError, match="knots"):
        mg.merge_knots(U1, U2[:-1], 3, 0)
    layout = mg.plan([a, b], "u", 2, samples=S)
    with pytest.raises(ValueError, match="ctrl"):
        layout.apply([a.ctrl, b.ctrl[:-1]])
    with pytest.raises(ValueError, match="ctrls"):
        layout.apply([a.ctrl])
    with pytest.raises(ValueError, match="samples"):
        mg.merge([a, b], "u", 2, samples=2)
    with pytest.raises(ValueError, match="trim"):
        mg.merge([a, b], "u", 2, samples=S, trim=[(0.5, 0.2), None])


# --- the plan cache and the compiled boundary -----------------------------------------------
def test_merge_reuses_the_cached_layout(surface):
    """A second `merge` with the same bases builds nothing (cache_info) and gives the same net as
    a fresh plan; new control values on the same bases reuse the layout too."""
    a, b = split(surface, "u", 0.5)
    mg.clear_cache()
    first = mg.merge([a, b], "u", 2, samples=S)
    assert mg.cache_info()["builds"] == 1 and mg.cache_info()["hits"] == 0
    second = mg.merge([a, b], "u", 2, samples=S)
    assert mg.cache_info()["builds"] == 1 and mg.cache_info()["hits"] == 1
    np.testing.assert_array_equal(first.ctrl, second.ctrl)
    mg.clear_cache()
    fresh = mg.plan([a, b], "u", 2, samples=S)
    np.testing.assert_array_equal(fresh.apply([a.ctrl, b.ctrl]), second.ctrl)
    moved = b.with_ctrl(b.ctrl * 1.01)
    mg.merge([a, moved], "u", 2, samples=S, orient="as_given")
    info = mg.cache_info()
    mg.merge([a, moved.with_ctrl(moved.ctrl + 0.01)], "u", 2, samples=S, orient="as_given")
    assert mg.cache_info()["builds"] == info["builds"] and mg.cache_info()["hits"] == info["hits"] + 1
    from bsjax import _boundary

    _boundary.clear_caches()
    assert mg.cache_info() == {"layouts": 0, "trims": 0, "builds": 0, "hits": 0}


def test_overlap_drop_is_keyed_by_values():
    """`overlap="drop"` finds the trims from the nets: moving the crossing patch changes the
    layout (no stale trims from the cache), the same nets reuse it."""
    a = _plate(0.0, 1.2, 5, 4)
    b = _plate(0.9, 2.0, 5, 4, lambda x, y: 0.5 * (x - 1.0))
    c = b.with_ctrl(b.ctrl + jnp.array([0.15, 0.0, 0.0])[None, None])
    kw = dict(samples=S, overlap="drop", overlap_method="dense", orient="as_given")
    mg.clear_cache()
    lay_b = mg.plan([a, b], "u", 0, **kw)
    lay_c = mg.plan([a, c], "u", 0, **kw)
    assert lay_c.patches[1][0].grid_shape != lay_b.patches[1][0].grid_shape
    assert mg.plan([a, b], "u", 0, **kw) is lay_b and mg.cache_info()["trims"] == 2


def test_bad_input_eager_and_jit(surface):
    """Value errors raise the same message eagerly and inside `jax.jit`; structure errors (a
    continuity out of range) too, while tracing."""
    from tests.helpers import raises_both

    a, b = split(surface, "u", 0.5)
    layout = mg.plan([a, b], "u", 2, samples=S)
    bad = a.ctrl.at[1, 2, 0].set(jnp.nan)
    raises_both(_apply_fn, layout, [bad, b.ctrl], match="finite")  # the program of test_layout_jit_vmap_grad
    raises_both(lambda p: layout.points([p, b.ctrl]), bad, match="finite")
    raises_both(_refine_fn, layout, [bad, b.ctrl], match="finite")  # one program with the test below
    raises_both(lambda p: mg.refit(layout, [a.ctrl, p]).ctrl, bad[: b.shape[0]], match="ctrls")
    raises_both(lambda p: mg.deviation([a.with_ctrl(p)], a, samples=5).max, bad, match="finite")
    raises_both(
        lambda p: mg.merge([a.with_ctrl(p), b], "u", 3, orient="as_given").ctrl, a.ctrl, match="continuity"
    )
    raises_both(
        lambda p: mg.plan([a.with_ctrl(p), b], "u", -1, orient="as_given").merged.a_u,
        a.ctrl,
        match="continuity",
    )
    raises_both(
        lambda p: mg.merge_grid([[a.with_ctrl(p)], [b]], 5, orient="as_given").ctrl,
        a.ctrl,
        match="continuity",
    )
    with pytest.raises(ValueError, match="finite"):
        mg.merge([a.with_ctrl(bad), b], "u", 2, samples=S)
    with pytest.raises(ValueError, match="rtol"):
        mg.refit(layout, [a.ctrl, b.ctrl], mg.RefitSolver(rtol=-1.0))
    with pytest.raises(ValueError, match="tolerance"):
        mg.deviation([a], a, samples=5, tolerance=0.0)
    with pytest.raises(TypeError, match="orient='auto'"):
        jax.jit(lambda p: mg.plan([a, b.with_ctrl(p)], "u", 2, samples=S).merged.a_u)(b.ctrl)


def test_merge_inside_jit_with_a_planned_layout(surface):
    """The documented way inside `jit`: plan outside, `layout.apply` and `refit` inside."""
    a, b = split(surface, "u", 0.5)
    layout = mg.plan([a, b], "u", 2, samples=S)
    want = mg.merge([a, b], "u", 2, samples=S, refine=True).ctrl
    got = jax.jit(_refine_fn)(layout, [a.ctrl, b.ctrl])
    np.testing.assert_allclose(got, want, atol=1e-12)
