"""Deprecated location (moved to `bsjax.basis._tensor` and `bsjax._safe`)."""

from bsjax._safe import norm as safe_norm
from bsjax._safe import unit as unit
from bsjax.basis._tensor import grid as grid
from bsjax.basis._tensor import homogeneous as homogeneous
from bsjax.basis._tensor import pointwise as pointwise
from bsjax.basis._tensor import rational_derivatives as rational_derivatives
from bsjax.basis._tensor import unit_normal as unit_normal

__all__ = ["grid", "homogeneous", "pointwise", "rational_derivatives", "safe_norm", "unit", "unit_normal"]
