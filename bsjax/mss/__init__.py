"""Mass-spring-damper physics (thesis ch. 5; Gao & Gibson, *Haptic sculpting of
multi-resolution B-spline surfaces with shaped tools*, §4): lattices, materials, forces,
integrators, surface coupling.

Pure functions over pytrees: `init(lattice) -> State`, `step(lattice, state, dt, …) -> State`,
`simulate(lattice, state, dt, n_steps, …) -> State` (a `lax.scan`). Rigid tools are the solid
`bsjax.collide` tools (`RigidSphere`/`RigidPlane` are `collide.Sphere`/`collide.Plane`);
`coupled_step` is the chain surface → contacts → forces → step → refit.
"""

from bsjax.mss._coupling import (
    SurfaceCoupling,
    coupled_step,
    simulate_coupled,
    surface_lattice,
)
from bsjax.mss._forces import (
    RigidPlane,
    RigidSphere,
    behind_plane,
    contact_tangent,
    edge_lengths,
    edge_sum,
    plane_penalty,
    sphere_penalty,
    spring_forces,
    tool_contacts,
    tool_forces,
)
from bsjax.mss._integrators import (
    Contact,
    Plasticity,
    check_dt,
    energy,
    forces,
    implicit_step,
    stable_dt,
    step,
)
from bsjax.mss._lattice import (
    HEX_DIRECTIONS,
    Lattice,
    State,
    from_material,
    grid_edges,
    hex_edges,
    hex_lattice,
    hex_volume,
    init,
)
from bsjax.mss._materials import (
    JELLY,
    PLASTICINE,
    PRESETS,
    STEEL,
    Material,
    damping_ratio,
    natural_frequency,
    spring_damping,
    spring_stiffness,
)
from bsjax.mss._rollout import relax, simulate, simulate_plastic, trajectory, yield_rest_lengths

__all__ = [
    "HEX_DIRECTIONS",
    "JELLY",
    "PLASTICINE",
    "PRESETS",
    "STEEL",
    "Contact",
    "Lattice",
    "Material",
    "Plasticity",
    "RigidPlane",
    "RigidSphere",
    "State",
    "SurfaceCoupling",
    "behind_plane",
    "check_dt",
    "contact_tangent",
    "coupled_step",
    "damping_ratio",
    "edge_lengths",
    "edge_sum",
    "energy",
    "forces",
    "from_material",
    "grid_edges",
    "hex_edges",
    "hex_lattice",
    "hex_volume",
    "implicit_step",
    "init",
    "natural_frequency",
    "plane_penalty",
    "relax",
    "simulate",
    "simulate_coupled",
    "simulate_plastic",
    "sphere_penalty",
    "spring_damping",
    "spring_forces",
    "spring_stiffness",
    "stable_dt",
    "step",
    "surface_lattice",
    "tool_contacts",
    "tool_forces",
    "trajectory",
    "yield_rest_lengths",
]
