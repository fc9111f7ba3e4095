"""What a CAD file says about its splines beyond the geometry: units, names, layers, parameter
domains, trimming loops and face orientation.

* `CadObject(geometry, name, layer, domain, reversed, trim)`: one surface (a Brep face, a
  surface, an extrusion wall or cap, an expanded block member) or one curve, with what the file
  says about it. `geometry` is the `BSplineSurface` / `BSplineCurve` on bsjax's [0, 1]
  parametrisation; `domain` the file's own parameter interval per direction, so a save maps
  [0, 1] back onto it.
* `Trim`: a face's trimming loops as closed polylines in the surface's [0, 1]² parameter space
  (outer loops counter-clockwise, inner loops — holes — clockwise, as in "The NURBS Book" §12 and
  OpenNURBS), with a vectorised point-in-region test `mask(u, v)`.
* `CadList`: what `bsjax.io.load_all` returns — a plain `list` of the splines (so callers that
  iterate, index or `len` it see only surfaces and curves, as before), with the file's `units`,
  its `objects` (one `CadObject` per item, same order) and `held` (a count of every kind of object
  the file held, loaded or not).
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from typing import TypeVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax._declared import check_fields
from bsjax.basis import Blending, BSplineCurve, BSplineSurface

Progress = Callable[[int, int], object]
_Item = TypeVar("_Item")


def counted(items: Sequence[_Item], progress: Progress | None) -> Iterator[_Item]:
    """`items`, calling `progress(k, len(items))` once item k − 1 has been handled."""
    for k, item in enumerate(items, 1):
        yield item
        if progress is not None:
            progress(k, len(items))


# unit name → metres; the names `load_all(units=...)` accepts and `CadList.units` holds
UNITS = {
    "nm": 1e-9,
    "um": 1e-6,
    "mm": 1e-3,
    "cm": 1e-2,
    "dm": 1e-1,
    "m": 1.0,
    "km": 1e3,
    "in": 0.0254,
    "ft": 0.3048,
    "yd": 0.9144,
    "mi": 1609.344,
}


def check_units(units, name: str = "units") -> None:
    if units is not None and units not in UNITS:
        _checks.fail(name, f"None or one of {', '.join(UNITS)}", repr(units))


def unit_scale(source: str | None, target: str | None, what: str) -> float:
    """The factor that turns lengths in `source` units into `target` units (1 when no target)."""
    if target is None or source == target:
        return 1.0
    if source is None:
        _checks.fail("units", f"a file with a unit system to convert {what} from", "a file without units")
    return UNITS[source] / UNITS[target]  # pyright: ignore[reportArgumentType]


class Trim(eqx.Module):
    """A face's trimming loops in its surface's [0, 1]² parameter space.

    **Fields:**
    - `segments (S, 2, 2)`: every loop's polyline edges `(start, end)` in `(u, v)`, loop after loop.
    - `loop_sizes`: the number of edges of each loop (static).
    - `outer`: per loop, `True` for an outer boundary, `False` for a hole (static).
    - `closed`: per direction `(u, v)`, `True` when the surface is closed there (a cylinder's or
      a revolve's seam): its parameter space is then periodic with period 1 (static).

    `mask(u, v)` is the even–odd (crossing-number) rule over all edges at once, so a point inside
    an outer loop and outside every hole is kept, whatever the loops' orientation. On a closed
    direction a loop may come shifted by a period or cross the seam (a hole over the seam given
    as one loop running past 1 or below 0): the rule then counts the loops' translates by −1, 0
    and +1 period too, which is the even–odd rule on the cylinder (the translates of a loop that
    lies inside [0, 1] add an even count and change nothing).
    """

    segments: Float[Array, "S 2 2"]
    loop_sizes: tuple[int, ...] = eqx.field(static=True)
    outer: tuple[bool, ...] = eqx.field(static=True)
    closed: tuple[bool, bool] = eqx.field(static=True, default=(False, False))

    def __check_init__(self):
        check_fields(self)
        if np.ndim(self.segments) != 3 or np.shape(self.segments)[1:] != (2, 2):
            _checks.fail("segments", "loop edges of shape (S, 2, 2)", np.shape(self.segments))
        if _checks.is_concrete(self.segments) and not np.all(np.isfinite(self.segments)):
            _checks.fail("segments", "finite (u, v) values", "NaN or inf")

    @classmethod
    def from_loops(cls, loops, outer, closed=(False, False)) -> Trim:
        """From closed polylines `loops[i] (k_i, 2)` (the last point may repeat the first); on a
        `closed` direction each loop is shifted by a whole period so that its mean lies in [0, 1)."""
        closed = tuple(bool(c) for c in closed)
        if len(closed) != 2:
            _checks.fail("closed", "two flags (u, v)", closed)
        segments, sizes = [], []
        for k, loop in enumerate(loops):
            loop = np.asarray(loop, dtype=np.float64)
            _checks.check_ndim(loop, f"loops[{k}]", 2, last=2)
            if loop.shape[0] < 3:
                _checks.fail(f"loops[{k}]", "a closed polyline of shape (k >= 3, 2)", loop.shape)
            if np.array_equal(loop[0], loop[-1]):
                loop = loop[:-1]
            loop = loop - np.where(closed, np.floor(loop.mean(axis=0)), 0.0)
            segments.append(np.stack([loop, np.roll(loop, -1, axis=0)], axis=1))
            sizes.append(loop.shape[0])
        if not segments:
            _checks.fail("loops", "at least one loop", "none")
        segments = jnp.asarray(np.concatenate(segments))
        return cls(segments, tuple(sizes), tuple(bool(o) for o in outer), closed)  # pyright: ignore

    def loops(self) -> list[np.ndarray]:
        """Each loop as a closed polyline `(k + 1, 2)` (first point repeated at the end)."""
        segments = np.asarray(self.segments)
        ends = np.cumsum((0, *self.loop_sizes))
        return [np.vstack([segments[a:b, 0], segments[a, :1]]) for a, b in itertools.pairwise(ends)]

    def to_dict(self) -> dict:
        """`{"loops", "outer"[, "closed"]}`, JSON-ready (what `.json` files and bsjax's `.3dm`
        user string `bsjax.trim` hold)."""
        loops = {"loops": [loop.tolist() for loop in self.loops()], "outer": list(self.outer)}
        return {**loops, "closed": list(self.closed)} if any(self.closed) else loops

    @classmethod
    def from_dict(cls, data: dict) -> Trim:
        """Inverse of `to_dict`."""
        return cls.from_loops(data["loops"], data["outer"], data.get("closed", (False, False)))

    def window(self, name: str = "trim", tol: float = 1e-7) -> tuple[float, float, float, float]:
        """The trim as a parameter window `(u0, u1, v0, v1)`, for `bsjax.merge.merge(...,
        trim=...)` (which keeps rectangular windows only).

        **Arguments:** `name`: the argument's name in an error; `tol`: how far (in [0, 1]²) a
        loop point may lie off the window's sides (projected loops are not exact).

        **Returns:** the tightest window around the outer loop, when the trim is one outer loop
        whose every edge runs along one side of that window (an axis-aligned rectangle);
        otherwise a `ValueError` naming `name` and what the trim is.
        """
        segments = np.asarray(self.segments, dtype=np.float64)
        if len(self.loop_sizes) != 1 or not self.outer[0]:
            holes = sum(not o for o in self.outer)
            _checks.fail(
                name,
                "an axis-aligned rectangular trim (one outer loop, no hole) — merge keeps windows only",
                f"{len(self.loop_sizes)} loops ({holes} holes)",
            )
        lo, hi = segments.reshape(-1, 2).min(axis=0), segments.reshape(-1, 2).max(axis=0)
        sides = [
            np.abs(segments[..., axis] - bound) <= tol for axis in (0, 1) for bound in (lo[axis], hi[axis])
        ]
        along = np.any([side.all(axis=1) for side in sides], axis=0)  # both ends on one side
        if not along.all():
            _checks.fail(
                name,
                "an axis-aligned rectangular trim (one outer loop, no hole) — merge keeps windows only",
                f"a loop with {int((~along).sum())} of {along.size} edges off its bounding rectangle "
                f"[{lo[0]:.4g}, {hi[0]:.4g}] x [{lo[1]:.4g}, {hi[1]:.4g}]",
            )
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])

    @compiled
    def mask(self, u: Float[Array, "..."], v: Float[Array, "..."]) -> Bool[Array, "..."]:
        """`True` where `(u, v)` lies inside the trimmed face (even–odd rule; "Computational
        Geometry in C", O'Rourke, §7.4 crossing test; on a closed direction over the loops'
        translates by −1, 0, +1 period).

        **Arguments:** `u`, `v`: finite parameters of the same shape (outside [0, 1]: outside).
        **Returns:** a boolean array of that shape.
        """
        u, v = jnp.broadcast_arrays(jnp.asarray(u), jnp.asarray(v))
        u, v = _checks.finite(u, "u"), _checks.finite(v, "v")
        crossings = sum(_crossings(self.segments, u, v - b, self.closed[0]) for b in _shifts(self.closed[1]))
        inside = jnp.asarray(crossings % 2 == 1)
        if any(self.closed):  # loops may run past the seam: [0, 1]² bounds the face explicitly
            inside = inside & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        return inside


def _shifts(closed: bool) -> tuple[float, ...]:
    return (-1.0, 0.0, 1.0) if closed else (0.0,)


def _crossings(segments, u, v, wrap_u: bool):
    """How many edges a ray from `(u, v)` towards +u crosses (per point); with `wrap_u`, the
    edges' translates by −1, 0 and +1 in u too (one pass: the edge at `c + k` lies right of the
    point when `u − c < k`)."""
    lead = (1,) * u.ndim  # explicit broadcasting (rank promotion may be off)
    u0, v0, u1, v1 = (segments[:, i, j].reshape(*lead, -1) for i in (0, 1) for j in (0, 1))
    pu, pv = u[..., None], v[..., None]
    straddles = (v0 > pv) != (v1 > pv)
    dv = jnp.where(straddles, v1 - v0, 1.0)
    gap = pu - (u0 + (pv - v0) * (u1 - u0) / dv)
    right = sum((gap < k).astype(jnp.int32) for k in _shifts(wrap_u))  # how many translates
    return jnp.sum(jnp.where(straddles, right, 0), axis=-1)


def closed_directions(surface: BSplineSurface, rtol: float = 1e-9) -> tuple[bool, bool]:
    """Per direction, whether the surface closes on itself (periodic, or a clamped net whose
    first and last rows coincide, weights included): its trims wrap there."""
    ctrl = np.asarray(surface.ctrl, dtype=np.float64)
    w = np.ones(ctrl.shape[:2]) if surface.weights is None else np.asarray(surface.weights, dtype=np.float64)
    hom = np.concatenate([ctrl * w[..., None], w[..., None]], axis=-1)
    tol = rtol * max(1.0, float(np.abs(hom).max()))
    out = []
    for axis, periodic in enumerate((surface.periodic_u, surface.periodic_v)):
        first, last = np.take(hom, 0, axis=axis), np.take(hom, -1, axis=axis)
        out.append(bool(periodic) or bool(np.allclose(first, last, rtol=0, atol=tol)))
    return out[0], out[1]


class CadObject(eqx.Module):
    """One surface or curve of a CAD file with what the file says about it.

    **Fields:**
    - `geometry`: the `BSplineSurface` or `BSplineCurve`, parametrised over [0, 1]; or a
      polycurve (a Rhino `PolyCurve`, a STEP wire of several edges): a tuple of `BSplineCurve`s,
      one per segment, in order.
    - `name`, `layer`: the object's name and layer path ("" when the file has none).
    - `domain`: the file's parameter interval per direction, `((u0, u1), (v0, v1))` for a
      surface, `((t0, t1),)` for a curve, one `(t0, t1)` per segment of a polycurve; a save
      maps [0, 1] back onto it.
    - `reversed`: `True` when the face's normal is opposite to the surface's `S_u × S_v`
      (a Brep face with a reversed orientation flag).
    - `trim`: the face's `Trim`, or `None` for an untrimmed surface.
    """

    geometry: BSplineSurface | BSplineCurve | tuple[BSplineCurve, ...]
    name: str = eqx.field(static=True, default="")
    layer: str = eqx.field(static=True, default="")
    domain: tuple[tuple[float, float], ...] | None = eqx.field(static=True, default=None)
    reversed: bool = eqx.field(static=True, default=False)
    trim: Trim | None = None

    def __check_init__(self):
        g = self.geometry
        polycurve = isinstance(g, tuple) and g and all(isinstance(c, BSplineCurve) for c in g)
        if not polycurve and not isinstance(g, (BSplineSurface, BSplineCurve)):
            _checks.fail(
                "geometry",
                "a BSplineSurface, a BSplineCurve or a non-empty tuple of BSplineCurves (a polycurve)",
                type(g).__name__ if not isinstance(g, tuple) else f"a tuple of {len(g)} items",
            )
        check_fields(self)  # name, layer, reversed, trim: their declared kinds

    @property
    def item(self) -> BSplineSurface | BSplineCurve | list[BSplineCurve]:
        """What `load_all` lists for this object: the spline, or a polycurve's segments as a list."""
        return list(self.geometry) if isinstance(self.geometry, tuple) else self.geometry

    @property
    def is_curve(self) -> bool:
        """A curve or a polycurve."""
        return not isinstance(self.geometry, BSplineSurface)

    @property
    def surface(self) -> BSplineSurface:
        if not isinstance(self.geometry, BSplineSurface):
            _checks.fail("geometry", "a BSplineSurface", type(self.geometry).__name__)
        return self.geometry  # pyright: ignore[reportReturnType]

    def mask(self, u, v):
        """`Trim.mask`, or all `True` for an untrimmed object."""
        if self.trim is None:
            return jnp.ones(jnp.broadcast_shapes(jnp.shape(u), jnp.shape(v)), dtype=bool)
        return self.trim.mask(u, v)

    def window(self, name: str = "trim") -> tuple[float, float, float, float]:
        """`Trim.window` of the face's trim, `(0, 1, 0, 1)` for an untrimmed one: pass the
        `CadObject` itself as a patch's entry of `bsjax.merge.merge(..., trim=...)`."""
        return (0.0, 1.0, 0.0, 1.0) if self.trim is None else self.trim.window(name)

    @compiled
    def sample_mask(self, blending: Blending) -> Bool[Array, "m n"]:
        """The trim's mask on the sample grid of `blending` (a `Blending` of this surface, any
        grid or window): `True` where sample `(params_u[i], params_v[j])` lies on the trimmed
        face, all `True` for an untrimmed object. Pass it as `collide.contacts(...,
        sample_mask=...)` or `io.tessellate(..., mask=...)`.

        **Arguments:** `blending`: a `bsjax.basis.Blending` whose control net has this
        surface's shape. **Returns:** booleans `(m, n)`.
        """
        if not isinstance(blending, Blending):
            raise TypeError(f"blending: expected a bsjax.basis.Blending, got {type(blending).__name__}")
        if tuple(blending.ctrl_shape) != tuple(self.surface.ctrl.shape[:2]):
            _checks.fail(
                "blending",
                f"a blending of this surface (control net {tuple(self.surface.ctrl.shape[:2])})",
                f"control net {tuple(blending.ctrl_shape)}",
            )
        u, v = blending.params_u[:, None], blending.params_v[None, :]
        if self.trim is None:
            return jnp.ones((u.shape[0], v.shape[1]), dtype=bool)
        return self.trim.mask(u, v)


class CadList(list):
    """The splines `bsjax.io.load_all` read (a `list`), with the file's `units` (a key of
    `bsjax.io.UNITS` or `None`), `objects` (a `CadObject` per item), `held` (a `Counter` of
    every kind of object the file held) and `annotations` (a `.3dm`'s text, text dots,
    dimensions and leaders, as rhino3dm objects in `units`: not geometry bsjax computes with,
    written back by `bsjax.io.save` to a `.3dm`)."""

    def __init__(
        self, items=(), units: str | None = None, objects=(), held: Counter | None = None, annotations=()
    ):
        super().__init__(items)
        self.units, self.objects, self.held = units, list(objects), held or Counter()
        self.annotations = list(annotations)

    def holding(self) -> str:
        """'2 Brep faces, 1 Mesh' — what the file held, for error messages."""
        return ", ".join(f"{n} {kind}" for kind, n in sorted(self.held.items())) or "nothing"


def seam_moved(obj: CadObject, tol: float = 1e-9) -> CadObject:
    """The face `obj` with the seam of each closed direction moved to a parameter no trim loop
    crosses, so that every loop lies in [0, 1]² (what STEP, IGES and `.3dm` trims need).

    A closed direction whose loops all lie in [0, 1] already is left as it is. Otherwise the
    seam goes to the middle of the widest gap between the loops' extents on the circle (a loop
    that is an axis-aligned band around the whole period — an outer loop along the old seam —
    stays the band around the new one): the knot `s` is inserted to multiplicity `p` (Boehm's
    insertion, "The NURBS Book" §5.2, Eq. 5.15; the geometry is unchanged), the two pieces
    `[0, s]`, `[s, 1]` swap places (`u' = (u − s) mod 1`) and each loop moves by `−s` and a whole
    period into [0, 1]. When every seam position is crossed, `obj` comes back unchanged.

    **Arguments:** `obj`: a surface `CadObject`; `tol`: how far past [0, 1] a loop may reach.
    **Returns:** the `CadObject` (same name, layer, domain and orientation).
    """
    trim = obj.trim
    if trim is None or not any(trim.closed) or obj.is_curve:
        return obj
    surface, loops = obj.surface, trim.loops()
    for axis in (0, 1):
        if not trim.closed[axis]:
            continue
        ends = [(float(loop[:, axis].min()), float(loop[:, axis].max())) for loop in loops]
        if all(lo >= -tol and hi <= 1 + tol for lo, hi in ends):
            continue
        band = [_is_band(loop, axis, tol) for loop in loops]
        seam = _gap_middle([e for e, b in zip(ends, band) if not b], tol)
        if seam is None:
            return obj
        surface = _rotated(surface, axis, seam)
        loops = [loop if is_band else _shifted(loop, axis, seam) for loop, is_band in zip(loops, band)]
    if surface is obj.surface:
        return obj
    new_trim = Trim.from_loops(loops, trim.outer, trim.closed)
    return CadObject(surface, obj.name, obj.layer, obj.domain, obj.reversed, new_trim)


def _is_band(loop: np.ndarray, axis: int, tol: float) -> bool:
    """A loop that spans the whole period along `axis` with its every edge on an iso line."""
    x = loop[:, axis]
    if abs(x.min()) > tol or abs(x.max() - 1.0) > tol:
        return False
    d = np.diff(loop, axis=0)
    return bool(np.all((np.abs(d[:, 0]) <= tol) | (np.abs(d[:, 1]) <= tol)))


def _gap_middle(ends, tol: float) -> float | None:
    """The middle of the widest arc of the unit circle no interval `(lo, hi)` covers, or `None`."""
    if not ends:
        return 0.5
    if any(hi - lo >= 1 - tol for lo, hi in ends):
        return None
    arcs = sorted(((lo % 1.0), (lo % 1.0) + (hi - lo)) for lo, hi in ends)
    best = None
    reach = arcs[0][1]
    for a, b in arcs[1:]:
        if a > reach and (best is None or a - reach > best[1] - best[0]):
            best = (reach, a)
        reach = max(reach, b)
    wrap = (reach, arcs[0][0] + 1.0)  # the gap after the last arc, around to the first
    if wrap[1] > wrap[0] and (best is None or wrap[1] - wrap[0] > best[1] - best[0]):
        best = wrap
    if best is None or best[1] - best[0] <= 2 * tol:
        return None
    middle = 0.5 * (best[0] + best[1]) % 1.0
    return middle if tol < middle < 1 - tol else None


def _shifted(loop: np.ndarray, axis: int, seam: float) -> np.ndarray:
    out = loop.copy()
    out[:, axis] = out[:, axis] - seam
    out[:, axis] -= np.floor(out[:, axis].min())
    return out


def _rotated(surface: BSplineSurface, axis: int, seam: float) -> BSplineSurface:
    """`surface` re-parametrised along `axis` by `u' = (u − seam) mod 1` (clamped result)."""
    from bsjax.basis import periodic_knots
    from bsjax.io import _knots

    d = "uv"[axis]
    p = getattr(surface, f"degree_{d}")
    ctrl = np.asarray(surface.ctrl, dtype=np.float64)
    w = np.ones(ctrl.shape[:2]) if surface.weights is None else np.asarray(surface.weights, dtype=np.float64)
    hom = np.moveaxis(np.concatenate([ctrl * w[..., None], w[..., None]], axis=-1), axis, 0)
    if getattr(surface, f"periodic_{d}"):
        n = hom.shape[0]
        hom = hom[np.arange(n + p) % n]
        hom, knots, _ = _knots.clamp(hom, np.asarray(periodic_knots(n, p), dtype=np.float64), p)
    else:
        knots = np.asarray(getattr(surface, f"knots_{d}"), dtype=np.float64)
    while np.sum(knots == seam) < p:
        hom, knots = _knots._insert(hom, knots, p, seam)
    n = hom.shape[0]
    j = int(np.flatnonzero(knots == seam)[0])  # P[j - 1] is the surface at the seam
    hom = np.concatenate([hom[j - 1 :], hom[1:j]])
    knots = np.concatenate(
        [
            np.zeros(p + 1),
            knots[j + p : n] - seam,
            np.full(p, 1.0 - seam),
            knots[p + 1 : j] + 1.0 - seam,
            np.ones(p + 1),
        ]
    )
    hom = np.moveaxis(hom, 0, axis)
    ctrl, weights = hom[..., :3] / hom[..., 3:], hom[..., 3]
    other = "vu"[axis]
    k = {
        d: knots,
        other: None if getattr(surface, f"periodic_{other}") else getattr(surface, f"knots_{other}"),
    }
    return BSplineSurface(
        ctrl,
        k["u"],
        k["v"],
        surface.degree_u,
        surface.degree_v,
        False if axis == 0 else surface.periodic_u,
        False if axis == 1 else surface.periodic_v,
        None if surface.weights is None else weights,
    )
