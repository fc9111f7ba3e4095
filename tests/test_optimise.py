"""bsjax.optimise against scipy.optimize and closed forms: optimum, monotone history, bounds, fixed
entries, penalty constraint, vmap over starts, progress, clear errors; the bowl example."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from bsjax import optimise
from tests.helpers import raises_both


def rosenbrock(x, args):
    return jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)


A = np.array([[3.0, 1.0, 0.2], [1.0, 2.0, 0.5], [0.2, 0.5, 1.5]])
C = np.array([2.0, -3.0, 0.4])


def quadratic(x, args):
    d = x - jnp.asarray(C)
    return 0.5 * d @ jnp.asarray(A) @ d


def monotone(history):
    return bool(np.all(np.diff(history) <= 0.0))


def test_rosenbrock_matches_scipy_bfgs():
    x0 = np.array([-1.2, 1.0, 0.8, -0.5])
    ours = optimise.minimise(rosenbrock, jnp.asarray(x0), max_steps=300, rtol=1e-10, atol=1e-10)
    ref = scipy.optimize.minimize(lambda x: float(rosenbrock(jnp.asarray(x), None)), x0, method="BFGS")
    assert int(ours.status) == 0 and ours.steps > 10
    np.testing.assert_allclose(ours.design, ref.x, atol=1e-4)
    np.testing.assert_allclose(ours.design, np.ones(4), atol=1e-7)
    history = ours.accepted()
    assert history[0] == pytest.approx(float(rosenbrock(jnp.asarray(x0), None)))
    assert history[-1] == pytest.approx(float(ours.value)) and monotone(history)
    assert np.all(np.diff(history) < 0)  # Armijo: every accepted step strictly lowers it
    assert np.isnan(np.asarray(ours.history)[int(ours.steps) + 1 :]).all()
    # forward mode takes the same gradient another way: the same first steps (rounding then
    # grows along the curved valley) and the same minimum
    fwd = optimise.minimise(
        rosenbrock, jnp.asarray(x0), max_steps=300, rtol=1e-10, atol=1e-10, autodiff_mode="fwd"
    )
    assert int(fwd.status) == 0
    np.testing.assert_allclose(fwd.accepted()[:10], history[:10], rtol=1e-9)
    np.testing.assert_allclose(fwd.design, np.ones(4), atol=1e-7)


def test_box_bound_matches_scipy_lbfgsb_and_is_respected():
    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    seen = []
    ours = optimise.minimise(
        quadratic,
        jnp.zeros(3),
        lower=jnp.asarray(lo),
        upper=jnp.asarray(hi),
        max_steps=200,
        rtol=1e-12,
        atol=1e-12,
        progress=lambda step, value: seen.append((step, value)),
    )
    jax.effects_barrier()
    ref = scipy.optimize.minimize(
        lambda x: float(quadratic(jnp.asarray(x), None)),
        np.zeros(3),
        jac=lambda x: np.asarray(jax.grad(quadratic)(jnp.asarray(x), None)),
        method="L-BFGS-B",
        bounds=list(zip(lo, hi)),
        options={"ftol": 1e-15, "gtol": 1e-12},
    )
    np.testing.assert_allclose(ours.design, ref.x, atol=1e-6)
    assert float(ours.value) == pytest.approx(ref.fun, rel=1e-9)
    assert np.all(np.asarray(ours.design) >= lo) and np.all(np.asarray(ours.design) <= hi)
    assert abs(float(ours.design[0]) - 1.0) < 1e-6  # the free optimum x0 = 2 is outside: on the bound
    # the progress callback saw every accepted step, in order, with the history's values
    assert [s for s, _ in seen] == list(range(int(ours.steps) + 1))
    np.testing.assert_allclose([v for _, v in seen], ours.accepted())


def test_one_sided_bounds_pytree_design():
    design = {"a": jnp.array([0.5, 0.5]), "b": jnp.array(1.9)}

    def f(d, args):
        return jnp.sum((d["a"] + 1.0) ** 2) + (d["b"] - 1.0) ** 2

    r = optimise.minimise(f, design, lower={"a": jnp.zeros(2), "b": -jnp.inf}, upper={"a": 2.0, "b": 2.0})
    np.testing.assert_allclose(r.design["a"], 0.0, atol=1e-6)  # lower bound active
    assert float(r.design["b"]) == pytest.approx(1.0, abs=1e-7)  # interior (below the upper 2)
    assert monotone(r.accepted())


def test_fixed_entries_match_scipy_on_the_free_subspace():
    free = np.array([True, False, True])
    x0 = np.array([0.3, 0.7, -0.2])
    ours = optimise.minimise(quadratic, jnp.asarray(x0), free=jnp.asarray(free), rtol=1e-12, atol=1e-12)
    assert float(ours.design[1]) == x0[1]  # exactly fixed

    def reduced(y):
        return float(quadratic(jnp.asarray(np.array([y[0], x0[1], y[1]])), None))

    ref = scipy.optimize.minimize(reduced, x0[free], method="BFGS", options={"gtol": 1e-10})
    np.testing.assert_allclose(np.asarray(ours.design)[free], ref.x, atol=1e-6)


def test_penalty_constraint_closed_form():
    # min ‖x‖² + ½ μ (Σx − 1)²  →  x_i = s/n with s = μ / (μ + 2/n)
    n, mu = 4, 50.0
    r = optimise.minimise(
        lambda x, a: jnp.sum(x**2),
        jnp.linspace(-1.0, 1.0, n),
        constraint=lambda x, a: jnp.sum(x) - 1.0,
        penalty=mu,
        rtol=1e-12,
        atol=1e-12,
    )
    s = mu / (mu + 2.0 / n)
    np.testing.assert_allclose(r.design, np.full(n, s / n), atol=1e-8)


@pytest.mark.parametrize("method", ["levenberg_marquardt", "gauss_newton"])
def test_least_squares_matches_scipy(method):
    t = np.linspace(0.0, 2.0, 12)
    y = 1.5 * np.exp(-0.8 * t) + 0.05 * np.sin(7 * t)

    def residuals(p, data):
        tt, yy = data
        return p[0] * jnp.exp(-p[1] * tt) - yy

    data = (jnp.asarray(t), jnp.asarray(y))
    ours = optimise.least_squares(residuals, jnp.array([1.0, 0.1]), data, method=method, max_steps=200)
    ref = scipy.optimize.least_squares(lambda p: np.asarray(residuals(jnp.asarray(p), data)), [1.0, 0.1])
    np.testing.assert_allclose(ours.design, ref.x, atol=1e-6)
    assert float(ours.value) == pytest.approx(ref.cost, rel=1e-8)  # both ½‖r‖²
    assert int(ours.status) == 0 and monotone(ours.accepted())


def test_vmap_over_starting_points():
    starts = jnp.array([[-1.2, 1.0], [0.0, 0.0], [2.0, 2.5]])
    batched = jax.vmap(lambda x0: optimise.minimise(rosenbrock, x0, max_steps=150, throw=False))(starts)
    for i in range(len(starts)):
        one = optimise.minimise(rosenbrock, starts[i], max_steps=150, throw=False)
        np.testing.assert_allclose(batched.design[i], one.design, atol=1e-10)
        assert int(batched.steps[i]) == int(one.steps)
    np.testing.assert_allclose(batched.design, np.ones((3, 2)), atol=1e-6)


def test_max_steps_status_and_throw():
    r = optimise.minimise(rosenbrock, jnp.array([-1.2, 1.0]), max_steps=15, throw=False)  # one step accepted
    assert optimise.STATUS[int(r.status)] == "max_steps" and int(r.evaluations) == 15
    assert float(r.value) < float(rosenbrock(jnp.array([-1.2, 1.0]), None))
    with pytest.raises(ValueError, match="max_steps: expected convergence within 5 steps"):
        optimise.minimise(rosenbrock, jnp.array([-1.2, 1.0]), max_steps=5)


def test_bad_input_raises_clear_errors():
    x = jnp.array([0.5, 0.5])
    raises_both(
        lambda x: optimise.minimise(lambda d, a: d**2, x), x, match="objective: expected a scalar float"
    )
    raises_both(
        lambda x: optimise.minimise(rosenbrock, x), jnp.array([jnp.nan, 1.0]), match="design: .*finite"
    )
    raises_both(
        lambda x: optimise.minimise(rosenbrock, x, lower=1.0, upper=0.0),
        x,
        match="lower: expected lower <= upper",
    )
    raises_both(
        lambda x: optimise.minimise(rosenbrock, x, lower=0.6, upper=1.0),
        x,
        match="design: expected a start within",
    )
    raises_both(
        lambda x: optimise.minimise(rosenbrock, x, constraint=lambda d, a: d[0], penalty=-1.0),
        x,
        match="penalty: expected finite",
    )
    raises_both(lambda x: optimise.least_squares(rosenbrock, x, rtol=jnp.nan), x, match="rtol")
    with pytest.raises(ValueError, match="max_steps: expected an int >= 2"):
        optimise.minimise(rosenbrock, x, max_steps=1)
    with pytest.raises(ValueError, match="method: expected one of"):
        optimise.minimise(rosenbrock, x, method="adam")
    with pytest.raises(ValueError, match="autodiff_mode: expected 'bwd' or 'fwd', got 'forward'"):
        optimise.minimise(rosenbrock, x, autodiff_mode="forward")
    with pytest.raises(ValueError, match="free: expected booleans of shape"):
        optimise.minimise(rosenbrock, x, free=jnp.array([1.0, 0.0]))
    with pytest.raises(TypeError, match="design: expected floating-point"):
        optimise.minimise(rosenbrock, jnp.array([1, 2]))
    with pytest.raises(
        ValueError,
        match=r"objective: expected a scalar float output \(shape \(\)\), got shape \(2,\) float64",
    ):
        optimise.minimise(lambda d, a: d**2, x)
    with pytest.raises(
        ValueError, match=r"objective: expected a scalar float output \(shape \(\)\), got shape \(\) int"
    ):
        jax.jit(lambda d: optimise.minimise(lambda e, a: jnp.sum(e > 0), d).design)(x)
    with pytest.raises(
        ValueError, match=r"residuals: expected a pytree of float arrays, got \{'r': 'int64\[2\]'\}"
    ):
        optimise.least_squares(lambda d, a: {"r": (d > 0).astype(int)}, x)
    with pytest.raises(ValueError, match=r"residuals: expected a pytree of float arrays, got \(\)"):
        optimise.least_squares(lambda d, a: (), x)


@pytest.mark.slow
@pytest.mark.users_compiler  # a chaotic rollout: a trial design diverged in an unoptimised build
def test_bowl_optimisation_lowers_spill_risk():
    """The spoon bowl on two deformable bodies (quick sizes): BFGS (with `jax.grad` through
    merge, the steel shell's rest shape, surface–surface contact and both lattices' rollout)
    lowers the spill risk itself, not only the objective, monotonically, with the rim fixed
    and within the bounds. (The derivative's parts are checked against central differences
    where they are built: `Body.with_ctrl` in test_mss_scene, the contact rollout there and in
    the demo's check, merge in test_merge; the comparison with scipy's Nelder–Mead on the same
    budget is `benchmarks/bowl.py`.)"""
    from bsjax.examples import bowl

    s = bowl.study(quick=True)
    found = bowl.optimise_bowl(s, max_steps=3)
    history = found.accepted()
    assert found.steps >= 1 and monotone(history) and history[-1] < history[0]
    assert float(jnp.max(jnp.abs(jnp.where(s.free, 0.0, found.design)))) == 0.0  # rim and others fixed
    assert float(found.design.min()) >= bowl.LOWER and float(found.design.max()) <= bowl.UPPER
    # the risk is the objective without its smoothness term (which is 0 at the start)
    risk = float(found.value) / 100.0 - float(s.smoothing * bowl.smoothness(found.design))
    assert risk < history[0] / 100.0


def test_lower_bound_only_and_change_of_variables_round_trip():
    r = optimise.minimise(lambda x, a: jnp.sum((x + 1.0) ** 2), jnp.array([1.0, 3.0]), lower=0.0)
    np.testing.assert_allclose(r.design, 0.0, atol=1e-6)
    assert float(r.design.min()) >= 0.0 and monotone(r.accepted())
    from bsjax.optimise import _to_design, _to_internal

    x = jnp.array([0.3, -2.0, 5.0, 0.7])
    lo = jnp.array([0.0, -jnp.inf, 1.0, -jnp.inf])
    hi = jnp.array([1.0, -1.0, jnp.inf, jnp.inf])
    np.testing.assert_allclose(_to_design(_to_internal(x, lo, hi), lo, hi), x, rtol=1e-12)


def test_non_finite_objective_reports_failure():
    def nan_objective(x, args):
        return jnp.sum(jnp.log(x))  # log of a negative entry: NaN at the start

    r = optimise.minimise(nan_objective, jnp.array([-1.0, 2.0]), throw=False)
    assert optimise.STATUS[int(r.status)] == "failed"
    with pytest.raises(ValueError, match="objective: expected finite values"):
        optimise.minimise(nan_objective, jnp.array([-1.0, 2.0]))
