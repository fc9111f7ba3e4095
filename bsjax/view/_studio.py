"""`Studio`: the modelling session behind `bsjax studio` — plain JSON commands in, scenes out
(the interaction of *Interactive shape modeling and dynamic deformation based on spline
sculpting*, PhD thesis, University of Trento, 2007: ch. 3 recognition, ch. 4 over-sketching,
ch. 5 drawing planes and surface construction, ch. 6 sculpting).

The page (`static/studio.html`, drawn by the view's renderer) sends every gesture as a command
over the view's WebSocket; `Studio.handle(command)` computes it in Python and returns the new
scene, so the page shows exactly what the library computes and a test can drive the session
without a browser. Commands (`{"cmd": NAME, …}`; an optional `seq` is echoed in the reply):

* `plane {point, normal}` — the drawing plane strokes are unprojected onto;
* `stroke {window, camera, times?}` — a stroke in normalised window coordinates (`[[x, y], …]`,
  (0, 0) lower-left) seen by `camera {eye, target, up?, fov, aspect}`: unprojected onto the
  plane (`sketch.unproject`, thesis §5.1.2, eqs. 5-1/5-2), recognised and regularised in the
  plane's coordinates (`sketch.recognise`, ch. 3); a new curve;
* `oversketch {curve, window, camera}` — the span of a curve under a new stroke replaced
  (`sketch.oversketch`, §4.2);
* `build {op, curves, vector?}` — a surface from curves (ids, in order): `revolve` (profile,
  axis line), `loft` (sections), `ruled`, `extrude` (curve [, height line]), `sweep` (profile,
  path), `coons` (bottom, top, left, right) through `bsjax.construct`, or `compose`: the
  composites of ch. 3 (`sketch.compose` over the session's decision tree);
* `adapt {curves, name, construction}` — a confirmed composite added to the tree (`sketch.adapt`);
* `drag {surface, u, v, target | window + camera, gesture?}` — the surface point at (u, v)
  moved to `target` (or to where the window point meets the plane through the point facing
  the camera) by the minimum-norm edit (`sculpt.prefactor` once per gesture, then
  `Factor.drag`: ch. 6); the drags of one `gesture` are one undo step;
* `target {surface, curve, lam}` — target-curve sculpting with stiffness λ (`sculpt.target_sculpt`);
* `drop {surface, seconds?}` — the surface as a jelly body (a shell, or a volume for a closed
  surface) falling onto a table for `seconds` (default 0.3 s); `press {surface, u, v, depth?,
  seconds?}` — lying on a table, pressed by a sphere above S(u, v) `depth` (default 0.05) of its
  size deep: the scene physics of `bsjax.mss` (`_studio_physics`), the deformed surface replaces
  the surface (one undo step);
* `delete {id}`, `clear`, `undo`, `redo`, `scene`;
* `save {name}` / `load {name}` — `.json`, `.3dm`, `.step`/`.stp` in the session's folder
  (`bsjax.io`; a bare file name: the page cannot reach outside that folder).

A reply is `{"type": "update", "seq", "scene", "result"}` or `{"type": "error", "seq", "error"}`,
the error naming the command and the field (`stroke.window: expected …`); no command raises.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from bsjax import io, sculpt, sketch
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.view import _studio_geometry as geo
from bsjax.view import _studio_physics as physics
from bsjax.view._scene import SurfaceMesh, _polyline
from bsjax.view._studio_geometry import BUILDS, DEFAULT_PLANE, Body, CommandError, DrawingPlane, Item

log = logging.getLogger("bsjax.view")

FORMATS = (".json", ".3dm", ".step", ".stp")
COMMANDS = ("plane", "stroke", "oversketch", "build", "adapt", "drag", "target", "drop", "press",
            "delete", "clear", "undo", "redo", "scene", "save", "load")  # fmt: skip
_UNDO = 100  # undo steps kept


class State(NamedTuple):
    """One undoable snapshot: the curves, the surfaces, the drawing plane, the decision tree and
    the next free id (everything immutable, so a snapshot is a reference)."""

    items: tuple[Item, ...]
    bodies: tuple[Body, ...]
    plane: DrawingPlane
    tree: sketch.DecisionTree
    next_id: int


@dataclasses.dataclass
class _Gesture:
    key: tuple
    factor: sculpt.Factor
    point: np.ndarray


class Studio:
    """An interactive modelling session (module docstring).

    **Arguments:** `folder`: where `save`/`load` read and write (default the working
    directory); `dtype`: the geometry's float type (`np.float64` needs `jax_enable_x64`);
    `samples`: the `(m, n)` grid a surface is drawn with.
    """

    def __init__(self, folder: str | os.PathLike = ".", dtype=np.float64, samples=(24, 24)):
        self.folder = Path(folder)
        self.dtype = np.dtype(dtype)
        self.samples = tuple(samples)
        self.state = State((), (), DEFAULT_PLANE, sketch.default_tree(), 1)
        self.undo_stack: list[State] = []
        self.redo_stack: list[State] = []
        self._gesture: _Gesture | None = None
        self._meshes: dict[int, tuple[BSplineSurface, dict]] = {}
        self._lock = threading.Lock()  # one command at a time, whichever page sent it

    # --- the entry -----------------------------------------------------------------------------
    def handle(self, message: Any) -> dict:
        """The reply to one command (a dict, JSON-able); never raises."""
        seq = message.get("seq") if isinstance(message, dict) else None
        try:
            name = _command(message)
            with self._lock:
                if name != "drag":
                    self._gesture = None
                result = getattr(self, "_" + name)(_Fields(name, message))
                scene = self.scene()
            return {"type": "update", "seq": seq, "command": name, "scene": scene, "result": result or {}}
        except (CommandError, ValueError, TypeError, OSError) as err:
            where = message.get("cmd") if isinstance(message, dict) else None
            return _error(seq, _one_line(err), where, isinstance(err, CommandError))
        except Exception as err:  # a bug must not take the page's server down: reported, logged
            log.exception("studio: %r failed", message)
            return _error(seq, f"internal error: {type(err).__name__}: {_one_line(err)}", None, False)

    def scene(self) -> dict:
        """The scene message: surfaces (sample grid, exact spline), curves, plane, history."""
        s = self.state
        return {
            "title": "bsjax studio",
            "surface": None,
            "surfaces": [self._surface_message(b) for b in s.bodies],
            "curves": [],
            "items": [self._item_message(i) for i in s.items],
            "plane": s.plane.message(),
            "history": {"undo": len(self.undo_stack), "redo": len(self.redo_stack)},
            "rules": [r.name for r in s.tree.rules],
            "tool_radius": 0.0,
            "replay": None,
        }

    # --- state ---------------------------------------------------------------------------------
    def _commit(self, state: State) -> None:
        self.undo_stack = [*self.undo_stack[-(_UNDO - 1) :], self.state]
        self.redo_stack = []
        self.state = state

    def _add_item(self, item: Item) -> None:
        s = self.state
        self._commit(s._replace(items=(*s.items, item), next_id=s.next_id + 1))

    def _add_body(self, op: str, surface: BSplineSurface, sources) -> int:
        s = self.state
        body = Body(s.next_id, op, surface, tuple(sources))
        self._commit(s._replace(bodies=(*s.bodies, body), next_id=s.next_id + 1))
        return body.id

    def _item(self, f: _Fields, key: str, value=None) -> Item:
        value = f.int(key) if value is None else value
        for item in self.state.items:
            if item.id == value:
                return item
        raise f.error(key, f"the id of a curve ({[i.id for i in self.state.items]})", value)

    def _body(self, f: _Fields, key: str) -> Body:
        value = f.int(key)
        for body in self.state.bodies:
            if body.id == value:
                return body
        raise f.error(key, f"the id of a surface ({[b.id for b in self.state.bodies]})", value)

    # --- commands ------------------------------------------------------------------------------
    def _plane(self, f: _Fields):
        point, normal = f.vector("point"), f.vector("normal")
        if not np.linalg.norm(normal) > 0:
            raise f.error("normal", "a nonzero vector", normal.tolist())
        self._commit(self.state._replace(plane=DrawingPlane.through(point, normal)))

    def _stroke(self, f: _Fields):
        points, times = self._unprojected(f)
        item = geo.drawn(self.state.next_id, points, times, self.state.plane)
        self._add_item(item)
        return {"id": item.id, "kind": item.kind, "score": getattr(item.recognised, "score", None)}

    def _oversketch(self, f: _Fields):
        item = self._item(f, "curve")
        if item.curve.weights is not None:
            raise f.error(
                "curve", "a polynomial curve (a line, polygon, spline)", f"a {item.kind} (rational)"
            )
        points, _ = self._unprojected(f, timed=False)
        new = geo.oversketched(item, points, self.state.plane)
        s = self.state
        self._commit(s._replace(items=tuple(new if i.id == item.id else i for i in s.items)))
        return {"id": item.id, "kind": new.kind}

    def _build(self, f: _Fields):
        op = f.choice("op", (*BUILDS, "compose"))
        ids = f.ints("curves")
        items = [self._item(f, f"curves[{k}]", v) for k, v in enumerate(ids)]
        if op == "compose":
            if len(items) < 2:
                raise f.error("curves", "at least 2 curve ids for a composite", len(items))
            name, surface = geo.compose(items, self.state.tree)
        else:
            build, low, high = BUILDS[op]
            if not low <= len(items) <= high:
                raise f.error("curves", f"{low} to {high} curve ids for {op}", len(items))
            options = {"vector": f.vector("vector") if "vector" in f.message else None}
            name, surface = op, build(items, options)
        return {"id": self._add_body(name, surface, ids), "op": name}

    def _adapt(self, f: _Fields):
        items = [self._item(f, f"curves[{k}]", v) for k, v in enumerate(f.ints("curves"))]
        if any(i.recognised is None for i in items):
            raise f.error("curves", "recognised strokes", [i.kind for i in items])
        name = f.text("name")
        construction = f.choice("construction", tuple(sketch.CONSTRUCTIONS))
        tree = sketch.adapt([i.recognised for i in items], name, construction, self.state.tree)
        self._commit(self.state._replace(tree=tree))
        return {"rules": [r.name for r in tree.rules]}

    def _drag(self, f: _Fields):
        body = self._body(f, "surface")
        u, v = f.unit("u"), f.unit("v")
        key = (body.id, u, v, f.message.get("gesture"))
        g = self._gesture
        fresh = g is None or g.key != key or key[-1] is None
        if fresh:  # the solve of this gesture, once (thesis §6.1); each event is one product
            at = np.asarray([u], self.dtype), np.asarray([v], self.dtype)
            point = np.asarray(body.surface.evaluate(*at)).reshape(3)
            g = _Gesture(key, sculpt.prefactor(body.surface, [sculpt.Position(u, point, v)]), point)
        assert g is not None
        if "target" in f.message:
            target = f.vector("target")
        else:
            window, cam = f.points("window", 1), self._camera(f)
            facing = DrawingPlane.through(g.point, np.asarray(cam.frame()[0]))
            target = geo.unproject(window, cam, facing)[0]
        surface = g.factor.drag([np.asarray(target, self.dtype)])
        if fresh:
            self._commit(self.state)  # the gesture is one undo step: the shape before it
            self._gesture = g
        s = self.state
        moved = dataclasses.replace(body, surface=surface)
        self.state = s._replace(bodies=tuple(moved if b.id == body.id else b for b in s.bodies))
        return {"id": body.id, "target": np.asarray(target).tolist(), "point": g.point.tolist()}

    def _target(self, f: _Fields):
        body, item = self._body(f, "surface"), self._item(f, "curve")
        lam = f.number("lam", 0.0, 1.0)
        result = sculpt.target_sculpt(body.surface, item.curve, lam)
        s = self.state
        moved = dataclasses.replace(body, surface=result.surface)
        self._commit(s._replace(bodies=tuple(moved if b.id == body.id else b for b in s.bodies)))
        return {"id": body.id, "status": int(result.status)}

    def _drop(self, f: _Fields):
        body = self._body(f, "surface")
        seconds = f.number("seconds", 1e-3, 5.0) if "seconds" in f.message else 0.3
        surface, steps = physics.dropped(body.surface, seconds)
        self._replace(body, surface)
        return {"id": body.id, "seconds": seconds, "steps": steps}

    def _press(self, f: _Fields):
        body = self._body(f, "surface")
        u, v = f.unit("u"), f.unit("v")
        depth = f.number("depth", 1e-4, 0.5) if "depth" in f.message else 0.05
        seconds = f.number("seconds", 1e-3, 5.0) if "seconds" in f.message else 0.3
        surface, steps = physics.pressed(body.surface, u, v, depth, seconds)
        self._replace(body, surface)
        return {"id": body.id, "seconds": seconds, "steps": steps}

    def _replace(self, body: Body, surface: BSplineSurface) -> None:
        """`body` with a new surface, one undo step."""
        s, moved = self.state, dataclasses.replace(body, surface=surface)
        self._commit(s._replace(bodies=tuple(moved if b.id == body.id else b for b in s.bodies)))

    def _delete(self, f: _Fields):
        value, s = f.int("id"), self.state
        items = tuple(i for i in s.items if i.id != value)
        bodies = tuple(b for b in s.bodies if b.id != value)
        if len(items) + len(bodies) == len(s.items) + len(s.bodies):
            raise f.error("id", "the id of a curve or surface", value)
        self._commit(s._replace(items=items, bodies=bodies))

    def _clear(self, f: _Fields):
        self._commit(self.state._replace(items=(), bodies=()))

    def _undo(self, f: _Fields):
        if not self.undo_stack:
            raise CommandError("undo: nothing to undo")
        self.redo_stack.append(self.state)
        self.state = self.undo_stack.pop()

    def _redo(self, f: _Fields):
        if not self.redo_stack:
            raise CommandError("redo: nothing to redo")
        self.undo_stack.append(self.state)
        self.state = self.redo_stack.pop()

    def _scene(self, f: _Fields):
        return None

    def _save(self, f: _Fields):
        path = self._path(f)
        s = self.state
        if not s.items and not s.bodies:
            raise f.error("name", "a session with a curve or surface to save", "an empty session")
        try:
            io.save([*(b.surface for b in s.bodies), *(i.curve for i in s.items)], path)
        except Exception as err:  # the writer's own refusal (OCCT's exceptions are not ValueErrors)
            raise f.error("name", "a file the writer accepts", f"{path.name!r}: {_one_line(err)}") from err
        return {"path": str(path)}

    def _load(self, f: _Fields):
        path = self._path(f)
        if not path.is_file():
            raise f.error("name", f"a file in {self.folder}", f"{path.name!r} (no such file)")
        s, next_id = self.state, self.state.next_id
        items, bodies = list(s.items), list(s.bodies)
        for obj in _flattened(io.load_all(path)):  # a polycurve: a list of its segments
            if isinstance(obj, BSplineSurface):
                bodies.append(Body(next_id, "loaded", obj))
            elif isinstance(obj, BSplineCurve):
                items.append(Item(next_id, "loaded", DEFAULT_PLANE.lift_curve(obj), s.plane))
            else:
                continue
            next_id += 1
        self._commit(s._replace(items=tuple(items), bodies=tuple(bodies), next_id=next_id))
        return {"ids": list(range(s.next_id, next_id))}

    # --- helpers -------------------------------------------------------------------------------
    def _camera(self, f: _Fields) -> sketch.Camera:
        data = f.message.get("camera")
        if not isinstance(data, dict):
            raise f.error("camera", "an object {eye, target, up, fov, aspect}", _kind(data))
        sub = _Fields(f"{f.command}.camera", data)
        for key in ("eye", "target") + (("up",) if "up" in data else ()):
            sub.vector(key)
        sub.number("fov", 1e-6, math.pi - 1e-6)
        sub.number("aspect", 1e-6, math.inf)
        return geo.camera(data, self.dtype)

    def _unprojected(self, f: _Fields, timed: bool = True):
        window = f.points("window", 3)
        times = None
        if timed and f.message.get("times") is not None:
            times = f.floats("times", len(window))
            if np.any(np.diff(times) <= 0):
                raise f.error("times", "strictly increasing time stamps", "a step <= 0")
        return geo.unproject(window, self._camera(f), self.state.plane), times

    def _path(self, f: _Fields) -> Path:
        name = f.text("name")
        if Path(name).name != name or name.startswith("."):
            raise f.error("name", "a bare file name (no folder)", repr(name))
        if Path(name).suffix.lower() not in FORMATS:
            raise f.error("name", f"a file name ending in one of {', '.join(FORMATS)}", repr(name))
        return self.folder / name

    def _surface_message(self, body: Body) -> dict:
        cached = self._meshes.get(body.id)
        if cached is None or cached[0] is not body.surface:
            mesh = SurfaceMesh(body.surface, *self.samples).message(body.surface.ctrl)
            self._meshes[body.id] = cached = (body.surface, mesh)
        return {"id": body.id, "op": body.op, "sources": list(body.sources), **cached[1],
                "spline": io.to_dict(body.surface)}  # fmt: skip

    def _item_message(self, item: Item) -> dict:
        rec = item.recognised
        outline = _polyline(item.curve) if rec is None else _flat(item.plane.lift(rec.outline))
        return {
            "id": item.id,
            "kind": item.kind,
            "score": None if rec is None else rec.score,
            "params": {} if rec is None else _jsonable(rec.params),
            "outline": outline,
            "stroke": None if item.stroke is None else _flat(item.stroke),
            "spline": io.to_dict(item.curve),
        }


# --- fields of a command -----------------------------------------------------------------------
class _Fields:
    """Typed access to a command's fields; every error names `command.field`."""

    def __init__(self, command: str, message: dict):
        self.command, self.message = command, message

    def error(self, key: str, expected: str, got) -> CommandError:
        return CommandError(f"{self.command}.{key}: expected {expected}, got {got}")

    def get(self, key: str):
        if key not in self.message:
            raise CommandError(f"{self.command}.{key}: missing")
        return self.message[key]

    def int(self, key: str) -> int:
        value = self.get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, "an integer id", _kind(value))
        return value

    def ints(self, key: str) -> list[int]:
        value = self.get(key)
        if not isinstance(value, list) or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in value
        ):
            raise self.error(key, "a list of integer ids", _kind(value))
        return value

    def number(self, key: str, low: float = -math.inf, high: float = math.inf) -> float:
        value = self.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
            raise self.error(key, f"a number in [{low}, {high}]", _kind(value))
        return float(value)

    def unit(self, key: str) -> float:
        return self.number(key, 0.0, 1.0)

    def text(self, key: str) -> str:
        value = self.get(key)
        if not isinstance(value, str) or not value:
            raise self.error(key, "a non-empty string", _kind(value))
        return value

    def choice(self, key: str, options: tuple[str, ...]) -> str:
        value = self.get(key)
        if value not in options:
            raise self.error(key, f"one of {', '.join(options)}", repr(value))
        return value

    def _array(self, key: str, expected: str) -> np.ndarray:
        value = self.get(key)
        try:
            if isinstance(value, (str, bytes, dict)) or value is None:
                raise TypeError
            out = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(key, expected, _kind(value)) from None
        if not np.all(np.isfinite(out)):
            raise self.error(key, f"{expected} (finite)", "NaN or inf")
        return out

    def vector(self, key: str) -> np.ndarray:
        out = self._array(key, "a list of 3 numbers [x, y, z]")
        if out.shape != (3,):
            raise self.error(key, "a list of 3 numbers [x, y, z]", f"shape {out.shape}")
        return out

    def points(self, key: str, minimum: int) -> np.ndarray:
        out = self._array(key, "a list of [x, y] window points")
        if out.ndim != 2 or out.shape[1] != 2 or out.shape[0] < minimum:
            raise self.error(key, f"a list of at least {minimum} [x, y] window points", f"shape {out.shape}")
        return out

    def floats(self, key: str, count: int) -> np.ndarray:
        out = self._array(key, f"a list of {count} numbers")
        if out.shape != (count,):
            raise self.error(key, f"a list of {count} numbers (one per window point)", f"shape {out.shape}")
        return out


def _command(message) -> str:
    if not isinstance(message, dict):
        raise CommandError(f"message: expected a JSON object {{'cmd': ...}}, got {_kind(message)}")
    if "cmd" not in message:
        raise CommandError("cmd: missing (one of " + ", ".join(COMMANDS) + ")")
    if message["cmd"] not in COMMANDS:
        raise CommandError(f"cmd: expected one of {', '.join(COMMANDS)}, got {message['cmd']!r}")
    return message["cmd"]


def _kind(value) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text[:40]}{'…' if len(text) > 40 else ''}"


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).strip().split("\n\n")[0].split())


def _error(seq, message: str, command, own: bool) -> dict:
    """The command's name before the message: `build.curves: …` for the session's own errors
    about a field (`curves: …`), `stroke: points: …` for a library function's argument."""
    if command in COMMANDS and not message.startswith(command):
        message = f"{command}{'.' if own else ': '}{message}"
    return {"type": "error", "seq": seq, "error": message}


def _flattened(objects):
    for obj in objects:
        yield from _flattened(obj) if isinstance(obj, (list, tuple)) else (obj,)


def _flat(points: np.ndarray) -> list:
    return np.round(np.asarray(points, np.float64), 6).reshape(-1).tolist()


def _jsonable(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        if isinstance(v, np.ndarray):
            out[k] = v.tolist()
        elif isinstance(v, (np.floating, np.integer, np.bool_)):
            out[k] = v.item()
        else:
            out[k] = v
    return out
