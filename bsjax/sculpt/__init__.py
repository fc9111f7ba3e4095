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

__all__ = [
    "AbstractConstraint",
    "AlongNormal",
    "Derivative",
    "Displacement",
    "Edit",
    "Factor",
    "Fixed",
    "Position",
    "min_norm",
    "prefactor",
]
