"""Collision detection and contact forces for deformable B-spline surfaces (the thesis, ch. 3).

- Tools: `Point`, `Sphere`, `Ellipsoid`, `Plane`, `Implicit`, `TriangleMesh`.
- Queries: `contacts(blending, ctrl, tool)` → `Contact`;
  `surface_contacts(blending_a, ctrl_a, blending_b, ctrl_b)` → `SurfaceContact`;
  `surface_penetration(blending_a, ctrl_a, blending_b, ctrl_b, reach=…)` → a `Penetration` per
  side (per-sample closest-point depth and contact normal).
- Kernels: `triangles_intersect`, `closest_point_on_triangle`, `hulls_apart`, `tessellate`.
- Forces: the contact model `DistributedSprings` (Gao & Gibson eq. 3.3: per-sample springs, equal
  and opposite pairs); `contact_force`, `sample_forces`, `nodal_forces`.
"""

from bsjax.collide.broad import hulls_apart, parametric_window
from bsjax.collide.contact import Contact, SurfaceContact, contacts, sample_window, surface_contacts
from bsjax.collide.force import DistributedSprings, contact_force, nodal_forces, sample_forces
from bsjax.collide.hierarchy import cell_triangles, sphere_hierarchy, tessellate
from bsjax.collide.penetration import Penetration, surface_penetration
from bsjax.collide.tools import (
    AbstractTool,
    Ellipsoid,
    Implicit,
    Plane,
    Point,
    ProjectionSolver,
    Sphere,
    TriangleMesh,
)
from bsjax.collide.triangles import closest_point_on_triangle, triangles_intersect

__all__ = [
    "AbstractTool",
    "Contact",
    "DistributedSprings",
    "Ellipsoid",
    "Implicit",
    "Penetration",
    "Plane",
    "Point",
    "ProjectionSolver",
    "Sphere",
    "SurfaceContact",
    "TriangleMesh",
    "cell_triangles",
    "closest_point_on_triangle",
    "contact_force",
    "contacts",
    "hulls_apart",
    "nodal_forces",
    "parametric_window",
    "sample_forces",
    "sample_window",
    "sphere_hierarchy",
    "surface_contacts",
    "surface_penetration",
    "tessellate",
    "triangles_intersect",
]
