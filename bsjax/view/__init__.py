"""The live 3-D view of a haptic session (or a saved surface or recording) in the browser."""

from bsjax.view._scene import SurfaceMesh as SurfaceMesh
from bsjax.view._scene import from_file as from_file
from bsjax.view._scene import live as live
from bsjax.view._server import ViewServer as ViewServer

__all__ = ["SurfaceMesh", "ViewServer", "from_file", "live"]
