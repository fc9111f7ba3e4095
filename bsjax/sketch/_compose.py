"""Composite constraint reasoning: strokes → a 3-D construction (thesis Table 3-1 STEPs 4–5,
Figs. 3-4…3-6, Table 3-2).

The decision tree of Fig. 3-5 is data: a `DecisionTree` of `Rule`s, each one row of Table 3-2 —
`previous` (Pre-Node: the kinds or rule names the strokes so far must have reached), `current`
(Curr-Node: the kinds the next stroke may have), `relations` (the Constraint: relation names of
`relations(previous stroke, next stroke)` that must all hold) and `construction` (the surface it
builds, a key of `CONSTRUCTIONS`; `None` for an intermediate node). `compose` walks the strokes
in drawing order (USER MODELING, Table 3-2's pseudo-code: each stroke links to the node the
previous ones reached); `adapt` is INSERT: a confirmed construction that matched no rule becomes
new rules, and the tree is saved and loaded as JSON.

The composites of Fig. 3-4 (`default_tree`):

* `prism`: triangle, then a line that crosses it inside its circumscribed circle (`intersect`,
  `within`) → `construct.extrude(triangle, h)`;
* `cylinder`: circle or ellipse, then a line `vertical` and `outside` → `construct.extrude(base, h)`;
* `cone`: circle or ellipse, then a line `vertical` and `inside` → `construct.ruled(base, apex)`,
  the apex `h` above the centre;
* `polygon volume` (three strokes): a polygon, a line that `touch`es it, a polygon that `touch`es
  the line → `construct.ruled(base, top)`;
* `extrusion`: a spline, then a spline or line that `touch`es it → `construct.extrude(profile, h)`;
* `skinning`: two `disjoint` splines → `construct.loft([a, b])`.

`h`, the height vector, is the last stroke's chord: in 3-D (strokes on drawing planes, e.g. from
`unproject`) oriented away from the base's plane; in a 2-D sketch the third dimension is the
drawing plane's normal `+z` and `h = |chord| ẑ` (the sketch draws the base face-on and the
height stroke beside it). 2-D curves are read at z = 0. Every surface is exact: the constructors
of `bsjax.construct` on the regularised curves (rational circles and ellipses stay rational).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bsjax import construct
from bsjax._declared import declared
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.sketch._recognise import KINDS, POLYGONS, Recognised
from bsjax.sketch._relations import RELATIONS, relations

_FORMAT = "bsjax.sketch.DecisionTree"


# --- constructions ------------------------------------------------------------------------------
def _curve3(r: Recognised) -> BSplineCurve:
    """The regularised curve in 3-D (a 2-D curve at z = 0)."""
    c = r.curve
    if c.dim == 3:
        return c
    ctrl = np.column_stack([np.asarray(c.ctrl), np.zeros(c.n_ctrl)])
    return BSplineCurve(ctrl.astype(np.asarray(c.ctrl).dtype), c.knots, c.degree, c.periodic, c.weights)


def _height(base: Recognised, stroke: Recognised) -> np.ndarray:
    """The height vector `(3,)` a stroke gives a base (see the module docstring)."""
    ends = np.asarray(stroke.curve.evaluate(np.array([0.0, 1.0])), float)
    chord = ends[1] - ends[0]
    length = float(np.linalg.norm(chord))
    if ends.shape[1] == 2 or base.points.shape[1] == 2:
        return np.array([0.0, 0.0, length])
    n = base.normal
    lift = (ends - base.frame[0]) @ n
    if abs(lift[1] - lift[0]) < 1e-9 * length:  # in the base's plane: along its normal
        return length * n
    return chord if abs(lift[1]) >= abs(lift[0]) else -chord


def _centre3(r: Recognised) -> np.ndarray:
    c = np.asarray(r.params["centre"], float)
    return c if c.shape[0] == 3 else np.append(c, 0.0)


def _extrude(strokes: Sequence[Recognised]) -> BSplineSurface:
    base = strokes[0]
    h = _height(base, strokes[-1])
    return construct.extrude(_curve3(base), h.astype(np.asarray(base.curve.ctrl).dtype))


def _cone(strokes: Sequence[Recognised]) -> BSplineSurface:
    base = strokes[0]
    rim = _curve3(base)
    apex = _centre3(base) + _height(base, strokes[-1])
    return construct.ruled(rim, rim.with_ctrl(np.broadcast_to(apex, rim.ctrl.shape).astype(rim.ctrl.dtype)))


def _volume(strokes: Sequence[Recognised]) -> BSplineSurface:
    base, top = _curve3(strokes[0]), _curve3(strokes[-1])
    if strokes[-1].points.shape[1] == 2:
        top = top.with_ctrl(np.asarray(top.ctrl) + _height(strokes[0], strokes[1]).astype(top.ctrl.dtype))
    return construct.ruled(base, top)


def _skin(strokes: Sequence[Recognised]) -> BSplineSurface:
    curves = [_curve3(s) for s in strokes]
    for i in range(1, len(curves)):  # sections drawn the other way round are reversed
        a = np.asarray(curves[i - 1].evaluate(np.array([0.0, 1.0])))
        b = np.asarray(curves[i].evaluate(np.array([0.0, 1.0])))
        if np.linalg.norm(a - b[::-1], axis=1).sum() < np.linalg.norm(a - b, axis=1).sum():
            curves[i] = _reversed(curves[i])
    return construct.loft(curves)


def _reversed(c: BSplineCurve) -> BSplineCurve:
    knots = None if c.knots is None else 1.0 - np.asarray(c.knots)[::-1]
    weights = None if c.weights is None else np.asarray(c.weights)[::-1]
    return BSplineCurve(np.asarray(c.ctrl)[::-1], knots, c.degree, c.periodic, weights)


def _revolve(strokes: Sequence[Recognised]) -> BSplineSurface:
    profile, axis = _curve3(strokes[0]), strokes[-1]
    ends = np.asarray(_curve3(axis).evaluate(np.array([0.0, 1.0])))
    return construct.revolve(profile, ends[0], ends[1] - ends[0])


CONSTRUCTIONS: dict[str, Callable[[Sequence[Recognised]], BSplineSurface]] = {
    "extrude": _extrude,
    "cone": _cone,
    "ruled": _volume,
    "loft": _skin,
    "revolve": _revolve,
}
"""The surfaces a rule can build from its strokes (first stroke = base or profile):
`extrude` (`construct.extrude` by the height vector of the last stroke), `cone`
(`construct.ruled` from the base to the apex over its centre), `ruled` (`construct.ruled` from
the first to the last stroke, the last lifted by the middle stroke's height in a 2-D sketch),
`loft` (`construct.loft` through every stroke), `revolve` (`construct.revolve` of the first
stroke about the last, a line)."""


# --- the decision tree ----------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Rule:
    """One node of the decision tree (a row of thesis Table 3-2).

    **Fields:** `name` (unique); `previous`: the kinds (`KINDS`) or rule names the strokes before
    must have reached (Pre-Node); `current`: the kinds the next stroke may have (Curr-Node);
    `relations`: `RELATIONS` names that must all be in `relations(previous, next)` (the
    Constraint); `construction`: a key of `CONSTRUCTIONS`, or `None` for an intermediate node.
    """

    name: str
    previous: tuple[str, ...]
    current: tuple[str, ...]
    relations: tuple[str, ...]
    construction: str | None

    def accepts(self, node: str, stroke: Recognised, found: frozenset[str]) -> bool:
        """Whether the next `stroke`, with relations `found` to the previous one, extends `node`."""
        return node in self.previous and stroke.kind in self.current and set(self.relations) <= found


@dataclasses.dataclass(frozen=True)
class DecisionTree:
    """The decision tree of thesis Fig. 3-5 / Table 3-2: the primitive kinds are its leaves,
    `rules` its branch nodes in priority order (the first that accepts a stroke wins)."""

    rules: tuple[Rule, ...]

    def __post_init__(self):
        names = set(KINDS)
        for i, rule in enumerate(self.rules):
            where = f"rules[{i}]"
            if not isinstance(rule, Rule):
                raise TypeError(f"{where}: expected a bsjax.sketch.Rule, got {type(rule).__name__}")
            if rule.name in names:
                _fail(f"{where}.name", "a name not used before (nor a kind)", repr(rule.name))
            for field, allowed in (
                ("previous", names),
                ("current", set(KINDS)),
                ("relations", set(RELATIONS)),
            ):
                bad = [x for x in getattr(rule, field) if x not in allowed]
                if bad or not isinstance(getattr(rule, field), tuple):
                    _fail(
                        f"{where}.{field}", f"a tuple of names from {sorted(allowed)}", getattr(rule, field)
                    )
            if rule.construction is not None and rule.construction not in CONSTRUCTIONS:
                _fail(
                    f"{where}.construction",
                    f"one of {sorted(CONSTRUCTIONS)} or None",
                    repr(rule.construction),
                )
            names.add(rule.name)

    def walk(self, strokes: Sequence[Recognised]):
        """The rules the strokes reach one after the other, and the relations between
        consecutive strokes; the path stops at the first stroke no rule accepts."""
        node, path, found = strokes[0].kind, [], []
        for a, b in itertools.pairwise(strokes):
            rel = relations(a, b)
            found.append(rel)
            rule = next((r for r in self.rules if r.accepts(node, b, rel)), None)
            if rule is None:
                break
            path.append(rule)
            node = rule.name
        return tuple(path), tuple(found)

    def to_json(self) -> str:
        """The tree as JSON text (`from_json` reads it back)."""
        rules = [dataclasses.asdict(r) for r in self.rules]
        return json.dumps({"format": _FORMAT, "version": 1, "rules": rules}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> DecisionTree:
        """A tree from `to_json`'s text (checked like the constructor)."""
        data = json.loads(text)
        if not isinstance(data, dict) or data.get("format") != _FORMAT or data.get("version") != 1:
            _fail("text", f"a JSON object with format {_FORMAT!r} and version 1", str(text)[:60])
        rules = []
        for i, r in enumerate(data.get("rules", [])):
            if not isinstance(r, dict) or set(r) != {f.name for f in dataclasses.fields(Rule)}:
                _fail(f"rules[{i}]", "an object with name, previous, current, relations, construction", r)
            lists = {k: tuple(r[k]) for k in ("previous", "current", "relations")}
            rules.append(Rule(r["name"], **lists, construction=r["construction"]))
        return cls(tuple(rules))

    def save(self, path: str | Path) -> None:
        """Write `to_json()` to `path`."""
        Path(path).write_text(self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> DecisionTree:
        """Read a tree written by `save`."""
        return cls.from_json(Path(path).read_text())


def _fail(name: str, expected: str, got) -> None:
    raise ValueError(f"{name}: expected {expected}, got {got}")


def default_tree() -> DecisionTree:
    """The composites of thesis Fig. 3-4 (see the module docstring's table)."""
    conics, lines, splines = ("circle", "ellipse"), ("line",), ("spline",)
    return DecisionTree((
        Rule("prism", ("triangle",), lines, ("intersect", "within"), "extrude"),
        Rule("cylinder", conics, lines, ("vertical", "outside"), "extrude"),
        Rule("cone", conics, lines, ("vertical", "inside"), "cone"),
        Rule("polygon edge", POLYGONS, lines, ("touch",), None),
        Rule("polygon volume", ("polygon edge",), POLYGONS, ("touch",), "ruled"),
        Rule("extrusion", splines, ("spline", "line"), ("touch",), "extrude"),
        Rule("skinning", splines, splines, ("disjoint",), "loft"),
    ))  # fmt: skip


# --- compose and adapt ------------------------------------------------------------------------------
class Construction(NamedTuple):
    """The result of `compose`: `name` (the rule reached, `None` when the strokes matched no
    composite), `surface` (its `BSplineSurface`, `None` when unmatched), `rules` (the path of
    rules reached) and `relations` (between consecutive strokes)."""

    name: str | None
    surface: BSplineSurface | None
    rules: tuple[Rule, ...]
    relations: tuple[frozenset[str], ...]


def _strokes(strokes, name: str = "strokes") -> list[Recognised]:
    if isinstance(strokes, Recognised) or not isinstance(strokes, Sequence):
        raise TypeError(
            f"{name}: expected a sequence of bsjax.sketch.Recognised, got {type(strokes).__name__}"
        )
    out = list(strokes)
    for i, s in enumerate(out):
        if not isinstance(s, Recognised):
            raise TypeError(f"{name}[{i}]: expected a bsjax.sketch.Recognised, got {type(s).__name__}")
    if len(out) < 2:
        _fail(name, "at least 2 recognised strokes (a composite)", len(out))
    return out


def _tree(tree) -> DecisionTree:
    if tree is None:
        return default_tree()
    if not isinstance(tree, DecisionTree):
        raise TypeError(f"tree: expected a bsjax.sketch.DecisionTree or None, got {type(tree).__name__}")
    return tree


def compose(strokes: Sequence[Recognised], tree: DecisionTree | None = None) -> Construction:
    """The 3-D construction of recognised strokes (thesis Table 3-1 STEP 4, Figs. 3-4, 3-6).

    The strokes, in drawing order, walk the tree: stroke 0's kind is the first node, and each
    next stroke moves to the first rule that accepts it (its kind, and the relations to the
    stroke before). The strokes make a construction when every stroke was accepted and the last
    rule reached builds a surface.

    **Arguments:** `strokes`: ≥ 2 `Recognised` strokes; `tree`: a `DecisionTree` (default:
    `default_tree()`, the composites of Fig. 3-4).
    **Returns:** a `Construction`; unmatched strokes give `name = surface = None` (see `adapt`).
    """
    strokes, tree = _strokes(strokes), _tree(tree)
    path, found = tree.walk(strokes)
    if len(path) < len(strokes) - 1 or path[-1].construction is None:
        return Construction(None, None, path, found)
    return Construction(path[-1].name, CONSTRUCTIONS[path[-1].construction](strokes), path, found)


@declared
def adapt(strokes: Sequence[Recognised], name: str, construction: str, tree: DecisionTree | None = None):
    """The user-adaptation step (thesis Table 3-1 STEP 5, §3.1.3, Fig. 3-6; INSERT of Table
    3-2): strokes that matched no composite, confirmed by the user as `construction` named
    `name`, become new rules — where the strokes leave the tree's path, one rule per remaining
    stroke (its kind, and every spatial relation observed to the stroke before; intermediate
    nodes are `name:1`, `name:2`, …). Returns the new `DecisionTree`; the old one is unchanged.

    **Arguments:** `strokes`: ≥ 2 `Recognised`; `name`: a new rule name; `construction`: a key of
    `CONSTRUCTIONS`; `tree`: the tree to extend (default `default_tree()`).
    """
    strokes, tree = _strokes(strokes), _tree(tree)
    if not isinstance(name, str) or not name:
        raise TypeError(f"name: expected a non-empty str, got {name!r}")
    if construction not in CONSTRUCTIONS:
        _fail("construction", f"one of {sorted(CONSTRUCTIONS)}", repr(construction))
    if compose(strokes, tree).name is not None:
        _fail(
            "strokes",
            "strokes that match no composite of the tree",
            f"a match: {compose(strokes, tree).name}",
        )
    path, _ = tree.walk(strokes)
    keep = min(len(path), len(strokes) - 2)  # a path ending on an intermediate node: redo its last step
    found = [relations(a, b) for a, b in itertools.pairwise(strokes)]
    node = path[keep - 1].name if keep else strokes[0].kind
    new = []
    for i in range(keep + 1, len(strokes)):
        last = i == len(strokes) - 1
        rule_name = name if last else f"{name}:{i}"
        observed = tuple(sorted(found[i - 1] - {"precedes"}))
        new.append(Rule(rule_name, (node,), (strokes[i].kind,), observed, construction if last else None))
        node = rule_name
    # new rules first: a confirmed construction is more specific than the rule it left
    return DecisionTree((*new, *tree.rules))
