"""Surface and curve files: JSON, `.3dm`, STEP/IGES, meshes — the dispatch by extension."""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path

import numpy as np

from bsjax import _checks, collide
from bsjax._declared import declared
from bsjax._optional import require
from bsjax.basis import BSplineCurve, BSplineSurface
from bsjax.io._cad import CadList, CadObject, Progress, Trim, check_units, counted, unit_scale

MESH_FORMATS = (".obj", ".stl", ".ply", ".glb")
_FORMAT = "bsjax.surface"
_CURVE_FORMAT = "bsjax.curve"
_MIXED_FORMAT = "bsjax.splines"  # a list holding curves (a list of surfaces only: "bsjax.surfaces")
_POLYCURVE_FORMAT = "bsjax.polycurve"  # {"segments": [curve objects]}
_KINDS = {"surface": BSplineSurface, "curve": BSplineCurve, None: (BSplineSurface, BSplineCurve)}


# --- JSON ---------------------------------------------------------------------------------
def _listed(x):
    return None if x is None else np.asarray(x).tolist()


@declared
def to_dict(spline: BSplineSurface | BSplineCurve) -> dict:
    """A JSON-ready dict holding every field of a surface or curve exactly (floats round-trip by repr)."""
    if not isinstance(spline, (BSplineSurface, BSplineCurve)):
        raise TypeError(f"spline: expected a BSplineSurface or BSplineCurve, got {type(spline).__name__}")
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


@declared
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


# --- meshes -------------------------------------------------------------------------------
@declared
def tessellate(surface: BSplineSurface, m: int = 82, n: int = 82, mask=None):
    """Triangle mesh of the `m × n` sample grid as a `trimesh.Trimesh`: `collide.grid_mesh`'s
    triangulation (two triangles per cell, split along the shorter diagonal).

    **Arguments:** `surface`; `m`, `n` (ints ≥ 2): the uniform sample grid; `mask (m, n)`:
    optional booleans on that grid (a trimmed face's `CadObject.sample_mask(surface.blending(m,
    n))`) — a triangle with any vertex where it is `False` is dropped, and so are the vertices
    no triangle uses. `None`: every triangle.

    Seams of periodic directions and collapsed pole rows are welded, so a closed surface gives
    a closed mesh. Needs the `mesh` extra (trimesh).
    """
    trimesh = require("trimesh", "mesh", "bsjax.io.tessellate")

    if not isinstance(surface, BSplineSurface):
        _checks.fail("surface", "a BSplineSurface", type(surface).__name__)
    m, n = _checks.check_count(m, "m", 2), _checks.check_count(n, "n", 2)
    vertices, faces = collide.grid_mesh(surface.blending(m, n).points(surface.ctrl))  # the one triangulation
    points, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces)
    if mask is not None:
        faces = faces[np.all(_grid_mask(mask, m, n).reshape(-1)[faces], axis=1)]
    mesh = trimesh.Trimesh(points, faces, process=False)
    if mask is not None:
        mesh.remove_unreferenced_vertices()
    scale = max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-300)
    mesh.merge_vertices(digits_vertex=int(np.clip(-np.log10(scale * 1e-9), 0, 15)))
    mesh.update_faces(mesh.nondegenerate_faces())
    if mask is None and len(mesh.faces) == 0:  # every triangle collapsed onto a pole or a seam
        _checks.fail("m, n", "a sample grid that leaves the surface at least one triangle", (m, n))
    if mesh.is_watertight:
        mesh.fix_normals()
    return mesh


def _trimmed_mesh(obj: CadObject, m: int, n: int):
    """`tessellate` of a face keeping only its triangles inside its trim."""
    surface = obj.surface
    return tessellate(surface, m, n, None if obj.trim is None else obj.sample_mask(surface.blending(m, n)))


def _grid_mask(mask, m: int, n: int) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise TypeError(f"mask: expected booleans of shape ({m}, {n}), got dtype {mask.dtype}")
    if mask.shape != (m, n):
        _checks.fail("mask", f"shape ({m}, {n}) (the sample grid)", f"shape {mask.shape}")
    return mask


# --- dispatch -----------------------------------------------------------------------------
_CAD = (".step", ".stp", ".iges", ".igs")
_SPLINE_FORMATS = (".json", ".3dm", *_CAD)
_ON_UNSUPPORTED = ("raise", "skip")


def _polycurve(item) -> bool:
    return isinstance(item, (list, tuple)) and bool(item) and all(isinstance(c, BSplineCurve) for c in item)


def _objects(items) -> list[CadObject]:
    """`save`'s items as `CadObject`s; an item that is itself a list of curves is a polycurve."""
    splines = (BSplineSurface, BSplineCurve)
    listed = [items] if isinstance(items, (*splines, CadObject)) else items
    listed = list(listed) if isinstance(listed, (list, tuple)) else []
    if not listed or not all(isinstance(s, (*splines, CadObject)) or _polycurve(s) for s in listed):
        _checks.fail(
            "surfaces",
            "a BSplineSurface, BSplineCurve or CadObject, or a non-empty list of them "
            "(a list of BSplineCurves in it: a polycurve)",
            type(items).__name__,
        )
    if isinstance(items, CadList) and len(items.objects) == len(items):
        listed = items.objects
    return [s if isinstance(s, CadObject) else CadObject(tuple(s) if _polycurve(s) else s) for s in listed]


@declared
def save(
    surfaces,
    path: str | os.PathLike,
    m: int = 82,
    n: int = 82,
    units: str | None = None,
    *,
    progress: Progress | None = None,
) -> Path:
    """Write one surface or curve, or a list of them; the format follows the extension of `path`.

    **Arguments:**
    - `surfaces`: a `BSplineSurface`, `BSplineCurve` or `CadObject`, a list of them, or what
      `load_all` returned (its `objects` — names, layers, domains, trims, orientation — and its
      `units` are written; to a `.3dm`, its `annotations` too). A list of `BSplineCurve`s inside
      the list is one polycurve (a `.3dm` `PolyCurve`, a STEP/IGES wire: its segments must meet
      end to start).
    - `path`: `.json`, `.3dm`, `.step`/`.stp`, `.iges`/`.igs` keep the splines exactly; `.obj`,
      `.stl`, `.ply`, `.glb` hold the tessellated `m × n` sample grid (surfaces only).
    - `units`: the unit system recorded in the file (a key of `bsjax.io.UNITS`); default the
      `CadList`'s own, else metres. The numbers are written unchanged (no conversion).
    - `progress`: an optional callback `progress(done, total)`, called after each of the `total`
      objects is converted (tessellated, for a mesh format) — what a large file's save spends its
      time on; the file is written after the last.
    """
    path = Path(path)
    objects = _objects(surfaces)
    check_units(units)
    _checks.check_progress(progress)
    units = units or getattr(surfaces, "units", None) or "m"
    ext = path.suffix.lower()
    if ext == ".json":
        path.write_text(json.dumps(_json_document(objects, units, progress)))
    elif ext == ".3dm":
        require("rhino3dm", "cad", f"writing {path.name!r}")
        from bsjax.io._rhino import save_3dm

        save_3dm(objects, path, units, getattr(surfaces, "annotations", ()), progress)
    elif ext in _CAD:
        require("OCP", "cad", f"writing {path.name!r}")
        from bsjax.io._occt import save_occt

        save_occt(objects, path, units, progress)
    elif ext in MESH_FORMATS:
        trimesh = require("trimesh", "mesh", f"writing {path.name!r}")

        if any(o.is_curve for o in objects):
            _checks.fail("surfaces", f"only surfaces for a mesh format ({ext})", "a BSplineCurve")
        meshes = [_trimmed_mesh(o, m, n) for o in counted(objects, progress)]
        (meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)).export(str(path))
    else:
        _checks.fail(
            "path", f"an extension in {', '.join(_SPLINE_FORMATS + MESH_FORMATS)}", repr(path.suffix)
        )
    return path


def _json_item(obj: CadObject) -> dict:
    if isinstance(obj.geometry, tuple):
        item = {"format": _POLYCURVE_FORMAT, "version": 1, "segments": [to_dict(c) for c in obj.geometry]}
    else:
        item = to_dict(obj.geometry)
    if obj.name or obj.layer:
        item.update(name=obj.name, layer=obj.layer)
    if obj.domain is not None:
        item["domain"] = [list(d) for d in obj.domain]
    if obj.reversed:
        item["reversed"] = True
    if obj.trim is not None:
        item["trim"] = obj.trim.to_dict()
    return item


def _json_document(objects: list[CadObject], units: str, progress: Progress | None = None) -> dict:
    items = [_json_item(o) for o in counted(objects, progress)]
    if len(items) == 1:
        return {**items[0], "units": units}
    if all(isinstance(o.geometry, BSplineSurface) for o in objects):
        return {"format": _FORMAT + "s", "units": units, "surfaces": items}
    return {"format": _MIXED_FORMAT, "units": units, "splines": items}


@declared
def load_all(
    path: str | os.PathLike,
    kind: str | None = None,
    *,
    units: str | None = None,
    on_unsupported: str = "raise",
    trims: bool = False,
) -> CadList:
    """Every surface and curve in a `.json`, `.3dm`, STEP or IGES file, in file order.

    **Arguments:**
    - `kind`: `"surface"` or `"curve"` keeps only those; `None` both.
    - `units`: `None` keeps the file's numbers; a unit name (`"mm"`, `"m"`, … keys of
      `bsjax.io.UNITS`) scales them into that unit (the file must have a unit system).
    - `on_unsupported`: `"raise"` (default) refuses a file holding objects bsjax cannot load
      (meshes, points, SubD, …) with a message listing them; `"skip"` loads the rest and warns
      with the same list. Annotations of a `.3dm` (text, text dots, dimensions, leaders) are
      not geometry: they are never refused, the geometry loads and a warning lists them.
    - `trims`: `False` returns the splines; `True` returns a `CadObject` per surface or curve
      (a Brep face with its `Trim` loops in [0, 1]² and its orientation flag `reversed`).

    A polycurve (a `.3dm` `PolyCurve`, a STEP/IGES wire) is one item: a list of `BSplineCurve`s,
    one per segment, in order (`kind="curve"` keeps it).

    **Returns:** a `CadList`: a `list` of the splines (or `CadObject`s with `trims=True`), with
    the attributes `units` (the file's unit system, or `units` when converted), `objects` (a
    `CadObject` per item: name, layer, domain, orientation, trim) and `held` (what the file held).
    """
    if kind not in _KINDS:
        _checks.fail("kind", "None, 'surface' or 'curve'", repr(kind))
    if on_unsupported not in _ON_UNSUPPORTED:
        _checks.fail("on_unsupported", "'raise' or 'skip'", repr(on_unsupported))
    if not isinstance(trims, bool):
        _checks.fail("trims", "True or False", repr(trims))
    check_units(units)
    read = _read_all(Path(path), units, on_unsupported, trims)
    objects = [o for o in read.objects if kind is None or (kind == "curve") == o.is_curve]
    items = objects if trims else [o.item for o in objects]
    return CadList(items, read.units, objects, read.held, read.annotations)


def _read_all(path: Path, units, on_unsupported: str, trims: bool) -> CadList:
    ext = path.suffix.lower()
    if ext == ".3dm":
        require("rhino3dm", "cad", f"reading {path.name!r}")
        from bsjax.io._rhino import load_3dm

        return load_3dm(path, units, on_unsupported, trims)
    if ext in _CAD:
        require("OCP", "cad", f"reading {path.name!r}")
        from bsjax.io._occt import load_occt

        return load_occt(path, units, on_unsupported, trims)
    if ext != ".json":
        _checks.fail(
            "path", f"a {', '.join(_SPLINE_FORMATS)} file (meshes hold no B-spline)", repr(path.suffix)
        )
    data = _read_json(path)
    file_units = data.get("units") if isinstance(data, dict) else None
    if file_units is not None:
        check_units(file_units, f"{path}: units")
    scale = unit_scale(file_units, units, str(path))
    items = [(data, str(path))]
    for fmt, key, what in ((_FORMAT + "s", "surfaces", "surface"), (_MIXED_FORMAT, "splines", "item")):
        if isinstance(data, dict) and data.get("format") == fmt:
            listed = data.get(key)
            if not isinstance(listed, list):
                _checks.fail(f"{path}: {key}", "a list of spline objects", _json_type(listed))
            items = [(d, f"{path} {what} {k}") for k, d in enumerate(listed)]  # pyright: ignore
    objects = [_json_object(d, source, scale) for d, source in items]
    held = Counter(
        "PolyCurve" if isinstance(o.geometry, tuple) else type(o.geometry).__name__ for o in objects
    )
    return CadList([o.item for o in objects], units or file_units, objects, held)


def _json_object(data, source: str, scale: float) -> CadObject:
    if isinstance(data, dict) and data.get("format") == _POLYCURVE_FORMAT:
        segments = data.get("segments")
        if not isinstance(segments, list) or not segments:
            _checks.fail(f"{source}: segments", "a non-empty list of curve objects", _json_type(segments))
        curves = [from_dict(d, f"{source} segment {k}") for k, d in enumerate(segments)]  # pyright: ignore
        if not all(isinstance(c, BSplineCurve) for c in curves):
            _checks.fail(f"{source}: segments", "curves only", "a surface")
        spline = tuple(c.with_ctrl(c.ctrl * scale) if scale != 1.0 else c for c in curves)
    else:
        spline = from_dict(data, source)
        if scale != 1.0:
            spline = spline.with_ctrl(spline.ctrl * scale)
    name, layer = data.get("name", ""), data.get("layer", "")
    domain = data.get("domain")
    trim = data.get("trim")
    try:
        domain = None if domain is None else tuple((float(a), float(b)) for a, b in domain)
        trim = None if trim is None else Trim.from_dict(trim)
        return CadObject(spline, str(name), str(layer), domain, bool(data.get("reversed", False)), trim)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{source}: domain or trim: expected the layout bsjax writes, got {err}") from None


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


@declared
def load(path: str | os.PathLike, kind: str | None = None, **options) -> BSplineSurface | BSplineCurve:
    """The single surface or curve in a file (use `load_all` for several); `kind="surface"` or
    `"curve"` looks only at those; `options` as for `load_all` (`units`, `on_unsupported`)."""
    items = load_all(path, kind, **options)
    what = {None: "surface or curve", "surface": "surface", "curve": "curve"}[kind]
    if len(items) != 1:
        _checks.fail(
            str(path),
            f"exactly one {what} (use bsjax.io.load_all for several)",
            f"{len(items)} items (the file holds {items.holding()})",
        )
    return items[0]
