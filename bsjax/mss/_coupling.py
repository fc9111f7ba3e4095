"""Surface coupling (Gao & Gibson, *Haptic B-spline surface sculpting with a shaped
tool of implicit surface*, §4.1; thesis §5.3): lattice nodes are the blending-matrix samples
`M = A_u P A_vᵀ` of a B-spline surface, and the control points come back from the nodes by the
stored least-squares refit `P = A_u⁺ M A_v⁺ᵀ` (thesis eq. 3.7) — every step or every N steps.

The one chain from a surface to its deformed surface, `coupled_step`:
surface samples = lattice nodes → contacts (each tool's `push`) → penalty forces on the nodes →
one integration step → refit of the control points. The haptic sculpting model
(`bsjax.device._physics`) and the spoon study (`bsjax.examples.spoon`) run it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from bsjax import _checks
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax.basis import Blending
from bsjax.mss._integrators import Penalty, _check_method, implicit_step, step
from bsjax.mss._lattice import Lattice, State, from_material, grid_edges, merge_coincident
from bsjax.mss._materials import Material
from bsjax.mss._rollout import trajectory


class SurfaceCoupling(eqx.Module):
    """Map between the `m × n` sample grid of a `Blending` and the `N` lattice nodes: each
    sample is a weighted sum of `K` nodes, and a force on a sample goes to those nodes with the
    same weights (the transpose).

    **Fields:** `blending`; `node_map (m, n, K)`: the nodes carrying each sample; `weights
    (m, n, K)`: their weights, summing to 1 per sample — `K = 1`, weight 1, where the samples
    are nodes (a surface lattice from `surface_lattice`, the outer layer of a shell,
    `SurfaceCoupling.on_nodes`; coincident samples on a closed seam or a pole share one node);
    `K = 8` trilinear weights of the hexahedral cell holding the sample where the surface is
    embedded in a volume lattice (`SurfaceCoupling.embedded`, SOFA's barycentric mapping);
    `sample (N,)`: the flat sample index of each node that is a sample, −1 otherwise;
    `surface_only` (static): every node is a sample; `poles` (static): which sides of the
    control net (u = 0, u = 1, v = 0, v = 1) are collapsed to a point at rest — the refit
    keeps them collapsed (`ctrl`).
    """

    blending: Blending
    node_map: Int[Array, "m n K"]
    weights: Float[Array, "m n K"]
    sample: Int[Array, " N"]
    surface_only: bool = eqx.field(static=True, default=True)
    poles: tuple[bool, bool, bool, bool] = eqx.field(static=True, default=(False, False, False, False))

    @classmethod
    def on_nodes(cls, blending: Blending, node_map, n_nodes: int) -> SurfaceCoupling:
        """The coupling of a lattice of `n_nodes` whose surface samples are the nodes
        `node_map (m, n)` (e.g. the outer layer of a hexahedral lattice below the surface)."""
        node_map = np.asarray(node_map)
        n_nodes = _checks.check_count(n_nodes, "n_nodes")
        if node_map.shape != tuple(blending.grid_shape):
            _checks.fail("node_map", f"shape {tuple(blending.grid_shape)} (the sample grid)", node_map.shape)
        if not np.issubdtype(node_map.dtype, np.integer) or node_map.min() < 0 or node_map.max() >= n_nodes:
            _checks.fail("node_map", f"integer node ids in [0, {n_nodes})", node_map.dtype)
        sample = np.full(n_nodes, -1, np.int32)
        sample[node_map.ravel()] = np.arange(node_map.size, dtype=np.int32)
        return cls._direct(blending, node_map, sample)

    @classmethod
    def _direct(
        cls, blending: Blending, node_map: np.ndarray, sample: np.ndarray, poles=(False,) * 4
    ) -> SurfaceCoupling:
        """Samples that are nodes: `node_map (m, n)`, `sample (N,)` (−1 where a node is none)."""
        ids = jnp.asarray(node_map.astype(np.int32)[..., None])
        ones = jnp.ones(ids.shape, blending.a_u.dtype)
        surface_only = bool(np.all(sample >= 0))
        return cls(blending, ids, ones, jnp.asarray(sample.astype(np.int32)), surface_only, poles)

    @classmethod
    def embedded(
        cls, blending: Blending, ctrl: Float[ArrayLike, "r s 3"], lattice: Lattice
    ) -> SurfaceCoupling:
        """The surface `blending.points(ctrl)` embedded in the hexahedral `lattice` (a
        `grid_shape`, e.g. `hex_lattice` on `vsofm.fit` nodes): each sample gets the trilinear
        coordinates of the cell holding it at rest (Newton's method on the trilinear map; a
        sample just outside the lattice — the surface's sag between boundary nodes — in the
        nearest cell, its coordinates slightly beyond [0, 1]), so `grid(rest_positions)` is the
        surface's samples to rounding and the samples move with the cells around them.

        Refused: a lattice without a grid, or a sample more than a cell outside it (a coarse
        VSOFM lattice leaves up to about half a cell between its boundary faces and the
        surface where box edges meet it).
        """
        cells = lattice.grid_shape if isinstance(lattice, Lattice) else None
        if cells is None:
            _checks.fail("lattice", "a hexahedral mss.Lattice (with a grid_shape)", type(lattice).__name__)
        samples = np.asarray(blending.points(jnp.asarray(ctrl)), np.float64)
        grid = np.asarray(lattice.rest_positions, np.float64).reshape(cells + (3,))
        ids, weights = trilinear_embedding(samples.reshape(-1, 3), grid)
        shape = tuple(blending.grid_shape) + (8,)
        dtype = lattice.rest_positions.dtype
        sample = jnp.full(lattice.n_nodes, -1, jnp.int32)
        ids, weights = jnp.asarray(ids.reshape(shape)), jnp.asarray(weights.reshape(shape), dtype)
        return cls(blending, ids, weights, sample, False, pole_sides(ctrl))

    @property
    def n_nodes(self) -> int:
        """`N`, the lattice's node count."""
        return self.sample.shape[0]

    def load(self) -> Float[Array, ""]:
        """The largest stiffness gain a contact spring on every sample puts on one node:
        `max_j Σ_s |w_sj| Σ_k |w_sk|` (a Gershgorin bound on `WᵀW`, W the `(samples, N)`
        weights). 1 where each node carries one sample; a pole node of a surface lattice carries
        a row of samples, an embedded surface's nodes several. Springs of stiffness k on the
        samples stiffen a node by at most `k · load()` (`scene_stable_dt`)."""
        w = jnp.abs(self.weights)
        row = jnp.sum(w, -1, keepdims=True)
        per_node = jax.ops.segment_sum((w * row).reshape(-1), self.node_map.reshape(-1), self.n_nodes)
        return jnp.max(per_node)

    @compiled
    def nodes(
        self, ctrl: Float[Array, "r s 3"], position: Float[Array, "N 3"] | None = None
    ) -> Float[Array, "N 3"]:
        """Node positions of a control net: the blending samples (thesis eq. 3.6) at the surface
        nodes; nodes below the surface keep `position` (needed unless `surface_only`). Only for
        couplings whose samples are nodes (`K = 1`): an embedded surface places no nodes."""
        if self.node_map.shape[-1] != 1:
            _checks.fail(
                "coupling", "samples that are nodes (an embedded surface places no nodes)", "embedded"
            )
        samples = self.blending.points(ctrl).reshape(-1, 3)
        if position is None:
            if not self.surface_only:
                _checks.fail("position", "the node positions (the lattice has nodes below the surface)", None)
            return samples[self.sample]
        on = (self.sample >= 0)[:, None]
        return jnp.where(on, samples[jnp.maximum(self.sample, 0)], position)

    @compiled
    def grid(self, position: Float[Array, "N 3"]) -> Float[Array, "m n 3"]:
        """The `(m, n, 3)` samples carried by node positions (or velocities): `Σ_k w_k x_k`."""
        return jnp.einsum("mnk,mnkd->mnd", self.weights, position[self.node_map])

    @compiled
    def ctrl(self, position: Float[Array, "N 3"]) -> Float[Array, "r s 3"]:
        """Control points of node positions by the stored least-squares refit (thesis eq. 3.7),
        each pole side (`poles`) then set to its mean: a pole stays a point, so the deformed
        surface keeps its topology and a well-defined normal there (a refit pole opened by
        rounding has a tiny, noisy `T_v` and a normal of any direction)."""
        ctrl = self.blending.refit(self.grid(position))
        for side, (axis, first) in zip(self.poles, ((0, True), (0, False), (1, True), (1, False))):
            if side:  # static slices and a concatenation (no gather, no scatter)
                net = ctrl if axis == 0 else jnp.swapaxes(ctrl, 0, 1)
                row = net[:1] if first else net[-1:]
                mean = jnp.broadcast_to(jnp.mean(row, 1, keepdims=True), row.shape)
                net = jnp.concatenate([mean, net[1:]] if first else [net[:-1], mean])
                ctrl = net if axis == 0 else jnp.swapaxes(net, 0, 1)
        return ctrl


def pole_sides(ctrl) -> tuple[bool, bool, bool, bool]:
    """Which sides of a control net `(r, s, 3)` — u = 0, u = 1, v = 0, v = 1 — are collapsed to
    one point (within `1e-9` of the net's extent): the poles of a sphere-like surface."""
    p = np.asarray(ctrl)
    scale = max(float(np.ptp(p.reshape(-1, 3), 0).max()), 1e-300)

    def collapsed(edge):  # (k, 3) control points of one side
        return bool(np.all(np.linalg.norm(edge - edge[:1], axis=-1) <= 1e-9 * scale))

    return collapsed(p[0]), collapsed(p[-1]), collapsed(p[:, 0]), collapsed(p[:, -1])


_CORNERS = np.array([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)])  # C order


def trilinear_embedding(points: np.ndarray, grid: np.ndarray, candidates: int = 8):
    """`(ids (P, 8), weights (P, 8))`: the trilinear coordinates of `points (P, 3)` in the cells of
    the node grid `grid (a, b, c, 3)` (host, NumPy). For each point the cells around its
    `candidates` nearest nodes are tried (Newton's method on `x(ξ) = Σ N_c(ξ) X_c`, 20 steps
    from the cell centre) and the one whose `ξ` lies least outside `[0, 1]³` is kept."""
    from scipy.spatial import cKDTree

    a, b, c = grid.shape[:3]
    flat = grid.reshape(-1, 3)
    near = cKDTree(flat).query(points, k=min(candidates, len(flat)))[1].reshape(len(points), -1)
    ijk = np.stack(np.unravel_index(near, (a, b, c)), -1)  # (P, q, 3)
    lo = (ijk[:, :, None, :] - _CORNERS[None, None]).reshape(len(points), -1, 3)  # cells at the nodes
    lo = np.clip(lo, 0, np.array([a - 2, b - 2, c - 2]))
    corner_ids = np.ravel_multi_index(tuple(np.moveaxis(lo[:, :, None] + _CORNERS, -1, 0)), (a, b, c))
    xi, residual = _invert_trilinear(flat[corner_ids], points[:, None, :])
    outside = np.sum(np.maximum(0.0, -xi) + np.maximum(0.0, xi - 1.0), -1) + residual
    best = np.argmin(outside, 1)
    rows = np.arange(len(points))
    worst = float(outside[rows, best].max()) if len(points) else 0.0
    if worst > 1.0:
        _checks.fail(
            "lattice", "a lattice whose cells hold the surface's samples", f"a sample {worst:.2g} cells out"
        )
    return corner_ids[rows, best].astype(np.int32), _trilinear_weights(xi[rows, best])


def _trilinear_weights(xi: np.ndarray) -> np.ndarray:
    """`(…, 8)` weights `N_c(ξ) = Π_d (ξ_d if c_d else 1 − ξ_d)` of the corners `_CORNERS`."""
    return np.prod(np.where(_CORNERS == 1, xi[..., None, :], 1.0 - xi[..., None, :]), -1)


def _invert_trilinear(corners: np.ndarray, x: np.ndarray, steps: int = 20):
    """`(ξ (…, 3), residual (…,))` with `Σ N_c(ξ) corners_c = x` (Newton; residual in cell sizes)."""
    xi = np.full(corners.shape[:-2] + (3,), 0.5)
    size = np.linalg.norm(corners[..., -1, :] - corners[..., 0, :], axis=-1) + 1e-300
    sign = np.where(_CORNERS == 1, 1.0, -1.0)  # d N_c / d ξ_d factor
    for _ in range(steps):
        w = _trilinear_weights(xi)
        r = np.einsum("...c,...cd->...d", w, corners) - x
        f = np.where(_CORNERS == 1, xi[..., None, :], 1.0 - xi[..., None, :])  # (…, 8, 3)
        grad = np.stack(
            [sign[:, d] * np.prod(np.delete(f, d, axis=-1), -1) for d in range(3)], -1
        )  # (…, 8, 3): dN_c/dξ_d
        jac = np.einsum("...cd,...ce->...de", corners, grad)  # (…, 3 xyz, 3 ξ)
        step = np.linalg.solve(jac + 1e-300 * np.eye(3), r[..., None])[..., 0]
        xi = np.clip(xi - step, -2.0, 3.0)
    w = _trilinear_weights(xi)
    r = np.einsum("...c,...cd->...d", w, corners) - x
    return xi, np.linalg.norm(r, axis=-1) / size


@compiled
def coupled_step(
    lattice: Lattice,
    coupling: SurfaceCoupling,
    state: State,
    dt: Float[ArrayLike, ""],
    tools=(),
    contact: Penalty | None = None,
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
       `n` by its `push` (`bsjax.mss._forces.tool_contacts`).
    3. Forces: penalty `k δ n − c min(v·n, 0) n` (`mss.tool_forces`, `contact = Penalty(k, c)`),
       plus springs, node damping, `external_force (N, 3)` and `gravity (3,)`.
    4. Step: semi-implicit Euler (`mss.step`, thesis eqs. 5.14–5.16; `dt` at most
       `stable_dt(lattice, k)` unless `check_stability=False`) or, with `method="implicit"`,
       linearised backward Euler (`mss.implicit_step`, `cg_iterations` CG iterations).
    5. Refit: the control points `P = A_u⁺ M A_v⁺ᵀ` of the new surface nodes (thesis eq. 3.7).

    `rest_length (E,)` overrides the lattice's rest lengths (plastic set).

    **Returns:** `(state, ctrl)`: the new state and the control net `(r, s, 3)` of its surface.
    """
    _check_method(method)
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


@declared
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
    return lattice, SurfaceCoupling._direct(blending, node_map, first, pole_sides(ctrl))


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
    with _checks.trusted():  # the rollout's own states (the entry checked the start)
        return final, jax.vmap(coupling.ctrl)(saved.position)
