"""The bad-input contract over the public API, generated: every public function of the snapshot
(`tests/public_api.txt`) is called with one argument replaced by a bad value drawn by hypothesis —
NaN, ±inf, complex, a string, an object array, one axis too many, a wrong type for an object
argument, a fractional or boolean count, an unknown option — and must raise `ValueError` or
`TypeError` whose message names that argument (the README's "Reliability" contract).

The valid call each mutation starts from is built from the argument's name (the library's
domain names: `ctrl`, `blending`, `lattice`, `curve`, `degree`, …; `VALID`, with per-module
meanings where a name means another thing there), so a new public function whose arguments have
known names is covered without a line here; one with an argument of an unknown name fails
`test_every_public_function_is_covered` until `VALID` (or `NOT_GENERATED`, with the reason)
names it. Only the bad call runs: a structure check raises before anything compiles, so those
cases cost seconds; a NaN/inf case is called directly, inside the caller's `jax.jit` or under
`jax.vmap` (drawn; the traced variants for the array arguments of functions that trace them).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import os
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bsjax import basis, collide, mss, shapes

SNAPSHOT = Path(__file__).with_name("public_api.txt")


# --- valid values, by argument name ----------------------------------------------------------
@functools.cache
def _plate():
    return shapes.plate(6, 6)


@functools.cache
def _blending():
    return _plate().blending(12, 12)


def _curve3(closed: bool = False):
    if closed:
        t = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        return basis.BSplineCurve(np.stack([2 * np.cos(t), np.sin(t)], 1), None, 3, periodic=True)
    x = np.linspace(0.0, 1.0, 6)
    ctrl = np.stack([x, 0.2 * np.sin(3 * x), 0.1 * x], 1)
    return basis.BSplineCurve(ctrl, basis.clamped_knots(6, 3), 3)


@functools.cache
def _lattice():
    g = np.stack(np.meshgrid(*[np.linspace(0.0, 0.01, 3)] * 3, indexing="ij"), -1)
    return mss.hex_lattice(g, material=mss.JELLY)


@functools.cache
def _state():
    return mss.init(_lattice())


def _points(n: int = 10, d: int = 3):
    rng = np.random.default_rng(0)
    return rng.uniform(0.1, 0.9, (n, d))


@functools.cache
def _surface_body():
    return mss.surface_lattice(_blending(), np.asarray(_plate().ctrl), mss.JELLY)


@functools.cache
def _scene():
    lattice, coupling = _surface_body()
    return mss.Scene([mss.Body(lattice, _plate(), coupling)], reach=0.01)


@functools.cache
def _contact():
    return collide.contacts(_blending(), np.asarray(_plate().ctrl), collide.Sphere([0.5, 0.5, 0.1], 0.25))


@functools.cache
def _files(tmp=None) -> Path:
    import tempfile

    from bsjax import io

    folder = Path(tempfile.mkdtemp(prefix="bsjax-contract-"))
    io.save(_plate(), folder / "plate.json")
    return folder


def _two_plates() -> list:
    return [_plate(), _plate().with_ctrl(np.asarray(_plate().ctrl) + [1.0, 0.0, 0.0])]


def _line(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return basis.BSplineCurve(a + np.linspace(0.0, 1.0, 4)[:, None] * (b - a), basis.clamped_knots(4, 3), 3)


def _stroke():
    from bsjax import sketch

    t = np.linspace(0.0, 2 * np.pi, 40)
    return sketch.recognise(np.stack([np.cos(t), np.sin(t)], 1))


@functools.cache
def _axes():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    return plt.figure().add_subplot(projection="3d")


# name -> factory; "module.name" or "function.name" for a meaning particular to one module or one
# function
VALID: dict[str, Callable[[], object]] = {
    "ctrl": lambda: np.asarray(_plate().ctrl),
    "blending": _blending,
    "surface": _plate,
    "spline": _plate,
    "knots": lambda: np.asarray(basis.clamped_knots(8, 3)),
    "degree": lambda: 3,
    "n_ctrl": lambda: 8,
    "params": lambda: np.linspace(0.0, 1.0, 7),
    "t": lambda: np.linspace(0.0, 1.0, 7),
    "points": lambda: _points(),
    "tool": lambda: collide.Sphere([0.5, 0.5, 0.1], 0.25),
    "stiffness": lambda: 100.0,
    "lattice": _lattice,
    "state": _state,
    "dt": lambda: 1e-5,
    "n_steps": lambda: 3,
    "x": lambda: np.asarray(_state().position),
    "v": lambda: np.asarray(_state().velocity),
    "positions": lambda: np.asarray(_state().position),
    "position": lambda: np.asarray(_state().position),
    "point": lambda: np.zeros(3),
    "normal": lambda: np.array([0.0, 0.0, 1.0]),
    "mass": lambda: 1e-3,
    "damping": lambda: 0.1,
    "material": lambda: mss.JELLY,
    "rest_length": lambda: 0.01,
    "area": lambda: 1e-4,
    "curve": _curve3,
    "curves": lambda: [_curve3(), _curve3().with_ctrl(np.asarray(_curve3().ctrl) + [0.0, 0.0, 1.0])],
    "profile": _curve3,
    "path": _curve3,
    "c0": _curve3,
    "c1": lambda: _curve3().with_ctrl(np.asarray(_curve3().ctrl) + [0.0, 0.0, 1.0]),
    "vector": lambda: np.array([0.0, 0.0, 1.0]),
    "axis_point": lambda: np.zeros(3),
    "axis_dir": lambda: np.array([0.0, 0.0, 1.0]),
    "amount": lambda: 0.5,
    "index": lambda: 0,
    "grammar.curve": lambda: _curve3(closed=True),
    "sketch.points": lambda: _points(20, 2),
    "merge.surfaces": lambda: _two_plates(),
    "merge.knots_a": lambda: np.asarray(basis.clamped_knots(8, 3)),
    "merge.knots_b": lambda: np.asarray(basis.clamped_knots(8, 3)),
    "merge.continuity": lambda: 2,
    "merge.originals": _plate,
    "merge.merged": _plate,
    "vsofm.points": lambda: _points(200),
    "vsofm.shape": lambda: (3, 3, 3),
    "vsofm.nodes": lambda: np.asarray(_lattice().rest_positions).reshape(3, 3, 3, 3),
    "old": lambda: _blending().direction_u,
    "new": lambda: _blending().direction_u,
    "tree": lambda: {"a": np.ones(3)},
    "fn": lambda: lambda x: x,
    "progress": lambda: lambda done, total: None,
    "done": lambda: 1,
    "total": lambda: 2,
    "contact": _contact,
    "blending_a": _blending,
    "blending_b": _blending,
    "ctrl_a": lambda: np.asarray(_plate().ctrl),
    "ctrl_b": lambda: np.asarray(_plate().ctrl) + [0.0, 0.0, 0.05],
    "reach": lambda: 0.05,
    "left": lambda: _line([0, 0, 0], [0, 1, 0]),
    "right": lambda: _line([1, 0, 0], [1, 1, 0]),
    "plane_normal": lambda: np.array([0.0, 0.0, 1.0]),
    "c_bottom": lambda: _line([0, 0, 0], [1, 0, 0]),
    "c_top": lambda: _line([0, 1, 0], [1, 1, 0]),
    "c_left": lambda: _line([0, 0, 0], [0, 1, 0]),
    "c_right": lambda: _line([1, 0, 0], [1, 1, 0]),
    "rail_a": lambda: _line([0, 0, 0], [0, 1, 0]),
    "rail_b": lambda: _line([1, 0, 0], [1, 1, 0]),
    "rail_rotation.profile": lambda: _line([0, 0, 0], [1, 0, 0]),
    "grammar.name": lambda: "M+m+M+m+",
    "grammar.rule": lambda: "Cm+",
    "max_extrema": lambda: 4,
    "data": lambda: __import__("bsjax.io", fromlist=["io"]).to_dict(_plate()),
    "io.path": lambda: _files() / "plate.json",
    "io.surfaces": _plate,
    "knot_list": lambda: [np.asarray(basis.clamped_knots(8, 3))] * 2,
    "rows": lambda: [_two_plates()],
    "oriented": lambda: [_two_plates()],
    "report": lambda: __import__("bsjax.merge", fromlist=["merge"]).deviation(_plate(), _plate(), samples=5),
    "scene": _scene,
    "states": lambda: [mss.init(_surface_body()[0])],
    "op": lambda: (False, True, False),
    "direction": lambda: "u",
    "layout": lambda: __import__("bsjax.merge", fromlist=["merge"]).plan(_two_plates(), "u"),
    "ctrls": lambda: [np.asarray(s.ctrl) for s in _two_plates()],
    "coupling": lambda: _surface_body()[1],
    "coupled_step.lattice": lambda: _surface_body()[0],
    "coupled_step.state": lambda: mss.init(_surface_body()[0]),
    "simulate_coupled.lattice": lambda: _surface_body()[0],
    "simulate_coupled.state": lambda: mss.init(_surface_body()[0]),
    "refit_every": lambda: 1,
    "rest_positions": lambda: np.asarray(_lattice().rest_positions),
    "edges": lambda: mss.hex_edges((3, 3, 3)),
    "volume": lambda: 1e-6,
    "mss.shape": lambda: (3, 3, 3),
    "plasticity": lambda: mss.Plasticity(0.1),
    "tools": lambda: (collide.Sphere([0.0, 0.0, 0.02], 0.01),),
    "residuals": lambda: lambda x, args: x - 1.0,
    "objective": lambda: lambda x, args: ((x - 1.0) ** 2).sum(),
    "design": lambda: np.zeros(3),
    "ax": _axes,
    "fig": lambda: _axes().figure,
    "plot.path": lambda: _files() / "figure.png",
    "plot.points": lambda: np.asarray(_blending().points(_plate().ctrl)),
    "xyz": lambda: _points(),
    "n_panels": lambda: 1,
    "bound_uv": lambda: np.array([[0.2, 0.2], [0.8, 0.2], [0.8, 0.8], [0.2, 0.8]]),
    "frame0": lambda: np.eye(3),
    "frame1": lambda: np.eye(3),
    "sculpt.shape": _curve3,
    "constraints": lambda: [__import__("bsjax.sculpt", fromlist=["sculpt"]).Position(0.5, [0.5, 0.2, 0.1])],
    "target_curve": lambda: _line([0.2, 0.5, 0.1], [0.8, 0.5, 0.1]),
    "strokes": lambda: [_stroke()],
    "adapt.strokes": lambda: [_stroke(), _stroke()],
    "sketch.name": lambda: "circle",
    "construction": lambda: "extrude",
    "a": _stroke,
    "b": _stroke,
    "stroke_curve": _curve3,
    "window_xy": lambda: np.zeros((3, 2)),
    "camera": lambda: __import__("bsjax.sketch", fromlist=["sketch"]).Camera(
        [0.0, 0.0, 5.0], [0.0, 0.0, 0.0]
    ),
    "plane": lambda: collide.Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
    # constructors
    "knots_u": lambda: np.asarray(basis.clamped_knots(6, 3)),
    "knots_v": lambda: np.asarray(basis.clamped_knots(6, 3)),
    "degree_u": lambda: 3,
    "degree_v": lambda: 3,
    "center": lambda: np.array([0.5, 0.5, 0.1]),
    "radius": lambda: 0.25,
    "radii": lambda: np.array([0.2, 0.3, 0.1]),
    "vertices": lambda: np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    "faces": lambda: np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    "youngs_modulus": lambda: 1e4,
    "density": lambda: 1000.0,
    "yield_strain": lambda: 0.1,
    "bodies": lambda: [_scene().bodies[0]],
    "State.position": lambda: np.asarray(_state().position),
    "velocity": lambda: np.asarray(_state().velocity),
    "sculpt.u": lambda: 0.5,
    "u1": lambda: 0.2,
    "u2": lambda: 0.8,
    "d": lambda: 0.1,
    "sculpt.target": lambda: np.array([0.5, 0.2, 0.1]),
    "sculpt.value": lambda: np.array([1.0, 0.0, 0.0]),
    "sculpt.delta": lambda: np.array([0.0, 0.0, 0.1]),
    "sculpt.surface": _plate,
    "sculpt.direction": lambda: np.array([1.0, 0.0, 0.0]),
    "eye": lambda: np.array([0.0, 0.0, 5.0]),
    "sketch.target": lambda: np.zeros(3),
    "geometry": _plate,
    "segments": lambda: np.array(
        [
            [[0.2, 0.2], [0.8, 0.2]],
            [[0.8, 0.2], [0.8, 0.8]],
            [[0.8, 0.8], [0.2, 0.8]],
            [[0.2, 0.8], [0.2, 0.2]],
        ]
    ),
    "loop_sizes": lambda: (4,),
    "outer": lambda: (True,),
    "SplineDirection.knots": lambda: np.asarray(basis.clamped_knots(6, 3)),
    # where a name means something particular to one function
    "basis.spline": _curve3,  # a curve: no `direction` needed
    "Point.position": lambda: np.zeros(3),
    "grid_mesh.points": lambda: np.asarray(_blending().points(_plate().ctrl)),
    "interpolate_grid.points": lambda: np.asarray(_blending().points(_plate().ctrl)),
    "convexify.curve": lambda: basis.BSplineCurve(
        np.asarray(_curve3().ctrl)[:, :2], basis.clamped_knots(6, 3), 3
    ),
    "apply_rule.index": lambda: 1,  # the m+ of M+m+M+m+
    "point_parameters.points": lambda: __import__("bsjax.grammar", fromlist=["g"]).characteristic_points(
        _curve3(closed=True)
    ),
    "simplify.points": lambda: __import__("bsjax.grammar", fromlist=["g"]).characteristic_points(
        _curve3(closed=True)
    ),
    "hex_lattice.positions": lambda: np.asarray(_lattice().rest_positions).reshape(3, 3, 3, 3),
    "Scene.bodies": lambda: [mss.Body.from_surface(_plate(), (6, 6, 2), mss.JELLY, thickness=0.01)],
    "apply_inverse.name": lambda: "M+0m-0m+",
    "apply_inverse.index": lambda: 1,  # its 0m-0
    "adapt.name": lambda: "ring",  # a new name adapt teaches the tree
    "compose.strokes": lambda: [_stroke(), _stroke()],
    "BSplineCurve.ctrl": lambda: np.asarray(_curve3().ctrl),
    "BSplineCurve.knots": lambda: np.asarray(basis.clamped_knots(6, 3)),
}

# public names the generator does not call, and why
RESULT = "a result type: returned by the library, its fields not checked at construction"
NOT_GENERATED = {
    **{
        f"bsjax.{name}": RESULT
        for name in (
            "basis:Blending",
            "basis:CurveBlending",
            "basis:Projection",
            "collide:Contact",
            "collide:FaceTree",
            "collide:Penetration",
            "collide:SurfaceContact",
            "construct:SurfaceFit",
            "grammar:CharacteristicPoints",
            "grammar:Measures",
            "grammar:OperatorResult",
            "grammar:PointParameters",
            "merge:Deviation",
            "merge:MergeLayout",
            "merge:RefitSolution",
            "mss:SurfaceCoupling",
            "optimise:OptimiseResult",
            "sculpt:Edit",
            "sculpt:Factor",
            "sculpt:SculptResult",
            "sketch:Construction",
            "sketch:CurveFit",
            "sketch:DecisionTree",
            "sketch:Features",
            "sketch:Oversketch",
            "sketch:Recognised",
            "sketch:Resampled",
            "sketch:Rule",
            "vsofm:Report",
        )
    },
    "bsjax.collide:AbstractTool": "abstract",
    "bsjax.sculpt:AbstractConstraint": "abstract",
    "bsjax.sculpt:AbstractNonlinear": "abstract",
    "bsjax.io:CadList": "a list (its items are checked where it is saved)",
    "bsjax.batch:initialize": "no arguments to spoil (its options are checked in tests/test_batch.py)",
    "bsjax.batch:mesh": "no required argument",
    "bsjax.merge:cache_info": "no arguments",
    "bsjax.merge:clear_cache": "no arguments",
    "bsjax.sketch:default_tree": "no arguments",
}
# arguments of any shape, for which one more axis is no mistake
ANY_SHAPE = {
    ("bsjax.basis:basis_functions", "t"),
    ("bsjax.mss:behind_plane", "positions"),  # points (..., 3)
    ("bsjax.sketch:unproject", "window_xy"),  # window points (..., 2)
    ("bsjax.optimise:least_squares", "design"),  # a design is any pytree of arrays
    ("bsjax.optimise:minimise", "design"),
}
# (function, argument, kind) whose "bad" value is valid there
VALID_THERE = {
    ("bsjax.batch:gather", "tree", "number"),  # a number is a pytree of one leaf
    ("bsjax.sketch:adapt", "name", "option"),  # adapt teaches the tree a new name
}
NOT_COVERED_PACKAGES = ("bsjax.cli", "bsjax.examples", "bsjax.device", "bsjax.view")


def _valid(key: str, name: str):
    """The factory of a valid value of argument `name` of the public function `key`."""
    module, function = key.split(":")
    short = module.rsplit(".", 1)[-1]
    return VALID.get(f"{function}.{name}") or VALID.get(f"{short}.{name}") or VALID.get(name)


def _functions() -> list[tuple[str, Callable]]:
    found = []
    for line in SNAPSHOT.read_text().splitlines():
        module, name = line.split()[0].split(":")
        if module.startswith(NOT_COVERED_PACKAGES) or module == "bsjax":
            continue
        obj = getattr(importlib.import_module(module), name)
        if callable(obj):
            found.append((f"{module}:{name}", obj))
    return found


def _required(fn) -> list[inspect.Parameter]:
    params = inspect.signature(fn).parameters.values()
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return [p for p in params if p.default is p.empty and p.kind in (*kinds, inspect.Parameter.KEYWORD_ONLY)]


def _call(key: str, fn, replace: str, bad, given: dict | None = None):
    """`fn` called with valid values of its required arguments (`given`'s where it names them),
    argument `replace` replaced by `bad` (an optional one passed as a keyword)."""
    args, kwargs = [], {} if replace in {p.name for p in _required(fn)} or not replace else {replace: bad}
    for p in _required(fn):
        if given is not None and p.name in given:
            value = given[p.name]
        else:
            value = bad if p.name == replace else _valid(key, p.name)()  # pyright: ignore[reportOptionalCall]
        if p.kind is inspect.Parameter.KEYWORD_ONLY:
            kwargs[p.name] = value
        else:
            args.append(value)
    more_args, more_kwargs = NEEDED.get(key, lambda: ((), {}))()
    return fn(*args, *more_args, **{**more_kwargs, **kwargs})


# what a valid call of these functions needs beyond their required arguments: `*args`, keywords
NEEDED: dict[str, Callable[[], tuple[tuple, dict]]] = {
    "bsjax.basis:insert_knots": lambda: ((), {"values": np.array([0.3, 0.6])}),
    "bsjax.batch:map": lambda: ((np.ones((2, 3)),), {}),
    "bsjax.mss:hex_lattice": lambda: ((), {"material": mss.JELLY}),
    "bsjax.mss:surface_lattice": lambda: ((), {"material": mss.JELLY}),
}


COVERED = [
    (key, fn)
    for key, fn in _functions()
    if key not in NOT_GENERATED and all(_valid(key, p.name) for p in _required(fn))
]


def test_every_public_function_is_covered():
    """Each public function is generated (every required argument has a valid value by name) or
    listed in `NOT_GENERATED` with its reason."""
    missing = {
        key: [p.name for p in _required(fn) if not _valid(key, p.name)]
        for key, fn in _functions()
        if key not in NOT_GENERATED
    }
    assert not {k: v for k, v in missing.items() if v}, missing


# --- bad values ------------------------------------------------------------------------------
def _spoiled(valid, draw) -> list[tuple[str, object]]:
    """`(kind, value)`: the spoiled versions of one valid argument value, their details (where
    the NaN sits, the text, the imaginary part, where the extra axis goes) drawn by hypothesis."""
    text = draw(st.text(min_size=1, max_size=8))
    if isinstance(valid, bool):
        return [("string", text), ("array", np.ones(2))]
    if isinstance(valid, int):
        fraction = draw(st.floats(0.01, 0.99))
        return [("fraction", valid + fraction), ("bool", True), ("string", str(valid)), ("nan", float("nan"))]
    imaginary = draw(st.floats(0.1, 10.0))
    if isinstance(valid, float):
        infinity = draw(st.sampled_from([np.inf, -np.inf]))
        return [("nan", np.nan), ("inf", infinity), ("complex", complex(valid, imaginary)), ("string", text)]
    if isinstance(valid, np.ndarray):
        nan, inf = valid.astype(float), valid.astype(float)
        nan.flat[draw(st.integers(0, valid.size - 1))] = np.nan
        inf.flat[draw(st.integers(0, valid.size - 1))] = draw(st.sampled_from([np.inf, -np.inf]))
        axis = draw(st.integers(0, valid.ndim))
        return [
            ("nan", nan),
            ("inf", inf),
            ("complex", valid + 1j * imaginary),
            ("string", text),
            ("object", valid.astype(object)),
            ("rank", np.expand_dims(valid, axis)),
        ]
    if isinstance(valid, str):
        return [("option", "no such " + text), ("number", 3)]
    if isinstance(valid, (list, tuple)):
        return [("string", text), ("number", 3.0)]
    return [("type", text), ("number", 3.0)]  # a bsjax object


ARGUMENTS = [(key, p.name) for key, fn in COVERED for p in _required(fn)]
FUNCTIONS = dict(COVERED)
VALUES = ("nan", "inf")  # bad values a compiled function sees only inside its program
# The value kinds compile each function's program once: `make test` draws this many arguments
# per run (a different draw each run); BSJAX_CONTRACT_VALUES=1000 runs them all (~40 s).
VALUE_EXAMPLES = int(os.environ.get("BSJAX_CONTRACT_VALUES", "15"))


# classes whose field values and shapes (not types) are checked where they are used
VALUES_AT_USE = {
    "bsjax.sculpt:": "a constraint's values are checked where it is solved (constraints[i].u: …)",
    "bsjax.mss:State": "a state's values are checked where it enters a step or a rollout",
}


def _wanted(key: str, name: str, kind: str) -> bool:
    """Whether the spoiled value of `kind` must be refused for this argument."""
    if kind == "rank" and (key, name) in ANY_SHAPE:
        return False
    if kind in (*VALUES, "rank") and key.startswith(tuple(VALUES_AT_USE)):
        return False
    return (key, name, kind) not in VALID_THERE


def _traced(key: str, name: str, how: str, bad):
    """The call with its array arguments traced (as in a caller's compiled code, where nothing
    is folded as a constant): inside the caller's `jax.jit`, or `jax.vmap` over the batch
    `[valid, bad]` of argument `name`; None when that argument is not an array, or the function
    cannot trace its arrays (a host-side function: files, recognition), where only the direct
    call applies; so for a constructor, whose traced fields are checked by the functions they
    enter (a module cannot replace its fields by their checked values in `__check_init__`)."""
    import jax

    fn = FUNCTIONS[key]
    values = {p.name: bad if p.name == name else _valid(key, p.name)() for p in _required(fn)}  # pyright: ignore[reportOptionalCall]
    valid = _valid(key, name)()  # pyright: ignore[reportOptionalCall]
    if inspect.isclass(fn) or not isinstance(valid, (np.ndarray, float)):
        return None
    arrays = {k: v for k, v in values.items() if isinstance(v, (np.ndarray, float))}

    def call(traced: dict):
        return _call(key, fn, "", None, {**values, **traced})

    try:
        jax.eval_shape(call, {**arrays, name: valid})
    except Exception:  # not traceable in these arguments
        return None
    if how == "jit":
        return lambda: jax.jit(call)(arrays)
    batch = {k: np.stack([np.asarray(v)] * 2) for k, v in arrays.items()}
    batch[name] = np.stack([np.asarray(valid, float), np.asarray(bad)])
    return lambda: jax.vmap(call)(batch)


def _refused(key: str, name: str, draw, kinds, how: str = "direct", valid=None) -> None:
    """Each spoiled value of the argument whose kind is in `kinds` raises `ValueError` or
    `TypeError` naming the argument (no result, no other exception); `how`: called directly,
    or traced in the caller's `jit` or `vmap` (`_traced`), where a value check's failure is a
    runtime error carrying the same message. `valid`: the value spoiled (default: `VALID`'s)."""
    import jax

    fn = FUNCTIONS[key]
    valid = _valid(key, name)() if valid is None else valid  # pyright: ignore[reportOptionalCall]
    for kind, bad in _spoiled(valid, draw):
        if kind not in kinds or not _wanted(key, name, kind):
            continue
        run = (how != "direct" and _traced(key, name, how, bad)) or (lambda: _call(key, fn, name, bad))
        try:
            out = run()
            jax.block_until_ready(out)
        except (ValueError, TypeError, jax.errors.JaxRuntimeError, eqx.EquinoxRuntimeError) as err:
            assert name in str(err), f"{key}({name}={kind}, {how}): {type(err).__name__}: {err}"
        else:
            raise AssertionError(f"{key}({name}={kind} {bad!r:.60}, {how}) returned {out!r:.80}")


STRUCTURE = ("fraction", "bool", "string", "complex", "object", "rank", "option", "number", "type", "array")


@pytest.mark.parametrize("key, name", ARGUMENTS, ids=[f"{k}-{n}" for k, n in ARGUMENTS])
@settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_badly_typed_or_shaped_argument_is_refused_by_name(key, name, data):
    """Every argument of every public function: wrong types, complex, strings, objects, an extra
    axis, fractional or boolean counts, unknown options (refused before anything compiles)."""
    _refused(key, name, data.draw, STRUCTURE)


# --- the valid calls ------------------------------------------------------------------------------
@settings(max_examples=VALUE_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(sorted(FUNCTIONS)))
def test_the_valid_call_of_a_public_function_runs(key):
    """The call a spoiled argument starts from is valid (a drawn sample of the functions per run:
    each compiles), so a refusal names a fault of the spoiled argument, not of the rest."""
    import jax

    jax.block_until_ready(_call(key, FUNCTIONS[key], "", None))


# --- optional arguments -------------------------------------------------------------------------


def _optional(fn) -> list[tuple[str, object]]:
    """`(name, default)` of the optional arguments whose default is a number, a bool or text."""
    params = inspect.signature(fn).parameters.values()
    return [
        (p.name, p.default)
        for p in params
        if p.default is not p.empty and type(p.default) in (float, int, bool, str)
    ]


def _option(fn, name: str) -> bool:
    """Whether argument `name` is declared as a set of options (`Literal[...]`): only then is an
    unknown text wrong; a plain `str` is free text (a name, a title, a label)."""
    return "Literal" in str(inspect.signature(fn).parameters[name].annotation)


OPTIONAL = [
    (key, name, default)
    for key, fn in COVERED
    if not key.startswith(tuple(VALUES_AT_USE))
    for name, default in _optional(fn)
]


@pytest.mark.parametrize("key, name, default", OPTIONAL, ids=[f"{k}-{n}" for k, n, _ in OPTIONAL])
@settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_badly_typed_optional_argument_is_refused_by_name(key, name, default, data):
    """Every optional number, flag or option of every public function: a wrong type, complex, a
    fraction or a flag for a count, an unknown option (`Literal`) — refused naming it."""
    kinds = [k for k in STRUCTURE if k != "option" or _option(FUNCTIONS[key], name)]
    _refused(key, name, data.draw, kinds, valid=default)


@settings(max_examples=VALUE_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(argument=st.sampled_from(ARGUMENTS), data=st.data())
def test_a_non_finite_argument_is_refused_by_name(argument, data):
    """NaN and ±inf at a drawn position of a drawn argument (a drawn sample of the arguments
    per run: each compiles its function's program), called directly, inside `jax.jit` or under
    `jax.vmap` (drawn too)."""
    _refused(*argument, data.draw, VALUES, data.draw(st.sampled_from(["direct", "jit", "vmap"])))
