"""Strokes to curves, curve editing by over-sketching, and sketch understanding (thesis ch. 3–4,
§5.1.2; *Interactive shape modeling and dynamic deformation based on spline sculpting*, PhD
thesis, University of Trento, 2007).

* `_strokes`: the stroke chain — `features` → `corners` → `resample` → `fit_curve` /
  `fit_stroke`; `oversketch`; `unproject` onto a drawing plane (a `collide.Plane`) seen by a `Camera`.
* `_recognise`: `recognise` — one stroke → a `Recognised` primitive of `KINDS`, regularised
  (its line, circle, ellipse and polygon fits in `_fits`).
* `_relations`: `relations` — how one recognised stroke stands to another (`RELATIONS`).
* `_compose`: `compose` — strokes → a 3-D `Construction` through a `DecisionTree` of `Rule`s
  (`default_tree`, the composites of Fig. 3-4); `adapt` adds a confirmed new composite.
"""

from bsjax.sketch._compose import CONSTRUCTIONS as CONSTRUCTIONS
from bsjax.sketch._compose import Construction as Construction
from bsjax.sketch._compose import DecisionTree as DecisionTree
from bsjax.sketch._compose import Rule as Rule
from bsjax.sketch._compose import adapt as adapt
from bsjax.sketch._compose import compose as compose
from bsjax.sketch._compose import default_tree as default_tree
from bsjax.sketch._recognise import KINDS as KINDS
from bsjax.sketch._recognise import Recognised as Recognised
from bsjax.sketch._recognise import recognise as recognise
from bsjax.sketch._relations import RELATIONS as RELATIONS
from bsjax.sketch._relations import relations as relations
from bsjax.sketch._strokes import Camera as Camera
from bsjax.sketch._strokes import CurveFit as CurveFit
from bsjax.sketch._strokes import Features as Features
from bsjax.sketch._strokes import Oversketch as Oversketch
from bsjax.sketch._strokes import Resampled as Resampled
from bsjax.sketch._strokes import corners as corners
from bsjax.sketch._strokes import features as features
from bsjax.sketch._strokes import fit_curve as fit_curve
from bsjax.sketch._strokes import fit_stroke as fit_stroke
from bsjax.sketch._strokes import oversketch as oversketch
from bsjax.sketch._strokes import resample as resample
from bsjax.sketch._strokes import unproject as unproject

__all__ = [
    "CONSTRUCTIONS",
    "KINDS",
    "RELATIONS",
    "Camera",
    "Construction",
    "CurveFit",
    "DecisionTree",
    "Features",
    "Oversketch",
    "Recognised",
    "Resampled",
    "Rule",
    "adapt",
    "compose",
    "corners",
    "default_tree",
    "features",
    "fit_curve",
    "fit_stroke",
    "oversketch",
    "recognise",
    "relations",
    "resample",
    "unproject",
]
