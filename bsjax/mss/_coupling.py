"""Surface coupling (paper 002 §4.1, thesis §5.3): lattice nodes are the blending-matrix samples
`M = A_u P A_vᵀ` of a B-spline surface, and the control points come back from the nodes by the
stored least-squares refit `P = A_u⁺ M A_v⁺ᵀ` (eq. 3.7) — every step or every N steps."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks
from bsjax._blending import Blending
from bsjax.mss._lattice import Lattice, State, from_material, grid_edges, merge_coincident
from bsjax.mss._materials import Material
from bsjax.mss._rollout import trajectory


class SurfaceCoupling(eqx.Module):
    """Map between the `m × n` sample grid of a `Blending` and the `N` lattice nodes.

    **Fields:** `blending`; `node_map (m, n)`: the node of each sample (coincident samples on a
    closed seam or a pole share one node); `sample (N,)`: the flat sample index of each node.
    """

    blending: Blending
    node_map: Int[Array, "m n"]
    sample: Int[Array, " N"]

    def nodes(self, ctrl: Float[Array, "r s 3"]) -> Float[Array, "N 3"]:
        """Node positions of a control net: the blending samples (eq. 3.6), one per node."""
        return self.blending.points(ctrl).reshape(-1, 3)[self.sample]

    def grid(self, position: Float[Array, "N 3"]) -> Float[Array, "m n 3"]:
        """The `(m, n, 3)` sample grid of node positions."""
        return position[self.node_map]

    def ctrl(self, position: Float[Array, "N 3"]) -> Float[Array, "r s 3"]:
        """Control points of node positions by the stored least-squares refit (eq. 3.7)."""
        return self.blending.refit(self.grid(position))


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
    samples two apart (thesis §5.3, paper 002 §4.1); periodic directions wrap. Samples closer
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
    """Physics every step, control points every `refit_every` steps (e.g. 1 kHz / 50 Hz → 20).

    **Returns:** the final state and the control nets after each block of `refit_every` steps,
    `(n_steps // refit_every, r, s, 3)`. Keyword arguments go to `mss.trajectory`.
    """
    final, saved = trajectory(
        lattice, state, dt, n_steps, external_force, gravity, save_every=refit_every, **kwargs
    )
    return final, jax.vmap(coupling.ctrl)(saved.position)
