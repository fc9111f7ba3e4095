"""The live 3-D view of a haptic session (or a saved surface or recording) in the browser, and the
interactive modelling session behind `bsjax studio` (`Studio`)."""

from bsjax.view._scene import SurfaceMesh as SurfaceMesh
from bsjax.view._scene import from_file as from_file
from bsjax.view._scene import live as live
from bsjax.view._server import ViewServer as ViewServer
from bsjax.view._studio import Studio as Studio

__all__ = ["Studio", "SurfaceMesh", "ViewServer", "from_file", "live"]
