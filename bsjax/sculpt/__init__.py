"""Constraint-based sculpting of B-spline curves and surfaces (thesis *Interactive shape modeling
and dynamic deformation based on spline sculpting*, ch. 6; Fowler & Bartels, *Constraint-based
curve manipulation*): minimum-norm edits under linear constraints, a factor computed once per
interaction and reused per drag event, nonlinear constraints by minimum-norm Gauss–Newton, and
target-curve sculpting."""

from bsjax.sculpt._constraints import AbstractConstraint as AbstractConstraint
from bsjax.sculpt._constraints import AlongNormal as AlongNormal
from bsjax.sculpt._constraints import Derivative as Derivative
from bsjax.sculpt._constraints import Displacement as Displacement
from bsjax.sculpt._constraints import Fixed as Fixed
from bsjax.sculpt._constraints import Position as Position
from bsjax.sculpt._min_norm import Edit as Edit
from bsjax.sculpt._min_norm import Factor as Factor
from bsjax.sculpt._min_norm import min_norm as min_norm
from bsjax.sculpt._min_norm import prefactor as prefactor
from bsjax.sculpt._nonlinear import AbstractNonlinear as AbstractNonlinear
from bsjax.sculpt._nonlinear import Distance as Distance
from bsjax.sculpt._nonlinear import NormalAngle as NormalAngle
from bsjax.sculpt._nonlinear import OnSurface as OnSurface
from bsjax.sculpt._nonlinear import TangentParallel as TangentParallel
from bsjax.sculpt._nonlinear import solve as solve
from bsjax.sculpt._target import SculptResult as SculptResult
from bsjax.sculpt._target import bound_mask as bound_mask
from bsjax.sculpt._target import frame_rotation as frame_rotation
from bsjax.sculpt._target import target_sculpt as target_sculpt

__all__ = [
    "AbstractConstraint",
    "AbstractNonlinear",
    "AlongNormal",
    "Derivative",
    "Displacement",
    "Distance",
    "Edit",
    "Factor",
    "Fixed",
    "NormalAngle",
    "OnSurface",
    "Position",
    "SculptResult",
    "TangentParallel",
    "bound_mask",
    "frame_rotation",
    "min_norm",
    "prefactor",
    "solve",
    "target_sculpt",
]
