"""The bad-input contract, table-driven: every case raises `ValueError`/`TypeError` whose message
names the argument the caller passed, eagerly and (for array arguments) inside `jax.jit`; and
array-likes (lists) are accepted where arrays are. Modules: collide, mss, merge, vsofm, shapes.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide, io, merge, mss, shapes, vsofm
from bsjax.basis import blending_matrix, clamped_knots, greville
from bsjax.collide import _hierarchy
from bsjax.collide._broad import hulls_apart
from bsjax.collide._triangles import closest_point_on_triangle
from bsjax.mss import _lattice
from tests.helpers import raises_both

C3 = jnp.array([0.5, 0.5, 0.1])
NAN3 = jnp.array([np.nan, 0.0, 0.0])
INF3 = jnp.array([np.inf, 0.0, 0.0])


@pytest.fixture(scope="module")
def plate():
    s = shapes.plate(6, 6)
    return s, s.blending(12, 12)


@pytest.fixture(scope="module")
def lattice():
    g = np.stack(np.meshgrid(*[np.linspace(0.0, 0.1, 3)] * 3, indexing="ij"), -1)
    lat = mss.hex_lattice(g, material=mss.JELLY)
    return lat, mss.init(lat)


def _sphere_radius(r):
    return collide.Sphere(C3, r)


def _point(p):
    return collide.Point(p)


def _ellipsoid_radii(r):
    return collide.Ellipsoid(C3, r)


# (label, function of the traced array, the array, the argument the message must name); cases of
# one function share its function object: under jit, one program serves them all
ARRAY_CASES = [
    ("Sphere centre NaN", lambda c: collide.Sphere(c, 0.2), NAN3, "center"),
    ("Sphere radius < 0", _sphere_radius, jnp.asarray(-1.0), "radius"),
    ("Sphere radius inf", _sphere_radius, jnp.asarray(np.inf), "radius"),
    ("Ellipsoid radii < 0", _ellipsoid_radii, jnp.array([1.0, -1.0, 1.0]), "radii"),
    ("Plane point inf", lambda p: collide.Plane(p, jnp.array([0.0, 0.0, 1.0])), INF3, "point"),
    ("Point position NaN", _point, NAN3, "position"),
    ("closest_point_on_triangle NaN", lambda x: closest_point_on_triangle(x, jnp.eye(3)), NAN3, "x"),
    ("stable_dt contact < 0", None, jnp.asarray(-1e3), "contact_stiffness"),
    ("step dt NaN", None, jnp.asarray(np.nan), "dt"),
    ("step dt < 0", None, jnp.asarray(-1e-4), "dt"),
    ("implicit_step dt inf", None, jnp.asarray(np.inf), "dt"),
    ("step force NaN", None, None, "external_force"),
    ("step gravity inf", None, INF3, "gravity"),
    ("step state NaN", None, None, "state.position"),
    ("relax tol < 0", None, jnp.asarray(-1.0), "tol"),
    ("hex_lattice positions NaN", None, jnp.full((2, 2, 2, 3), np.nan), "positions"),
    ("vsofm.fit points inf", lambda p: vsofm.fit(p, (3, 3, 3), cycles=2), None, "points"),
    # extreme but finite: refused where the quadratics of the depth would overflow
    ("Sphere radius 1e300", _sphere_radius, jnp.asarray(1e300), "radius"),
    ("Point position 1e300", _point, jnp.array([1e300, 0.0, 0.0]), "position"),
    ("Ellipsoid aspect 1e13", _ellipsoid_radii, jnp.array([1e13, 1.0, 1.0]), "radii"),
    (
        "Sphere float32 radius 1e39",
        lambda r: collide.Sphere(jnp.zeros(3, jnp.float32), r),
        jnp.asarray(1e39),
        "radius",
    ),
    (
        "Ellipsoid float32 radii 1e39",
        lambda r: collide.Ellipsoid(jnp.zeros(3, jnp.float32), r),
        jnp.array([1e39, 1.0, 1.0]),
        "radii",
    ),
    ("hex_lattice flat grid", None, None, "positions"),
    ("hex_lattice overflowing grid", None, None, "positions"),
]


_LATTICE_TABLE: dict = {}


def _lattice_case(label, lat, state):
    """The case's function of the lattice fixture's lattice and state; built once per lattice,
    so that cases of one function share its function object (one program under jit)."""
    if _LATTICE_TABLE.get("lattice") is not lat:
        _LATTICE_TABLE.clear()
        _LATTICE_TABLE.update(_lattice_table(lat, state), lattice=lat)
    return _LATTICE_TABLE[label]


def _lattice_table(lat, state):
    n = lat.n_nodes

    def step_dt(dt):
        return mss.step(lat, state, dt)

    def hex_lattice(x):
        return mss.hex_lattice(x, material=mss.JELLY)

    return {
        "stable_dt contact < 0": lambda k: mss.stable_dt(lat, k),
        "step dt NaN": step_dt,
        "step dt < 0": step_dt,
        "implicit_step dt inf": lambda dt: mss.implicit_step(lat, state, dt),
        "step force NaN": (lambda f: mss.step(lat, state, 1e-5, external_force=f), jnp.full((n, 3), np.nan)),
        "step gravity inf": lambda g: mss.step(lat, state, 1e-5, gravity=g),
        "step state NaN": (
            lambda x: mss.step(lat, mss.State(x, state.velocity), 1e-5),
            state.position.at[0, 0].set(np.nan),
        ),
        "relax tol < 0": lambda t: mss.relax(lat, state, 1e-5, tol=t, max_steps=2, check_every=1),
        "hex_lattice positions NaN": hex_lattice,
        "hex_lattice flat grid": (hex_lattice, _grid().at[..., 2].set(0.0)),
        "hex_lattice overflowing grid": (hex_lattice, _grid() * 1e300),
    }


def _grid():
    return jnp.stack(jnp.meshgrid(*[jnp.linspace(0.0, 0.1, 3)] * 3, indexing="ij"), -1)


def test_extreme_finite_tools_give_finite_contacts(plate):
    """At the documented limits (coordinates up to `coordinate_limit`, an ellipsoid of aspect
    1e12) every contact field, the force and the push are finite."""
    from bsjax._checks import coordinate_limit

    s, b = plate
    big = 0.9 * coordinate_limit(np.float64)
    tools = [
        collide.Sphere(C3, big),
        collide.Sphere(jnp.array([big, 0.5, 0.0]), big),
        collide.Ellipsoid(C3, jnp.array([1e6, 1.0, 1e-6])),
        collide.Sphere(C3, 1e-300),
        collide.Plane(jnp.array([big, 0.0, 0.0]), jnp.array([1e-300, 0.0, 1.0])),
    ]
    for tool in tools:
        c = collide.contacts(b, s.ctrl, tool)
        leaves = [c.depth, c.points, c.normals, c.tool_normals, collide.contact_force(c, 1e3)]
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(leaves)), tool
        depth, normal = tool.push(s.ctrl.reshape(-1, 3))
        assert bool(jnp.all(jnp.isfinite(depth))) and bool(jnp.all(jnp.isfinite(normal)))


@pytest.mark.parametrize("label, fn, array, name", ARRAY_CASES, ids=[c[0] for c in ARRAY_CASES])
def test_bad_values_name_the_argument_eagerly_and_under_jit(lattice, label, fn, array, name):
    if fn is None:
        fn = _lattice_case(label, *lattice)
        if isinstance(fn, tuple):
            fn, array = fn
    if array is None:  # vsofm's samples
        array = jnp.asarray(np.random.default_rng(0).normal(size=(40, 3))).at[3, 1].set(np.inf)
    raises_both(fn, array, match=rf"(?:^|Error: ){name.replace('.', '[.]')}: expected")


@pytest.fixture(scope="module")
def env(plate, lattice):
    s, b = plate
    lat, state = lattice
    a2 = s.with_ctrl(s.ctrl + jnp.array([[[1.0, 0.0, 0.0]]]))
    pts = np.random.default_rng(0).normal(size=(40, 3))
    return SimpleNamespace(s=s, b=b, a2=a2, lat=lat, state=state, pts=pts)


# (label, function of the environment, error type, the argument the message must name)
STRUCTURE_CASES = [
    ("Sphere complex radius", lambda e: collide.Sphere(C3, 1j), TypeError, "radius"),
    ("Sphere boolean radius", lambda e: collide.Sphere(C3, True), TypeError, "radius"),
    ("Sphere centre shape", lambda e: collide.Sphere(jnp.zeros(2), 0.2), ValueError, "center"),
    ("Plane zero normal", lambda e: collide.Plane(C3, jnp.zeros(3)), ValueError, "normal"),
    (
        "TriangleMesh NaN vertex",
        lambda e: collide.TriangleMesh(
            np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]]), np.array([[0, 1, 2]])
        ),
        ValueError,
        "vertices",
    ),
    (
        "TriangleMesh face index",
        lambda e: collide.TriangleMesh(np.eye(3), np.array([[0, 1, 5]])),
        ValueError,
        "faces",
    ),
    (
        "TriangleMesh float faces",
        lambda e: collide.TriangleMesh(np.eye(3), np.array([[0, 1, 2.0]])),
        ValueError,
        "faces",
    ),
    (
        "contacts ctrl shape",
        lambda e: collide.contacts(e.b, e.s.ctrl[:4], collide.Sphere(C3, 0.2)),
        ValueError,
        "ctrl",
    ),
    ("contacts tool type", lambda e: collide.contacts(e.b, e.s.ctrl, "sphere"), TypeError, "tool"),
    (
        "contacts boolean ctrl",
        lambda e: collide.contacts(e.b, e.s.ctrl > 0, collide.Sphere(C3, 0.2)),
        TypeError,
        "ctrl",
    ),
    ("tessellate shape", lambda e: collide.grid_mesh(jnp.zeros((5, 3))), ValueError, "points"),
    ("sphere_hierarchy levels", lambda e: _hierarchy.sphere_hierarchy(e.s.ctrl, -1), ValueError, "levels"),
    (
        "hex_lattice positions shape",
        lambda e: mss.hex_lattice(np.zeros((3, 3, 3)), material=mss.JELLY),
        ValueError,
        "positions",
    ),
    ("hex_edges zero size", lambda e: mss.hex_edges((0, 2, 2)), ValueError, "shape"),
    ("grid_edges node_map", lambda e: _lattice.grid_edges(np.zeros(4, dtype=int)), ValueError, "node_map"),
    ("grid_edges float node_map", lambda e: _lattice.grid_edges(np.zeros((3, 3))), ValueError, "node_map"),
    ("Contact stiffness < 0", lambda e: mss.Penalty(stiffness=-1.0), ValueError, "stiffness"),
    (
        "step gravity shape",
        lambda e: mss.step(e.lat, e.state, 1e-5, gravity=jnp.zeros(2)),
        ValueError,
        "gravity",
    ),
    ("simulate n_steps 0", lambda e: mss.simulate(e.lat, e.state, 1e-5, 0), ValueError, "n_steps"),
    ("simulate n_steps float", lambda e: mss.simulate(e.lat, e.state, 1e-5, 2.5), TypeError, "n_steps"),
    (
        "simulate Point tool",
        lambda e: mss.simulate(e.lat, e.state, 1e-5, 2, tools=[collide.Point(C3)]),
        TypeError,
        "tools",
    ),
    (
        "relax check_every -1",
        lambda e: mss.relax(e.lat, e.state, 1e-5, check_every=-1),
        ValueError,
        "check_every",
    ),
    (
        "trajectory save_every 0",
        lambda e: mss.trajectory(e.lat, e.state, 1e-5, 4, save_every=0),
        ValueError,
        "save_every",
    ),
    (
        "implicit cg_iterations 0",
        lambda e: mss.implicit_step(e.lat, e.state, 1e-5, cg_iterations=0),
        ValueError,
        "cg_iterations",
    ),
    ("merge continuity", lambda e: merge.merge([e.s, e.a2], "u", 5), ValueError, "continuity"),
    ("merge direction", lambda e: merge.merge([e.s, e.a2], "w", 0), ValueError, "direction"),
    ("merge one patch", lambda e: merge.merge([e.s], "u", 0), ValueError, "surfaces"),
    ("merge samples 1", lambda e: merge.merge([e.s, e.a2], "u", 0, samples=1), ValueError, "samples"),
    ("merge samples float", lambda e: merge.merge([e.s, e.a2], "u", 0, samples=20.5), ValueError, "samples"),
    ("merge not a surface", lambda e: merge.merge([e.s, "x"], "u", 0), TypeError, r"surfaces\[1\]"),
    (
        "deviation samples 0",
        lambda e: merge.deviation([e.s, e.a2], merge.merge([e.s, e.a2], "u", 0), samples=0),
        ValueError,
        "samples",
    ),
    ("vsofm cycles 0", lambda e: vsofm.fit(e.pts, (3, 3, 3), cycles=0), ValueError, "cycles"),
    ("vsofm shape", lambda e: vsofm.fit(e.pts, (1, 3, 3)), ValueError, "shape"),
    (
        "vsofm Settings",
        lambda e: vsofm.Settings(learning_rate_start=-1.0),
        ValueError,
        "learning_rate_start",
    ),
    ("corner_jacobians shape", lambda e: vsofm.corner_jacobians(jnp.zeros((3, 3, 3))), ValueError, "nodes"),
    ("plate r 0", lambda e: shapes.plate(0, 8), ValueError, "r"),
    ("plate r float", lambda e: shapes.plate(8.5, 8), TypeError, "r"),
    ("plate size < 0", lambda e: shapes.plate(8, 8, size=-1.0), ValueError, "size"),
    ("sphere radius < 0", lambda e: shapes.sphere(radius=-1.0), ValueError, "radius"),
    ("sphere radius complex", lambda e: shapes.sphere(radius=1j), TypeError, "radius"),
    # found by trying (issue: no silent result, every error names its argument)
    ("Sphere centre a string", lambda e: collide.Sphere("abc", 0.2), TypeError, "center"),
    (
        "Implicit gives vectors",
        lambda e: collide.contacts(e.b, e.s.ctrl, collide.Implicit(lambda x: x)),
        ValueError,
        "fn",
    ),
    (
        "behind_plane zero normal",
        lambda e: mss.behind_plane(e.state.position, C3, jnp.zeros(3)),
        ValueError,
        "normal",
    ),
    ("behind_plane NaN point", lambda e: mss.behind_plane(e.state.position, NAN3, C3), ValueError, "point"),
    (
        "hex_lattice object masses",
        lambda e: mss.hex_lattice(np.zeros((2, 2, 2, 3)), 1.0, 0.1, np.array([1.0, None])),
        TypeError,
        "mass",
    ),
    (
        "hex_lattice string stiffness",
        lambda e: mss.hex_lattice(np.zeros((2, 2, 2, 3)), "10", 0.1, 1.0),
        TypeError,
        "stiffness",
    ),
    (
        "stable_dt overflowing bound",
        lambda e: mss.stable_dt(mss.hex_lattice(e.lat.rest_positions.reshape(3, 3, 3, 3), 1e308, 0.1, 1e-3)),
        ValueError,
        "lattice",
    ),
    (
        "simulate gravity NaN",
        lambda e: mss.simulate(e.lat, e.state, 1e-5, 2, gravity=NAN3),
        ValueError,
        "gravity",
    ),
    ("vsofm float lattice size", lambda e: vsofm.fit(e.pts, (2.5, 3, 3)), TypeError, "shape"),
    (
        "vsofm flat samples",
        lambda e: vsofm.fit(e.pts * np.array([1.0, 1.0, 0.0]), (3, 3, 3)),
        ValueError,
        "points",
    ),
    (
        "vsofm collinear samples",
        lambda e: vsofm.fit(e.pts * np.array([1.0, 0.0, 0.0]), (3, 3, 3)),
        ValueError,
        "points",
    ),
    ("greville too few knots", lambda e: greville(np.linspace(0, 1, 8), 5), ValueError, "knots"),
    ("merge_knots empty", lambda e: merge.merge_knots([], clamped_knots(5, 3), 3, 1), ValueError, "knots_a"),
    (
        "cross_knots NaN",
        lambda e: merge.cross_knots([np.r_[0, 0, 0, 0, np.nan, 1, 1, 1, 1]], 3, 5),
        ValueError,
        r"knot_list\[0\]",
    ),
    ("to_dict not a spline", lambda e: io.to_dict("x"), TypeError, "spline"),
]


@pytest.mark.parametrize("label, fn, error, name", STRUCTURE_CASES, ids=[c[0] for c in STRUCTURE_CASES])
def test_bad_arguments_name_the_argument(env, label, fn, error, name):
    with pytest.raises(error, match=rf"^{name}[ :(]"):
        jax.block_until_ready(fn(env))


def test_lists_are_array_likes(plate):
    """A nested list of numbers is accepted wherever an array is, with the same result."""
    s, b = plate
    tool = collide.Sphere(C3, 0.3)
    as_array = collide.contacts(b, s.ctrl, tool)
    as_list = collide.contacts(b, np.asarray(s.ctrl).tolist(), collide.Sphere([0.5, 0.5, 0.1], 0.3))
    np.testing.assert_array_equal(as_array.depth, as_list.depth)
    assert int(jnp.sum(as_array.mask)) > 0
    pts = np.asarray(s.ctrl).reshape(-1, 3)
    assert bool(hulls_apart(pts.tolist(), (pts + 5.0).tolist()))
    assert bool(hulls_apart(pts, pts + 5.0))  # numpy arrays
    knots = clamped_knots(6, 3)
    np.testing.assert_array_equal(
        blending_matrix(knots, 3, [0.25, 0.5]), blending_matrix(knots, 3, jnp.array([0.25, 0.5]))
    )
    grid = b.points(s.ctrl)
    np.testing.assert_array_equal(b.refit(np.asarray(grid).tolist()), b.refit(grid))


def test_value_check_failures_are_not_logged_as_tracebacks(plate, caplog):
    """A failed value check reaches the caller as one ValueError with the check's message — on
    the first call and on later ones (which take JAX's C++ dispatch path); JAX's log of the
    failed host callback (a traceback per call) is dropped for bsjax's own checks."""
    s, b = plate
    tool = collide.Sphere(C3, 0.2)
    collide.contacts(b, s.ctrl, tool)  # compiled: the bad calls below take the fast path
    for _ in range(2):
        with caplog.at_level(logging.ERROR), pytest.raises(ValueError, match="^radius: expected"):
            collide.Sphere(C3, jnp.asarray(-1.0))
        with caplog.at_level(logging.ERROR), pytest.raises(ValueError, match="^ctrl: expected finite"):
            collide.contacts(b, s.ctrl.at[0, 0, 0].set(np.nan), tool)
    assert not [r for r in caplog.records if "callback" in r.getMessage()], caplog.text


def test_vsofm_fit_is_scale_free_at_extreme_magnitudes():
    """Samples of size 1e-300 or 1e300 train to the unit result scaled (no overflow in the
    neighbour search, no underflow in the updates)."""
    p = np.random.default_rng(0).normal(size=(200, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    unit = vsofm.fit(p, (3, 3, 3), cycles=5)
    for scale in (1e300, 1e-300):
        nodes = vsofm.fit(p * scale, (3, 3, 3), cycles=5)
        np.testing.assert_allclose(np.asarray(nodes) / scale, unit, atol=1e-12)


def test_plot_bad_input_names_the_argument(tmp_path):
    from bsjax import plot

    grid = np.zeros((4, 5, 3))
    fig, (ax,) = plot.figure(1)
    cases = [
        (lambda: plot.figure(0), ValueError, "n_panels"),
        (lambda: plot.figure(2.5), TypeError, "n_panels"),
        (lambda: plot.figure(1, size=-1.0), ValueError, "size"),
        (lambda: plot.draw_surface(ax, np.zeros((4, 3))), ValueError, "points"),
        (lambda: plot.draw_surface(ax, np.full((4, 5, 3), np.nan)), ValueError, "points"),
        (lambda: plot.draw_surface(ax, grid.astype(complex)), TypeError, "points"),
        (lambda: plot.draw_surface(ax, grid, ctrl=np.zeros((3, 3, 2))), ValueError, "ctrl"),
        (lambda: plot.draw_surface(ax, grid, values=np.zeros((5, 4))), ValueError, "values"),
        (lambda: plot.draw_surface(ax, grid, values=np.zeros((4, 5)), cmap="nope"), ValueError, "cmap"),
        (lambda: plot.save_figure(fig, tmp_path / "no" / "such" / "f.png"), ValueError, "path"),
        (lambda: plot.save_figure(fig, tmp_path / "f.xyz"), ValueError, "path"),
    ]
    for fn, error, name in cases:
        with pytest.raises(error, match=rf"^{name}[ :]"):
            fn()
    plot.draw_surface(ax, grid + np.arange(5)[None, :, None], values=np.ones((4, 5)))
    plot.save_figure(fig, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0


def test_parameters_refuse_booleans_and_complex():
    """A boolean is not a parameter (it would silently read as 0 or 1), complex is not real."""
    import bsjax

    t = np.linspace(0.0, 1.0, 6)
    curve = bsjax.BSplineCurve(np.stack([t, t**2], -1), bsjax.clamped_knots(6, 3), 3)
    surface = shapes.plate(5, 5)
    for fn in (lambda x: curve.evaluate(x), lambda x: curve.curvature(x), lambda x: surface.evaluate(x, 0.5)):
        for bad in (True, np.array([True, False]), np.array([0.5 + 1j])):
            with pytest.raises(TypeError, match="expected real numbers"):
                fn(bad)


def test_empty_constraint_list_is_named():
    """An empty list reaches the compiled solve as a (0,)-shaped array: the message still says
    what came."""
    import bsjax
    from bsjax import sculpt

    t = np.linspace(0.0, 1.0, 7)
    curve = bsjax.BSplineCurve(np.stack([t, t**2], -1), bsjax.clamped_knots(7, 3), 3)
    for fn in (sculpt.min_norm, sculpt.solve):
        with pytest.raises(
            ValueError, match="^constraints: expected a non-empty list of constraints, got an empty list"
        ):
            fn(curve, [])
