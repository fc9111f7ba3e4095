"""Mass-spring-damper physics (thesis ch. 5; Gao & Gibson, *Haptic B-spline surface
sculpting with a shaped tool of implicit surface*, §4): lattices, materials, forces,
integrators, surface coupling.

Pure functions over pytrees: `init(lattice) -> State`, `step(lattice, state, dt, …) -> State`,
`simulate(lattice, state, dt, n_steps, …) -> State` (a `lax.scan`). Rigid tools are the solid
`bsjax.collide` tools (`collide.Sphere`, `collide.Plane`, …);
`coupled_step` is the chain surface → contacts → forces → step → refit.
"""

from bsjax.mss._coupling import (
    SurfaceCoupling,
    coupled_step,
    simulate_coupled,
    surface_lattice,
)
from bsjax.mss._forces import (
    behind_plane,
    edge_lengths,
    tool_forces,
)
from bsjax.mss._integrators import (
    Penalty,
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
    hex_edges,
    hex_lattice,
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
from bsjax.mss._scene import (
    Body,
    Scene,
    scene_contact_forces,
    scene_energy,
    scene_init,
    scene_stable_dt,
    simulate_scene,
    tool_reactions,
)

__all__ = [
    "HEX_DIRECTIONS",
    "JELLY",
    "PLASTICINE",
    "PRESETS",
    "STEEL",
    "Body",
    "Lattice",
    "Material",
    "Penalty",
    "Plasticity",
    "Scene",
    "State",
    "SurfaceCoupling",
    "behind_plane",
    "check_dt",
    "coupled_step",
    "damping_ratio",
    "edge_lengths",
    "energy",
    "forces",
    "from_material",
    "hex_edges",
    "hex_lattice",
    "implicit_step",
    "init",
    "natural_frequency",
    "relax",
    "scene_contact_forces",
    "scene_energy",
    "scene_init",
    "scene_stable_dt",
    "simulate",
    "simulate_coupled",
    "simulate_plastic",
    "simulate_scene",
    "spring_damping",
    "spring_stiffness",
    "stable_dt",
    "step",
    "surface_lattice",
    "tool_forces",
    "tool_reactions",
    "trajectory",
    "yield_rest_lengths",
]
