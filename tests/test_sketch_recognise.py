"""bsjax.sketch recognition (thesis ch. 3): single strokes against the generating truth
(tests/strokes.py: noise, wobble, jitter, speed variation, over-tracing, random similarity
transforms), relations on constructed pairs, the composites of Fig. 3-4 against the
`bsjax.construct` constructors called directly, and the decision tree's JSON and adaptation."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from bsjax import construct, sketch
from bsjax.basis import BSplineCurve
from tests import strokes as gen

PER_CLASS = 50


def _confusion(data, timed: bool) -> np.ndarray:
    matrix = np.zeros((len(gen.KINDS), len(gen.KINDS)), int)
    for s in data:
        kind = sketch.recognise(s.points, s.times if timed else None).kind
        matrix[gen.KINDS.index(s.kind), gen.KINDS.index(kind)] += 1
    return matrix


def _table(matrix) -> str:
    head = " " * 10 + "".join(f"{k[:6]:>7}" for k in gen.KINDS)
    rows = [f"{k:>10}" + "".join(f"{c:7d}" for c in row) for k, row in zip(gen.KINDS, matrix)]
    return "\n".join([head, *rows])


# --- single strokes ---------------------------------------------------------------------------
def test_kinds_are_the_contract():
    assert sketch.KINDS == gen.KINDS


def test_confusion_matrix_timed():
    """≥ 95 % of 50 strokes per class (several sizes, positions, rotations) recognised."""
    matrix = _confusion(gen.strokes(PER_CLASS, seed=0), timed=True)
    accuracy = np.diag(matrix) / matrix.sum(axis=1)
    assert matrix.sum(axis=1).tolist() == [PER_CLASS] * len(gen.KINDS)
    assert np.all(accuracy >= 0.95), "\n" + _table(matrix)


def test_confusion_matrix_untimed():
    """Without time stamps (corners by curvature alone): ≥ 90 % of 20 strokes per class."""
    matrix = _confusion(gen.strokes(20, seed=1), timed=False)
    assert np.all(np.diag(matrix) / matrix.sum(axis=1) >= 0.9), "\n" + _table(matrix)


@pytest.mark.parametrize("kind", gen.KINDS)
def test_independent_of_position_size_rotation(kind):
    """A similarity transform of a stroke gives the same kind and transformed parameters."""
    rng = np.random.default_rng(7)
    s = gen.draw(kind, rng)
    angle, scale, shift = 2.1, 37.0, np.array([-4.0e3, 2.5e2])
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    a = sketch.recognise(s.points, s.times)
    b = sketch.recognise(scale * s.points @ rot.T + shift, s.times)
    assert a.kind == b.kind == kind
    for key in ("endpoints", "centre", "corners", "vertices"):
        if key in a.params:
            moved = scale * np.asarray(a.params[key]) @ rot.T + shift
            np.testing.assert_allclose(b.params[key], moved, atol=1e-7 * scale * s.scale)
    for key in ("radius", "axes"):
        if key in a.params:
            np.testing.assert_allclose(b.params[key], scale * np.asarray(a.params[key]), rtol=1e-7)
    assert abs(a.score - b.score) < 1e-6


def _by_kind(count=40, seed=4):
    out: dict[str, list] = {}
    for s in gen.strokes(count, seed=seed):
        r = sketch.recognise(s.points, s.times)
        if r.kind == s.kind:
            out.setdefault(s.kind, []).append((s, r))
    return out


@pytest.fixture(scope="module")
def recognised():
    return _by_kind()


def _within(errors, median: float, worst: float):
    errors = np.asarray(errors)
    assert errors.size >= 30
    assert np.median(errors) <= median and errors.max() <= worst, (np.median(errors), errors.max())


def test_circle_and_arc_parameters(recognised):
    """Centre within 5 % (arcs 8 %) of the radius, radius within 3 % (arcs 5 %); medians within
    1.5 %; arc sweeps within 8°."""
    for kind, centre_tol, radius_tol in (("circle", 0.05, 0.03), ("arc", 0.08, 0.05)):
        pairs = recognised[kind]
        offsets = [
            np.linalg.norm(r.params["centre"] - s.truth["centre"]) / s.truth["radius"] for s, r in pairs
        ]
        _within(offsets, 0.015, centre_tol)
        _within([abs(r.params["radius"] / s.truth["radius"] - 1) for s, r in pairs], 0.015, radius_tol)
    sweeps = [abs(r.params["end"] - r.params["start"] - s.truth["sweep"]) for s, r in recognised["arc"]]
    _within(np.degrees(sweeps), 2.0, 8.0)


def test_ellipse_parameters(recognised):
    pairs = recognised["ellipse"]
    _within([np.linalg.norm(r.params["centre"] - s.truth["centre"]) / s.truth["axes"][0] for s, r in pairs],
            0.02, 0.05)  # fmt: skip
    _within([np.max(np.abs(r.params["axes"] / s.truth["axes"] - 1)) for s, r in pairs], 0.03, 0.08)
    cos = [abs(r.params["major"] @ s.truth["major"]) for s, r in pairs]
    _within(np.degrees(np.arccos(np.minimum(cos, 1.0))), 1.5, 5.0)
    for _, r in pairs:
        assert -math.pi / 2 < r.params["angle"] <= math.pi / 2 and r.params["axes"][0] >= r.params["axes"][1]


@pytest.mark.parametrize("kind", ["line", "triangle", "square", "rectangle", "diamond", "polyline"])
def test_corners_and_endpoints(recognised, kind):
    """Each true corner (line: endpoint) has a recognised one within 12 % of the shape's unit
    (median 3 %), and there are as many."""
    key = {"line": "endpoints", "polyline": "vertices"}.get(kind, "corners")
    truth_key = "endpoints" if kind == "line" else "corners"
    errors = []
    for s, r in recognised[kind]:
        ours, truth = np.asarray(r.params[key]), s.truth[truth_key]
        assert ours.shape == truth.shape
        errors.append(np.linalg.norm(ours[:, None] - truth[None], axis=2).min(axis=0).max() / s.scale)
    _within(errors, 0.03, 0.12)


def test_regularised_curves_are_exact():
    """Circle and ellipse: rational quadratics whose every point is on the fitted conic
    (1e-12); arc: its ends at the start/end angles; polygons: the curve passes through the
    corners; line: its endpoints."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 101)
    for kind in ("circle", "ellipse", "arc", "square", "line"):
        s = gen.draw(kind, rng)
        r = sketch.recognise(s.points, s.times)
        assert r.kind == kind and isinstance(r.curve, BSplineCurve)
        x = np.asarray(r.curve.evaluate(t))
        p = r.params
        if kind == "circle":
            assert r.curve.weights is not None
            np.testing.assert_allclose(np.linalg.norm(x - p["centre"], axis=1), p["radius"], rtol=1e-12)
        elif kind == "ellipse":
            major = p["major"]
            minor = np.array([-major[1], major[0]])
            local = (x - p["centre"]) @ np.stack([major, minor], 1) / p["axes"]
            np.testing.assert_allclose(np.sum(local**2, axis=1), 1.0, rtol=1e-12)
        elif kind == "arc":
            np.testing.assert_allclose(np.linalg.norm(x - p["centre"], axis=1), p["radius"], rtol=1e-12)
            ends = [
                p["centre"] + p["radius"] * np.array([math.cos(a), math.sin(a)])
                for a in (p["start"], p["end"])
            ]
            np.testing.assert_allclose(x[[0, -1]], ends, atol=1e-9 * s.scale)
        elif kind == "square":
            at = np.asarray(r.curve.knots)[1:-1]
            np.testing.assert_allclose(
                np.asarray(r.curve.evaluate(at))[:-1], p["corners"], atol=1e-9 * s.scale
            )
        else:
            np.testing.assert_allclose(x[[0, -1]], p["endpoints"], atol=1e-9 * s.scale)
        assert 0.0 <= r.score <= 1.0


def test_three_d_stroke_in_its_plane():
    """A 3-D circle on a tilted plane: recognised in that plane, centre and radius in space."""
    rng = np.random.default_rng(5)
    s = gen.draw("circle", rng)
    e1, e2 = np.array([1.0, 0.0, 1.0]) / math.sqrt(2), np.array([0.0, 1.0, 0.0])
    lift = lambda q: np.array([1.0, 2.0, 3.0]) + q[..., :1] * e1 + q[..., 1:] * e2
    r = sketch.recognise(lift(s.points), s.times)
    flat = sketch.recognise(s.points, s.times)
    assert r.kind == "circle"
    np.testing.assert_allclose(r.params["centre"], lift(flat.params["centre"]), atol=1e-7 * s.scale)
    np.testing.assert_allclose(r.params["radius"], flat.params["radius"], rtol=1e-7)
    assert abs(abs(r.normal @ np.cross(e1, e2)) - 1) < 1e-9
    x = np.asarray(r.curve.evaluate(np.linspace(0, 1, 33)))
    np.testing.assert_allclose(np.linalg.norm(x - r.params["centre"], axis=1), r.params["radius"], rtol=1e-12)


# --- relations ----------------------------------------------------------------------------------
_T = np.linspace(0.0, 1.0, 90)


def _circle(c, r, z=None):
    a = 2 * np.pi * _T
    pts = np.stack([c[0] + r * np.cos(a), c[1] + r * np.sin(a)], 1)
    return pts if z is None else np.column_stack([pts, np.full(len(a), z)])


def _segment(p, q):
    p, q = np.asarray(p, float), np.asarray(q, float)
    return p + _T[:, None] * (q - p)


def _polygon(vertices):
    v = np.asarray(vertices, float)
    ring = np.concatenate([v, v[:1]])
    return np.concatenate([_segment(a, b)[:-1] for a, b in itertools.pairwise(ring)] + [ring[-1:]])


def _rotate(points, angle, centre=(0.0, 0.0)):
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    return (np.asarray(points) - centre) @ rot.T + centre


R = sketch.recognise


@pytest.mark.parametrize(
    ("a", "b", "present", "absent"),
    [
        (_circle((0, 0), 1), _segment((0.2, -0.5), (0.2, 0.6)), {"inside", "vertical", "within", "disjoint"},
         {"outside", "intersect"}),
        (_circle((0, 0), 1), _segment((1.5, -0.5), (1.5, 1.5)), {"outside", "vertical", "disjoint"},
         {"inside", "within"}),
        (_circle((0, 0), 1), _segment((-2, 0.1), (2, 0.3)), {"intersect"}, {"inside", "outside", "vertical"}),
        (_circle((0, 0), 1), _segment((-1, 1), (1, 1)), {"touch", "tangent", "outside"}, {"intersect"}),
        (_circle((0, 0), 1), _segment((1, 0), (2, 0.2)), {"touch"}, {"tangent", "intersect"}),
        (_circle((0, 0), 2), _circle((0.02, 0), 0.7), {"concentric", "inside", "within"}, {"contains"}),
        (_circle((0, 0), 0.7), _circle((0, 0), 2), {"concentric", "contains"}, {"inside"}),
        (_polygon([(0, 0), (2, 0), (1, 1.6)]), _segment((0.2, 0.5), (1.8, 0.7)), {"intersect", "within"},
         set()),
        (_segment((0, 0), (3, 1)), _segment((0, 2), (3, 3)), {"parallel", "disjoint"},
         {"perpendicular"}),
        (_segment((0, 0), (3, 1)), _segment((1.2, 1.4), (1.8, -0.4)),
         {"perpendicular", "intersect", "within"}, {"parallel"}),
    ],
)  # fmt: skip
def test_relations_on_constructed_pairs(a, b, present, absent):
    """The relations of two clean strokes, in their own frame and rotated: rotation-independent
    except `vertical` (a 2-D sketch's vertical is the page's +y)."""
    found = sketch.relations(R(a), R(b))
    assert present <= found and not (absent & found), found
    turned = sketch.relations(R(_rotate(a, 0.7) * 3.0 + 5), R(_rotate(b, 0.7) * 3.0 + 5))
    assert turned - {"vertical"} == found - {"vertical"}


def test_relations_on_noisy_strokes():
    """Generated strokes (noise, over-tracing) keep the relations of their truth."""
    rng = np.random.default_rng(11)
    circle = gen.draw("circle", rng)
    centre, radius = circle.truth["centre"], circle.truth["radius"]
    up = _segment(centre + [0.2 * radius, -0.3 * radius], centre + [0.2 * radius, 0.5 * radius])
    side = _segment(centre + [2 * radius, 0], centre + [2 * radius, 1.5 * radius])
    assert {"inside", "vertical"} <= sketch.relations(R(circle.points, circle.times), R(up))
    assert {"outside", "vertical"} <= sketch.relations(R(circle.points, circle.times), R(side))


def test_composites_of_noisy_strokes():
    """Generated (noisy, over-traced) circles with a wobbly upright line beside or inside them
    make cylinders and cones whose height is the line's regularised length."""
    rng = np.random.default_rng(12)
    for _ in range(3):
        circle = gen.draw("circle", rng)
        base = R(circle.points, circle.times)
        c, r = circle.truth["centre"], circle.truth["radius"]
        wobble = 0.01 * r * np.sin(9 * _T)[:, None] * [1.0, 0.0]
        for x, name in ((2.0, "cylinder"), (0.3, "cone")):
            line = R(_segment(c + [x * r, -0.4 * r], c + [x * r, 0.9 * r]) + wobble)
            built = sketch.compose([base, line])
            assert built.name == name
            height = np.linalg.norm(np.diff(line.params["endpoints"], axis=0))
            top = np.asarray(built.surface.evaluate(np.linspace(0, 1, 5), np.ones(5)))
            np.testing.assert_allclose(top[:, 2], height, rtol=1e-12)


def test_precedes_and_three_d_vertical():
    a = R(_circle((0, 0), 1, z=0.0), np.linspace(0.0, 1.0, 90))
    standing = R(
        np.column_stack([np.full(90, 0.3), np.zeros(90), np.linspace(0.0, 2.0, 90)]), np.linspace(2, 3, 90)
    )
    lying = R(
        np.column_stack([np.linspace(0.0, 0.5, 90), np.full(90, 0.1), np.zeros(90)]), np.linspace(2, 3, 90)
    )
    assert {"vertical", "inside", "precedes"} <= sketch.relations(a, standing)
    assert "vertical" not in sketch.relations(a, lying)
    assert "precedes" not in sketch.relations(standing, a)
    assert "precedes" not in sketch.relations(R(_circle((0, 0), 1)), R(_segment((0, 0), (1, 1))))


# --- composites ---------------------------------------------------------------------------------
def _curve3(r):
    c = r.curve
    ctrl = np.column_stack([np.asarray(c.ctrl), np.zeros(c.n_ctrl)])
    return BSplineCurve(ctrl, c.knots, c.degree, weights=c.weights)


def _same(a, b):
    np.testing.assert_allclose(np.asarray(a.ctrl), np.asarray(b.ctrl), atol=1e-12)
    for x, y in ((a.weights, b.weights), (a.knots_u, b.knots_u), (a.knots_v, b.knots_v)):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=1e-12)


def test_cylinder_and_cone():
    """Fig. 3-4b, c: a vertical line outside a circle → `extrude(circle, |line| ẑ)`; inside →
    the cone `ruled(circle, apex)`, apex |line| above the centre; both rational and exact."""
    base = R(_circle((1.0, 2.0), 1.0))
    line_out, line_in = R(_segment((2.6, 1.5), (2.6, 3.5))), R(_segment((1.1, 1.6), (1.1, 2.9)))
    cylinder = sketch.compose([base, line_out])
    assert cylinder.name == "cylinder"
    _same(cylinder.surface, construct.extrude(_curve3(base), [0.0, 0.0, 2.0]))
    cone = sketch.compose([base, line_in])
    assert cone.name == "cone"
    apex = np.array([*base.params["centre"], 1.3])
    rim = _curve3(base)
    _same(cone.surface, construct.ruled(rim, rim.with_ctrl(np.broadcast_to(apex, rim.ctrl.shape))))
    x = np.asarray(cone.surface.evaluate(np.linspace(0, 1, 7), np.zeros(7)))
    radius = np.linalg.norm(x[:, :2] - base.params["centre"], axis=1)
    np.testing.assert_allclose(radius, base.params["radius"], rtol=1e-12)
    assert abs(base.params["radius"] - 1.0) < 1e-3
    np.testing.assert_allclose(np.asarray(cone.surface.evaluate(0.3, 1.0)), apex, atol=1e-12)


def test_prism_and_polygon_volume():
    triangle = R(_polygon([(0, 0), (2, 0), (1, 1.6)]))
    prism = sketch.compose([triangle, R(_segment((0.2, 0.5), (1.8, 0.7)))])
    assert prism.name == "prism"
    _same(prism.surface, construct.extrude(_curve3(triangle), [0.0, 0.0, math.hypot(1.6, 0.2)]))
    base = R(_polygon([(0, 0), (2, 0), (2, 1), (0, 1)]))
    edge = R(_segment((2, 1), (2.6, 1.6)))
    top = R(_polygon([(0.6, 1.6), (2.6, 1.6), (2.6, 2.6), (0.6, 2.6)]))
    volume = sketch.compose([base, edge, top])
    assert volume.name == "polygon volume" and [r.name for r in volume.rules] == [
        "polygon edge",
        "polygon volume",
    ]
    lifted = _curve3(top)
    lifted = lifted.with_ctrl(np.asarray(lifted.ctrl) + [0.0, 0.0, math.hypot(0.6, 0.6)])
    _same(volume.surface, construct.ruled(_curve3(base), lifted))


def test_extrusion_and_skinning():
    wave = np.stack([3 * _T, 0.3 * np.sin(2 * np.pi * _T) + 0.2 * np.sin(5 * _T)], 1)
    profile = R(wave)
    assert profile.kind == "spline"
    riser = R(_segment(wave[-1], wave[-1] + [0.5, 1.4]))
    extrusion = sketch.compose([profile, riser])
    assert extrusion.name == "extrusion"
    _same(extrusion.surface, construct.extrude(_curve3(profile), [0.0, 0.0, math.hypot(0.5, 1.4)]))
    other = R(np.stack([3 * _T, 2 + 0.3 * np.sin(3 * np.pi * _T)], 1)[::-1])  # drawn the other way
    skin = sketch.compose([profile, other])
    assert other.kind == "spline" and skin.name == "skinning"
    flipped = _curve3(other)
    flipped = BSplineCurve(
        np.asarray(flipped.ctrl)[::-1], 1 - np.asarray(flipped.knots)[::-1], flipped.degree
    )
    _same(skin.surface, construct.loft([_curve3(profile), flipped]))


def test_three_d_cone_on_a_drawing_plane():
    """Strokes lifted onto drawing planes (`unproject`): a circle on the ground, a line standing
    on it: the cone's apex is the line's length above the centre along the plane's normal."""
    base = R(_circle((0.0, 0.0), 1.0, z=0.0))
    line = R(np.column_stack([np.full(90, 0.2), np.full(90, -0.1), np.linspace(0.0, 1.5, 90)]))
    cone = sketch.compose([base, line])
    assert cone.name == "cone"
    apex = base.params["centre"] + [0.0, 0.0, 1.5]
    np.testing.assert_allclose(np.asarray(cone.surface.evaluate(0.5, 1.0)), apex, atol=1e-9)
    np.testing.assert_allclose(apex, [0.0, 0.0, 1.5], atol=1e-3)


# --- the decision tree ---------------------------------------------------------------------------
def test_tree_json_round_trip(tmp_path):
    tree = sketch.default_tree()
    assert sketch.DecisionTree.from_json(tree.to_json()) == tree
    tree.save(tmp_path / "tree.json")
    assert sketch.DecisionTree.load(tmp_path / "tree.json") == tree
    assert {r.name for r in tree.rules} >= {
        "prism",
        "cylinder",
        "cone",
        "polygon volume",
        "extrusion",
        "skinning",
    }


def _vase(seed):
    """A profile spline beside a vertical axis line: no composite of Fig. 3-4."""
    rng = np.random.default_rng(seed)
    z = np.linspace(0.0, 2.0, 90)
    radius = 0.6 + 0.25 * np.sin(2.5 * z + rng.uniform(-0.2, 0.2)) + rng.normal(0, 0.002, 90)
    return [R(np.stack([radius + 0.5, z], 1)), R(_segment((0.0, -0.1), (0.0, 2.2)))]


def test_adaptation_adds_a_composite(tmp_path):
    """Table 3-1 STEP 5: an unmatched, confirmed construction becomes a rule; the new tree
    (and its JSON copy) builds the surface of the construct constructor called directly, for
    another drawing of the same composite too; the old tree is unchanged."""
    strokes = _vase(0)
    tree = sketch.default_tree()
    assert sketch.compose(strokes, tree).name is None
    adapted = sketch.adapt(strokes, "vase", "revolve", tree)
    assert len(adapted.rules) == len(tree.rules) + 1 and tree == sketch.default_tree()
    adapted.save(tmp_path / "user.json")
    loaded = sketch.DecisionTree.load(tmp_path / "user.json")
    for drawing in (strokes, _vase(1)):
        result = sketch.compose(drawing, loaded)
        assert result.name == "vase"
        axis = np.asarray(_curve3(drawing[1]).evaluate(np.array([0.0, 1.0])))
        _same(result.surface, construct.revolve(_curve3(drawing[0]), axis[0], axis[1] - axis[0]))
    with pytest.raises(ValueError, match="strokes"):
        sketch.adapt(strokes, "again", "revolve", adapted)


# --- bad input ----------------------------------------------------------------------------------
def test_bad_input():
    good = _circle((0, 0), 1)
    with pytest.raises(ValueError, match="points: expected at least 3 samples"):
        sketch.recognise(good[:2])
    with pytest.raises(ValueError, match="points: expected finite"):
        sketch.recognise(np.where(np.arange(90)[:, None] == 5, np.nan, good))
    with pytest.raises(ValueError, match="points: expected stroke samples of dimension 2 or 3"):
        sketch.recognise(np.zeros((10, 4)))
    with pytest.raises(ValueError, match="points: expected an array with 2 dimension"):
        sketch.recognise(np.zeros(10))
    with pytest.raises(TypeError, match="points: expected real numbers"):
        sketch.recognise(good.astype(complex))
    with pytest.raises(TypeError, match="points"):
        sketch.recognise("a stroke")
    with pytest.raises(TypeError, match="points"):
        sketch.recognise([["a", "b"], ["c", "d"], ["e", "f"]])
    with pytest.raises(ValueError, match="points: expected a stroke of nonzero length"):
        sketch.recognise(np.ones((5, 2)))
    with pytest.raises(ValueError, match=r"times: expected shape \(90,\)"):
        sketch.recognise(good, np.arange(5.0))
    with pytest.raises(ValueError, match="times: expected strictly increasing"):
        sketch.recognise(good, np.zeros(90))
    r = sketch.recognise(good)
    with pytest.raises(TypeError, match="b: expected a bsjax.sketch.Recognised"):
        sketch.relations(r, good)
    with pytest.raises(ValueError, match="strokes: expected at least 2"):
        sketch.compose([r])
    with pytest.raises(TypeError, match=r"strokes\[1\]"):
        sketch.compose([r, good])
    with pytest.raises(TypeError, match="tree"):
        sketch.compose([r, r], tree="default")
    with pytest.raises(ValueError, match="construction: expected one of"):
        sketch.adapt([r, r], "x", "teleport")
    with pytest.raises(ValueError, match=r"rules\[0\].relations"):
        sketch.DecisionTree((sketch.Rule("x", ("circle",), ("line",), ("levitating",), "extrude"),))
    with pytest.raises(ValueError, match=r"rules\[1\].name"):
        rule = sketch.Rule("x", ("circle",), ("line",), (), "extrude")
        sketch.DecisionTree((rule, rule))
    with pytest.raises(ValueError, match="text: expected a JSON object"):
        sketch.DecisionTree.from_json('{"rules": []}')
