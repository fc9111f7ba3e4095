"""Collision detection and contact forces for deformable B-spline surfaces (the thesis, ch. 3).

- Tools: `Point`, `Sphere`, `Ellipsoid`, `Plane`, `Implicit`, `TriangleMesh`.
- Queries: `contacts(blending, ctrl, tool)` → `Contact`;
  `surface_contacts(blending_a, ctrl_a, blending_b, ctrl_b)` → `SurfaceContact`;
  `surface_penetration(blending_a, ctrl_a, blending_b, ctrl_b, reach=…)` → a `Penetration` per
  side (per-sample closest-point depth and contact normal).
- Meshing: `grid_mesh` (the sample grid as triangles).
- Forces: the contact model `DistributedSprings` (Gao & Gibson eq. 3.3: per-sample springs, equal
  and opposite pairs); `contact_force` (the force on a tool) and
  `sample_forces` (its reaction on the surface samples).
"""

from bsjax.collide._contact import Contact, SurfaceContact, contacts, surface_contacts
from bsjax.collide._force import DistributedSprings, contact_force, sample_forces
from bsjax.collide._hierarchy import grid_mesh
from bsjax.collide._mesh_bvh import FaceTree
from bsjax.collide._penetration import Penetration, surface_penetration
from bsjax.collide._tools import (
    AbstractTool,
    Ellipsoid,
    Implicit,
    Plane,
    Point,
    Sphere,
    TriangleMesh,
)

__all__ = [
    "AbstractTool",
    "Contact",
    "DistributedSprings",
    "Ellipsoid",
    "FaceTree",
    "Implicit",
    "Penetration",
    "Plane",
    "Point",
    "Sphere",
    "SurfaceContact",
    "TriangleMesh",
    "contact_force",
    "contacts",
    "grid_mesh",
    "sample_forces",
    "surface_contacts",
    "surface_penetration",
]
