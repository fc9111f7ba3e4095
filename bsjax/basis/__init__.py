"""Knots, spline directions, basis functions, blending matrices, curves, surfaces and their
refits (thesis ch. 3).

A blending matrix holds every basis function (or its derivative) of one direction at a list of
parameters, `A[a, i] = B_{i,k}(u_a)` (thesis eq. 3.6); a surface sampled on a grid is then
`M = A_u P A_v^T`, and the least-squares control net of a grid `P = A_u^+ M A_v^{+T}` (eq. 3.7).
"""

from bsjax.basis._curve import BSplineCurve as BSplineCurve
from bsjax.basis._curve import CurveBlending as CurveBlending
from bsjax.basis._direction import SplineDirection as SplineDirection
from bsjax.basis._functions import basis_functions as basis_functions
from bsjax.basis._functions import blending_matrix as blending_matrix
from bsjax.basis._functions import periodic_blending_matrix as periodic_blending_matrix
from bsjax.basis._knots import clamped_knots as clamped_knots
from bsjax.basis._knots import greville as greville
from bsjax.basis._knots import periodic_knots as periodic_knots
from bsjax.basis._project import Projection as Projection
from bsjax.basis._project import ProjectionSolver as ProjectionSolver
from bsjax.basis._project import closest_points as closest_points
from bsjax.basis._project import project as project
from bsjax.basis._refine import change_of_basis as change_of_basis
from bsjax.basis._refine import elevate_degree as elevate_degree
from bsjax.basis._refine import insert_knots as insert_knots
from bsjax.basis._refine import reduce_degree as reduce_degree
from bsjax.basis._surface import Blending as Blending
from bsjax.basis._surface import BSplineSurface as BSplineSurface

__all__ = [
    "BSplineCurve",
    "BSplineSurface",
    "Blending",
    "CurveBlending",
    "Projection",
    "ProjectionSolver",
    "SplineDirection",
    "basis_functions",
    "blending_matrix",
    "change_of_basis",
    "clamped_knots",
    "closest_points",
    "elevate_degree",
    "greville",
    "insert_knots",
    "periodic_blending_matrix",
    "periodic_knots",
    "project",
    "reduce_degree",
]
