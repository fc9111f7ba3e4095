"""The closest-point projection used by the merge (deviation report, parameter correction):
the one projection of the library, `bsjax.basis` (`closest_points`, `project`), re-exported
here so `bsjax.merge.closest_points` and friends keep their public paths."""

from __future__ import annotations

from bsjax.basis import Projection as Projection
from bsjax.basis import ProjectionSolver as ProjectionSolver
from bsjax.basis import closest_points as closest_points
from bsjax.basis import project as project
