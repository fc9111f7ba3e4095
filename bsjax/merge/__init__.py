"""Merging B-spline patches into one surface (thesis ch. 4, §6.3, App. A; SPEC §4).

Any number of dissimilar patches become one B-spline surface with the continuity asked for at
each seam, without matching the edges first. Each patch is discretised with its blending
matrices (`M_i = A_u^i P^i A_v^iT`), the grids are stacked (`[M1; M2]`, `[M1 M2]`,
`[M1 M2; M3 M4]`), and one control net is refitted with the revised blending matrices
(eq. 3.7). The merged knot vector joins the patches' vectors with `degree − c` knots at a C^c
seam (§4.3.3); across, the patches' knots are averaged (§6.3.1.3) or made uniform.

* `merge(surfaces, direction, continuity)` / `merge_grid(rows, continuity)`: one call; both take
  patches in any orientation (`orient="auto"`, or explicit flips/transposes), trimmed windows
  (`trim`) and intersecting patches (`overlap="drop"`).
* `plan(...)` / `plan_grid(...)` → `MergeLayout`: all the fixed work once; `layout.apply(ctrls)`
  is then jittable and differentiable in the input control nets; `layout.reduction_error`
  reports what `degrees="reduce"` costs each patch.
* `merge_knots`, `average_knots`, `cross_knots`, `common_degree`, `merged_knots`: the knot and
  degree rules (the merged basis without building matrices).
* `deviation(originals, merged)` → `Deviation` (mean, median, std, max, close points) by
  closest-point projection (`closest_points`: vmapped optimistix Gauss–Newton); `plot_deviation`
  draws the heat map.
* `refit(layout, ctrls, RefitSolver())` → `RefitSolution` (net, corrected parameters, RMS
  history, status): nonlinear refit with parameter correction (beyond the thesis);
  `refine(layout, ctrls)` / `merge(..., refine=True)` give its net.
"""

from __future__ import annotations

from collections.abc import Sequence

from bsjax.basis import BSplineSurface
from bsjax.merge._deviation import Deviation, closest_parameters, deviation, plot_deviation
from bsjax.merge._knots import average_knots, combine_knots, cross_knots, merge_knots
from bsjax.merge._layout import MergeLayout, common_degree, grid_orientations, merged_knots, plan, plan_grid
from bsjax.merge._nonlinear import RefitSolution, RefitSolver, refine, refit
from bsjax.merge._orient import orient_grid, orient_row, orient_surface
from bsjax.merge._overlap import contact_masks, grid_overlap_windows, overlap_trims
from bsjax.merge._project import Projection, ProjectionSolver, closest_points, project

__all__ = [
    "Deviation",
    "MergeLayout",
    "Projection",
    "ProjectionSolver",
    "RefitSolution",
    "RefitSolver",
    "average_knots",
    "closest_parameters",
    "closest_points",
    "combine_knots",
    "common_degree",
    "contact_masks",
    "cross_knots",
    "deviation",
    "grid_orientations",
    "grid_overlap_windows",
    "merge",
    "merge_grid",
    "merge_knots",
    "merged_knots",
    "orient_grid",
    "orient_row",
    "orient_surface",
    "overlap_trims",
    "plan",
    "plan_grid",
    "plot_deviation",
    "project",
    "refine",
    "refit",
]


def _finish(layout: MergeLayout, ctrls, refine_fit: bool) -> BSplineSurface:
    ctrl = refine(layout, ctrls) if refine_fit else layout.apply(ctrls)
    return layout.surface(ctrl)


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
) -> BSplineSurface:
    """Merge 2 or more patches in a row into one `BSplineSurface` (thesis §4.3, §4.4).

    **Arguments:** as `plan` (`direction`, `continuity` 0 ≤ c < degree, `samples` per patch,
    `cross_knots`, `degrees` = None/"elevate"/"reduce", `orient`, `trim`, `overlap`
    = "keep"/"drop", `overlap_method`), plus `refine`: also run the nonlinear refit with
    parameter correction (`refit`).

    **Returns:** the merged surface: degree `(k, l)`, `r = Σ r_i − (N − 1)` control points along
    the merge direction (more or fewer after a degree change), the largest count across.
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
    return _finish(layout, [s.ctrl for s in surfaces], refine)


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
) -> BSplineSurface:
    """Merge a grid of patches (`rows[i][j]`, rows stacked along u) into one surface (§4.4.3).

    **Arguments:** as `plan_grid` (`continuity` one int or `(c_u, c_v)`, `samples`, `degrees`,
    `orient` = "auto"/"as_given"/explicit rows, `trim` = rows of `(u0, u1, v0, v1)`, `overlap`,
    `overlap_method`), plus `refine` as for `merge`.
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
    return _finish(layout, [[s.ctrl for s in row] for row in rows], refine)
