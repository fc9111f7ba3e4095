"""Surface and curve files: lossless JSON, Rhino `.3dm` (rhino3dm), and tessellated meshes (trimesh).

* `save(spline_or_list, path)` / `load(path)` / `load_all(path)` pick the format by extension:
  `.json` and `.3dm` keep the exact B-spline surfaces and curves (degrees, knots, control points,
  weights, periodicity); `.obj`, `.stl`, `.ply`, `.glb` write the tessellated sample grid of
  surfaces.
* `.3dm`: a periodic direction is written as Rhino writes a periodic NURBS — uniform unclamped
  knots with the first `degree` control columns repeated at the end — and read back as periodic,
  so the round trip is exact and Rhino shows a closed surface. Curves are `NurbsCurve`s of
  dimension 2 or 3 (control points stored homogeneous, `[w P, w]`, as for surfaces).
* From the shell: `bsjax convert IN OUT` (`bsjax.cli.convert`).

rhino3dm and trimesh are imported by the functions that use them, so `import bsjax.io` stays light.
"""

from __future__ import annotations

import json
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from bsjax import _checks, collide
from bsjax.basis import BSplineCurve, BSplineSurface, periodic_knots

__all__ = ["MESH_FORMATS", "from_dict", "load", "load_all", "save", "tessellate", "to_dict"]

MESH_FORMATS = (".obj", ".stl", ".ply", ".glb")
_FORMAT = "bsjax.surface"
_CURVE_FORMAT = "bsjax.curve"
_MIXED_FORMAT = "bsjax.splines"  # a list holding curves (a list of surfaces only: "bsjax.surfaces")
_KINDS = {"surface": BSplineSurface, "curve": BSplineCurve, None: (BSplineSurface, BSplineCurve)}


# --- JSON ---------------------------------------------------------------------------------
def _listed(x):
    return None if x is None else np.asarray(x).tolist()


def to_dict(spline: BSplineSurface | BSplineCurve) -> dict:
    """A JSON-ready dict holding every field of a surface or curve exactly (floats round-trip by repr)."""
    if isinstance(spline, BSplineCurve):
        return {
            "format": _CURVE_FORMAT,
            "version": 1,
            "dtype": str(spline.ctrl.dtype),
            "degree": spline.degree,
            "periodic": spline.periodic,
            "knots": _listed(spline.knots),
            "ctrl": _listed(spline.ctrl),
            "weights": _listed(spline.weights),
        }
    surface = spline
    return {
        "format": _FORMAT,
        "version": 1,
        "dtype": str(surface.ctrl.dtype),
        "degree_u": surface.degree_u,
        "degree_v": surface.degree_v,
        "periodic_u": surface.periodic_u,
        "periodic_v": surface.periodic_v,
        "knots_u": _listed(surface.knots_u),
        "knots_v": _listed(surface.knots_v),
        "ctrl": _listed(surface.ctrl),
        "weights": _listed(surface.weights),
    }


def from_dict(data: dict, source: str = "data") -> BSplineSurface | BSplineCurve:
    """Inverse of `to_dict`; errors name `source` and the field at fault."""
    if isinstance(data, dict) and data.get("format") == _CURVE_FORMAT:
        return _curve_from_dict(data, source)
    if not isinstance(data, dict) or data.get("format") != _FORMAT:
        _checks.fail(
            source,
            f"a JSON object with format {_FORMAT!r} or {_CURVE_FORMAT!r}",
            type(data).__name__ if not isinstance(data, dict) else data.get("format"),
        )
    return _spline_from_fields(data, source, BSplineSurface, _SURFACE_FIELDS)


# constructor arguments in order: (field, kind, required)
_SURFACE_FIELDS = (
    ("ctrl", "array", True),
    ("knots_u", "array", True),
    ("knots_v", "array", True),
    ("degree_u", "integer", True),
    ("degree_v", "integer", True),
    ("periodic_u", "boolean", False),
    ("periodic_v", "boolean", False),
    ("weights", "array", False),
)
_CURVE_FIELDS = (
    ("ctrl", "array", True),
    ("knots", "array", True),
    ("degree", "integer", True),
    ("periodic", "boolean", False),
    ("weights", "array", False),
)


def _curve_from_dict(data: dict, source: str) -> BSplineCurve:
    return _spline_from_fields(data, source, BSplineCurve, _CURVE_FIELDS)


def _spline_from_fields(data: dict, source: str, cls, fields):
    """`cls(*fields)` read through `_Fields`; errors name `source` and the field at fault."""
    required = [k for k, _, needed in fields if needed]
    missing = [k for k in required if k not in data]
    if missing:
        _checks.fail(source, f"the fields {', '.join(required)}", f"missing {missing}")
    field = _Fields(data, source)
    args = [getattr(field, kind)(key) for key, kind, _ in fields]
    try:
        return cls(*args)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{source}: {err}") from err


class _Fields:
    """Typed access to the fields of one JSON spline object; every error names the source and
    the field (a degree must be a JSON integer, a flag a JSON boolean, arrays nested lists of
    numbers, the dtype float32 or float64)."""

    def __init__(self, data: dict, source: str):
        self.data, self.source = data, source
        dtype = data.get("dtype", "float64")
        if dtype not in ("float32", "float64"):
            self.fail("dtype", "'float32' or 'float64'", repr(dtype))
        self.dtype = np.dtype(dtype)

    def fail(self, key: str, expected: str, got) -> None:
        _checks.fail(f"{self.source}: {key}", expected, got)

    def integer(self, key: str) -> int:
        value = self.data.get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, "an integer", repr(value))
        return value  # pyright: ignore[reportReturnType]

    def boolean(self, key: str) -> bool:
        value = self.data.get(key, False)
        if not isinstance(value, bool):
            self.fail(key, "true or false", repr(value))
        return value

    def array(self, key: str):
        value = self.data.get(key)
        if value is None:
            return None
        if not _numeric_lists(value):
            self.fail(key, "nested lists of numbers", _json_type(value))
        with np.errstate(over="ignore"):  # too large for the dtype → inf, refused as non-finite next
            try:
                out = np.asarray(value, dtype=np.float64).astype(self.dtype)
            except (OverflowError, ValueError) as err:  # an integer beyond float64, ragged lists
                self.fail(key, "a rectangular array of float64-representable numbers", str(err))
        if not np.isfinite(out).all():
            self.fail(key, f"finite {self.dtype} values", "NaN, inf or a value beyond the dtype's range")
        return out


def _numeric_lists(value) -> bool:
    if isinstance(value, list):
        return all(_numeric_lists(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _json_type(value) -> str:
    return {dict: "an object", str: "a string", bool: "a boolean", list: "a list holding other values"}.get(
        type(value), type(value).__name__
    )


# --- Rhino .3dm -----------------------------------------------------------------------------
def _to_rhino(surface: BSplineSurface):
    import rhino3dm

    ctrl = np.asarray(surface.ctrl, dtype=np.float64)
    w = np.ones(ctrl.shape[:2]) if surface.weights is None else np.asarray(surface.weights, dtype=np.float64)
    knots = []
    for axis, d in enumerate("uv"):
        degree, periodic = getattr(surface, f"degree_{d}"), getattr(surface, f"periodic_{d}")
        if periodic:  # wrap: n + p control points over the unclamped uniform knots
            wrap = np.arange(ctrl.shape[axis] + degree) % ctrl.shape[axis]
            ctrl, w = np.take(ctrl, wrap, axis=axis), np.take(w, wrap, axis=axis)
        knots.append(_rhino_knots(getattr(surface, f"knots_{d}"), degree, periodic, surface.shape[axis]))
    r, s = ctrl.shape[:2]
    srf = rhino3dm.NurbsSurface.Create(
        3, surface.weights is not None, surface.degree_u + 1, surface.degree_v + 1, r, s
    )
    for i, k in enumerate(knots[0]):
        srf.KnotsU[i] = float(k)
    for j, k in enumerate(knots[1]):
        srf.KnotsV[j] = float(k)
    for i in range(r):
        for j in range(s):
            x, y, z = ctrl[i, j] * w[i, j]
            srf.Points[i, j] = rhino3dm.Point4d(float(x), float(y), float(z), float(w[i, j]))
    return srf


def _rhino_knots(knots, degree: int, periodic: bool, n: int) -> np.ndarray:
    """Rhino's knots: ours (or the unclamped uniform ones of a periodic direction) without the
    two superfluous end knots."""
    full = np.asarray(periodic_knots(n, degree) if periodic else knots, dtype=np.float64)
    return full[1:-1]


def _curve_to_rhino(curve: BSplineCurve):
    import rhino3dm

    ctrl = np.asarray(curve.ctrl, dtype=np.float64)
    n, dim = ctrl.shape
    w = np.ones(n) if curve.weights is None else np.asarray(curve.weights, dtype=np.float64)
    if curve.periodic:  # n + p control points over the unclamped uniform knots, as Rhino's own
        wrap = np.arange(n + curve.degree) % n
        ctrl, w = ctrl[wrap], w[wrap]
    out = rhino3dm.NurbsCurve(dim, curve.weights is not None, curve.degree + 1, ctrl.shape[0])
    for i, k in enumerate(_rhino_knots(curve.knots, curve.degree, curve.periodic, n)):
        out.Knots[i] = float(k)
    hom = np.concatenate([ctrl * w[:, None], np.zeros((ctrl.shape[0], 3 - dim)), w[:, None]], axis=1)
    for i, (x, y, z, wi) in enumerate(hom):
        out.Points[i] = rhino3dm.Point4d(float(x), float(y), float(z), float(wi))
    return out


def _curve_from_rhino(crv, source: str) -> BSplineCurve:
    hom = np.array([_point4(crv.Points[i]) for i in range(len(crv.Points))])
    w = hom[:, 3]
    ctrl = hom[:, : crv.Dimension] / w[:, None]
    inner = np.array(list(crv.Knots), dtype=np.float64)
    ctrl, w, knots, periodic = _direction_from_rhino(ctrl, w, inner, crv.Order - 1, 0, source)
    weights = None if np.allclose(w, 1.0, rtol=0, atol=0) else w
    return BSplineCurve(ctrl, knots, crv.Order - 1, periodic, weights)


def _from_rhino(srf, source: str) -> BSplineSurface:
    r, s = srf.Points.CountU, srf.Points.CountV
    hom = np.array([[_point4(srf.Points[i, j]) for j in range(s)] for i in range(r)])
    w = hom[..., 3]
    ctrl = hom[..., :3] / w[..., None]
    knots, periodic = {}, {}
    degrees = {"u": srf.OrderU - 1, "v": srf.OrderV - 1}
    for axis, d in enumerate("uv"):
        inner = np.array(list(srf.KnotsU if d == "u" else srf.KnotsV), dtype=np.float64)
        ctrl, w, knots[d], periodic[d] = _direction_from_rhino(
            ctrl, w, inner, degrees[d], axis, f"{source} ({d})"
        )
    weights = None if np.allclose(w, 1.0, rtol=0, atol=0) else w
    return BSplineSurface(
        ctrl, knots["u"], knots["v"], degrees["u"], degrees["v"], periodic["u"], periodic["v"], weights
    )


def _direction_from_rhino(ctrl, w, inner, degree, axis, source):
    """Rhino's knots (no superfluous ends) → ours on [0, 1], detecting the periodic layout
    (`ctrl` and `w` hold the control points along `axis`: a surface net or a curve's points)."""
    clamped = np.all(inner[:degree] == inner[0]) and np.all(inner[-degree:] == inner[-1])
    if clamped:
        full = np.concatenate([[inner[0]], inner, [inner[-1]]])
        return ctrl, w, (full - full[0]) / (full[-1] - full[0]), False
    n = ctrl.shape[axis] - degree
    head, tail = np.take(ctrl, range(degree), axis=axis), np.take(ctrl, range(n, n + degree), axis=axis)
    uniform = np.allclose(np.diff(inner), np.diff(inner)[0], rtol=1e-9, atol=0)
    if not (uniform and n > degree and np.allclose(head, tail, rtol=0, atol=1e-12)):
        _checks.fail(
            source, "clamped knots, or a uniform periodic spline", f"unclamped knots {inner.tolist()}"
        )
    keep = range(n)
    return np.take(ctrl, keep, axis=axis), np.take(w, keep, axis=axis), None, True


def _point4(p):
    return (p.X, p.Y, p.Z, p.W)


def _save_3dm(splines, path: Path) -> None:
    import rhino3dm

    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Meters
    for spline in splines:
        if isinstance(spline, BSplineCurve):
            model.Objects.AddCurve(_curve_to_rhino(spline))
        else:
            model.Objects.AddSurface(_to_rhino(spline))
    if not model.Write(str(path), 7):
        raise OSError(f"{path}: rhino3dm could not write the file")


def _load_3dm(path: Path) -> list[BSplineSurface | BSplineCurve]:
    import rhino3dm

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    model = rhino3dm.File3dm.Read(str(path))
    if model is None:
        _checks.fail(str(path), "a readable Rhino .3dm file", "a file rhino3dm cannot parse")
    splines, skipped, untrimmed, reversed_faces = [], Counter(), 0, 0
    for index, obj in enumerate(model.Objects):
        geometry, source = obj.Geometry, f"{path} object {index}"
        if isinstance(geometry, rhino3dm.Curve):
            splines.append(_curve_from_rhino(geometry.ToNurbsCurve(), source))
        elif isinstance(geometry, rhino3dm.Brep):
            if not geometry.IsSurface:  # trimmed or several faces: the faces' underlying surfaces
                untrimmed += len(geometry.Faces)
            for face in (geometry.Faces[i] for i in range(len(geometry.Faces))):
                reversed_faces += bool(face.OrientationIsReversed)
                splines.append(_from_rhino(face.ToNurbsSurface(), source))
        elif isinstance(geometry, rhino3dm.Surface):
            splines.append(_from_rhino(geometry.ToNurbsSurface(), source))
        else:
            skipped[type(geometry).__name__] += 1
    _warn_dropped(path, skipped, untrimmed, reversed_faces)
    return splines


def _warn_dropped(path: Path, skipped: Counter, untrimmed: int, reversed_faces: int) -> None:
    """One warning listing what a `.3dm` file held that was not loaded as it is in the file."""
    notes = []
    if skipped:
        notes.append("not loaded: " + ", ".join(f"{n} {kind}" for kind, n in sorted(skipped.items())))
    if untrimmed:
        notes.append(f"{untrimmed} faces of trimmed or multi-face Breps loaded as their untrimmed surfaces")
    if reversed_faces:
        notes.append(f"{reversed_faces} Brep faces have reversed orientation (loaded with the surface's own)")
    if notes:
        warnings.warn(f"{path}: " + "; ".join(notes), stacklevel=4)


# --- meshes -------------------------------------------------------------------------------
def tessellate(surface: BSplineSurface, m: int = 82, n: int = 82):
    """Triangle mesh of the `m × n` sample grid as a `trimesh.Trimesh`: `collide.tessellate`'s
    triangulation (two triangles per cell, split along the shorter diagonal).

    Seams of periodic directions and collapsed pole rows are welded, so a closed surface gives
    a closed mesh.
    """
    import trimesh

    vertices, faces = collide.tessellate(surface.blending(m, n).points(surface.ctrl))  # the one triangulation
    points = np.asarray(vertices, dtype=np.float64)
    mesh = trimesh.Trimesh(points, np.asarray(faces), process=False)
    scale = max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-300)
    mesh.merge_vertices(digits_vertex=int(np.clip(-np.log10(scale * 1e-9), 0, 15)))
    mesh.update_faces(mesh.nondegenerate_faces())
    if mesh.is_watertight:
        mesh.fix_normals()
    return mesh


# --- dispatch -----------------------------------------------------------------------------
def save(surfaces, path, m: int = 82, n: int = 82) -> Path:
    """Write one surface or curve, or a list of them; the format follows the extension of `path`
    (meshes: surfaces only)."""
    path = Path(path)
    splines = (BSplineSurface, BSplineCurve)
    items = [surfaces] if isinstance(surfaces, splines) else list(surfaces)
    if not items or not all(isinstance(s, splines) for s in items):
        _checks.fail(
            "surfaces",
            "a BSplineSurface or BSplineCurve, or a non-empty list of them",
            type(surfaces).__name__,
        )
    ext = path.suffix.lower()
    if ext == ".json":
        path.write_text(json.dumps(_json_document(items)))
    elif ext == ".3dm":
        _save_3dm(items, path)
    elif ext in MESH_FORMATS:
        import trimesh

        if any(isinstance(s, BSplineCurve) for s in items):
            _checks.fail("surfaces", f"only surfaces for a mesh format ({ext})", "a BSplineCurve")
        meshes = [tessellate(s, m, n) for s in items]
        (meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)).export(str(path))
    else:
        _checks.fail("path", f"an extension in .json, .3dm, {', '.join(MESH_FORMATS)}", repr(path.suffix))
    return path


def _json_document(items) -> dict:
    if len(items) == 1:
        return to_dict(items[0])
    if all(isinstance(s, BSplineSurface) for s in items):
        return {"format": _FORMAT + "s", "surfaces": [to_dict(s) for s in items]}
    return {"format": _MIXED_FORMAT, "splines": [to_dict(s) for s in items]}


def load_all(path, kind: str | None = None) -> list[BSplineSurface | BSplineCurve]:
    """Every surface and curve in a `.json` or `.3dm` file, in file order; `kind="surface"` or
    `"curve"` keeps only those."""
    if kind not in _KINDS:
        _checks.fail("kind", "None, 'surface' or 'curve'", repr(kind))
    return [s for s in _read_all(Path(path)) if isinstance(s, _KINDS[kind])]


def _read_all(path: Path) -> list:
    ext = path.suffix.lower()
    if ext == ".3dm":
        return _load_3dm(path)
    if ext != ".json":
        _checks.fail("path", "a .json or .3dm file (meshes hold no B-spline)", repr(path.suffix))
    data = _read_json(path)
    for fmt, key, what in ((_FORMAT + "s", "surfaces", "surface"), (_MIXED_FORMAT, "splines", "item")):
        if isinstance(data, dict) and data.get("format") == fmt:
            items = data.get(key)
            if not isinstance(items, list):
                _checks.fail(f"{path}: {key}", "a list of spline objects", _json_type(items))
            return [from_dict(d, f"{path} {what} {k}") for k, d in enumerate(items)]  # pyright: ignore
    return [from_dict(data, str(path))]


def _read_json(path: Path):
    """The parsed JSON of `path`; every failure a `ValueError` (or the `OSError`) naming the file."""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from None
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply to be a bsjax file") from None
    except ValueError as err:  # e.g. an integer literal longer than Python's conversion limit
        raise ValueError(f"{path}: not a bsjax JSON file ({err})") from None


def load(path, kind: str | None = None) -> BSplineSurface | BSplineCurve:
    """The single surface or curve in a `.json` or `.3dm` file (use `load_all` for several);
    `kind="surface"` or `"curve"` looks only at those."""
    items = load_all(path, kind)
    what = {None: "surface or curve", "surface": "surface", "curve": "curve"}[kind]
    if len(items) != 1:
        _checks.fail(
            str(path), f"exactly one {what} (use bsjax.io.load_all for several)", f"{len(items)} items"
        )
    return items[0]
