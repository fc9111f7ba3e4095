"""What the view shows: scene and frame builders for a live session, a surface file or a recording.

The surface is drawn as its `m × n` sample grid, $S = A_u P A_v^T$ (the blending-matrix form of
a B-spline surface, The NURBS Book eq. 3.11), evaluated with numpy from the blending matrices
computed once, so a frame costs a few small matrix products and never a JAX dispatch.
"""

from __future__ import annotations

import os
import time

import numpy as np

from bsjax._declared import declared

_REPLAY_HZ = 100.0  # recordings are sent to the page at this rate (the slider's resolution)


class SurfaceMesh:
    """The `m × n` sample grid of a surface for any control net of its shape."""

    def __init__(self, surface, m: int = 32, n: int = 32):
        blending = surface.blending(m, n)
        self.shape = (m, n)
        self._a_u, self._a_v = np.asarray(blending.a_u[0]), np.asarray(blending.a_v[0])
        self._weights = None if blending.weights is None else np.asarray(blending.weights)
        self._blending = blending

    def points(self, ctrl) -> np.ndarray:
        """`(m, n, 3)` sample points for the control net `ctrl` `(r, s, 3)`."""
        ctrl = np.asarray(ctrl, dtype=np.float64)
        if self._weights is not None:
            return np.asarray(self._blending.points(ctrl), dtype=np.float64)
        r, s, _ = ctrl.shape
        rows = (self._a_u @ ctrl.reshape(r, s * 3)).reshape(-1, s, 3)  # A_u P: (m, s, 3)
        return self._a_v @ rows  # (A_u P) A_v^T per coordinate: (m, n, 3)

    def message(self, ctrl) -> dict:
        pts = np.round(self.points(ctrl), 5)
        return {"shape": list(self.shape), "points": pts.reshape(-1).tolist()}


@declared
def live(loop, model, title: str = "bsjax haptics"):
    """`(scene, frame)` callables for a running `ServoLoop` and its physics model."""
    surface0 = getattr(model, "surface0", None)
    mesh = SurfaceMesh(surface0) if surface0 is not None else None
    radius = float(
        getattr(model, "tool_radius", 0.0) or getattr(getattr(model, "tool", None), "radius", 0.25)
    )
    state = {"ticks": None, "at": 0.0}

    def surface():
        return None if mesh is None else mesh.message(model.ctrl)

    def scene() -> dict:
        return {"title": title, "surface": surface(), "tool_radius": radius, "replay": None}

    def frame() -> dict:
        snap = loop.snapshot()
        out = {
            "tool": snap["position"],
            "force": snap["force"],
            "gain": snap["gain"],
            "servo_hz": snap["rate_hz"],
            "ticks": snap["ticks"],
            "physics_updates": snap["physics_updates"],
            "max_force": loop.max_force,
            "mode": loop.mode,
            "t": time.perf_counter(),
        }
        ticks = getattr(model, "ticks", None)
        now = time.perf_counter()
        if mesh is not None and ticks != state["ticks"] and now - state["at"] >= 0.04:
            state["ticks"], state["at"] = ticks, now
            out["surface"] = surface()
        return out

    return scene, frame


@declared
def from_file(path: str | os.PathLike, tool_radius: float = 0.25):
    """The scene of a saved surface (`.json`, `.3dm`, …: every surface `bsjax.io.load_all`
    finds), or of a recorded session (`.npz`: the tool path, played with a time slider)."""
    path = os.fspath(path)
    title = os.path.basename(path)
    if path.endswith(".npz"):
        from bsjax.device import Recording

        rec = Recording.load(path)
        step = (
            max(1, int(round(len(rec) / max(1.0, (rec.time[-1] - rec.time[0]) * _REPLAY_HZ))))
            if len(rec) > 1
            else 1
        )
        t = rec.time[::step] - rec.time[0]
        replay = {
            "time": np.round(t, 4).tolist(),
            "position": np.round(rec.position[::step], 5).reshape(-1).tolist(),
            "force": np.round(rec.force[::step], 4).reshape(-1).tolist(),
        }
        scene = {"title": title, "surface": None, "tool_radius": tool_radius, "replay": replay}
    else:
        from bsjax import io

        objects = list(_geometry(io.load_all(path)))
        surfaces = [SurfaceMesh(g).message(g.ctrl) for kind, g in objects if kind == "surface"]
        curves = [_polyline(g) for kind, g in objects if kind == "curve"]
        if not surfaces and not curves:
            raise ValueError(f"{path}: no surface or curve to show")
        scene = {
            "title": title,
            "surface": surfaces[0] if surfaces else None,
            "surfaces": surfaces[1:],
            "curves": curves,
            "tool_radius": 0.0,
            "replay": None,
        }
    return (lambda: scene), None


def _geometry(objects):
    from bsjax.basis import BSplineCurve, BSplineSurface

    for item in objects if isinstance(objects, (list, tuple)) else [objects]:
        obj = getattr(item, "geometry", item)
        if isinstance(obj, BSplineSurface):
            yield "surface", obj
        elif isinstance(obj, BSplineCurve):
            yield "curve", obj


def _polyline(curve, samples: int = 96) -> list:
    """A curve as `samples` points (flat `[x0, y0, z0, x1, …]`; planar curves at z = 0)."""
    t = np.linspace(0.0, 1.0, samples)
    pts = np.asarray(curve.direction.matrix(t)) @ np.asarray(curve.ctrl, dtype=np.float64)
    if curve.weights is not None:
        w = np.asarray(curve.direction.matrix(t)) @ np.asarray(curve.weights, dtype=np.float64)
        pts = (
            np.asarray(curve.direction.matrix(t))
            @ (np.asarray(curve.ctrl) * np.asarray(curve.weights)[:, None])
        ) / w[:, None]
    if pts.shape[1] == 2:
        pts = np.concatenate([pts, np.zeros((len(t), 1))], axis=1)
    return np.round(pts, 5).reshape(-1).tolist()
