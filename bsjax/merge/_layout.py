"""The merge itself (thesis §4.3–4.4): discretise each patch with its blending matrices, stack the
point grids, and refit one control net with the revised blending matrices (eq. 3.7).

Everything that depends only on the layout — orientations, common degrees, knot vectors, sample
parameters, the per-patch blending matrices and the merged surface's pseudo-inverses — is decided
once by `plan`/`plan_grid` into a `MergeLayout`. `MergeLayout.apply` is then two small matrix
products per patch plus one refit: jittable, and differentiable in the input control nets.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks
from bsjax._blending import Blending
from bsjax.basis import BSplineSurface, reduce_degree
from bsjax.merge import _knots, _orient, _overlap

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

    def points(self, ctrls) -> Float[Array, "m n 3"]:
        """Combined sample grid `M = [M_11 M_12 …; M_21 …]`, `M_ij = A_u^ij P^ij A_v^ijT` (§4.3.1).

        `ctrls`: the input control nets as given to `plan` (a list) or `plan_grid` (rows).
        """
        rows = self._rows(ctrls)
        blocks = [
            jnp.concatenate(
                [b.points(_orient.orient_ctrl(jnp.asarray(c), op)) for b, c, op in zip(brow, crow, orow)],
                axis=1,
            )
            for brow, crow, orow in zip(self.patches, rows, self.orientations)
        ]
        return jnp.concatenate(blocks, axis=0)

    def apply(self, ctrls) -> Float[Array, "r s 3"]:
        """Merged control net `P = A_u^+ M (A_v^+)^T` (thesis eq. 3.7) with the stored factors."""
        return self.merged.refit(self.points(ctrls))

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
    """One patch's `(u0, u1, v0, v1)` from `None`, `(lo, hi)` along `direction`, or a full window."""
    if t is None:
        return (0.0, 1.0, 0.0, 1.0)
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


def merged_knots(oriented, continuity=2, *, cross="average", degrees=None, windows=None):
    """Degrees and knot vectors of the merged surface of an `R × C` grid of oriented patches
    (thesis §4.3.3, §4.4.2, §4.4.3) — the merged basis, without building any matrix.

    **Returns:** `(k, l, knots_u, knots_v)` (float64 knot vectors).
    """
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
    """Plan the merge of an `R × C` grid of (already oriented) patches; see `plan`."""
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
    r_ctrl, s_ctrl = len(knots_u) - k - 1, len(knots_v) - l - 1
    if len(pu) < r_ctrl or len(pv) < s_ctrl:
        _checks.fail(
            "samples",
            f"at least {r_ctrl} × {s_ctrl} samples in all for the merged net",
            f"{len(pu)} × {len(pv)}",
        )
    dummy = BSplineSurface(
        jnp.zeros((r_ctrl, s_ctrl, 3), dtype), knots_u.astype(dtype), knots_v.astype(dtype), k, l
    )
    merged = dummy.blending(params_u=pu.astype(dtype), params_v=pv.astype(dtype))
    errors = jnp.asarray(
        [[reduction_error(s, b, k, l) for s, b in zip(srow, brow)] for srow, brow in zip(oriented, blends)],
        dtype,
    )
    return MergeLayout(
        patches=tuple(tuple(row) for row in blends),
        merged=merged,
        reduction_error=errors,
        orientations=tuple(tuple(row) for row in ops),
        flat=flat,
    )


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
    - `orient`: `"auto"` finds which edges meet and flips/transposes patches to match;
      `"as_given"` trusts that patch i's `direction = 1` edge meets patch i+1's `= 0` edge; or
      one `(transpose, flip_u, flip_v)` per patch.
    - `trim`: per patch `None` or `(lo, hi)`: keep only the sample rows with parameter in
      `[lo, hi]` along `direction` (trimmed or intersecting patches, §4.4.1), in the parameters
      of the patch as oriented.
    - `overlap`: `"keep"`, or `"drop"` to find intersecting patches' overlapping sample rows and
      leave them out (§4.4.1, `overlap_trims`). Not with `trim`.
    - `overlap_method`: `"collide"` (bsjax.collide's surface contacts) or `"dense"` (a distance
      test between the sample grids).

    **Returns:** a `MergeLayout`; `layout.apply([P1, P2, …])` gives the merged control net.
    """
    if direction not in ("u", "v"):
        _checks.fail("direction", "'u' or 'v'", repr(direction))
    surfaces = list(surfaces)
    if len(surfaces) < 2:
        _checks.fail("surfaces", "a list of 2 or more patches", len(surfaces))
    for i, s in enumerate(surfaces):
        _check_patch(s, f"surfaces[{i}]")
    if isinstance(orient, str):
        _check_orient_mode(orient)
        ops = (
            _orient.orient_row(surfaces, direction, _samples(samples))
            if orient == "auto"
            else [_orient.IDENTITY] * len(surfaces)
        )
    else:
        ops = _explicit_orientations([orient], 1, len(surfaces))[0]
    if _drop_overlap(overlap, trim):
        m, n = _samples(samples)
        oriented = [_orient.orient_surface(s, op) for s, op in zip(surfaces, ops)]
        trim = _overlap.overlap_trims(
            oriented, direction, m if direction == "u" else n, method=overlap_method
        )
    grid = [[s] for s in surfaces] if direction == "u" else [surfaces]
    ogrid = [[op] for op in ops] if direction == "u" else [ops]
    cont = list(continuity) if isinstance(continuity, (tuple, list)) else continuity
    cont = (cont, 0) if direction == "u" else (0, cont)
    return build_layout(
        grid,
        cont,
        samples=samples,
        cross=cross_knots,
        degrees=degrees,
        orientations=ogrid,
        trim=trim,
        direction=direction,
        flat=True,
    )


def _drop_overlap(overlap, trim) -> bool:
    if overlap not in ("keep", "drop"):
        _checks.fail("overlap", "'keep' or 'drop'", repr(overlap))
    if overlap == "drop" and trim is not None:
        _checks.fail("trim", "None when overlap='drop' (the trims are computed)", trim)
    return overlap == "drop"


def _check_orient_mode(orient):
    if orient not in ("auto", "as_given"):
        _checks.fail(
            "orient", "'auto', 'as_given' or explicit (transpose, flip_u, flip_v) per patch", repr(orient)
        )


def _explicit_orientations(orient, R: int, C: int):
    """Validate rows of explicit `(transpose, flip_u, flip_v)` orientations."""
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


def grid_orientations(rows, orient="auto", samples=82):
    """Orientations of a grid of patches: `"auto"` (`_orient.orient_grid`), `"as_given"`, or
    explicit rows of `(transpose, flip_u, flip_v)` (validated)."""
    R, C = len(rows), len(rows[0])
    if isinstance(orient, str):
        _check_orient_mode(orient)
        if orient == "as_given":
            return [[_orient.IDENTITY] * C for _ in range(R)]
        return _orient.orient_grid(rows, _samples(samples))
    return _explicit_orientations(orient, R, C)


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
    (the orientations are applied inside).
    """
    rows = [list(r) for r in rows]
    if not rows or not rows[0]:
        _checks.fail("rows", "a non-empty list of non-empty rows of patches", rows)
    if any(len(r) != len(rows[0]) for r in rows):
        _checks.fail(
            "rows", f"rows of equal length {len(rows[0])} (a rectangular grid)", [len(r) for r in rows]
        )
    if len(rows) * len(rows[0]) < 2:
        _checks.fail("rows", "at least 2 patches", 1)
    for i, row in enumerate(rows):
        for j, s in enumerate(row):
            _check_patch(s, f"rows[{i}][{j}]")
    ops = grid_orientations(rows, orient, samples)
    if _drop_overlap(overlap, trim):
        oriented = [
            [_orient.orient_surface(s, op) for s, op in zip(row, orow)] for row, orow in zip(rows, ops)
        ]
        trim = _overlap.grid_overlap_windows(oriented, _samples(samples), method=overlap_method)
    return build_layout(
        rows,
        continuity,
        samples=samples,
        cross="average",
        degrees=degrees,
        orientations=ops,
        trim=trim,
        direction=None,
    )
