"""`Blending`: grid evaluation, derivatives, normals, refit and views against references."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import shapes
from bsjax.basis import Blending, BSplineSurface, clamped_knots, greville
from tests.helpers import check_grad, random_knots
from tests.oracles import ndbspline_surface, periodic_reference, scipy_matrix, tolerance

R, S, M, N = 7, 5, 13, 11  # non-square control net and non-square grid


def _surface(rng, kind, k=3, l=2):
    """clamped random knots, periodic in v, or rational (weights)."""
    tu = random_knots(rng, R, k)
    ctrl = rng.normal(size=(R, S, 3))
    if kind == "periodic":
        return BSplineSurface(ctrl, tu, None, k, l, periodic_v=True)
    w = rng.uniform(0.5, 2.0, (R, S)) if kind == "rational" else None
    return BSplineSurface(ctrl, tu, random_knots(rng, S, l), k, l, weights=w)


def _grid_reference(surface, b, nu, nv):
    u, v = np.meshgrid(np.asarray(b.params_u), np.asarray(b.params_v), indexing="ij")
    return ndbspline_surface(surface, u, v, nu, nv)


@eqx.filter_jit
def _derivatives(b, ctrl):
    return {(a, c): b.derivative(ctrl, a, c) for a in range(3) for c in range(3) if a + c <= 2}


KINDS = ["clamped", "periodic", "rational"]
# Eager calls compile every primitive for each new shape (seconds on a busy CPU): the tests go
# through these jitted wrappers (a Blending is a pytree) and check eager == jit once.
_points = jax.jit(lambda b, c: b.points(c))
_normals = jax.jit(lambda b, c: b.normals(c))
_refit = jax.jit(lambda b, p: b.refit(p))


@pytest.mark.parametrize("kind", KINDS)
def test_grid_derivatives_match_ndbspline(kind):
    rng = np.random.default_rng(KINDS.index(kind))
    surface = _surface(rng, kind)
    b = surface.blending(M, N)
    assert b.grid_shape == (M, N) and b.ctrl_shape == (R, S)
    np.testing.assert_array_equal(b.params_u, np.linspace(0, 1, M))  # u = 1 included
    for (nu, nv), got in _derivatives(b, surface.ctrl).items():
        ref = _grid_reference(surface, b, nu, nv)
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance(ref), err_msg=str((nu, nv)))
    np.testing.assert_array_equal(b.points(surface.ctrl), _derivatives(b, surface.ctrl)[0, 0])


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_stored_matrices_match_scipy(degree):
    rng = np.random.default_rng(10 + degree)
    tu = random_knots(rng, 8, degree)
    surface = BSplineSurface(rng.normal(size=(8, 6, 3)), tu, None, degree, 3, periodic_v=True)
    params_u = np.sort(np.concatenate([[0.0, 1.0], tu[degree + 1 : -degree - 1], rng.uniform(0, 1, 5)]))
    b = surface.blending(params_u=params_u, n=9)
    for nu in range(3):
        ref = scipy_matrix(tu, degree, params_u, nu)
        np.testing.assert_allclose(b.a_u[nu], ref, rtol=0, atol=tolerance(ref))
        ref = periodic_reference(6, 3, np.linspace(0, 1, 9), nu)
        np.testing.assert_allclose(b.a_v[nu], ref, rtol=0, atol=tolerance(ref))


def test_tangents_and_normals():
    rng = np.random.default_rng(20)
    surface = _surface(rng, "rational")
    b = surface.blending(M, N)
    t_u, t_v = b.tangents(surface.ctrl)
    np.testing.assert_allclose(t_u, _grid_reference(surface, b, 1, 0), atol=tolerance(t_u))
    np.testing.assert_allclose(t_v, _grid_reference(surface, b, 0, 1), atol=tolerance(t_v))
    n = np.asarray(_normals(b, surface.ctrl))
    ref = np.cross(t_u, t_v)
    np.testing.assert_allclose(n, ref / np.linalg.norm(ref, axis=-1, keepdims=True), atol=1e-10)
    u, v = np.meshgrid(np.asarray(b.params_u), np.asarray(b.params_v), indexing="ij")
    np.testing.assert_allclose(n, surface.normal(u, v), atol=1e-12)


def test_teardrop_normals_outward_and_finite_on_the_82_grid():
    drop = shapes.teardrop()
    b = drop.blending()
    n = np.asarray(_normals(b, drop.ctrl))
    p = np.asarray(_points(b, drop.ctrl))
    assert b.grid_shape == (82, 82) and np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    centre = p.reshape(-1, 3).mean(0)
    assert np.mean(np.sum(n * (p - centre), -1) > 0) > 0.99  # outward almost everywhere
    assert np.all(n[0, :, 2] > 0) and np.all(n[-1, :, 2] < 0)  # the poles


# --- refit -------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("grid", [(M, N), (R, S)])  # over-determined and square (m = r, n = s)
def test_refit_round_trip(kind, grid):
    rng = np.random.default_rng(30 + KINDS.index(kind))
    surface = _surface(rng, kind)
    if grid == (R, S):
        # Square grid at the Greville abscissae (Schoenberg–Whitney holds, A_u is invertible);
        # a closed direction samples [0, 1) without repeating the seam.
        pv = np.arange(S) / S if kind == "periodic" else greville(surface.knots_v, 2)
        b = surface.blending(params_u=greville(surface.knots_u, 3), params_v=pv)
        assert np.linalg.matrix_rank(np.asarray(b.a_u[0])) == R
    else:
        b = surface.blending(*grid)
    ctrl = jnp.asarray(rng.normal(size=(R, S, 3)))
    np.testing.assert_allclose(_refit(b, _points(b, ctrl)), ctrl, rtol=0, atol=1e-10)


def test_refit_is_least_squares_for_noisy_points():
    """Refit of noisy points = numpy lstsq on the Kronecker system (independent solve)."""
    rng = np.random.default_rng(40)
    surface = _surface(rng, "clamped")
    b = surface.blending(M, N)
    pts = _points(b, surface.ctrl) + 0.01 * rng.normal(size=(M, N, 3))
    kron = np.kron(np.asarray(b.a_u[0]), np.asarray(b.a_v[0]))  # (M N, R S)
    ref = np.linalg.lstsq(kron, np.asarray(pts).reshape(M * N, 3), rcond=None)[0].reshape(R, S, 3)
    np.testing.assert_allclose(_refit(b, pts), ref, rtol=0, atol=1e-10)


def test_refit_gradient_and_jit():
    rng = np.random.default_rng(41)
    surface = _surface(rng, "periodic")
    b = surface.blending(M, N)
    probe = jnp.asarray(rng.normal(size=(R, S, 3)))
    f = jax.jit(lambda pts: jnp.sum(_refit(b, pts) * probe))
    pts = _points(b, surface.ctrl)
    g = check_grad(f, pts)
    # refit is linear: its gradient is A_u^{+T} probe A_v^{+}, an explicit pseudo-inverse product.
    pu, pv = np.linalg.pinv(np.asarray(b.a_u[0])), np.linalg.pinv(np.asarray(b.a_v[0]))
    np.testing.assert_allclose(g, np.einsum("ia,ijc,jb->abc", pu, np.asarray(probe), pv), atol=1e-10)


# --- views -------------------------------------------------------------------------------------
def test_window_is_a_row_subset_with_indices():
    rng = np.random.default_rng(50)
    surface = _surface(rng, "rational")
    b = surface.blending(21, 17)
    w = b.window(0.2, 0.55, 0.5, 1.0)
    pu, pv = np.linspace(0, 1, 21), np.linspace(0, 1, 17)
    rows = np.nonzero((pu >= 0.2) & (pu <= 0.55))[0]
    cols = np.nonzero(pv >= 0.5)[0]
    np.testing.assert_array_equal(w.index_u, rows)
    np.testing.assert_array_equal(w.index_v, cols)
    np.testing.assert_array_equal(w.a_u, np.asarray(b.a_u)[:, rows])
    np.testing.assert_array_equal(w.a_v, np.asarray(b.a_v)[:, cols])
    full = np.asarray(_points(b, surface.ctrl))
    np.testing.assert_allclose(_points(w, surface.ctrl), full[np.ix_(rows, cols)], rtol=0, atol=1e-14)
    np.testing.assert_allclose(
        _normals(w, surface.ctrl), np.asarray(_normals(b, surface.ctrl))[np.ix_(rows, cols)], atol=1e-14
    )
    assert w.refit_u is None and w.grid_shape == (len(rows), len(cols))


@pytest.mark.parametrize("q_u, q_v, m, n", [(4, None, 21, 17), (3, 5, 20, 17), (1, 2, 9, 8)])
def test_lod_is_every_qth_row_and_keeps_the_last(q_u, q_v, m, n):
    rng = np.random.default_rng(51)
    surface = _surface(rng, "periodic")
    b = surface.blending(m, n)
    lod = b.lod(q_u, q_v)
    qv = q_u if q_v is None else q_v
    rows = sorted(set(range(0, m, q_u)) | {m - 1})
    cols = sorted(set(range(0, n, qv)) | {n - 1})
    np.testing.assert_array_equal(lod.index_u, rows)
    np.testing.assert_array_equal(lod.index_v, cols)
    np.testing.assert_array_equal(lod.params_u, np.asarray(b.params_u)[rows])
    full = np.asarray(_points(b, surface.ctrl))
    np.testing.assert_allclose(_points(lod, surface.ctrl), full[np.ix_(rows, cols)], rtol=0, atol=1e-14)
    window = b.window(0.3, 1.0, 0.0, 1.0)
    inside = np.asarray(window.index_u)
    np.testing.assert_array_equal(
        window.lod(2).index_u, inside[sorted(set(range(0, len(inside), 2)) | {len(inside) - 1})]
    )
    coarse = window.lod(2)
    np.testing.assert_allclose(
        _points(coarse, surface.ctrl), full[np.ix_(coarse.index_u, coarse.index_v)], rtol=0, atol=1e-14
    )


def test_surface_round_trip_and_custom_params():
    rng = np.random.default_rng(52)
    surface = _surface(rng, "rational")
    pu = np.sort(rng.uniform(0, 1, M))
    b = Blending.from_surface(surface, params_u=pu, n=N)
    np.testing.assert_array_equal(b.params_u, pu)
    back = b.surface(surface.ctrl)
    u, v = np.meshgrid(pu, np.linspace(0, 1, N), indexing="ij")
    np.testing.assert_allclose(_points(b, surface.ctrl), back.evaluate(u, v), atol=1e-13)
    np.testing.assert_array_equal(back.weights, surface.weights)


# --- jit / vmap / grad / dtype -----------------------------------------------------------------
@pytest.mark.parametrize("kind", ["clamped", "rational"])
def test_vmap_over_control_nets_equals_loop(kind):
    rng = np.random.default_rng(60)
    surface = _surface(rng, kind)
    b = surface.blending(M, N)
    nets = jnp.asarray(rng.normal(size=(6, R, S, 3)))
    single = jax.jit(lambda c: (_points(b, c), _normals(b, c)))
    pts, nrm = jax.jit(jax.vmap(single))(nets)
    for i in range(6):
        p, n = single(nets[i])
        np.testing.assert_allclose(pts[i], p, rtol=0, atol=1e-13)
        np.testing.assert_allclose(nrm[i], n, rtol=0, atol=1e-13)


@pytest.mark.parametrize("kind", KINDS)
def test_grad_through_points_and_normals(kind):
    rng = np.random.default_rng(70)
    surface = _surface(rng, kind)
    b = surface.blending(M, N)
    probe = jnp.asarray(rng.normal(size=(M, N, 3)))
    f = jax.jit(lambda c: jnp.sum(_points(b, c) * probe) + jnp.sum(_normals(b, c) * probe))
    check_grad(f, surface.ctrl)
    # points are linear in the control net: the gradient is A_u^T probe A_v (no FD involved).
    g = jax.grad(lambda c: jnp.sum(_points(b, c) * probe))(surface.ctrl)
    if kind != "rational":
        ref = np.einsum("ai,abc,bj->ijc", np.asarray(b.a_u[0]), np.asarray(probe), np.asarray(b.a_v[0]))
        np.testing.assert_allclose(g, ref, atol=1e-12)


def test_grad_through_weights():
    rng = np.random.default_rng(71)
    surface = _surface(rng, "rational")
    b = surface.blending(M, N)
    probe = jnp.asarray(rng.normal(size=(M, N, 3)))
    f = jax.jit(lambda w: jnp.sum(eqx.tree_at(lambda x: x.weights, b, w).points(surface.ctrl) * probe))
    check_grad(f, surface.weights)


@pytest.mark.parametrize("kind", KINDS)
def test_float32_stays_float32(kind):
    rng = np.random.default_rng(80)
    s64 = _surface(rng, kind)
    # uniform knots: random ones can leave a knot span without samples (A_u near-singular,
    # harmless in float64, but float32's pseudo-inverse cut-off drops that component)
    s64 = eqx.tree_at(lambda s: s.knots_u, s64, clamped_knots(R, 3))
    s32 = BSplineSurface(
        np.asarray(s64.ctrl, np.float32),
        s64.knots_u,
        s64.knots_v,
        3,
        2,
        periodic_v=s64.periodic_v,
        weights=None if s64.weights is None else np.asarray(s64.weights, np.float32),
    )
    b = s32.blending(M, N)
    leaves = [x for x in jax.tree_util.tree_leaves(b) if jnp.issubdtype(x.dtype, jnp.floating)]
    assert all(x.dtype == jnp.float32 for x in leaves), [x.dtype for x in leaves]
    out = [_points(b, s32.ctrl), _normals(b, s32.ctrl), _refit(b, _points(b, s32.ctrl))]
    assert all(x.dtype == jnp.float32 for x in out)
    np.testing.assert_allclose(out[0], _grid_reference(s64, b, 0, 0), atol=2e-5)
    np.testing.assert_allclose(out[2], s32.ctrl, atol=5e-4)


def test_periodic_refit_round_trip_with_as_many_samples_as_control_points():
    """SPEC §2: `refit(points(P)) == P` to 1e-10 whenever m ≥ r and n ≥ s. In a closed
    direction the default `linspace(0, 1, n)` samples the seam twice (u = 0 ≡ u = 1), so with
    n == s the stored pseudo-inverse is rank-deficient and the refit is silently wrong (error
    O(1)). Either sample [0, 1) in closed directions or refuse (rank check) in `Blending`."""
    rng = np.random.default_rng(1)
    r, s = 6, 5
    surface = BSplineSurface(rng.normal(size=(r, s, 3)), clamped_knots(r, 3), None, 3, 3, periodic_v=True)
    b = surface.blending(r + 4, s)
    ctrl = jnp.asarray(rng.normal(size=(r, s, 3)))
    try:
        back = b.refit(b.points(ctrl))
    except ValueError as error:  # refusing with a clear message also satisfies the contract
        assert "n" in str(error)
        return
    np.testing.assert_allclose(back, ctrl, rtol=0, atol=1e-10)
