"""bsjax: differentiable B-spline geometry and physics in JAX.

The names a newcomer needs first; everything else lives in its module
(`bsjax.basis`, `bsjax.io`, …). Importing bsjax changes no global configuration.
"""

from bsjax.basis import Blending, BSplineSurface, blending_matrix, clamped_knots, periodic_blending_matrix

__version__ = "0.1.0"

__all__ = [
    "BSplineSurface",
    "Blending",
    "blending_matrix",
    "clamped_knots",
    "periodic_blending_matrix",
]
