"""Surface coupling (Gao & Gibson, *Haptic sculpting of multi-resolution B-spline surfaces with
shaped tools*, §4.1; thesis §5.3): lattice nodes are the blending-matrix samples
`M = A_u P A_vᵀ` of a B-spline surface, and the control points come back from the nodes by the
stored least-squares refit `P = A_u⁺ M A_v⁺ᵀ` (thesis eq. 3.7) — every step or every N steps.

The one chain from a surface to its deformed surface, `coupled_step`:
surface samples = lattice nodes → contacts (each tool's `push`) → penalty forces on the nodes →
one integration step → refit of the control points. The haptic sculpting model
(`bsjax.device.physics`) and the spoon study (`bsjax.examples.spoon`) run it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax.basis import Blending
from bsjax.mss._integrators import Contact, implicit_step, step
from bsjax.mss._lattice import Lattice, State, from_material, grid_edges, merge_coincident
from bsjax.mss._materials import Material
from bsjax.mss._rollout import trajectory

METHODS = ("semi_implicit", "implicit")


class SurfaceCoupling(eqx.Module):
    """Map between the `m × n` sample grid of a `Blending` and the `N` lattice nodes.

    **Fields:** `blending`; `node_map (m, n)`: the node of each sample (coincident samples on a
    closed seam or a pole share one node); `sample (N,)`: the flat sample index of each node,
    −1 for a node below the surface; `surface_only` (static): every node is a sample (a surface
    lattice from `surface_lattice`), else the surface is one layer of a volumetric lattice
    (`SurfaceCoupling.on_nodes`).
    """

    blending: Blending
    node_map: Int[Array, "m n"]
    sample: Int[Array, " N"]
    surface_only: bool = eqx.field(static=True, default=True)

    @classmethod
    def on_nodes(cls, blending: Blending, node_map, n_nodes: int) -> SurfaceCoupling:
        """The coupling of a volumetric lattice of `n_nodes` whose surface layer is the nodes
        `node_map (m, n)` (e.g. the outer layer of a hexahedral lattice below the surface)."""
        node_map = np.asarray(node_map)
        n_nodes = _checks.check_count(n_nodes, "n_nodes")
        if node_map.shape != tuple(blending.grid_shape):
            _checks.fail("node_map", f"shape {tuple(blending.grid_shape)} (the sample grid)", node_map.shape)
        if not np.issubdtype(node_map.dtype, np.integer) or node_map.min() < 0 or node_map.max() >= n_nodes:
            _checks.fail("node_map", f"integer node ids in [0, {n_nodes})", node_map.dtype)
        sample = np.full(n_nodes, -1, np.int32)
        sample[node_map.ravel()] = np.arange(node_map.size, dtype=np.int32)
        surface_only = bool(np.all(sample >= 0))
        return cls(blending, jnp.asarray(node_map.astype(np.int32)), jnp.asarray(sample), surface_only)

    @compiled
    def nodes(
        self, ctrl: Float[Array, "r s 3"], position: Float[Array, "N 3"] | None = None
    ) -> Float[Array, "N 3"]:
        """Node positions of a control net: the blending samples (thesis eq. 3.6) at the surface
        nodes; nodes below the surface keep `position` (needed unless `surface_only`)."""
        samples = self.blending.points(ctrl).reshape(-1, 3)
        if position is None:
            if not self.surface_only:
                _checks.fail("position", "the node positions (the lattice has nodes below the surface)", None)
            return samples[self.sample]
        on = (self.sample >= 0)[:, None]
        return jnp.where(on, samples[jnp.maximum(self.sample, 0)], position)

    @compiled
    def grid(self, position: Float[Array, "N 3"]) -> Float[Array, "m n 3"]:
        """The `(m, n, 3)` sample grid of node positions."""
        return position[self.node_map]

    @compiled
    def ctrl(self, position: Float[Array, "N 3"]) -> Float[Array, "r s 3"]:
        """Control points of node positions by the stored least-squares refit (thesis eq. 3.7)."""
        return self.blending.refit(position[self.node_map])


@compiled
def coupled_step(
    lattice: Lattice,
    coupling: SurfaceCoupling,
    state: State,
    dt: Float[ArrayLike, ""],
    tools=(),
    contact: Contact | None = None,
    external_force: Float[ArrayLike, "N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    rest_length: Float[ArrayLike, " E"] | None = None,
    *,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
    check_stability: bool = True,
) -> tuple[State, Float[Array, "r s 3"]]:
    """One step of the chain surface → contacts → forces on the lattice nodes → step → refit.

    1. The surface is the lattice's sample nodes (`coupling`; `coupling.nodes(ctrl)` places them).
    2. Contacts: every `bsjax.collide` tool in `tools` (`Sphere`, `Ellipsoid`, `Plane`,
       `Implicit`, `TriangleMesh`) reports each node's penetration depth `δ` and outward normal
       `n` by its `push` (`mss.tool_contacts`).
    3. Forces: penalty `k δ n − c min(v·n, 0) n` (`mss.tool_forces`, `contact = Contact(k, c)`),
       plus springs, node damping, `external_force (N, 3)` and `gravity (3,)`.
    4. Step: semi-implicit Euler (`mss.step`, thesis eqs. 5.14–5.16; `dt` at most
       `stable_dt(lattice, k)` unless `check_stability=False`) or, with `method="implicit"`,
       linearised backward Euler (`mss.implicit_step`, `cg_iterations` CG iterations).
    5. Refit: the control points `P = A_u⁺ M A_v⁺ᵀ` of the new surface nodes (thesis eq. 3.7).

    `rest_length (E,)` overrides the lattice's rest lengths (plastic set).

    **Returns:** `(state, ctrl)`: the new state and the control net `(r, s, 3)` of its surface.
    """
    if method not in METHODS:
        _checks.fail("method", f"one of {METHODS}", repr(method))
    tools = tuple(tools)
    if method == "semi_implicit":
        state = step(
            lattice,
            state,
            dt,
            external_force,
            gravity,
            tools,
            contact,
            rest_length,
            check_stability=check_stability,
        )
    else:
        state = implicit_step(
            lattice, state, dt, external_force, gravity, tools, contact, rest_length, cg_iterations
        )
    return state, coupling.ctrl(state.position)


def surface_lattice(
    blending: Blending,
    ctrl: Float[Array, "r s 3"],
    material: Material | None = None,
    *,
    thickness: float = 0.01,
    stiffness=None,
    damping=None,
    mass=None,
    fixed=None,
    shear: bool = True,
    bending: bool = True,
    node_damping=0.0,
    tol: float | None = None,
) -> tuple[Lattice, SurfaceCoupling]:
    """A surface lattice on the sample grid of `blending` for the control net `ctrl`.

    Structural springs join grid neighbours, shear springs the diagonals, bending springs
    samples two apart (thesis §5.3, Gao & Gibson §4.1); periodic directions wrap. Samples closer
    than `tol` (default `1e-9 ×` the grid's size) merge into one node. Parameters from a
    `material` treat the surface as a shell of `thickness` m; else give `stiffness`, `damping`,
    `mass` (scalars or per spring/node). `fixed`: `(m, n)` mask of samples held in place.

    **Returns:** `(lattice, coupling)`.
    """
    if blending.refit_u is None or blending.refit_v is None:
        _checks.fail(
            "blending", "a full grid with a stored refit (m >= r, n >= s)", f"grid {blending.grid_shape}"
        )
    points = np.asarray(blending.points(ctrl))
    if tol is None:
        tol = 1e-9 * max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-300)
    first, node_map = merge_coincident(points, tol)
    edges = grid_edges(node_map, blending.periodic_u, blending.periodic_v, shear, bending)
    x = jnp.asarray(points.reshape(-1, 3)[first], dtype=jnp.asarray(ctrl).dtype)
    fixed_nodes = None
    if fixed is not None:
        fixed = np.asarray(fixed)
        if fixed.shape != points.shape[:2] or fixed.dtype != bool:
            _checks.fail(
                "fixed", f"a boolean mask of shape {points.shape[:2]}", f"{fixed.dtype} {fixed.shape}"
            )
        fixed_nodes = jnp.asarray(
            np.bincount(node_map.ravel(), weights=fixed.ravel(), minlength=len(first)) > 0
        )
    if material is not None:
        lattice = from_material(
            x, edges, material, _grid_area(points) * thickness, fixed_nodes, node_damping=node_damping
        )
    else:
        if stiffness is None or damping is None or mass is None:
            _checks.fail("stiffness, damping, mass", "all three, or a material", "some missing")
        lattice = Lattice(x, edges, stiffness, damping, mass, fixed_nodes, node_damping=node_damping)
    return lattice, SurfaceCoupling(blending, jnp.asarray(node_map), jnp.asarray(first.astype(np.int32)))


def _grid_area(points: np.ndarray) -> float:
    """Area of a sample grid as two triangles per cell."""
    p = points
    a, b, c, d = p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]
    t1 = np.linalg.norm(np.cross(b - a, c - a), axis=-1)
    t2 = np.linalg.norm(np.cross(c - a, d - a), axis=-1)
    return 0.5 * float(np.sum(t1 + t2))


@compiled
def simulate_coupled(
    lattice: Lattice,
    coupling: SurfaceCoupling,
    state: State,
    dt,
    n_steps: int,
    refit_every: int,
    external_force=None,
    gravity=None,
    **kwargs,
) -> tuple[State, Float[Array, "k r s 3"]]:
    """Physics every step, control points every `refit_every` steps (e.g. 1 kHz / 50 Hz → 20):
    the chain of `coupled_step` as one rollout (`mss.trajectory`, a `lax.scan`).

    **Arguments:** as `coupled_step`; `n_steps` and `refit_every` ints ≥ 1, `refit_every`
    dividing `n_steps`. Keyword arguments go to `mss.trajectory` (`tools`, `tool_path`,
    `contact`, `method`, `cg_iterations`, `check_stability`).

    **Returns:** the final state and the control nets after each block of `refit_every` steps,
    `(n_steps // refit_every, r, s, 3)`.
    """
    final, saved = trajectory(
        lattice, state, dt, n_steps, external_force, gravity, save_every=refit_every, **kwargs
    )
    return final, jax.vmap(coupling.ctrl)(saved.position)
