"""bsjax: differentiable B-spline geometry and physics in JAX.

The names a newcomer needs first; everything else lives in its module (`bsjax.basis`,
`bsjax.collide`, `bsjax.merge`, `bsjax.mss`, `bsjax.vsofm`, `bsjax.device`, `bsjax.io`, …).
Importing bsjax changes no global configuration. Every public function that computes is
compiled at its boundary; `clear_caches()` forgets every compiled entry point and cached plan;
`enable_compilation_cache()` keeps the compiled programs on disk for the next process.

Sources cited in the docstrings:
* the thesis — H. Pungotra, *Collision detection and merging of deformable B-spline surfaces in
  virtual reality environment*, PhD thesis, The University of Western Ontario (2010);
* Pungotra, Knopf & Canas, *An alternative methodology to represent B-spline surface for
  applications in virtual reality environment*, Computer-Aided Design & Applications (2013);
* Gao & Gibson, *Haptic B-spline surface sculpting with a shaped tool of implicit surface*,
  Computer-Aided Design & Applications (2005);
* *Interactive shape modeling and dynamic deformation based on spline sculpting*, PhD thesis,
  University of Trento (2007);
* Piegl & Tiller, *The NURBS Book* (2nd ed., 1997).
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bsjax._boundary import clear_caches as clear_caches
    from bsjax._cache import enable_compilation_cache as enable_compilation_cache
    from bsjax.basis import Blending as Blending
    from bsjax.basis import BSplineCurve as BSplineCurve
    from bsjax.basis import BSplineSurface as BSplineSurface
    from bsjax.basis import CurveBlending as CurveBlending
    from bsjax.basis import SplineDirection as SplineDirection
    from bsjax.basis import blending_matrix as blending_matrix
    from bsjax.basis import clamped_knots as clamped_knots
    from bsjax.basis import periodic_blending_matrix as periodic_blending_matrix

# Loaded on first use (PEP 562), so `import bsjax` — e.g. in the haptic servo's own process —
# does not import JAX until something that computes is asked for.
_NAMES = {
    "clear_caches": "bsjax._boundary",
    "enable_compilation_cache": "bsjax._cache",
    **{
        name: "bsjax.basis"
        for name in (
            "Blending",
            "BSplineCurve",
            "BSplineSurface",
            "CurveBlending",
            "SplineDirection",
            "blending_matrix",
            "clamped_knots",
            "periodic_blending_matrix",
        )
    },
}


def __getattr__(name: str):
    if name in _NAMES:
        value = getattr(importlib.import_module(_NAMES[name]), name)
    elif importlib.util.find_spec(f"bsjax.{name}") is not None and not name.startswith("_"):
        value = importlib.import_module(f"bsjax.{name}")  # a submodule: bsjax.collide, …
    else:
        raise AttributeError(f"module 'bsjax' has no attribute {name!r}")
    globals()[name] = value
    return value


__version__ = "0.1.0"

__all__ = [
    "BSplineCurve",
    "BSplineSurface",
    "Blending",
    "CurveBlending",
    "SplineDirection",
    "blending_matrix",
    "clamped_knots",
    "clear_caches",
    "enable_compilation_cache",
    "periodic_blending_matrix",
]
