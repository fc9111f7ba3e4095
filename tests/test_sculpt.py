"""bsjax.sculpt: minimum-norm edits against numpy's pseudo-inverse / lstsq on scipy's basis rows,
the closed forms of the thesis (eqs. 6-10, 6-12, the tensor single-point formula), the factor
reused per drag, nonlinear constraints, target-curve sculpting, and bad input."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import BSpline

from bsjax import sculpt
from bsjax.basis import BSplineCurve
from tests.helpers import check_grad, jit_vmap_grad, raises_both, random_knots, random_surface


def _curve(rng, n=9, p=3, dim=2):
    knots = random_knots(rng, n, p)
    ctrl = np.stack([np.linspace(0, 1, n), 0.3 * rng.normal(size=n)], -1)
    if dim == 3:
        ctrl = np.concatenate([ctrl, 0.2 * rng.normal(size=(n, 1))], -1)
    return BSplineCurve(ctrl, knots, p)


def _rows(knots, p, t, nu=0):
    """scipy's basis rows (an independent reference): `(m, n)` of `B^{(nu)}_i(t)`."""
    n = len(knots) - p - 1
    eye = np.eye(n)
    return np.stack([BSpline(knots, eye[i], p)(np.atleast_1d(t), nu) for i in range(n)], -1)


# --- min_norm: references ----------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_min_norm_curve_equals_pinv_of_free_columns(dim):
    rng = np.random.default_rng(1)
    c = _curve(rng, dim=dim)
    knots, n = np.asarray(c.knots), c.n_ctrl
    t = np.array([0.2, 0.55, 0.8])
    target = rng.normal(size=(3, dim))
    tangent = rng.normal(size=dim)
    free = np.ones(n, bool)
    free[[0, 1, n - 1]] = False
    metric = rng.uniform(0.5, 3.0, n)
    cons = [sculpt.Position(t, target), sculpt.Derivative(0.3, tangent)]
    edit = sculpt.min_norm(c, cons, free, metric)

    f = np.concatenate([_rows(knots, 3, t), _rows(knots, 3, 0.3, 1)])
    ctrl = np.asarray(c.ctrl)
    b = np.concatenate([target - f[:3] @ ctrl, tangent[None] - f[3:] @ ctrl])
    s = np.where(free, 1 / np.sqrt(metric), 0.0)
    expect = s[:, None] * (np.linalg.pinv(f * s[None]) @ b)
    np.testing.assert_allclose(edit.displacement, expect, atol=1e-12)
    np.testing.assert_allclose(edit.shape.evaluate(t), target, atol=1e-11)
    np.testing.assert_allclose(edit.shape.evaluate(0.3, 1), tangent, atol=1e-10)
    assert int(edit.status) == 0 and int(edit.rank) == 4 * dim
    assert float(edit.residual) < 1e-12
    assert np.all(np.asarray(edit.displacement)[~free] == 0)


def test_closed_form_single_constraint_6_10():
    """One position constraint: `d = F0ᵀ β0 / f̂00` (eq. 6-10)."""
    c = _curve(np.random.default_rng(2))
    delta = np.array([0.1, -0.4])
    edit = sculpt.min_norm(c, [sculpt.Displacement(0.37, delta)])
    f0 = _rows(np.asarray(c.knots), 3, 0.37)[0]
    np.testing.assert_allclose(edit.displacement, np.outer(f0, delta) / (f0 @ f0), atol=1e-14)


def test_closed_form_position_and_frozen_tangent_6_12():
    """Position change β0 with the tangent unchanged (β1 = 0):
    `d = [F0ᵀ F1ᵀ] [f̂11, −f̂10]ᵀ β0 / f̂` (eq. 6-12)."""
    c = _curve(np.random.default_rng(3))
    beta0 = np.array([0.2, 0.3])
    cons = [sculpt.Displacement(0.6, beta0), sculpt.Derivative(0.6, c.evaluate(0.6, 1))]
    edit = sculpt.min_norm(c, cons)
    f0 = _rows(np.asarray(c.knots), 3, 0.6)[0]
    f1 = _rows(np.asarray(c.knots), 3, 0.6, 1)[0]
    g00, g01, g11 = f0 @ f0, f0 @ f1, f1 @ f1
    det = g00 * g11 - g01**2
    expect = np.outer(f0 * g11 - f1 * g01, beta0) / det
    np.testing.assert_allclose(edit.displacement, expect, atol=1e-12)
    np.testing.assert_allclose(edit.shape.evaluate(0.6, 1), c.evaluate(0.6, 1), atol=1e-11)


@pytest.mark.parametrize("scheme", ["tensor", "separable"])
def test_surface_single_point_formula(scheme):
    """`d_ij = a_i b_j δ / (‖a‖² ‖b‖²)` (§6.2.1); the separable scheme equals it for one point."""
    s = random_surface(np.random.default_rng(4), r=6, s=5)
    delta = np.array([0.0, 0.1, 0.5])
    edit = sculpt.min_norm(s, [sculpt.Displacement(0.3, delta, v=0.65)], scheme=scheme)
    a = _rows(np.asarray(s.knots_u), 3, 0.3)[0]
    b = _rows(np.asarray(s.knots_v), 2, 0.65)[0]
    expect = np.einsum("i,j,c->ijc", a, b, delta) / ((a @ a) * (b @ b))
    np.testing.assert_allclose(edit.displacement, expect, atol=1e-14)


def test_separable_meets_constraints_on_distinct_iso_curves():
    s = random_surface(np.random.default_rng(5), r=7, s=6)
    u, v = np.array([0.2, 0.5, 0.8]), np.array([0.3, 0.6, 0.4])
    target = np.asarray(s.evaluate(u, v)) + np.array([0.0, 0.0, 0.3])
    cons = [
        sculpt.Position(u, target, v=v),
        sculpt.Derivative(0.5, s.evaluate(0.5, 0.6, 0, 1), v=0.6, direction="v"),
    ]
    edit = sculpt.min_norm(s, cons, scheme="separable")
    np.testing.assert_allclose(edit.shape.evaluate(u, v), target, atol=1e-11)
    assert int(edit.status) == 0
    tensor = sculpt.min_norm(s, cons)
    assert np.linalg.norm(tensor.displacement) <= np.linalg.norm(edit.displacement) + 1e-12


def test_surface_tensor_equals_pinv_with_free_mask():
    s = random_surface(np.random.default_rng(6), r=6, s=5)
    u, v = np.array([0.25, 0.7]), np.array([0.4, 0.5])
    target = np.asarray(s.evaluate(u, v)) + 0.1
    free = np.zeros((6, 5), bool)
    free[1:-1, 1:-1] = True
    edit = sculpt.min_norm(s, [sculpt.Position(u, target, v=v)], free)
    a, b = _rows(np.asarray(s.knots_u), 3, u), _rows(np.asarray(s.knots_v), 2, v)
    f = np.einsum("mi,mj->mij", a, b).reshape(2, -1)
    rhs = target - f @ np.asarray(s.ctrl).reshape(-1, 3)
    mask = free.reshape(-1)
    expect = np.zeros((30, 3))
    expect[mask] = np.linalg.pinv(f[:, mask]) @ rhs
    np.testing.assert_allclose(np.asarray(edit.displacement).reshape(-1, 3), expect, atol=1e-12)


def test_over_constrained_is_least_squares_with_status_1():
    """More independent constraints than free control points: numpy's lstsq, status 1, no NaN."""
    c = _curve(np.random.default_rng(7), n=5)
    t = np.linspace(0.05, 0.95, 8)
    target = np.stack([t, np.sin(3 * t)], -1)
    edit = sculpt.min_norm(c, [sculpt.Position(t, target)])
    f = _rows(np.asarray(c.knots), 3, t)
    b = target - f @ np.asarray(c.ctrl)
    expect, res, *_ = np.linalg.lstsq(f, b, rcond=None)
    np.testing.assert_allclose(edit.displacement, expect, atol=1e-11)
    np.testing.assert_allclose(float(edit.residual), np.sqrt(res.sum()), rtol=1e-9)
    assert int(edit.status) == 1 and int(edit.rank) == 5 * 2


def test_contradictory_constraints_give_status_1_no_nan():
    c = _curve(np.random.default_rng(8))
    cons = [sculpt.Position(0.5, [0.0, 1.0]), sculpt.Position(0.5, [0.0, 2.0]), sculpt.Fixed(0.5)]
    edit = sculpt.min_norm(c, cons)
    assert int(edit.status) == 1 and int(edit.rank) == 2
    assert np.all(np.isfinite(edit.displacement))
    p, t1, t2 = np.asarray(c.evaluate(0.5)), np.array([0.0, 1.0]), np.array([0.0, 2.0])
    np.testing.assert_allclose(edit.shape.evaluate(0.5), p + (t1 + t2 - 2 * p) / 3, atol=1e-12)


def test_along_normal_planar_and_surface():
    c = _curve(np.random.default_rng(9))
    edit = sculpt.min_norm(c, [sculpt.AlongNormal(0.4, 0.2)])
    t = np.asarray(c.evaluate(0.4, 1))
    n = np.array([-t[1], t[0]]) / np.linalg.norm(t)
    np.testing.assert_allclose(edit.shape.evaluate(0.4) - c.evaluate(0.4), 0.2 * n, atol=1e-12)
    s = random_surface(np.random.default_rng(10))
    edit = sculpt.min_norm(s, [sculpt.AlongNormal(0.5, -0.3, v=0.45)])
    moved = edit.shape.evaluate(0.5, 0.45) - s.evaluate(0.5, 0.45)
    np.testing.assert_allclose(moved, -0.3 * np.asarray(s.normal(0.5, 0.45)), atol=1e-12)


def test_rational_curve_position():
    rng = np.random.default_rng(11)
    c0 = _curve(rng)
    w = rng.uniform(0.5, 2.0, c0.n_ctrl)
    c = BSplineCurve(c0.ctrl, c0.knots, 3, weights=w)
    target = np.array([0.4, 0.9])
    edit = sculpt.min_norm(c, [sculpt.Position(0.45, target), sculpt.Derivative(0.45, [1.0, 0.5])])
    np.testing.assert_allclose(edit.shape.evaluate(0.45), target, atol=1e-11)
    np.testing.assert_allclose(edit.shape.evaluate(0.45, 1), [1.0, 0.5], atol=1e-9)


# --- the factor --------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", ["tensor", "separable"])
def test_drag_equals_fresh_solve(scheme):
    s = random_surface(np.random.default_rng(12), r=6, s=5)
    u, v = np.array([0.3, 0.6]), np.array([0.5, 0.35])
    cons = [sculpt.Position(u, s.evaluate(u, v), v=v), sculpt.Fixed(0.9, v=0.9)]
    factor = sculpt.prefactor(s, cons, scheme=scheme)
    new = np.asarray(s.evaluate(u, v)) + np.array([[0.0, 0.1, 0.2], [0.05, 0.0, -0.1]])
    dragged = factor.drag([new, None])
    fresh = sculpt.min_norm(s, [sculpt.Position(u, new, v=v), cons[1]], scheme=scheme).shape
    np.testing.assert_allclose(dragged.ctrl, fresh.ctrl, atol=1e-13)
    rep = factor.edit([new, None])
    np.testing.assert_allclose(rep.shape.ctrl, fresh.ctrl, atol=1e-13)
    assert int(rep.status) == 0


def test_drag_as_array_of_targets():
    c = _curve(np.random.default_rng(13))
    cons = [sculpt.Position(0.2, c.evaluate(0.2)), sculpt.Position(0.7, c.evaluate(0.7))]
    factor = sculpt.prefactor(c, cons)
    targets = np.array([[0.2, 0.5], [0.7, -0.2]])
    out = factor.drag(targets)
    np.testing.assert_allclose(out.evaluate(np.array([0.2, 0.7])), targets, atol=1e-12)


# --- transformations ---------------------------------------------------------------------------
def test_jit_vmap_grad():
    c = _curve(np.random.default_rng(14))

    def moved(target):
        return sculpt.min_norm(c, [sculpt.Position(0.5, target), sculpt.Fixed(0.1)]).shape.ctrl

    target = jnp.array([0.5, 0.8])
    # jit, vmap and grad in one program (its batch: target, target ± eps d, target + 0.1)
    jit_vmap_grad(moved, target, target + 0.1, lambda y: jnp.sum(y**2), {"atol": 1e-14}, n_dirs=4)

    def by_param(u):  # the rows depend on u: differentiate through the pseudo-inverse
        return jnp.sum(sculpt.min_norm(c, [sculpt.Displacement(u, jnp.array([0.0, 0.3]))]).shape.ctrl ** 2)

    check_grad(by_param, jnp.asarray(0.43))


def test_compiled_once_per_structure():
    c = _curve(np.random.default_rng(15))
    sculpt.min_norm(c, [sculpt.Position(0.5, [0.1, 0.2])])
    before = len(sculpt.min_norm._cache)
    sculpt.min_norm(c, [sculpt.Position(0.25, [0.3, 0.1])])  # new float values reuse it
    assert len(sculpt.min_norm._cache) == before


# --- bad input ---------------------------------------------------------------------------------
def test_bad_input():
    c = _curve(np.random.default_rng(16))
    s = random_surface(np.random.default_rng(17))
    raises_both(
        lambda u: sculpt.min_norm(c, [sculpt.Position(u, [0.0, 1.0])]),
        jnp.asarray(1.5),
        match=r"constraints\[0\]\.u: expected values in \[0.0, 1.0\]",
    )
    raises_both(
        lambda x: sculpt.min_norm(c, [sculpt.Fixed(0.1), sculpt.Position(0.5, x)]),
        jnp.array([jnp.nan, 1.0]),
        match=r"constraints\[1\]\.target: expected finite",
    )
    raises_both(
        lambda m: sculpt.min_norm(c, [sculpt.Fixed(0.5)], metric=m),
        -jnp.ones(c.n_ctrl),
        match="metric: expected finite values > 0",
    )
    raises_both(
        lambda x: sculpt.min_norm(c, [sculpt.Position(0.5, x)]),
        jnp.ones(3),
        match=r"constraints\[0\]\.target: expected shape \(2,\)",
    )
    raises_both(
        lambda v: sculpt.min_norm(s, [sculpt.Fixed(0.5, v=v)]),
        jnp.asarray(-0.1),
        match=r"constraints\[0\]\.v: expected values in \[0.0, 1.0\]",
    )
    factor = sculpt.prefactor(c, [sculpt.Position(0.5, [0.0, 1.0])])
    raises_both(lambda x: factor.drag([x]), jnp.array([jnp.inf, 0.0]), match=r"targets\[0\]: expected finite")
    with pytest.raises(ValueError, match=r"constraints\[0\]\.v: expected a parameter v"):
        sculpt.min_norm(s, [sculpt.Fixed(0.5)])
    with pytest.raises(ValueError, match="free: expected a boolean mask of shape"):
        sculpt.min_norm(c, [sculpt.Fixed(0.5)], np.ones(3, bool))
    with pytest.raises(ValueError, match="scheme: expected 'tensor' or 'separable'"):
        sculpt.min_norm(s, [sculpt.Fixed(0.5, v=0.5)], scheme="fast")
    with pytest.raises(ValueError, match=r"targets: expected one value per constraint \(1\)"):
        factor.drag([None, None])
    with pytest.raises(ValueError, match="order: expected a derivative order 1 or 2"):
        sculpt.Derivative(0.5, [1.0, 0.0], order=3)
    with pytest.raises(TypeError, match=r"constraints\[0\]: expected an AbstractConstraint"):
        sculpt.min_norm(c, ["Position(0.5)"])


# --- nonlinear constraints ---------------------------------------------------------------------
def test_solve_linear_equals_min_norm():
    c = _curve(np.random.default_rng(20))
    cons = [sculpt.Position(0.4, [0.5, 1.0]), sculpt.Fixed(0.0), sculpt.Derivative(0.8, [1.0, 0.2])]
    free = np.arange(c.n_ctrl) != 3
    a, b = sculpt.solve(c, cons, free), sculpt.min_norm(c, cons, free)
    np.testing.assert_allclose(a.displacement, b.displacement, atol=1e-12)
    assert int(a.status) == 0


def test_distance_against_slsqp_and_kkt():
    """Fig. 6-3: a distance changed from d0 to 1.2 d0 with two blocked points; the minimum-norm
    displacement equals scipy's SLSQP minimiser of ‖d‖² under the same constraints."""
    from scipy.optimize import minimize

    c = _curve(np.random.default_rng(21), n=7)
    p0, p1 = np.asarray(c.evaluate(0.3)), np.asarray(c.evaluate(0.7))
    d0 = np.linalg.norm(p1 - p0)
    cons = [sculpt.Distance(0.3, 0.7, 1.2 * d0), sculpt.Fixed(0.0), sculpt.Fixed(1.0)]
    edit = sculpt.solve(c, cons)
    q = np.asarray(edit.shape.evaluate(np.array([0.3, 0.7])))
    np.testing.assert_allclose(np.linalg.norm(q[1] - q[0]), 1.2 * d0, rtol=1e-12)
    assert int(edit.status) == 0 and int(edit.rank) == 5

    knots = np.asarray(c.knots)
    r = _rows(knots, 3, np.array([0.3, 0.7, 0.0, 1.0]))
    ctrl = np.asarray(c.ctrl)

    def dist(x):
        moved = ctrl + x.reshape(ctrl.shape)
        return np.linalg.norm((r[1] - r[0]) @ moved) - 1.2 * d0

    eqs = [
        {"type": "eq", "fun": dist},
        {"type": "eq", "fun": lambda x: (r[2:] @ x.reshape(ctrl.shape)).ravel()},
    ]
    ref = minimize(
        lambda x: x @ x, np.zeros(ctrl.size), constraints=eqs, method="SLSQP", options={"ftol": 1e-14}
    )
    np.testing.assert_allclose(np.asarray(edit.displacement).ravel(), ref.x, atol=1e-6)


def test_tangent_parallel_and_normal_angle_met():
    c = _curve(np.random.default_rng(22))
    cons = [
        sculpt.TangentParallel(0.5, [1.0, 1.0]),
        sculpt.NormalAngle(0.2, [0.0, 1.0], 0.3),
        sculpt.Fixed(0.9),
    ]
    edit = sculpt.solve(c, cons)
    t = np.asarray(edit.shape.evaluate(0.5, 1))
    assert abs(t[0] - t[1]) < 1e-10 * np.linalg.norm(t)
    t2 = np.asarray(edit.shape.evaluate(0.2, 1))
    n = np.array([-t2[1], t2[0]]) / np.linalg.norm(t2)
    np.testing.assert_allclose(n[1], np.cos(0.3), atol=1e-10)
    assert int(edit.status) == 0


def test_on_surface_contact():
    rng = np.random.default_rng(23)
    s = random_surface(rng, r=5, s=5)
    c = _curve(rng, dim=3)
    edit = sculpt.solve(c, [sculpt.OnSurface(0.5, s)], max_steps=16)
    p = np.asarray(edit.shape.evaluate(0.5))
    from bsjax.basis import closest_points

    assert float(closest_points(s, p[None]).distances[0]) < 1e-9
    assert int(edit.status) == 0


def test_solve_gradient_implicit():
    c = _curve(np.random.default_rng(24), n=7)
    d0 = float(np.linalg.norm(np.asarray(c.evaluate(0.3)) - np.asarray(c.evaluate(0.7))))

    def energy(d):
        edit = sculpt.solve(c, [sculpt.Distance(0.3, 0.7, d), sculpt.Fixed(0.0), sculpt.Fixed(1.0)])
        return jnp.sum(edit.displacement**2)

    check_grad(energy, jnp.asarray(1.3 * d0), eps=1e-6, rtol=1e-4, n_dirs=1)


def test_solve_bad_input():
    c = _curve(np.random.default_rng(25))
    raises_both(
        lambda d: sculpt.solve(c, [sculpt.Distance(0.3, 0.7, d)]),
        jnp.asarray(-1.0),
        match=r"constraints\[0\]\.d: expected finite values >= 0",
    )
    raises_both(
        lambda a: sculpt.solve(c, [sculpt.NormalAngle(0.3, [0.0, 1.0], a)]),
        jnp.asarray(4.0),
        match=r"constraints\[0\]\.angle: expected values in \[0.0, 3.14",
    )
    with pytest.raises(ValueError, match="max_steps: expected an int >= 1"):
        sculpt.solve(c, [sculpt.Fixed(0.5)], max_steps=0)


# --- target-curve sculpting --------------------------------------------------------------------
def _flat_sheet(r=9, s=7):
    from bsjax.basis import BSplineSurface, clamped_knots

    x, y = np.meshgrid(np.linspace(0, 1, r), np.linspace(0, 1, s), indexing="ij")
    ctrl = np.stack([x, y, 0.05 * np.sin(3 * x) * np.cos(2 * y)], -1)
    return BSplineSurface(ctrl, clamped_knots(r, 3), clamped_knots(s, 3), 3, 3)


def _target():
    from bsjax.basis import clamped_knots

    pts = np.array([[0.2, 0.3, 0.3], [0.4, 0.45, 0.35], [0.6, 0.5, 0.35], [0.8, 0.6, 0.3]])
    return BSplineCurve(pts, clamped_knots(4, 3), 3)


def test_target_sculpt_lambda_one_interpolates_keys_and_adaptive_count():
    from bsjax.basis import closest_points, greville

    surf, target = _flat_sheet(), _target()
    res = sculpt.target_sculpt(surf, target, 1.0)
    on = np.asarray(res.active)
    uv = np.asarray(res.foot_params)[on]
    np.testing.assert_allclose(res.surface.evaluate(uv[:, 0], uv[:, 1]), np.asarray(res.keys)[on], atol=1e-12)
    assert int(res.status) == 0
    # eq. 6-24: one key per iso-curve (Greville abscissa) crossed along the dominant direction
    ends = closest_points(surf, np.asarray(target.evaluate(np.array([0.0, 1.0])))).params
    lo, hi = np.sort(np.asarray(ends)[:, 0])  # u dominates for this target
    g = greville(np.asarray(surf.knots_u), 3)
    assert on.sum() == max(2, np.sum((g >= lo) & (g <= hi)))


@pytest.mark.parametrize("lam", [0.8, 0.5])
def test_single_key_foot_moves_by_lambda_d(lam):
    surf, target = _flat_sheet(), _target()
    res = sculpt.target_sculpt(surf, target, jnp.asarray(lam), n_keys=1)  # (an array: one program)
    uv = np.asarray(res.foot_params)
    moved = np.asarray(res.surface.evaluate(uv[:, 0], uv[:, 1])) - np.asarray(res.feet)
    np.testing.assert_allclose(moved, lam * (np.asarray(res.keys) - np.asarray(res.feet)), atol=1e-12)
    np.testing.assert_allclose(res.forces, lam * (np.asarray(res.keys) - np.asarray(res.feet)), atol=1e-14)


def test_bound_mask_against_matplotlib_and_blocked_points_fixed():
    from matplotlib.path import Path

    from bsjax.basis import greville

    surf, target = _flat_sheet(), _target()
    poly = np.array([[0.1, 0.15], [0.9, 0.2], [0.95, 0.8], [0.5, 0.9], [0.15, 0.7]])
    mask = np.asarray(sculpt.bound_mask(surf, poly))
    gu, gv = greville(np.asarray(surf.knots_u), 3), greville(np.asarray(surf.knots_v), 3)
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    expect = Path(poly).contains_points(np.stack([uu.ravel(), vv.ravel()], -1)).reshape(uu.shape)
    np.testing.assert_array_equal(mask, expect)
    res = sculpt.target_sculpt(surf, target, 1.0, bound=poly, relax=2)
    np.testing.assert_array_equal(np.asarray(res.surface.ctrl)[~mask], np.asarray(surf.ctrl)[~mask])
    assert np.abs(np.asarray(res.surface.ctrl) - np.asarray(surf.ctrl))[mask].max() > 1e-3


def test_frame_rotation_against_scipy():
    from scipy.spatial.transform import Rotation

    for rotvec in ([0.3, -0.5, 0.4], [0.0, 0.0, 2.5], [1e-3, 0.0, 0.0]):
        rot = Rotation.from_rotvec(rotvec)
        f0 = Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix().T  # rows U, V, W
        axis, angle = sculpt.frame_rotation(f0, rot.apply(f0))
        np.testing.assert_allclose(np.asarray(axis) * float(angle), rotvec, atol=1e-9)
    axis, angle = sculpt.frame_rotation(np.eye(3), np.eye(3))  # pure translation: safe branch
    assert float(angle) == 0.0 and np.all(np.asarray(axis) == 0)


def test_target_bad_input():
    surf, target = _flat_sheet(), _target()
    raises_both(
        lambda lam: sculpt.target_sculpt(surf, target, lam, n_keys=1),  # eagerly: the program above
        jnp.asarray(1.5),
        match=r"lam: expected values in \[0.0, 1.0\]",
    )
    raises_both(
        lambda p: sculpt.bound_mask(surf, p),
        jnp.array([[0.1, 0.1], [2.0, 0.1], [0.5, 0.9]]),
        match=r"bound_uv: expected values in \[0.0, 1.0\]",
    )
    raises_both(
        lambda f: sculpt.frame_rotation(f, jnp.eye(3)),
        jnp.full((3, 3), jnp.nan),
        match="frame0: expected finite values",
    )
    with pytest.raises(ValueError, match="n_keys: expected an int >= 1"):
        sculpt.target_sculpt(surf, target, n_keys=0)
    with pytest.raises(ValueError, match=r"bound: expected a boolean mask of shape \(9, 7\)"):
        sculpt.target_sculpt(surf, target, bound=np.ones((3, 3), bool))
