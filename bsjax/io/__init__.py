"""Surface and curve files: lossless JSON, Rhino `.3dm` (rhino3dm), STEP and IGES (OCCT), and
tessellated meshes (trimesh).

* `save(items, path)` / `load(path)` / `load_all(path)` pick the format by extension: `.json`,
  `.3dm`, `.step`/`.stp` and `.iges`/`.igs` keep the exact B-spline surfaces and curves
  (degrees, knots, control points, weights); `.obj`, `.stl`, `.ply`, `.glb` write the
  tessellated sample grid of surfaces.
* `load_all` returns a `CadList`: a list of the splines (as before) that also carries the file's
  `units`, its `objects` (`CadObject`: name, layer, parameter domain, orientation, `Trim`) and
  what the file `held`; `trims=True` returns the `CadObject`s themselves. Objects bsjax cannot
  load are listed in an error (`on_unsupported="raise"`, default) or a warning (`"skip"`).
* Rhino's closed surfaces with non-uniform periodic knots load as exact clamped B-splines (knot
  insertion at the domain ends, `bsjax.io._knots`); a uniform periodic direction loads periodic.
  The file's parameter domain is kept and written back.
* Trims reach collision and meshes: `CadObject.sample_mask(blending)` is a face's trim on a
  sample grid, for `collide.contacts(..., sample_mask=)` and `tessellate(..., mask=)` (a mesh
  format written by `save` drops the triangles outside a face's trim).
* Closed surfaces: a trim loop that lies on or crosses the seam (shifted by a period, or split
  there) masks correctly on both sides of the seam (`Trim.closed`).
* Polycurves (a `.3dm` `PolyCurve`, a STEP/IGES wire) load as a list of `BSplineCurve`s, one per
  segment; `save` writes a list of curves inside the list as a polycurve.
* `merge.merge(..., trim=[face, ...])` takes a face whose trim is a rectangle (`Trim.window`).
* STEP keeps names and layers (OCCT's XCAF document: products and layer assignments); IGES keeps
  ASCII names and integer layers (levels).
* From the shell: `bsjax convert IN OUT` (`bsjax.cli.convert`).

rhino3dm, OCP and trimesh are imported by the functions that use them, so `import bsjax.io`
stays light; they are the extras `cad` (rhino3dm, OCP) and `mesh` (trimesh), and a format used
without its extra raises an `ImportError` that names it (`pip install 'bsjax[cad]'`).
"""

from bsjax.io._cad import UNITS as UNITS
from bsjax.io._cad import CadList as CadList
from bsjax.io._cad import CadObject as CadObject
from bsjax.io._cad import Trim as Trim
from bsjax.io._files import MESH_FORMATS as MESH_FORMATS
from bsjax.io._files import from_dict as from_dict
from bsjax.io._files import load as load
from bsjax.io._files import load_all as load_all
from bsjax.io._files import save as save
from bsjax.io._files import tessellate as tessellate
from bsjax.io._files import to_dict as to_dict

__all__ = [
    "MESH_FORMATS",
    "UNITS",
    "CadList",
    "CadObject",
    "Trim",
    "from_dict",
    "load",
    "load_all",
    "save",
    "tessellate",
    "to_dict",
]
