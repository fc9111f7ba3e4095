"""The faster collision kernels give the results of the plain formulas (issue #11, item 2).

References are independent of the kernels under test: the basis's own `Blending.points` and
`Blending.normals`, the tools' closed forms written with numpy, a fixed-step Frank–Wolfe loop
in numpy for the hull test, the one-program (`lax.while_loop`) path of `surface_contacts` inside
the caller's `jit` for its two-program direct path, a brute-force nearest triangle for the
point tool, the thesis's three-point spheres in numpy for the sphere hierarchy, and the
every-pair triangle test for the gathered candidate pairs.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import shapes
from bsjax.basis import BSplineSurface, SplineDirection
from bsjax.collide import (
    Ellipsoid,
    Plane,
    Point,
    Sphere,
    contacts,
    grid_mesh,
    surface_contacts,
)
from bsjax.collide._broad import hulls_apart
from bsjax.collide._contact import points_normals, sample_window
from bsjax.collide._hierarchy import block_order, levels_for, sphere_hierarchy
from bsjax.collide._triangles import candidate_pairs_intersect, closest_point_on_triangle, triangles_intersect
from tests.helpers import check_grad, raises_both, random_surface


def _periodic(rng):
    """Closed in u (a tube-like band), clamped in v."""
    du, dv = SplineDirection.closed(6, 3), SplineDirection.uniform(5, 2)
    angle = np.linspace(0, 2 * np.pi, 6, endpoint=False)[:, None]
    height = np.linspace(0, 1, 5)[None, :]
    ring = 1 + 0.1 * rng.normal(size=(6, 5))
    ctrl = np.stack([ring * np.cos(angle), ring * np.sin(angle), np.broadcast_to(height, (6, 5))], -1)
    return BSplineSurface.from_directions(ctrl, du, dv)


def _pole(rng):
    """A polynomial surface whose first row collapses to one point (T_v = 0 there)."""
    surf = random_surface(rng, 6, 5, 3, 2)
    ctrl = np.asarray(surf.ctrl).copy()
    ctrl[0] = ctrl[0].mean(0)
    return surf.with_ctrl(jnp.asarray(ctrl))


SHAPES = {
    "clamped 3x2": lambda rng: random_surface(rng, 6, 5, 3, 2),
    "degrees 1x5": lambda rng: random_surface(rng, 4, 7, 1, 5),
    "degrees 4x2 uniform": lambda rng: random_surface(rng, 6, 4, 4, 2, uniform=True),
    "periodic": _periodic,
    "rational": lambda rng: random_surface(rng, 5, 6, 2, 3, weights=True),
    "pole": _pole,
}


def _surface(name, seed=0):
    surf = SHAPES[name](np.random.default_rng(seed))
    return surf, surf.blending(13, 11), jnp.asarray(surf.ctrl)


@pytest.mark.parametrize("name", list(SHAPES))
def test_points_normals_match_the_basis(name):
    _, b, ctrl = _surface(name)
    pts, nrm = jax.jit(points_normals)(b, ctrl)
    np.testing.assert_allclose(np.asarray(pts), np.asarray(b.points(ctrl)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(nrm), np.asarray(b.normals(ctrl)), rtol=0, atol=1e-12)
    if name == "pole":  # the limit normal branch ran: unit normals on the collapsed row too
        np.testing.assert_allclose(np.linalg.norm(np.asarray(nrm)[0], axis=-1), 1, atol=1e-12)


def _rotation(seed):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _closer_root(a, b, c):
    disc = np.sqrt(np.maximum(b * b - a * c, 0))
    t_plus, t_minus = (-b + disc) / a, (-b - disc) / a
    return np.where(np.abs(t_plus) <= np.abs(t_minus), t_plus, t_minus)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _reference(tool, x, n):
    """`(value, depth, tool_normal)` of the tool's closed form, vectors as `(..., 3)` arrays."""
    if isinstance(tool, Sphere):
        c, r = np.asarray(tool.center), float(tool.radius)
        y = x - c
        t = _closer_root(np.sum(n * n, -1), np.sum(y * n, -1), np.sum(y * y, -1) - r * r)
        return np.sum(y * y, -1) - r * r, np.abs(t), _unit(x + t[..., None] * n - c)
    if isinstance(tool, Ellipsoid):
        c, radii, rot = (np.asarray(a) for a in (tool.center, tool.radii, tool.rotation))
        y, m = ((x - c) @ rot) / radii, (n @ rot) / radii
        t = _closer_root(np.sum(m * m, -1), np.sum(y * m, -1), np.sum(y * y, -1) - 1)
        grad = ((y + t[..., None] * m) / radii) @ rot.T
        return np.sum(y * y, -1) - 1, np.abs(t), _unit(grad)
    p, normal = np.asarray(tool.point), np.asarray(tool.normal)
    value = np.sum((x - p) * normal, -1)
    return value, -value, np.broadcast_to(normal, x.shape)


TOOLS = {
    "sphere": Sphere([0.5, 0.45, 0.05], 0.3),
    "ellipsoid": Ellipsoid([0.45, 0.5, 0.0], [0.35, 0.2, 0.15], _rotation(3)),
    "plane": Plane([0.0, 0.0, 0.02], [0.1, -0.2, 1.0]),
}


@pytest.mark.parametrize("tool", list(TOOLS))
def test_tool_kernels_match_closed_forms(tool):
    rng = np.random.default_rng(1)
    x = rng.uniform(-0.2, 1.2, (7, 5, 3))
    n = _unit(rng.normal(size=(7, 5, 3)))
    value, depth, normal = _reference(TOOLS[tool], x, n)
    got_depth, got_normal = TOOLS[tool].penetration(jnp.asarray(x), jnp.asarray(n))
    np.testing.assert_allclose(np.asarray(TOOLS[tool].value(jnp.asarray(x))), value, rtol=0, atol=1e-12)
    inside = value < 0  # outside, a quadric's ray may miss it (then both give the vertex of the quadratic)
    np.testing.assert_allclose(np.asarray(got_depth)[inside], depth[inside], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(got_normal)[inside], normal[inside], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "name, tool",
    [(name, "sphere") for name in SHAPES]
    + [(name, "ellipsoid") for name in ("clamped 3x2", "degrees 1x5", "rational", "pole", "periodic")]
    + [("periodic", "plane")],
)
def test_contacts_match_a_dense_reference(name, tool):
    """Masks identical, depths and normals to 1e-12 against the basis's samples and normals and
    the tools' closed forms (inside the window of `sample_window`)."""
    _, b, ctrl = _surface(name)
    if name == "periodic":  # the band around the origin: a tool near its wall
        tool_obj = {
            "sphere": Sphere([1.0, 0.0, 0.5], 0.3),
            "plane": Plane([0.9, 0, 0], [1.0, 0.1, 0]),
            "ellipsoid": Ellipsoid([1.0, 0.0, 0.5], [0.35, 0.2, 0.25], _rotation(5)),
        }[tool]
    else:
        tool_obj = TOOLS[tool]
    got = contacts(b, ctrl, tool_obj)
    x, n = np.asarray(b.points(ctrl)), np.asarray(b.normals(ctrl))
    value, depth, tool_normal = _reference(tool_obj, x, n)
    window_mask, window = sample_window(b, ctrl, tool_obj)
    once = (_first_samples(b) == np.arange(x.shape[0] * x.shape[1])).reshape(x.shape[:2])
    inside = (value < 0) & np.asarray(window_mask) & once  # a closed seam's second copy: never
    assert inside.any()
    np.testing.assert_array_equal(np.asarray(got.mask), inside)
    np.testing.assert_allclose(np.asarray(got.depth), np.where(inside, depth, 0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(got.points), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(got.normals), n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(got.tool_normals)[inside], tool_normal[inside], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(got.window), np.asarray(window))


def test_ellipsoid_box_overlap_is_the_bounding_box_of_the_eight_corners():
    """`Ellipsoid.box_overlap` (the parallelepiped's bounding box `M (mid − c) ± |M| half`) against
    the 8 box corners mapped into the unit-sphere frame one by one, their bounding box tested
    against the unit ball (numpy)."""
    tool = TOOLS["ellipsoid"]
    c, radii, rot = (np.asarray(a) for a in (tool.center, tool.radii, tool.rotation))
    rng = np.random.default_rng(4)
    lo = rng.uniform(-0.4, 1.2, (40, 30, 3))
    hi = lo + rng.uniform(0, 0.3, lo.shape)
    corners = np.stack([np.where(np.array(bits, bool), hi, lo) for bits in np.ndindex(2, 2, 2)], -2)
    local = ((corners - c) @ rot) / radii
    near = np.clip(0.0, local.min(-2), local.max(-2))
    expected = np.sum(near**2, -1) <= 1
    got = np.asarray(tool.box_overlap(jnp.asarray(lo), jnp.asarray(hi)))
    assert 0 < expected.sum() < expected.size
    np.testing.assert_array_equal(got, expected)


def test_contacts_jit_vmap_and_gradient():
    _, b, ctrl = _surface("clamped 3x2", seed=2)
    sphere = TOOLS["sphere"]
    direct = contacts(b, ctrl, sphere)
    jitted = jax.jit(contacts)(b, ctrl, sphere)
    for field in ("mask", "depth", "normals", "tool_normals"):
        np.testing.assert_array_equal(np.asarray(getattr(jitted, field)), np.asarray(getattr(direct, field)))
    lifts = jnp.array([0.0, 0.05, 5.0])
    up = jnp.array([0.0, 0.0, 1.0])[None, None]
    batched = jax.vmap(lambda h: contacts(b, ctrl + up * h, sphere).depth)(lifts)
    for k in range(3):
        one = contacts(b, ctrl + up * lifts[k], sphere).depth
        np.testing.assert_allclose(np.asarray(batched[k]), np.asarray(one), rtol=0, atol=1e-14)
    assert float(batched[2].sum()) == 0 and float(batched[0].sum()) > 0
    check_grad(jax.jit(lambda p: contacts(b, p, sphere).depth.sum()), ctrl, rtol=1e-4)
    check_grad(jax.jit(lambda p: contacts(b, p, TOOLS["ellipsoid"]).tool_normals.sum()), ctrl, rtol=1e-4)


def _hulls_apart_reference(a, b, margin, steps=24):
    """The fixed-step Frank–Wolfe certificate of `hulls_apart`, every step run (numpy)."""
    x, certified = a[0] - b[0], False
    for _ in range(steps):
        s = a[np.argmin(a @ x)] - b[np.argmax(b @ x)]
        if np.any(x != 0):
            certified |= bool(np.dot(s, x) / np.linalg.norm(x) > margin)
        d = x - s
        dd = np.dot(d, d)
        gamma = np.clip(np.dot(x, d) / dd, 0, 1) if dd > 0 else 0.0
        x = x - gamma * d
    return certified


def test_hulls_apart_stops_early_with_the_same_answer():
    """Random point sets of 1 to 29 points; after the first four cases each set is padded to 32
    rows with repeats of its own points (the same hull, the same supports: one program for the
    rest instead of one per pair of sizes)."""
    rng = np.random.default_rng(4)
    answers = set()
    pad = lambda p, k: p if k < 4 else np.resize(p, (32, 3))  # cycles through p's rows
    for k in range(24):
        a = rng.normal(size=(rng.integers(1, 30), 3))
        b = rng.normal(size=(rng.integers(1, 30), 3)) + rng.uniform(0, 6) * _unit(rng.normal(size=3))
        a, b = pad(a, k), pad(b, k)
        margin = [0.0, 0.3, 1.0, np.inf][k % 4]
        expect = _hulls_apart_reference(a, b, margin)
        assert bool(hulls_apart(a, b, margin)) == expect, k
        answers.add(expect)
    assert answers == {True, False}


def test_surface_contacts_direct_equals_one_program_after_an_overflow():
    """Two coplanar plates: every sphere intersects, the exact pass overflows, and the direct
    call (the exact program, then the flat one) gives the result of the one program that decides
    in one loop inside the caller's `jit` (the sheets of test_collide's flat-contact test, so
    the suite compiles their direct programs once; test_collide's direct/jit/vmap test covers a
    crossing without overflow). A NaN in a control net raises eagerly and under `jit` (the
    direct exact program and this `jit` program: no more compilations for the bad value)."""
    plate = shapes.plate(6, 6)
    b, ca = plate.blending(22, 22), jnp.asarray(plate.ctrl)
    cb = ca + jnp.array([0.3, 0.2, 0.0])[None, None]
    query = lambda x, y: surface_contacts(b, x, b, y, capacity=64)
    direct, jitted = query(ca, cb), jax.jit(query)(ca, cb)
    for field in direct.__dataclass_fields__:
        np.testing.assert_array_equal(np.asarray(getattr(direct, field)), np.asarray(getattr(jitted, field)))
    assert int(direct.flat_pairs) > 0 and bool(direct.hit)
    raises_both(query, ca, cb.at[1, 2, 0].set(jnp.nan), match="ctrl_b")


def test_bad_values_raise_eagerly_and_under_jit():
    _, b, ctrl = _surface("clamped 3x2")
    bad = ctrl.at[1, 2, 0].set(jnp.nan)
    raises_both(lambda p: contacts(b, p, TOOLS["sphere"]), bad, match="ctrl")
    # surface_contacts' NaN check: test_surface_contacts_direct_equals_one_program_after_an_overflow
    raises_both(lambda a: hulls_apart(a, jnp.ones((2, 3))), jnp.full((3, 3), jnp.inf), match="a")


def _nearest_reference(points, x):
    """Every triangle of the tessellated grid, the nearest to `x` by brute force (numpy):
    `(faces within 1e-12 of the smallest distance, their closest points, barycentrics, faces)`."""
    verts, faces = (np.asarray(a) for a in grid_mesh(jnp.asarray(points)))
    closest, bary = (np.asarray(a) for a in closest_point_on_triangle(x, jnp.asarray(verts[faces])))
    dist = np.linalg.norm(closest - x, axis=-1)
    best = np.flatnonzero(dist <= dist.min() + 1e-12)
    return best, closest, bary, faces, verts


def _first_samples(b) -> np.ndarray:
    """Reference of `Blending.first_samples`, flat `(m n,)`: per sample the first sample at the
    same parameters (numpy's first occurrence; modulo 1 in a closed direction)."""

    def first(params, periodic):
        p = np.mod(np.asarray(params), 1.0) if periodic else np.asarray(params)
        _, index, inverse = np.unique(p, return_index=True, return_inverse=True)
        return index[inverse]

    fu, fv = first(b.params_u, b.periodic_u), first(b.params_v, b.periodic_v)
    return (fu[:, None] * len(fv) + fv[None, :]).reshape(-1)


@pytest.mark.parametrize("name", ["clamped 3x2", "degrees 1x5", "periodic", "rational", "pole"])
def test_point_contact_is_the_nearest_of_every_triangle(name):
    """The point tool's 5 × 5-cell search with its corner-ball certificate (and the full search
    it falls back to) finds a nearest triangle of the whole tessellation: mask, depth split by
    barycentrics, and probe normal as that triangle gives them (inside, outside, far away)."""
    _, b, ctrl = _surface(name, seed=3)
    points, normals = np.asarray(b.points(ctrl)), np.asarray(b.normals(ctrl))
    m, n = points.shape[:2]
    first = _first_samples(b)
    positions = [
        points[m // 2, n // 3] - 0.03 * normals[m // 2, n // 3],  # just behind: in contact
        points[2, n - 3] + 0.05 * normals[2, n - 3],  # in front: no contact
        points[m - 2, 1] - 0.02 * normals[m - 2, 1],
        points.reshape(-1, 3).mean(0) + np.array([0.0, 0.0, 3.0]),  # far: the certificate fails
    ]
    seen = set()
    for x in positions:
        got = contacts(b, ctrl, Point(x))
        best, closest, bary, faces, verts = _nearest_reference(points, x)
        matches = []
        for k in best:
            tri = verts[faces[k]]
            normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            offset = x - closest[k]
            inside = np.dot(offset, normal) < 0
            face = first[faces[k]]  # a seam copy's share goes to the first copy
            depth = np.zeros(m * n)
            np.add.at(depth, face, bary[k] * np.linalg.norm(offset) if inside else 0)
            mask = np.zeros(m * n, bool)
            mask[face] = inside
            matches.append(
                np.array_equal(np.asarray(got.mask).reshape(-1), mask)
                and np.allclose(np.asarray(got.depth).reshape(-1), depth, rtol=0, atol=1e-12)
                and bool(got.hit) == inside
            )
            if inside:
                probe = np.asarray(got.tool_normals).reshape(-1, 3)[face]
                matches[-1] &= np.allclose(probe, offset / np.linalg.norm(offset), rtol=0, atol=1e-12)
            seen.add(bool(inside))
        assert any(matches), (name, x)
    assert seen == {True, False}


def _sphere_hierarchy_reference(points, levels):
    """The thesis's three-point spheres of every level, written with numpy (`(N, 3)` vectors)."""

    def three_point(p00, p10, p01, p11):
        long_main = np.sum((p11 - p00) ** 2, -1) >= np.sum((p10 - p01) ** 2, -1)
        a = np.where(long_main[..., None], p00, p10)
        b = np.where(long_main[..., None], p11, p01)
        c = np.where(long_main[..., None], p10, p00)
        u, v = b - a, c - a
        w = np.cross(u, v)
        ww, uu, vv = np.sum(w * w, -1), np.sum(u * u, -1), np.sum(v * v, -1)
        ok = ww > np.finfo(float).eps * uu * vv
        off = (uu[..., None] * np.cross(v, w) + vv[..., None] * np.cross(w, u)) / (2 * np.where(ok, ww, 1))[
            ..., None
        ]
        return np.where(ok[..., None], a + off, 0.5 * (a + b))

    m, n = points.shape[:2]
    out, centers, radii = [], None, None
    for level in range(levels + 1):
        step, count = 3**level, 3 ** (levels - level)
        iu = np.minimum(np.arange(count + 1) * step, m - 1)
        iv = np.minimum(np.arange(count + 1) * step, n - 1)
        q = points[iu][:, iv]
        corners = [q[:-1, :-1], q[1:, :-1], q[:-1, 1:], q[1:, 1:]]
        rows, cols = block_order(levels - level)
        c = three_point(*corners)[rows, cols]
        if level == 0:
            radius = np.max([np.linalg.norm(p[rows, cols] - c, axis=-1) for p in corners], 0)
        else:
            child_c, child_r = centers.reshape(-1, 9, 3), radii.reshape(-1, 9)
            radius = np.max(np.linalg.norm(child_c - c[:, None], axis=-1) + child_r, 1)
        valid = (rows * step < m - 1) & (cols * step < n - 1)
        centers, radii = c, np.where(valid, radius, -np.inf)
        out.append((c, radii))
    return out


@pytest.mark.parametrize("grid", [(16, 16), (13, 11), (2, 5), (30, 10)])
def test_sphere_hierarchy_matches_the_three_point_spheres(grid):
    surf = random_surface(np.random.default_rng(sum(grid)), 6, 5, 3, 2)
    points = np.asarray(surf.blending(*grid).points(jnp.asarray(surf.ctrl)))
    levels = levels_for(max(grid) - 1)
    got = sphere_hierarchy(points, levels)
    for (c, r), (c_ref, r_ref) in zip(got, _sphere_hierarchy_reference(points, levels), strict=True):
        np.testing.assert_allclose(np.asarray(c).T, c_ref, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.isinf(np.asarray(r)), np.isinf(r_ref))
        finite = np.isfinite(r_ref)
        np.testing.assert_allclose(np.asarray(r)[finite], r_ref[finite], rtol=0, atol=1e-12)


@pytest.mark.parametrize("share", [0.0, 0.1, 0.6])
def test_candidate_pairs_gathered_after_the_plane_tests_equal_every_pair(share):
    """Pairs that survive the plane tests are finished a quarter of the batch at a time (one
    round when few survive, several when many do); the answer is `triangles_intersect` of every
    pair, also under `vmap`."""
    rng = np.random.default_rng(int(share * 10))
    n = 1024
    t1 = rng.normal(size=(n, 3, 3))
    t2 = rng.normal(size=(n, 3, 3)) + rng.choice([0.0, 8.0], p=[share, 1 - share], size=(n, 1, 1))
    t2[:40, :2] = t1[:40, :2]  # a shared edge
    t1[40:80, :, 2] = t2[40:80, :, 2] = 0.5  # coplanar
    active = rng.uniform(size=n) < 0.8
    expect = np.asarray(triangles_intersect(jnp.asarray(t1), jnp.asarray(t2))) & active
    got = jax.jit(candidate_pairs_intersect)(jnp.asarray(t1), jnp.asarray(t2), jnp.asarray(active))
    np.testing.assert_array_equal(np.asarray(got), expect)
    halves = jax.vmap(candidate_pairs_intersect)(
        jnp.asarray(t1).reshape(2, -1, 3, 3),
        jnp.asarray(t2).reshape(2, -1, 3, 3),
        jnp.asarray(active).reshape(2, -1),
    )
    np.testing.assert_array_equal(np.asarray(halves).reshape(-1), expect)


def test_point_contact_jit_vmap_and_gradient():
    _, b, ctrl = _surface("clamped 3x2", seed=4)
    points, normals = np.asarray(b.points(ctrl)), np.asarray(b.normals(ctrl))
    positions = jnp.asarray(
        [
            points[6, 4] - 0.03 * normals[6, 4],
            points[3, 7] + 0.05 * normals[3, 7],
            points[10, 2] - 0.02 * normals[10, 2],
        ]
    )
    depth = lambda x: contacts(b, ctrl, Point(x)).depth
    direct = [np.asarray(depth(x)) for x in positions]
    np.testing.assert_array_equal(np.asarray(jax.jit(depth)(positions[0])), direct[0])
    batched = np.asarray(jax.vmap(depth)(positions))
    for k in range(3):
        np.testing.assert_allclose(batched[k], direct[k], rtol=0, atol=1e-14)
    assert direct[0].sum() > 0 and direct[1].sum() == 0
    check_grad(jax.jit(lambda p: contacts(b, p, Point(positions[0])).depth.sum()), ctrl, rtol=1e-4)
