"""Merging B-spline patches into one surface (thesis ch. 4, §6.3, App. A).

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
* `merge_knots`, `average_knots`, `cross_knots`, `merged_knots`: the knot and degree rules (the
  merged basis without building matrices).
* `deviation(originals, merged)` → `Deviation` (mean, median, std, max, close points) by
  closest-point projection (`basis.closest_points`: batched Gauss–Newton); `plot_deviation`
  draws the heat map.
* `refit(layout, ctrls, RefitSolver())` → `RefitSolution` (net, corrected parameters, RMS
  history, status): nonlinear refit with parameter correction (beyond the thesis);
  `refine(layout, ctrls)` / `merge(..., refine=True)` give its net.

Every function that computes is compiled at the boundary (`bsjax._boundary.compiled`). The
host-side plan (knot vectors, layout, blending matrices and their pseudo-inverses) is cached by
its static key — the patches' bases (degrees, periodicity, knot and weight values), orientations,
sample counts, trims and options — so a repeated `merge(...)` with the same bases only runs the
compiled apply. `clear_cache()` empties it (so does `bsjax._boundary.clear_caches()`);
`cache_info()` counts builds and reuses.
"""

from bsjax.merge._deviation import Deviation as Deviation
from bsjax.merge._deviation import deviation as deviation
from bsjax.merge._deviation import plot_deviation as plot_deviation
from bsjax.merge._knots import average_knots as average_knots
from bsjax.merge._knots import cross_knots as cross_knots
from bsjax.merge._knots import merge_knots as merge_knots
from bsjax.merge._layout import MergeLayout as MergeLayout
from bsjax.merge._layout import cache_info as cache_info
from bsjax.merge._layout import clear_cache as clear_cache
from bsjax.merge._layout import merge as merge
from bsjax.merge._layout import merge_grid as merge_grid
from bsjax.merge._layout import merged_knots as merged_knots
from bsjax.merge._layout import plan as plan
from bsjax.merge._layout import plan_grid as plan_grid
from bsjax.merge._nonlinear import RefitSolution as RefitSolution
from bsjax.merge._nonlinear import RefitSolver as RefitSolver
from bsjax.merge._nonlinear import refine as refine
from bsjax.merge._nonlinear import refit as refit
from bsjax.merge._orient import orient_grid as orient_grid
from bsjax.merge._orient import orient_surface as orient_surface
from bsjax.merge._overlap import overlap_trims as overlap_trims

__all__ = [
    "Deviation",
    "MergeLayout",
    "RefitSolution",
    "RefitSolver",
    "average_knots",
    "cache_info",
    "clear_cache",
    "cross_knots",
    "deviation",
    "merge",
    "merge_grid",
    "merge_knots",
    "merged_knots",
    "orient_grid",
    "orient_surface",
    "overlap_trims",
    "plan",
    "plan_grid",
    "plot_deviation",
    "refine",
    "refit",
]
