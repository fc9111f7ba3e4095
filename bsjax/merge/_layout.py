"""The merge itself (thesis §4.3–4.4): discretise each patch with its blending matrices, stack the
point grids, and refit one control net with the revised blending matrices (eq. 3.7).

Everything that depends only on the layout — orientations, common degrees, knot vectors, sample
parameters, the per-patch blending matrices and the merged surface's pseudo-inverses — is decided
once by `plan`/`plan_grid` into a `MergeLayout`. `MergeLayout.apply` is then two small matrix
products per patch plus one refit: compiled, jittable, and differentiable in the input nets.

The plan is host-side work (knot vectors decide array sizes), so it is **cached** by its static
key (`_cache.py`): the bases of the patches (degrees, periodicity, the knot vectors' and weights'
values), the resolved orientations, sample counts, trims and options. A repeated `plan` or
`merge` with the same bases reuses the layout — its blending matrices and pseudo-inverses — and
only the compiled `apply` runs. What depends on control-point values is never cached under a key
of bases alone: `orient="auto"` is decided from the nets' edges at every call (one compiled
evaluation of the edges) and becomes part of the key; `overlap="drop"` keys its trims by the
nets' values too; `degrees="reduce"` recomputes `reduction_error` at every call.
`bsjax.merge.clear_cache()` (and `bsjax._boundary.clear_caches()`) empties the cache.
"""

from __future__ import annotations

import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _boundary, _checks
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax.basis import Blending, BSplineSurface, SplineDirection, reduce_degree
from bsjax.merge import _knots, _nonlinear, _orient, _overlap

DEGREE_POLICIES = (None, "elevate", "reduce")


class MergeLayout(eqx.Module):
    """Pre-computed merge of an `R × C` arrangement of patches (thesis §4.3.4).

    **Fields:**
    - `patches`: `R` rows of `C` `Blending`s, one per (oriented, possibly trimmed) input patch.
    - `merged`: the merged surface's `Blending` at the stacked sample parameters, holding the
      refit factors `A_u^+`, `A_v^+` (computed once).
    - `orientations` (static): per patch `(transpose, flip_u, flip_v)` applied to its control net.
    - `flat` (static): the layout came from a row (`plan`), so `apply` takes a flat list.
    - `reduction_error (R, C)`: per patch, the largest distance between the patch as planned
      and its least-squares reduction to the merged degrees (`bsjax.basis.reduce_degree`) over
      its merge samples; 0 where no degree was lowered (`degrees="reduce"`, §4.4.2). The merge
      fits the original samples directly, so this is the loss the lower degree alone implies.
    """

    patches: tuple[tuple[Blending, ...], ...]
    merged: Blending
    reduction_error: Float[Array, "R C"]
    orientations: tuple[tuple[_orient.Orientation, ...], ...] = eqx.field(static=True)
    flat: bool = eqx.field(static=True)

    @property
    def grid_shape(self) -> tuple[int, int]:
        """Patch arrangement `(R, C)`."""
        return len(self.patches), len(self.patches[0])

    def _rows(self, ctrls):
        if not isinstance(ctrls, (list, tuple)):
            _checks.fail("ctrls", "a list of control nets (rows of them for a grid)", type(ctrls).__name__)
        ctrls = list(ctrls)
        rows = (
            [ctrls]
            if self.flat and len(self.patches) == 1
            else ([[c] for c in ctrls] if self.flat else ctrls)
        )
        R, C = self.grid_shape
        if len(rows) != R or any(len(row) != C for row in rows):
            _checks.fail(
                "ctrls", f"{R * C} control nets arranged as the layout {R}×{C}", [len(row) for row in rows]
            )
        return rows

    @compiled
    def points(self, ctrls) -> Float[Array, "m n 3"]:
        """Combined sample grid `M = [M_11 M_12 …; M_21 …]`, `M_ij = A_u^ij P^ij A_v^ijT` (§4.3.1).

        `ctrls`: the input control nets as given to `plan` (a list) or `plan_grid` (rows), each
        `(r_ij, s_ij, 3)` and finite. Compiled once per layout shape.
        """
        rows = self._rows(ctrls)
        blocks = []
        for i, (brow, crow, orow) in enumerate(zip(self.patches, rows, self.orientations)):
            grids = []
            for j, (b, c, op) in enumerate(zip(brow, crow, orow)):
                name = f"ctrls[{i * len(brow) + j}]" if self.flat else f"ctrls[{i}][{j}]"
                c = jnp.asarray(c)
                _checks.check_real(c, name)
                expected = b.ctrl_shape[::-1] if op[0] else b.ctrl_shape
                if c.shape != (*expected, 3):
                    _checks.fail(name, f"shape {(*expected, 3)}", c.shape)
                c = _checks.finite(c, name)
                grids.append(b.points(_orient.orient_ctrl(c, op)))
            blocks.append(jnp.concatenate(grids, axis=1))
        return jnp.concatenate(blocks, axis=0)

    @compiled
    def apply(self, ctrls) -> Float[Array, "r s 3"]:
        """Merged control net `P = A_u^+ M (A_v^+)^T` (thesis eq. 3.7) with the stored factors.

        `ctrls` as for `points`. Compiled once per layout shape (a direct call is one XLA call).
        """
        return self.merged.refit(self.points(ctrls))

    @compiled
    def surface(self, ctrl: Float[Array, "r s 3"]) -> BSplineSurface:
        """The merged `BSplineSurface` with control net `ctrl` (e.g. from `apply`)."""
        return self.merged.surface(ctrl)


# --- degrees -------------------------------------------------------------------------------
def changed_degree_knots(knots, degree: int, target: int) -> np.ndarray:
    """Knot vector after a degree change, by the rules of `bsjax.basis.elevate_degree` (every
    distinct knot gains `target − degree` in multiplicity: exact) and `reduce_degree` (end
    multiplicities drop, interior ones are capped at the new degree: least squares)."""
    values, counts = np.unique(np.asarray(knots, np.float64), return_counts=True)
    if target >= degree:
        return np.repeat(values, counts + (target - degree))
    counts = np.minimum(counts, target)
    counts[0] = counts[-1] = target + 1
    return np.repeat(values, counts)


def _direction_knots(surface, direction: str, target: int):
    degree = getattr(surface, f"degree_{direction}")
    return changed_degree_knots(getattr(surface, f"knots_{direction}"), degree, target)


def common_degree(surfaces: Sequence[BSplineSurface], degrees=None):
    """Common degrees `(k, l)` of `surfaces` and each patch's knot vectors at those degrees.

    `degrees=None` requires equal degrees; `"elevate"` raises every patch to the largest degree
    (exact, `bsjax.basis.elevate_degree`), `"reduce"` lowers to the smallest (least squares,
    `bsjax.basis.reduce_degree`) — thesis §4.4.2: "the algorithm just needs to change the knot
    vector and the number of control points". Only the knot vectors change: the patches are still
    sampled with their own bases, so the merge fit sees the exact original geometry (the loss of
    a reduction shows up in the deviation report, not twice).

    **Returns:** `(k, l, knots_u list, knots_v list)`.
    """
    if degrees not in DEGREE_POLICIES:
        _checks.fail("degrees", f"one of {DEGREE_POLICIES}", repr(degrees))
    du = [s.degree_u for s in surfaces]
    dv = [s.degree_v for s in surfaces]
    if degrees is None and (len(set(du)) > 1 or len(set(dv)) > 1):
        _checks.fail(
            "degrees",
            "'elevate' or 'reduce' for patches of different degrees",
            f"None with degrees {list(zip(du, dv))}",
        )
    pick = min if degrees == "reduce" else max
    k, l = pick(du), pick(dv)
    out_u = [_direction_knots(s, "u", k) for s in surfaces]
    out_v = [_direction_knots(s, "v", l) for s in surfaces]
    return k, l, out_u, out_v


def reduction_error(surface: BSplineSurface, blending: Blending, k: int, l: int) -> Float[Array, ""]:
    """Largest distance, over `blending`'s sample grid, between `surface` and its least-squares
    reduction to degrees `(k, l)` (`bsjax.basis.reduce_degree`); 0 when no degree drops."""
    reduced = surface
    for direction, target in (("u", k), ("v", l)):
        times = getattr(surface, f"degree_{direction}") - target
        if times > 0:
            reduced, _ = reduce_degree(reduced, direction, times)
    if reduced is surface:
        return jnp.zeros((), surface.ctrl.dtype)
    approx = reduced.blending(params_u=blending.params_u, params_v=blending.params_v).points(reduced.ctrl)
    return jnp.max(jnp.linalg.norm(blending.points(surface.ctrl) - approx, axis=-1))


# --- plan ------------------------------------------------------------------------------------
def _check_patch(s, name):
    if not isinstance(s, BSplineSurface):
        raise TypeError(f"{name}: expected a BSplineSurface, got {type(s).__name__}")
    if s.periodic_u or s.periodic_v:
        _checks.fail(
            name,
            "an open (clamped) patch; periodic patches have no free edge to merge",
            f"periodic_u={s.periodic_u}, periodic_v={s.periodic_v}",
        )


def _samples(samples) -> tuple[int, int]:
    m, n = (samples, samples) if np.ndim(samples) == 0 else tuple(samples)
    for name, x in (("samples (u)", m), ("samples (v)", n)):
        if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < 2:
            _checks.fail(name, "an int >= 2", x)
    return int(m), int(n)


def _continuity_pair(continuity):
    if isinstance(continuity, (tuple, list)):
        if len(continuity) != 2:
            _checks.fail("continuity", "one int or a pair (c_u, c_v)", continuity)
        return continuity[0], continuity[1]
    return continuity, continuity


def _merged_direction(knots_by_line, degree, continuity):
    """Merged knots along a direction with several patches: merge each line of patches, then
    average the lines (equal counts) or keep the line with most control points (thesis §4.4.3)."""
    lines = [_knots.combine_knots(ts, degree, continuity) for ts in knots_by_line]
    if len({len(t) for t in lines}) == 1:
        return np.mean(np.stack(lines), axis=0)
    return max(lines, key=len)


def _window(t, name, direction):
    """One patch's `(u0, u1, v0, v1)` from `None`, `(lo, hi)` along `direction`, a full window, or
    a face whose trim is a rectangle (a `bsjax.io.CadObject` or `Trim`: anything with a
    `window(name)` method, duck-typed so that merge does not import io)."""
    if t is None:
        return (0.0, 1.0, 0.0, 1.0)
    if callable(getattr(t, "window", None)):
        return _window(t.window(name), name, None)
    t = tuple(float(x) for x in t)
    if direction is not None and len(t) == 2:
        t = t + (0.0, 1.0) if direction == "u" else (0.0, 1.0) + t
    expected = "(lo, hi) with 0 <= lo < hi <= 1" if direction else "(u0, u1, v0, v1) with 0 <= lo < hi <= 1"
    if len(t) != 4 or not (0.0 <= t[0] < t[1] <= 1.0 and 0.0 <= t[2] < t[3] <= 1.0):
        _checks.fail(name, expected, t)
    return t


def _windows(trim, grid, direction):
    """Per-patch parameter windows `(u0, u1, v0, v1)`. For a row (`direction` "u"/"v") `trim` has
    one entry per patch, `None` or `(lo, hi)` along `direction`; for a grid (`direction=None`)
    it has the grid's rows of `None` or `(u0, u1, v0, v1)`, the same u-window along each row of
    patches and the same v-window down each column (the combined grid stays rectangular)."""
    R, C = len(grid), len(grid[0])
    if trim is None:
        return [[(0.0, 1.0, 0.0, 1.0)] * C for _ in range(R)]
    if direction is not None:
        if len(trim) != R * C:
            _checks.fail("trim", f"{R * C} entries (None or (lo, hi)), one per patch", len(trim))
        flat = [_window(t, f"trim[{i}]", direction) for i, t in enumerate(trim)]
        return [flat[r * C : (r + 1) * C] for r in range(R)]
    if len(trim) != R or any(len(row) != C for row in trim):
        _checks.fail(
            "trim", f"{R} rows of {C} entries (None or (u0, u1, v0, v1))", [len(row) for row in trim]
        )
    win = [[_window(t, f"trim[{r}][{c}]", None) for c, t in enumerate(row)] for r, row in enumerate(trim)]
    for r in range(R):
        for c in range(C):
            if win[r][c][:2] != win[r][0][:2] or win[r][c][2:] != win[0][c][2:]:
                _checks.fail(
                    "trim",
                    "the same u-window along each row of patches and the same v-window down each column",
                    f"patch ({r}, {c}): {win[r][c]}",
                )
    return win


def _affine(p, lo, hi, a, b):
    return a + (b - a) * (p - lo) / (hi - lo)


@declared
def merged_knots(
    oriented: Sequence[Sequence[BSplineSurface]], continuity=2, *, cross="average", degrees=None, windows=None
):
    """Degrees and knot vectors of the merged surface of an `R × C` grid of oriented patches
    (thesis §4.3.3, §4.4.2, §4.4.3) — the merged basis, without building any matrix.

    **Returns:** `(k, l, knots_u, knots_v)` (float64 knot vectors).
    """
    _knots.check_cross(cross, "cross")
    R, C = len(oriented), len(oriented[0])
    o_flat = [s for row in oriented for s in row]
    k, l, ku, kv = common_degree(o_flat, degrees)
    cu, cv = _continuity_pair(continuity)
    win = [w for row in windows for w in row] if windows else [(0.0, 1.0, 0.0, 1.0)] * len(o_flat)
    ku = [_knots.window_knots(t, k, w[0], w[1]) for t, w in zip(ku, win)]
    kv = [_knots.window_knots(t, l, w[2], w[3]) for t, w in zip(kv, win)]
    ku_grid = [ku[r * C : (r + 1) * C] for r in range(R)]
    kv_grid = [kv[r * C : (r + 1) * C] for r in range(R)]
    if R > 1:
        knots_u = _merged_direction([[ku_grid[r][c] for r in range(R)] for c in range(C)], k, cu)
    else:
        knots_u = _knots.cross_knots(ku_grid[0], k, max(len(t) for t in ku) - k - 1, cross)
    if C > 1:
        knots_v = _merged_direction(kv_grid, l, cv)
    else:
        knots_v = _knots.cross_knots([row[0] for row in kv_grid], l, max(len(t) for t in kv) - l - 1, cross)
    return k, l, knots_u, knots_v


def build_layout(
    grid,
    continuity=2,
    *,
    samples=82,
    cross="average",
    degrees=None,
    orientations=None,
    trim=None,
    direction="u",
    flat=False,
) -> MergeLayout:
    """Plan the merge of an `R × C` grid of patches (not cached; see `plan`). The layout's
    `reduction_error` is zero here: it depends on the control nets (`plan` fills it in)."""
    R, C = len(grid), len(grid[0])
    ops = orientations or [[_orient.IDENTITY] * C for _ in range(R)]
    oriented = [[_orient.orient_surface(s, op) for s, op in zip(row, orow)] for row, orow in zip(grid, ops)]
    o_flat = [s for row in oriented for s in row]
    m, n = _samples(samples)
    win = _windows(trim, grid, direction)
    k, l, knots_u, knots_v = merged_knots(oriented, continuity, cross=cross, degrees=degrees, windows=win)

    dtype = o_flat[0].ctrl.dtype
    blends = [[s.blending(m, n) for s in row] for row in oriented]
    blends = [
        [b.window(*w) if w != (0.0, 1.0, 0.0, 1.0) else b for b, w in zip(brow, wrow)]
        for brow, wrow in zip(blends, win)
    ]
    bu, bv = np.linspace(0.0, 1.0, R + 1), np.linspace(0.0, 1.0, C + 1)
    pu = np.concatenate(
        [
            _affine(np.asarray(blends[r][0].params_u), win[r][0][0], win[r][0][1], bu[r], bu[r + 1])
            for r in range(R)
        ]
    )
    pv = np.concatenate(
        [
            _affine(np.asarray(blends[0][c].params_v), win[0][c][2], win[0][c][3], bv[c], bv[c + 1])
            for c in range(C)
        ]
    )
    for r in range(R):
        for c in range(C):
            if blends[r][c].grid_shape != (blends[r][0].grid_shape[0], blends[0][c].grid_shape[1]):
                _checks.fail("trim", "the same kept rows for patches side by side", f"patch ({r}, {c})")
    du = SplineDirection(knots_u, k, name="knots_u", dtype=dtype)
    dv = SplineDirection(knots_v, l, name="knots_v", dtype=dtype)
    if len(pu) < du.n_ctrl or len(pv) < dv.n_ctrl:
        _checks.fail(
            "samples",
            f"at least {du.n_ctrl} × {dv.n_ctrl} samples in all for the merged net",
            f"{len(pu)} × {len(pv)}",
        )
    merged = Blending.from_directions(du, dv, jnp.asarray(pu, dtype), jnp.asarray(pv, dtype))
    return MergeLayout(
        patches=tuple(tuple(row) for row in blends),
        merged=merged,
        reduction_error=jnp.zeros((R, C), dtype),
        orientations=tuple(tuple(row) for row in ops),
        flat=flat,
    )


# --- the plan cache ---------------------------------------------------------------------------
class _PlanCache:
    """Layouts (and overlap trims) by their static key, least recently used dropped first."""

    size = 128

    def __init__(self):
        self.layouts: OrderedDict = OrderedDict()
        self.trims: OrderedDict = OrderedDict()
        self.builds = self.hits = 0

    def get(self, store: OrderedDict, key, build):
        if key in store:
            store.move_to_end(key)
            self.hits += store is self.layouts
            return store[key]
        # host planning: evaluate now even when called while a caller's jit is tracing, so the
        # cache never holds a tracer
        with jax.core.eval_context():
            value = build()
        self.builds += store is self.layouts
        store[key] = value
        if len(store) > self.size:
            store.popitem(last=False)
        return value

    def clear_cache(self) -> None:
        self.layouts.clear()
        self.trims.clear()
        _KEY_MEMO.clear()
        self.builds = self.hits = 0


_CACHE = _PlanCache()
_boundary.register(_CACHE)  # bsjax.clear_caches() clears it with the compiled calls


def clear_cache() -> None:
    """Forget every cached merge layout and overlap trim (`plan`'s cache; the compiled entry
    points are cleared by `bsjax._boundary.clear_caches()`, which also calls this)."""
    _CACHE.clear_cache()


def cache_info() -> dict:
    """`{"layouts": cached layouts, "trims": cached overlap trims, "builds": layouts built,
    "hits": layouts reused}` since the last `clear_cache()`."""
    return {
        "layouts": len(_CACHE.layouts),
        "trims": len(_CACHE.trims),
        "builds": _CACHE.builds,
        "hits": _CACHE.hits,
    }


def _concrete(x, name: str, why: str):
    if isinstance(x, jax.core.Tracer):
        raise TypeError(f"{name}: expected concrete values ({why}), got a traced array")
    return x


_AUTO = "orient='auto' reads the edges of the nets; inside jit pass 'as_given' or explicit orientations"
_HOST = "a merge is planned on the host: call plan/merge outside jit, layout.apply inside"


def _bytes(x, name):
    if x is None:
        return None
    return str(x.dtype), np.asarray(_concrete(x, name, _HOST)).tobytes()


def basis_key(s: BSplineSurface, name: str) -> tuple:
    """The static key of a patch's basis: net size, dtype, degrees, periodicity, and the values
    of its knot vectors and weights (as bytes: equal values, equal key). Remembered for the same
    (immutable) surface object, by weak reference."""
    hit = _KEY_MEMO.get(id(s))
    if hit is not None and hit[0]() is s:
        return hit[1]
    key = _basis_key(s, name)
    if _checks.is_concrete(s.ctrl):
        _KEY_MEMO[id(s)] = (weakref.ref(s), key)
        if len(_KEY_MEMO) > 256:
            _KEY_MEMO.pop(next(iter(_KEY_MEMO)))
    return key


_KEY_MEMO: dict = {}


def _basis_key(s: BSplineSurface, name: str) -> tuple:
    return (
        s.shape,
        str(s.ctrl.dtype),
        s.degree_u,
        s.degree_v,
        s.periodic_u,
        s.periodic_v,
        _bytes(s.knots_u, f"{name}.knots_u"),
        _bytes(s.knots_v, f"{name}.knots_v"),
        _bytes(s.weights, f"{name}.weights"),
    )


def _require_concrete(surfaces, names, why):
    for s, n in zip(surfaces, names):
        _concrete(s.ctrl, f"{n}.ctrl", why)


def _values_key(surfaces, names, why):
    return tuple(np.asarray(_concrete(s.ctrl, f"{n}.ctrl", why)).tobytes() for s, n in zip(surfaces, names))


def _freeze(x):
    """Lists → tuples, floats kept, a face's trim (`window()`) as its window: a hashable key part."""
    if isinstance(x, (list, tuple)):
        return tuple(_freeze(v) for v in x)
    if callable(getattr(x, "window", None)):
        try:
            return ("window", x.window())
        except ValueError:  # not a rectangle: `_window` raises it, naming the patch's entry
            return ("window", id(x))
    return float(x) if isinstance(x, (float, np.floating)) else x


def _with_reduction_error(layout: MergeLayout, grid, ops) -> MergeLayout:
    """`layout` with each patch's loss from lowering its degrees (depends on the nets: per call)."""
    k, l = layout.merged.degree_u, layout.merged.degree_v
    with jax.core.eval_context():
        errors = jnp.asarray(
            [
                [
                    reduction_error(_orient.orient_surface(s, op), b, k, l)
                    for s, op, b in zip(srow, orow, brow)
                ]
                for srow, orow, brow in zip(grid, ops, layout.patches)
            ],
            layout.reduction_error.dtype,
        )
    return eqx.tree_at(lambda lay: lay.reduction_error, layout, errors)


def _seam_degrees(surfaces, ops, direction: str, degrees):
    """Common degree of the oriented patches along `direction` (structure only)."""
    along = [
        (s.degree_v if op[0] else s.degree_u) if direction == "u" else (s.degree_u if op[0] else s.degree_v)
        for s, op in zip(surfaces, ops)
    ]
    if degrees is None:
        return along[0] if len(set(along)) == 1 else None
    return min(along) if degrees == "reduce" else max(along)


def _check_seams(continuity, surfaces, ops, direction, degrees, seams: int):
    """Continuity at each seam `0 ≤ c < degree` (structure: checked before any planning)."""
    if degrees not in DEGREE_POLICIES:
        _checks.fail("degrees", f"one of {DEGREE_POLICIES}", repr(degrees))
    k = _seam_degrees(surfaces, ops, direction, degrees)
    cs = list(continuity) if isinstance(continuity, (tuple, list)) else [continuity] * seams
    if len(cs) != seams:
        _checks.fail("continuity", f"one int or {seams} ints (one per seam)", len(cs))
    for c in cs:
        if k is None:
            _knots._check_continuity(c, 10**9)  # the type; degrees are refused later
        else:
            _knots._check_continuity(c, k)


# --- plan ---------------------------------------------------------------------------------------
@declared
def plan(
    surfaces: Sequence[BSplineSurface],
    direction: str = "u",
    continuity: int = 2,
    *,
    samples=82,
    cross_knots: str = "average",
    degrees=None,
    orient: str = "auto",
    trim=None,
    overlap: str = "keep",
    overlap_method: str = "collide",
) -> MergeLayout:
    """Plan the merge of N ≥ 2 patches in a row along `direction` (thesis §4.3, §4.4).

    **Arguments:**
    - `surfaces`: open `BSplineSurface`s, in order along `direction`.
    - `direction`: `"u"` (patches stacked along u, `M = [M1; M2]`) or `"v"` (`M = [M1 M2]`).
    - `continuity`: C^c at every seam (one int, or one per seam), `0 ≤ c < degree`.
    - `samples`: `m` or `(m, n)` samples per patch (the thesis uses 82 or 101).
    - `cross_knots`: `"average"` (§6.3.1.3; the merged knot set when counts differ) or
      `"uniform"` (§4.3.3) for the other direction.
    - `degrees`: `None` (degrees must agree), `"elevate"` or `"reduce"` (§4.4.2).
    - `orient`: `"auto"` finds which edges meet and flips/transposes patches to match (read from
      the nets' edges at every call); `"as_given"` trusts that patch i's `direction = 1` edge
      meets patch i+1's `= 0` edge; or one `(transpose, flip_u, flip_v)` per patch.
    - `trim`: per patch `None` or `(lo, hi)`: keep only the sample rows with parameter in
      `[lo, hi]` along `direction` (trimmed or intersecting patches, §4.4.1), in the parameters
      of the patch as oriented; or a face read from a CAD file (`bsjax.io.CadObject` / `Trim`)
      whose trim is an axis-aligned rectangle: its window (`Trim.window`; other trims refused).
    - `overlap`: `"keep"`, or `"drop"` to find intersecting patches' overlapping sample rows and
      leave them out (§4.4.1, `overlap_trims`). Not with `trim`.
    - `overlap_method`: `"collide"` (bsjax.collide's surface contacts) or `"dense"` (a distance
      test between the sample grids).

    **Returns:** a `MergeLayout`; `layout.apply([P1, P2, …])` gives the merged control net.

    **Cache:** the layout is cached by the patches' bases (degrees, periodicity, knot and weight
    values), the resolved orientations, `samples`, `trim` and the options, so a second call with
    the same bases returns the same layout without building anything. With `overlap="drop"` the
    trims depend on the nets: they are cached by the nets' exact values (a changed net finds its
    overlap again). `clear_cache()` empties the cache; `cache_info()` counts builds and hits.
    """
    if direction not in ("u", "v"):
        _checks.fail("direction", "'u' or 'v'", repr(direction))
    _knots.check_cross(cross_knots, "cross_knots")
    surfaces = list(surfaces)
    if len(surfaces) < 2:
        _checks.fail("surfaces", "a list of 2 or more patches", len(surfaces))
    names = [f"surfaces[{i}]" for i in range(len(surfaces))]
    for s, name in zip(surfaces, names):
        _check_patch(s, name)
    m, n = _samples(samples)
    drop = _drop_overlap(overlap, trim, overlap_method)
    if isinstance(orient, str):
        _check_orient_mode(orient)
        if orient == "auto":
            _require_concrete(surfaces, names, _AUTO)
            ops = _orient.orient_row(surfaces, direction)
        else:
            ops = [_orient.IDENTITY] * len(surfaces)
    else:
        ops = _explicit_orientations([orient], 1, len(surfaces))[0]
    _check_seams(continuity, surfaces, ops, direction, degrees, len(surfaces) - 1)
    bases = tuple(basis_key(s, name) for s, name in zip(surfaces, names))
    if drop:
        values = _values_key(surfaces, names, "overlap='drop' finds the overlap from the nets")
        count = m if direction == "u" else n
        trim = _CACHE.get(
            _CACHE.trims,
            ("row", bases, values, tuple(ops), direction, count, overlap_method),
            lambda: _overlap.overlap_trims(
                [_orient.orient_surface(s, op) for s, op in zip(surfaces, ops)],
                direction,
                count,
                method=overlap_method,
            ),
        )
    grid = [[s] for s in surfaces] if direction == "u" else [surfaces]
    ogrid = [[op] for op in ops] if direction == "u" else [ops]
    cont = list(continuity) if isinstance(continuity, (tuple, list)) else continuity
    cont = (cont, 0) if direction == "u" else (0, cont)
    key = ("row", bases, direction, _freeze(cont), (m, n), cross_knots, degrees, tuple(ops), _freeze(trim))
    layout = _CACHE.get(
        _CACHE.layouts,
        key,
        lambda: build_layout(
            grid,
            cont,
            samples=(m, n),
            cross=cross_knots,
            degrees=degrees,
            orientations=ogrid,
            trim=trim,
            direction=direction,
            flat=True,
        ),
    )
    return _with_reduction_error(layout, grid, ogrid) if degrees == "reduce" else layout


def _drop_overlap(overlap, trim, method) -> bool:
    if overlap not in ("keep", "drop"):
        _checks.fail("overlap", "'keep' or 'drop'", repr(overlap))
    if overlap == "drop" and trim is not None:
        _checks.fail("trim", "None when overlap='drop' (the trims are computed)", trim)
    if method not in ("collide", "dense"):
        _checks.fail("overlap_method", "'collide' or 'dense'", repr(method))
    return overlap == "drop"


def _check_orient_mode(orient):
    if orient not in ("auto", "as_given"):
        _checks.fail(
            "orient", "'auto', 'as_given' or explicit (transpose, flip_u, flip_v) per patch", repr(orient)
        )


def _explicit_orientations(orient, R: int, C: int):
    """Validate rows of explicit `(transpose, flip_u, flip_v)` orientations."""
    expected = f"'auto', 'as_given' or {R} rows of {C} (transpose, flip_u, flip_v) orientations"
    if not isinstance(orient, (list, tuple)) or not all(isinstance(r, (list, tuple)) for r in orient):
        _checks.fail("orient", expected, type(orient).__name__)
    rows = [list(r) for r in orient]
    if len(rows) != R or any(len(r) != C for r in rows):
        _checks.fail(
            "orient", f"{R} rows of {C} (transpose, flip_u, flip_v) orientations", [len(r) for r in rows]
        )
    out = []
    for r, row in enumerate(rows):
        for c, op in enumerate(row):
            if len(tuple(op)) != 3 or not all(isinstance(x, (bool, np.bool_)) for x in op):
                _checks.fail(
                    f"orient[{r}][{c}]" if R > 1 else f"orient[{c}]", "(transpose, flip_u, flip_v) bools", op
                )
        out.append([tuple(bool(x) for x in op) for op in row])
    return out


def grid_orientations(rows, orient="auto"):
    """Orientations of a grid of patches: `"auto"` (`_orient.orient_grid`, from the nets'
    edges), `"as_given"`, or explicit rows of `(transpose, flip_u, flip_v)` (validated)."""
    R, C = len(rows), len(rows[0])
    if isinstance(orient, str):
        _check_orient_mode(orient)
        if orient == "as_given":
            return [[_orient.IDENTITY] * C for _ in range(R)]
        names = [f"rows[{i}][{j}]" for i in range(R) for j in range(C)]
        flat = [s for row in rows for s in row]
        _require_concrete(flat, names, _AUTO)
        return _orient.orient_grid(rows)
    return _explicit_orientations(orient, R, C)


@declared
def plan_grid(
    rows: Sequence[Sequence[BSplineSurface]],
    continuity=2,
    *,
    samples=82,
    degrees=None,
    orient="auto",
    trim=None,
    overlap: str = "keep",
    overlap_method: str = "collide",
) -> MergeLayout:
    """Plan the merge of a grid of patches, `M = [M11 M12 …; M21 M22 …]` (thesis §4.4.3).

    `rows[i][j]`: patches side by side along v within a row, rows stacked along u; after
    orientation patch `(i, j)`'s `u = 1` edge meets `(i+1, j)`'s `u = 0` edge and its `v = 1`
    edge meets `(i, j+1)`'s `v = 0` edge. `continuity`: one int or `(c_u, c_v)`.
    `orient`: `"auto"` (find which edges meet and flip/transpose patches to match),
    `"as_given"`, or rows of explicit `(transpose, flip_u, flip_v)`. `trim`: rows of `None` or
    `(u0, u1, v0, v1)` kept windows (oriented parameters), one u-window per row of patches and
    one v-window per column. `overlap="drop"`: leave out the rows/columns where neighbours
    intersect (`grid_overlap_windows`; not with `trim`), found by `overlap_method`.
    **Returns:** a `MergeLayout`; `layout.apply(rows_of_ctrl)` takes the control nets as given
    (the orientations are applied inside). Cached like `plan`'s layouts.
    """
    rows = [list(r) for r in rows]
    if not rows or not rows[0]:
        _checks.fail("rows", "a non-empty list of non-empty rows of patches", rows)
    if any(len(r) != len(rows[0]) for r in rows):
        _checks.fail(
            "rows", f"rows of equal length {len(rows[0])} (a rectangular grid)", [len(r) for r in rows]
        )
    R, C = len(rows), len(rows[0])
    if R * C < 2:
        _checks.fail("rows", "at least 2 patches", 1)
    names = [[f"rows[{i}][{j}]" for j in range(C)] for i in range(R)]
    for row, nrow in zip(rows, names):
        for s, name in zip(row, nrow):
            _check_patch(s, name)
    m, n = _samples(samples)
    drop = _drop_overlap(overlap, trim, overlap_method)
    ops = grid_orientations(rows, orient)
    cu, cv = _continuity_pair(continuity)
    flat = [s for row in rows for s in row]
    flat_ops = [op for orow in ops for op in orow]
    if R > 1:
        _check_seams(cu, flat, flat_ops, "u", degrees, 1)
    if C > 1:
        _check_seams(cv, flat, flat_ops, "v", degrees, 1)
    bases = tuple(tuple(basis_key(s, name) for s, name in zip(row, nrow)) for row, nrow in zip(rows, names))
    frozen_ops = tuple(tuple(orow) for orow in ops)
    if drop:
        why = "overlap='drop' finds the overlap from the nets"
        values = _values_key(flat, [nm for nrow in names for nm in nrow], why)
        trim = _CACHE.get(
            _CACHE.trims,
            ("grid", bases, values, frozen_ops, (m, n), overlap_method),
            lambda: _overlap.grid_overlap_windows(
                [[_orient.orient_surface(s, op) for s, op in zip(row, orow)] for row, orow in zip(rows, ops)],
                (m, n),
                method=overlap_method,
            ),
        )
    key = ("grid", bases, _freeze(continuity), (m, n), degrees, frozen_ops, _freeze(trim))
    layout = _CACHE.get(
        _CACHE.layouts,
        key,
        lambda: build_layout(
            rows,
            continuity,
            samples=(m, n),
            cross="average",
            degrees=degrees,
            orientations=ops,
            trim=trim,
            direction=None,
        ),
    )
    return _with_reduction_error(layout, rows, ops) if degrees == "reduce" else layout


# --- one call -----------------------------------------------------------------------------------
@compiled
def _merged_surface(layout: MergeLayout, ctrls, refine: bool, progress=None) -> BSplineSurface:
    ctrl = _nonlinear.refine(layout, ctrls, progress=progress) if refine else layout.apply(ctrls)
    return layout.surface(ctrl)


@declared
def merge(
    surfaces: Sequence[BSplineSurface],
    direction: str = "u",
    continuity: int = 2,
    *,
    samples=82,
    cross_knots: str = "average",
    degrees=None,
    orient="auto",
    trim=None,
    overlap: str = "keep",
    overlap_method: str = "collide",
    refine: bool = False,
    progress: Callable[[int, int], object] | None = None,
) -> BSplineSurface:
    """Merge 2 or more patches in a row into one `BSplineSurface` (thesis §4.3, §4.4).

    **Arguments:** as `plan` (`direction`, `continuity` 0 ≤ c < degree, `samples` per patch,
    `cross_knots`, `degrees` = None/"elevate"/"reduce", `orient`, `trim`, `overlap`
    = "keep"/"drop", `overlap_method`), plus `refine`: also run the nonlinear refit with
    parameter correction (`refit`), and `progress`: with `refine`, an optional callback
    `progress(done, rounds)` after each round of the refit (see `refit`).

    **Returns:** the merged surface: degree `(k, l)`, `r = Σ r_i − (N − 1)` control points along
    the merge direction (more or fewer after a degree change), the largest count across.

    The layout comes from `plan`'s cache (built once per bases and options); the merge itself
    is one compiled call. Inside a caller's `jit`, plan outside and call `layout.apply`.
    """
    surfaces = list(surfaces)
    layout = plan(
        surfaces,
        direction,
        continuity,
        samples=samples,
        cross_knots=cross_knots,
        degrees=degrees,
        orient=orient,
        trim=trim,
        overlap=overlap,
        overlap_method=overlap_method,
    )
    return _merged_surface(layout, [s.ctrl for s in surfaces], bool(refine), progress)


@declared
def merge_grid(
    rows: Sequence[Sequence[BSplineSurface]],
    continuity=2,
    *,
    samples=82,
    degrees=None,
    orient="auto",
    trim=None,
    overlap: str = "keep",
    overlap_method: str = "collide",
    refine: bool = False,
    progress: Callable[[int, int], object] | None = None,
) -> BSplineSurface:
    """Merge a grid of patches (`rows[i][j]`, rows stacked along u) into one surface (§4.4.3).

    **Arguments:** as `plan_grid` (`continuity` one int or `(c_u, c_v)`, `samples`, `degrees`,
    `orient` = "auto"/"as_given"/explicit rows, `trim` = rows of `(u0, u1, v0, v1)`, `overlap`,
    `overlap_method`), plus `refine` and `progress` as for `merge`. Cached and compiled like
    `merge`.
    """
    rows = [list(r) for r in rows]
    layout = plan_grid(
        rows,
        continuity,
        samples=samples,
        degrees=degrees,
        orient=orient,
        trim=trim,
        overlap=overlap,
        overlap_method=overlap_method,
    )
    return _merged_surface(layout, [[s.ctrl for s in row] for row in rows], bool(refine), progress)
