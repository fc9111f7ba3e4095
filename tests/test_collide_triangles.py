"""Triangle–triangle overlap against python-fcl and an exact LP reference; closest points vs trimesh."""

import fcl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from scipy.optimize import linprog

from bsjax.collide._triangles import closest_point_on_triangle, triangles_intersect
from tests.helpers import raises_both

_intersect = jax.jit(triangles_intersect)


def _fcl_hit(a, b):
    objs = []
    for t in (a, b):
        model = fcl.BVHModel()
        model.beginModel(3, 1)
        model.addSubModel(np.asarray(t, np.float64), np.array([[0, 1, 2]]))
        model.endModel()
        objs.append(fcl.CollisionObject(model, fcl.Transform()))
    return fcl.collide(objs[0], objs[1], fcl.CollisionRequest()) > 0


def _lp_hit(a, b):
    """Exact-enough reference: is there λ, μ ≥ 0, Σ = 1 with Σ λ_i a_i = Σ μ_j b_j? (LP feasibility)."""
    a_eq = np.zeros((5, 6))
    a_eq[:3, :3], a_eq[:3, 3:] = a.T, -b.T
    a_eq[3, :3] = a_eq[4, 3:] = 1
    res = linprog(np.zeros(6), A_eq=a_eq, b_eq=[0, 0, 0, 1, 1], bounds=(0, None), method="highs")
    return res.status == 0


def _near_degenerate(rng, count):
    """Pairs within ~1e-6 of touching: shared/perturbed vertices, edges, near-coplanar overlaps."""
    out = []
    for i in range(count):
        t1 = rng.normal(size=(3, 3))
        n = np.cross(t1[1] - t1[0], t1[2] - t1[0])
        n /= np.linalg.norm(n)
        kind = i % 4
        eps = 1e-6 * rng.choice([-1.0, 1.0])
        if kind == 0:  # vertex of t2 just above/below the interior of t1
            w = rng.dirichlet(np.ones(3))
            apex = w @ t1 + eps * n
            t2 = np.stack(
                [
                    apex,
                    apex + rng.normal(size=3) + 0.5 * n * np.sign(eps),
                    apex + rng.normal(size=3) + 0.5 * n * np.sign(eps),
                ]
            )
        elif kind == 1:  # nearly coplanar, offset by eps along the normal, overlapping or not
            t2 = (t1 - t1.mean(0)) @ _rot(rng, n) + t1.mean(0) + rng.normal(size=3) * 0.8
            t2 = t2 - ((t2 - t1[0]) @ n)[:, None] * n + eps * n
        elif kind == 2:  # edge of t2 crossing an edge of t1 at distance eps
            p = t1[0] + rng.uniform(0.2, 0.8) * (t1[1] - t1[0])
            d = np.cross(t1[1] - t1[0], n)
            d /= np.linalg.norm(d)
            side = np.cross(d, n)
            t2 = np.stack(
                [p + eps * d + side, p + eps * d - side, p + eps * d + 2 * d + rng.normal(size=3) * 0.3]
            )
        else:  # shared vertex, second triangle tilted away or into t1
            t2 = np.stack([t1[0] + eps * n, t1[0] + rng.normal(size=3), t1[0] + rng.normal(size=3)])
        out.append((t1, t2))
    a, b = zip(*out)
    return np.array(a), np.array(b)


def _rot(rng, axis):
    angle = rng.uniform(0, 2 * np.pi)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_random_pairs_match_fcl():
    rng = np.random.default_rng(1)
    n = 1500
    t1 = rng.normal(size=(n, 3, 3))
    t2 = rng.normal(size=(n, 3, 3)) * rng.uniform(0.5, 1.5, (n, 1, 1)) + rng.normal(size=(n, 1, 3)) * 0.3
    ref = np.array([_fcl_hit(a, b) for a, b in zip(t1, t2)])
    got = np.asarray(_intersect(t1, t2))
    assert 0.1 < ref.mean() < 0.9
    np.testing.assert_array_equal(got, ref)
    # symmetric in the argument order
    np.testing.assert_array_equal(np.asarray(_intersect(t2, t1)), ref)


def test_near_degenerate_pairs_match_fcl_and_lp():
    rng = np.random.default_rng(2)
    t1, t2 = _near_degenerate(rng, 1000)
    got = np.asarray(_intersect(t1, t2))
    ref = np.array([_fcl_hit(a, b) for a, b in zip(t1, t2)])
    assert 0.2 < ref.mean() < 0.8
    disagree = np.nonzero(got != ref)[0]
    # fcl misjudges some edges lying in the other triangle's plane (2 % here); wherever it
    # disagrees, an LP feasibility check of the intersection must side with us
    assert len(disagree) <= 0.05 * len(got), len(disagree)
    for i in disagree:
        assert got[i] == _lp_hit(t1[i], t2[i])


def test_exact_degenerate_cases_match_lp():
    """Small-integer triangles: coplanar, shared vertices/edges, zero-area (segments, points)."""
    rng = np.random.default_rng(3)
    n = 600
    t1 = rng.integers(-3, 4, size=(n, 3, 3)).astype(float)
    t2 = rng.integers(-3, 4, size=(n, 3, 3)).astype(float)
    t1[: n // 2, :, 2] = 0  # half coplanar in z = 0
    t2[: n // 2, :, 2] = 0
    t2[n // 2 : 3 * n // 4, 0] = t1[n // 2 : 3 * n // 4, 1]  # shared vertex
    t1[::7, 2] = t1[::7, 0] + 2 * (t1[::7, 1] - t1[::7, 0])  # collinear (zero area)
    t2[::11, 1] = t2[::11, 2] = t2[::11, 0]  # a point
    got = np.asarray(_intersect(t1, t2))
    ref = np.array([_lp_hit(a, b) for a, b in zip(t1, t2)])
    assert 0.2 < ref.mean() < 0.9
    np.testing.assert_array_equal(got, ref)


def test_broadcasting_jit_vmap():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(5, 1, 3, 3))
    b = rng.normal(size=(1, 4, 3, 3))
    out = _intersect(a, b)
    assert out.shape == (5, 4) and out.dtype == jnp.bool_
    loop = np.array([[_fcl_hit(a[i, 0], b[0, j]) for j in range(4)] for i in range(5)])
    np.testing.assert_array_equal(np.asarray(out), loop)
    vm = jax.jit(jax.vmap(jax.vmap(triangles_intersect, (None, 0)), (0, None)))(a[:, 0], b[0])
    np.testing.assert_array_equal(np.asarray(vm), loop)
    with pytest.raises(ValueError, match="t1, t2"):
        triangles_intersect(np.zeros((3, 2)), np.zeros((3, 3)))


def test_closest_point_matches_trimesh():
    rng = np.random.default_rng(5)
    tris = rng.normal(size=(500, 3, 3))
    tris[::10, 2] = tris[::10, 1]  # some degenerate
    pts = rng.normal(size=(500, 3)) * 2
    got, bary = closest_point_on_triangle(jnp.asarray(pts), jnp.asarray(tris))
    ref = trimesh.triangles.closest_point(tris, pts)
    np.testing.assert_allclose(
        np.linalg.norm(np.asarray(got) - pts, axis=1), np.linalg.norm(ref - pts, axis=1), atol=1e-9
    )
    np.testing.assert_allclose(np.asarray(jnp.einsum("nk,nkc->nc", bary, tris)), np.asarray(got), atol=1e-12)
    assert np.all(np.asarray(bary) >= -1e-12)


@pytest.mark.parametrize(
    ("fn", "args", "match"),
    [
        (triangles_intersect, (np.full((2, 3, 3), np.nan), np.zeros((2, 3, 3))), "t1: expected finite"),
        (triangles_intersect, (np.zeros((2, 3, 3)), np.zeros((3, 3, 3))), "t1, t2: expected batch shapes"),
        (closest_point_on_triangle, (np.array([0.0, np.inf, 0.0]), np.eye(3)), "x: expected finite"),
        (closest_point_on_triangle, (np.zeros(3), np.full((4, 3, 3), np.nan)), "tri: expected finite"),
        (closest_point_on_triangle, (np.zeros(2), np.eye(3)), "x: expected shape"),
    ],
)
def test_bad_values_raise_eagerly_and_under_jit(fn, args, match):
    raises_both(fn, *(jnp.asarray(a) for a in args), match=match)


def test_closest_point_direct_matches_jit_on_degenerate_triangles():
    """Zero-area triangles (segments, points) give the same closest point as called and inside
    the caller's `jit`: no decision rests on an exact cancellation that fused code breaks."""
    rng = np.random.default_rng(6)
    tris = rng.normal(size=(300, 3, 3))
    tris[::3, 2] = tris[::3, 1]  # segments
    tris[1::3, 1] = tris[1::3, 2] = tris[1::3, 0]  # points
    pts = rng.normal(size=(300, 3))
    direct, _ = closest_point_on_triangle(pts, tris)
    inside_jit, _ = jax.jit(lambda x, t: closest_point_on_triangle(x, t))(pts, tris)
    ref = trimesh.triangles.closest_point(tris, pts)
    for got in (direct, inside_jit):
        np.testing.assert_allclose(
            np.linalg.norm(np.asarray(got) - pts, axis=1), np.linalg.norm(ref - pts, axis=1), atol=1e-12
        )


def test_batched_candidate_test_agrees_with_the_single_pair_test():
    """The masked batch test of `surface_contacts` (`candidate_pairs_intersect`) gives exactly
    `triangles_intersect` on active pairs — touching at one vertex, along an edge, coplanar,
    zero-area — and False on inactive (padding) pairs."""
    from bsjax.collide._triangles import candidate_pairs_intersect

    rng = np.random.default_rng(6)
    n = 400
    t1 = rng.integers(-2, 3, size=(n, 3, 3)).astype(float)
    t2 = rng.integers(-2, 3, size=(n, 3, 3)).astype(float)
    t2[: n // 4, 0] = t1[: n // 4, 2]  # one shared vertex
    t2[n // 4 : n // 2, :2] = t1[n // 4 : n // 2, :2]  # a shared edge
    t1[n // 2 : 3 * n // 4, :, 2] = t2[n // 2 : 3 * n // 4, :, 2] = 1.0  # coplanar
    t2[::9, 1] = t2[::9, 2] = t2[::9, 0]  # a point
    single = np.asarray(triangles_intersect(jnp.asarray(t1), jnp.asarray(t2)))
    assert single[: n // 2].all() and 0.2 < single[n // 2 :].mean() < 0.95
    active = rng.uniform(size=n) < 0.7
    batched = np.asarray(candidate_pairs_intersect(jnp.asarray(t1), jnp.asarray(t2), jnp.asarray(active)))
    np.testing.assert_array_equal(batched, single & active)


def test_surfaces_touching_at_one_vertex_are_in_contact():
    """Two plates whose sample grids share only the corner (1, 1, 0), the second tilted up and
    away: `surface_contacts` reports the contact (the single-pair test alone would find it).
    Bicubic 6 × 6 nets at 10 × 10 samples and capacity 512, as test_collide's direct/jit/vmap
    test: the run's compilation cache serves both programs (the exact pass and the dense one)."""
    from bsjax import collide, shapes

    a = shapes.plate(6, 6)
    tilt = jnp.asarray(a.ctrl) * jnp.array([[[1.0, 1.0, 0.0]]])
    b = a.with_ctrl(tilt + jnp.array([[[1.0, 1.0, 0.0]]]) + tilt[..., :1] * jnp.array([[[0.0, 0.0, 1.0]]]))
    ba, bb = a.blending(10, 10), b.blending(10, 10)
    assert np.allclose(bb.points(b.ctrl)[0, 0], [1.0, 1.0, 0.0]) and np.allclose(
        ba.points(a.ctrl)[-1, -1], [1, 1, 0]
    )
    out = collide.surface_contacts(ba, a.ctrl, bb, b.ctrl, capacity=512, flat_angle=None)
    dense = collide.surface_contacts(ba, a.ctrl, bb, b.ctrl, method="dense")
    assert bool(dense.hit) and bool(out.hit)
    assert bool(out.mask_a[-1, -1]) and bool(out.mask_b[0, 0])
