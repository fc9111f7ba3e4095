"""Deformable bodies that push on each other (thesis §3.3 and §5.3.3; Gao & Gibson, *Haptic
B-spline surface sculpting with a shaped tool of implicit surface*, §3.2–4.2).

A `Body` is a mass-spring lattice bounded by a B-spline surface: a shell whose outer layer is the
surface's samples, or a VSOFM volume lattice in which the surface's samples are embedded by
trilinear weights (`SurfaceCoupling`). A `Scene` holds bodies, rigid `bsjax.collide` tools, gravity and one
contact model (`collide.DistributedSprings`). Each step of `simulate_scene`:

1. every body's surface is refit from its nodes (`coupling.ctrl`, thesis eq. 3.7; poles kept
   collapsed);
2. every pair of bodies: `collide.surface_penetration` (closest-point depth and normal on both
   sides, within `scene.reach`) → `DistributedSprings.surface_forces` on the samples, each force
   with its equal and opposite reaction at the foot point on the other body;
3. every rigid tool: each node's `push` (closest-point depth and outward normal) → the same
   spring law, the tool taking the reaction;
4. the forces act on the refit surfaces' samples `S(x)` (what the contact sees) and reach the
   nodes by virtual work, `(∂S/∂x)ᵀ f` (coupling weights and refit together; the dampers see
   `(∂S/∂x) v`), so the contact does no work the bodies do not feel; every body takes one
   step with gravity — semi-implicit Euler (`mss.step`), or backward Euler for a stiff body
   (`method="implicit"` or `"linear_implicit"`: its springs implicit, the contact forces
   explicit) — and the prescribed `motion` moves its fixed nodes.

So Σ of the contact forces over all bodies plus the tools' reactions is zero to rounding.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, collide, vsofm
from bsjax._boundary import compiled
from bsjax._declared import check_fields, declared
from bsjax.basis import BSplineSurface
from bsjax.mss._coupling import SurfaceCoupling, pole_sides
from bsjax.mss._forces import tool_contacts
from bsjax.mss._integrators import (
    _check_method,
    _checked_dt,
    _checked_implicit_dt,
    _stable_dt,
    energy,
)
from bsjax.mss._lattice import Lattice, State, hex_lattice
from bsjax.mss._materials import Material
from bsjax.mss._rollout import _kernel, _scan


class Body(eqx.Module):
    """A deformable body: `lattice` (its mass-spring lattice), `surface` (the B-spline surface
    that bounds it, at rest) and `coupling` (its surface samples as lattice nodes)."""

    lattice: Lattice
    surface: BSplineSurface
    coupling: SurfaceCoupling

    def __check_init__(self):
        check_fields(self)

    @classmethod
    def from_surface(
        cls,
        surface: BSplineSurface,
        shape: tuple[int, int, int],
        material: Material,
        *,
        thickness: float | None = None,
        fixed: Callable | np.ndarray | None = None,
        samples: tuple[int, int] | None = None,
        **vsofm_options,
    ) -> Body:
        """The body bounded by `surface`, of lattice `shape = (a, b, c)` and `material`.

        - A **closed** surface (every side periodic or collapsed to a pole: a sphere, a jelly)
          without `thickness`: a volume lattice of `shape` fitted inside it by the VSOFM
          (`bsjax.vsofm.fit` on the surface's samples, then `hex_lattice`; further keyword
          arguments go to `vsofm.fit`: `cycles`, `key`, `settings`), the surface embedded in
          it (`SurfaceCoupling.embedded`: each of the `samples = (m, n)` surface samples —
          default `(2a, 2b)` — moves with the trilinear weights of the cell holding it).
        - An **open** surface (a spoon's bowl, a plate) with `thickness` (m, > 0): a shell
          lattice of `a × b` nodes across the surface (its blending's samples) and `c ≥ 2`
          layers through the thickness, layer k at `S(u, v) − (c−1−k)/(c−1) · thickness ·
          N(u, v)` (the last layer is the surface, the others inward, against the normal); the
          springs of a hexahedral grid (`hex_lattice`), masses from the shell's volume.

        `fixed`: a function of the rest positions `(N, 3) → (N,)` booleans, or a boolean mask
        `(N,)`, of the nodes held in place (a clamp, a hand).
        """
        if not isinstance(surface, BSplineSurface):
            raise TypeError(f"surface: expected a bsjax.basis.BSplineSurface, got {type(surface).__name__}")
        if not isinstance(material, Material):
            raise TypeError(f"material: expected a bsjax.mss.Material, got {type(material).__name__}")
        a, b, c = _checked_shape(shape)
        closed = _is_closed(surface)
        if thickness is None:
            if not closed:
                _checks.fail("thickness", "a shell thickness in m (the surface is open)", None)
            return cls._volume(surface, (a, b, c), material, fixed, samples, vsofm_options)
        if closed or surface.periodic_u or surface.periodic_v:
            _checks.fail(
                "surface", "an open surface for a shell (a closed one: no thickness)", "a closed one"
            )
        if samples is not None or vsofm_options:
            _checks.fail("samples", "None for a shell (its samples are its a × b nodes)", samples)
        r, s = surface.ctrl.shape[:2]
        if a < r or b < s:
            _checks.fail("shape", f"a ≥ {r} and b ≥ {s} (the control net, for the refit)", (a, b, c))
        thickness = float(_checks.positive(np.asarray(thickness, float), "thickness"))
        blending = surface.blending(a, b)
        nodes = _shell_nodes(blending, surface.ctrl, thickness, c)
        rest = nodes.reshape(-1, 3)
        held = None if fixed is None else _fixed_mask(fixed, rest)
        lattice = hex_lattice(nodes, material=material, fixed=held)
        node_map = (np.arange(a * b).reshape(a, b) * c + c - 1).astype(np.int32)
        return cls(lattice, surface, SurfaceCoupling.on_nodes(blending, node_map, lattice.n_nodes))

    def with_ctrl(self, ctrl: Float[ArrayLike, "r s 3"]) -> Body:
        """The shell body whose rest shape follows a new control net `ctrl` of its surface (a
        shape to optimise): its nodes at rest rebuilt as `from_surface` builds them (the
        thickness measured from its own rest layers), its springs' rest lengths their new
        lengths; masses, stiffnesses, fixed nodes and the coupling kept (for small changes of
        shape). Differentiable in `ctrl`. A volume body (its lattice a VSOFM fit) is refused."""
        if self.coupling.node_map.shape[-1] > 1:
            _checks.fail("self", "a shell body (from an open surface with a thickness)", "a volume body")
        want = self.surface.ctrl.shape
        _checks.check_real(ctrl, "ctrl")
        if np.shape(ctrl) != want:
            _checks.fail("ctrl", f"a control net of shape {want}", np.shape(ctrl))
        ctrl = _checks.finite(_checks.array(ctrl, "ctrl", self.surface.ctrl.dtype), "ctrl")
        shape = self.lattice.grid_shape
        assert shape is not None
        layers = self.lattice.rest_positions.reshape(shape + (3,))
        thickness = jnp.mean(jnp.linalg.norm(layers[:, :, -1] - layers[:, :, 0], axis=-1))
        rest = _shell_nodes(self.coupling.blending, ctrl, thickness, shape[2]).reshape(-1, 3)
        i, j = self.lattice.edges[:, 0], self.lattice.edges[:, 1]
        lengths = jnp.linalg.norm(rest[i] - rest[j], axis=-1)
        lattice = eqx.tree_at(
            lambda lat: (lat.rest_positions, lat.rest_length), self.lattice, (rest, lengths)
        )
        return Body(lattice, self.surface.with_ctrl(ctrl), self.coupling)

    @compiled
    def point_load(self, u: ArrayLike, v: ArrayLike, force: Float[ArrayLike, " 3"]) -> Float[Array, "N 3"]:
        """Node forces `(N, 3)` of a force `force (3,)` in N applied at the surface point
        `S(u, v)` (the user's pull or push on the model, thesis §5.3.3, Figs 5.8–5.10).

        The virtual-work equivalent through the coupling and the refit, `f = (∂S(u, v)/∂x)ᵀ F`
        — the map every contact force of a scene takes to the nodes — so the load keeps its
        resultant and its moment: `Σ f_i = F` and `Σ x_i × f_i = S(u, v) × F` at the rest
        positions (the refit commutes with rigid motions). Forces spread over the nodes that
        carry the surface around `(u, v)` (the refit's least squares reach a little further,
        with quickly decaying weights). `u`, `v`: scalars in [0, 1] (traced: a new point does
        not recompile); pass the result as `external_force` to `mss.relax` / `mss.simulate`.
        """
        dtype = self.lattice.rest_positions.dtype
        force = _checks.finite(_checks.vector3(force, "force", dtype), "force")
        u, v = (_parameter(t, name, dtype) for t, name in ((u, "u"), (v, "v")))

        def point(x):
            return self.surface.with_ctrl(self.coupling.ctrl(x)).evaluate(u, v)

        with _checks.trusted():  # checked above; the nodes are the lattice's own rest positions
            _, pull = jax.vjp(point, self.lattice.rest_positions)
        return pull(force)[0]

    @classmethod
    def _volume(cls, surface, shape, material, fixed, samples, vsofm_options) -> Body:
        """A closed surface's VSOFM volume body (`from_surface`)."""
        a, b, _ = shape
        m, n = (2 * a, 2 * b) if samples is None else _checked_samples(samples)
        r, s = surface.ctrl.shape[:2]
        if m < r or n < s:
            _checks.fail("samples", f"m ≥ {r} and n ≥ {s} (the control net, for the refit)", (m, n))
        blending = surface.blending(m, n)
        points = blending.points(surface.ctrl).reshape(-1, 3)
        nodes = vsofm.fit(points, shape, **vsofm_options)
        held = None if fixed is None else _fixed_mask(fixed, nodes.reshape(-1, 3))
        lattice = hex_lattice(nodes, material=material, fixed=held)
        return cls(lattice, surface, SurfaceCoupling.embedded(blending, surface.ctrl, lattice))


def _shell_nodes(blending, ctrl, thickness, layers: int) -> Array:
    """A shell's nodes `(a, b, layers, 3)`: layer k at `S − (layers−1−k)/(layers−1) · thickness
    · N` on the blending's samples (the last layer is the surface, the others inward)."""
    top, normal = blending.points(ctrl), blending.normals(ctrl)
    depth = jnp.linspace(1.0, 0.0, layers, dtype=top.dtype) * thickness
    return top[:, :, None, :] - depth[None, None, :, None] * normal[:, :, None, :]


def _parameter(t, name: str, dtype) -> Array:
    """`t` as a real scalar parameter of `dtype` in [0, 1]."""
    _checks.check_real(t, name)
    if np.shape(t) != ():
        _checks.fail(name, "a scalar parameter", np.shape(t))
    return _checks.in_range(_checks.array(t, name, dtype), name, 0.0, 1.0)


def _is_closed(surface: BSplineSurface) -> bool:
    """Every side of the net is periodic, or collapsed to one point (a pole)."""
    u0, u1, v0, v1 = pole_sides(surface.ctrl)
    return bool((surface.periodic_u or (u0 and u1)) and (surface.periodic_v or (v0 and v1)))


def _checked_samples(samples) -> tuple[int, int]:
    if not (isinstance(samples, (tuple, list)) and len(samples) == 2) or any(
        isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2 for k in samples
    ):
        _checks.fail("samples", "a tuple (m, n) of ints ≥ 2", samples)
    return int(samples[0]), int(samples[1])


def _checked_shape(shape) -> tuple[int, int, int]:
    if not (isinstance(shape, (tuple, list)) and len(shape) == 3):
        _checks.fail("shape", "a tuple (a, b, c) of ints ≥ 2", shape)
    for n in shape:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
            _checks.fail("shape", "a tuple (a, b, c) of ints ≥ 2", shape)
    return int(shape[0]), int(shape[1]), int(shape[2])


def _fixed_mask(fixed, rest) -> Array:
    """`fixed` as a boolean mask over the nodes: a function of the rest positions, or a mask."""
    mask = fixed(rest) if callable(fixed) else fixed
    mask = np.asarray(mask)
    if mask.shape != (rest.shape[0],) or mask.dtype != np.bool_:
        _checks.fail("fixed", f"booleans of shape ({rest.shape[0]},) (or a function giving them)", mask.shape)
    return jnp.asarray(mask)


class Scene(eqx.Module):
    """Bodies, rigid tools, gravity and the contact model of a simulation.

    **Fields:** `bodies`: a tuple of `Body`; `tools`: rigid `bsjax.collide` tools (solid ones:
    `Sphere`, `Ellipsoid`, `Plane`, `Implicit`, `TriangleMesh`); `gravity (3,)` in m/s² or None;
    `contact`: a `collide.DistributedSprings` (default k = 1e3 N/m per sample, c = 0);
    `reach`: the deepest penetration counted between bodies (m; default: the thinnest body's
    shell thickness, or half a volume body's smallest extent — `surface_penetration`).
    """

    bodies: tuple[Body, ...]
    tools: tuple
    gravity: Float[Array, " 3"] | None
    contact: collide.DistributedSprings
    reach: Float[Array, ""]

    @declared
    def __init__(self, bodies: Sequence[Body], tools=(), gravity=None, contact=None, reach=None):
        bodies = tuple(bodies)
        for i, body in enumerate(bodies):
            if not isinstance(body, Body):
                raise TypeError(f"bodies[{i}]: expected a bsjax.mss.Body, got {type(body).__name__}")
        self.bodies = bodies
        self.tools = tuple(tools)
        dtype = bodies[0].lattice.rest_positions.dtype if bodies else jnp.result_type(float)
        if gravity is not None:
            _checks.check_real(gravity, "gravity")
            if np.shape(gravity) != (3,):
                _checks.fail("gravity", "shape (3,)", np.shape(gravity))
            gravity = _checks.finite(_checks.array(gravity, "gravity", dtype), "gravity")
        self.gravity = gravity
        contact = collide.DistributedSprings(1e3) if contact is None else contact
        if not isinstance(contact, collide.DistributedSprings):
            raise TypeError(f"contact: expected a collide.DistributedSprings, got {type(contact).__name__}")
        self.contact = contact
        if reach is None:
            reach = min((_thickness(b, f"bodies[{i}]") for i, b in enumerate(bodies)), default=1.0)
        self.reach = _checks.positive(_checks.array(reach, "reach", dtype), "reach")


def _thickness(body: Body, name: str) -> float:
    """How deep another body may reach into `body`: a shell's thickness (the rest distance from
    its surface node to the innermost one); half the smallest extent of a volume body. A shell
    of one layer (`mss.surface_lattice`) has neither: the scene's `reach` must be given."""
    x = np.asarray(body.lattice.rest_positions)
    if body.coupling.node_map.shape[-1] > 1:  # an embedded surface: a volume lattice
        return 0.5 * float(np.ptp(x, 0).min())
    shape = body.lattice.grid_shape
    if shape is None:
        _checks.fail("reach", f"a value: {name} is a shell of one layer, without a thickness", None)
    grid = x.reshape(shape + (3,))
    return float(np.linalg.norm(grid[0, 0, 0] - grid[0, 0, -1]))


@compiled
def scene_init(scene: Scene) -> tuple[State, ...]:
    """One `State` per body: at rest, zero velocity."""
    return tuple(
        State(b.lattice.rest_positions, jnp.zeros_like(b.lattice.rest_positions)) for b in scene.bodies
    )


@compiled
def scene_contact_forces(scene: Scene, states: Sequence[State]) -> tuple[Float[Array, "N 3"], ...]:
    """The contact force on every node of every body, `(N_i, 3)` per body (module docstring,
    steps 1–4): bodies against each other and against the rigid tools."""
    return _contact_forces(scene, _checked_states(scene, states))[0]


@compiled
def tool_reactions(scene: Scene, states: Sequence[State]) -> Float[Array, "T 3"]:
    """The reaction on every rigid tool, `(T, 3)`: minus the sum of its forces on the nodes."""
    return _contact_forces(scene, _checked_states(scene, states))[1]


@compiled
def scene_energy(scene: Scene, states: Sequence[State]) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """`(kinetic, potential)` of the scene in J: every body's `mss.energy` (springs, gravity)
    plus the contact springs' `½ k Σ d_i²` over the samples of every pair (both sides) and the
    nodes inside the rigid tools. Without input and with damping it does not grow (to the
    integrator's O(Δt) wobble)."""
    states = _checked_states(scene, states)
    kinetic = potential = jnp.zeros((), states[0].position.dtype if states else jnp.result_type(float))
    for body, state in zip(scene.bodies, states):
        k_i, p_i = energy(body.lattice, state, scene.gravity)
        kinetic, potential = kinetic + k_i, potential + p_i
    k = scene.contact.stiffness
    for _, _, ab, ba in _penetrations(scene, states):
        potential = potential + 0.5 * k * (jnp.sum(ab.depth**2) + jnp.sum(ba.depth**2))
    for _, _, depth, _ in _tool_pushes(scene, states):
        potential = potential + 0.5 * k * jnp.sum(depth**2)
    return kinetic, potential


def _checked_states(scene: Scene, states) -> tuple[State, ...]:
    """`states`: one `State` per body, of its lattice's shape, finite."""
    states = tuple(states)
    if len(states) != len(scene.bodies):
        _checks.fail("states", f"{len(scene.bodies)} States (one per body)", f"{len(states)}")
    for i, (body, state) in enumerate(zip(scene.bodies, states)):
        if not isinstance(state, State):
            raise TypeError(f"states[{i}]: expected a bsjax.mss.State, got {type(state).__name__}")
        want = body.lattice.rest_positions.shape
        if state.position.shape != want or state.velocity.shape != want:
            _checks.fail(f"states[{i}]", f"position and velocity of shape {want}", state.position.shape)
    return tuple(
        State(_checks.finite(s.position, "states"), _checks.finite(s.velocity, "states")) for s in states
    )


def _penetrations(scene: Scene, states):
    """`(i, j, i-in-j, j-in-i)` for every pair of bodies: their refit surfaces'
    `collide.surface_penetration` within `scene.reach`."""
    surfaces = [(b.coupling.blending, b.coupling.ctrl(s.position)) for b, s in zip(scene.bodies, states)]
    for i in range(len(surfaces)):
        for j in range(i + 1, len(surfaces)):
            yield (i, j, *collide.surface_penetration(*surfaces[i], *surfaces[j], reach=scene.reach))


def _tool_pushes(scene: Scene, states):
    """`(tool index, body index, depth (N,), normal (N, 3))` for every rigid tool and body
    (`tool_contacts`: the tool's `push`, depth 0 outside it)."""
    for k, state in enumerate(states):
        for t, (depth, normal) in enumerate(tool_contacts(scene.tools, state.position)):
            yield t, k, depth, normal


def _contact_forces(scene: Scene, states):
    """Per-body node forces and per-tool reactions (no checks: `_checks.trusted`, the states
    were checked at the entry and a rollout's step is traced in its loop body). A body's contact
    forces act on its refit surface's samples `S(x) = points(ctrl(x))`, the surface the contact
    sees; they reach the nodes by virtual work, `f_nodes = (∂S/∂x)ᵀ f_samples` (coupling weights
    and refit together), and the dampers see the samples' velocity `(∂S/∂x) v`."""
    with _checks.trusted():
        return _unchecked_contact_forces(scene, states)


def _unchecked_contact_forces(scene: Scene, states):
    dtype = states[0].position.dtype if states else jnp.result_type(float)
    maps = [_surface_map(b, s) for b, s in zip(scene.bodies, states)]
    sample_f = [jnp.zeros(b.coupling.node_map.shape[:2] + (3,), dtype) for b in scene.bodies]
    for i, j, ab, ba in _penetrations(scene, states):
        fi, fj = scene.contact.surface_forces(ab, ba, maps[i][0], maps[j][0])
        sample_f[i], sample_f[j] = sample_f[i] + fi, sample_f[j] + fj
    node_f = [pull(f) for (_, pull), f in zip(maps, sample_f)]
    reactions = [jnp.zeros(3, dtype) for _ in scene.tools]
    for t, k, depth, normal in _tool_pushes(scene, states):
        closing = -jnp.sum(states[k].velocity * normal, -1)  # the tool at rest
        f = scene.contact.magnitudes(depth, closing, depth > 0)[:, None] * normal
        node_f[k] = node_f[k] + f
        reactions[t] = reactions[t] - jnp.sum(f, 0)
    return tuple(node_f), jnp.stack(reactions) if reactions else jnp.zeros((0, 3), dtype)


def _surface_map(body: Body, state: State):
    """`(sample velocities (m, n, 3), pullback)` of the body's refit surface samples
    `S(x) = points(ctrl(x))`: `(∂S/∂x) v` and `f ↦ (∂S/∂x)ᵀ f` (a linear map of the nodes).

    `S` is evaluated by the dense blending products (`banded=False`, the same matrices): their
    transpose is two matrix products, where the band's is a scatter-add per basis function, each
    compiled into a loop kernel of its own on XLA:CPU (first call of a two-body scene −12 %)."""
    dense = dataclasses.replace(body.coupling.blending, banded=False)

    def surface(x):
        return dense.points(body.coupling.ctrl(x))

    _, push = jax.linearize(surface, state.position)  # traced once for both directions
    pull = jax.linear_transpose(push, state.position)
    return push(state.velocity), lambda force: pull(force)[0]


def _methods(scene: Scene, method) -> tuple[str, ...]:
    """`method`: one of `mss.METHODS` for every body, or a sequence of them, one per body."""
    methods = (method,) * len(scene.bodies) if isinstance(method, str) else tuple(method)
    if len(methods) != len(scene.bodies):
        _checks.fail("method", f"a method, or {len(scene.bodies)} (one per body)", f"{len(methods)} methods")
    for m, body in zip(methods, scene.bodies):
        _check_method(m, body.lattice)
    return methods


def _body_limit(body: Body, scene: Scene, method: str) -> tuple[Array, Array, bool]:
    """`(k, c, springs)` of `body`'s explicit limit in the scene: the contact's spring and
    damper times the coupling's load; the lattice's own springs only when it steps explicitly
    (an implicit body takes its contact forces explicitly, its springs implicitly)."""
    gain = body.coupling.load()
    return scene.contact.stiffness * gain, scene.contact.damping * gain, method == "semi_implicit"


def _stable_dt_scene(scene: Scene, dt, methods):
    """`dt`, checked against every body's explicit limit (`scene_stable_dt`) and, for a body
    stepped implicitly, against the overflow of its implicit system."""
    for b, m in zip(scene.bodies, methods):
        k, c, springs = _body_limit(b, scene, m)
        dt = _checked_dt(b.lattice, dt, k, contact_damping=c, springs=springs)
        if not springs:
            dt = _checked_implicit_dt(b.lattice, dt, k)
    return dt


@compiled
def scene_stable_dt(scene: Scene, method: str | Sequence[str] = "semi_implicit") -> Float[Array, ""]:
    """The largest stable step of `simulate_scene` in s: the least over the bodies of
    `mss.stable_dt(lattice, k · load, c · load)`, with the contact model's `k`, `c` and the
    coupling's `load()` (a node carrying several samples feels several contact springs). A body
    stepped with `method="implicit"` counts its contact springs alone (its lattice's springs
    are integrated implicitly: steel, say)."""
    methods = _methods(scene, method)
    limits = [_stable_dt(b.lattice, *_body_limit(b, scene, m)) for b, m in zip(scene.bodies, methods)]
    return jnp.min(jnp.stack(limits)) if limits else jnp.asarray(jnp.inf, scene.reach.dtype)


@compiled
def simulate_scene(
    scene: Scene,
    states: Sequence[State],
    dt: float,
    n_steps: int,
    *,
    motion: Sequence[Callable | None] | None = None,
    method: str | Sequence[str] = "semi_implicit",
    cg_iterations: int = 20,
    checkpoint_every: int | None = None,
    progress: Callable[[int, int], object] | None = None,
) -> tuple[State, ...]:
    """`n_steps` steps of the scene (module docstring) as one `lax.scan`.

    **Arguments:**
    - `scene`; `states` (one per body, `scene_init`); `dt` in s (at most
      `scene_stable_dt(scene, method)`); `n_steps` (static int ≥ 1).
    - `motion`: per body None or a function `t ↦ (rotation (3, 3), translation (3,))` that
      moves the body's fixed nodes rigidly from their rest positions (a tilt, a shaking hand;
      their velocity is its time derivative, by `jax.jvp`).
    - `method`: `"semi_implicit"` (symplectic Euler, `mss.step`), `"implicit"` (linearised
      backward Euler, `mss.implicit_step` with `cg_iterations`) or `"linear_implicit"`
      (backward Euler linearised about the rest shape, solved exactly: `mss.simulate`), for
      all bodies or one per body: an implicit body takes its lattice's springs implicitly and
      the contact forces of the step's start explicitly (IMEX), so a stiff body (a steel bowl)
      does not set the step.
    - `checkpoint_every`: rematerialise chunks of this many steps in the backward pass (memory
      O(n/c + c) states, as `mss.simulate`).
    - `progress`: an optional callback `progress(done, n_steps)` on the host (`mss.simulate`).

    **Returns:** the states after `n_steps`.
    """
    states = _checked_states(scene, states)
    n_steps = _checks.check_count(n_steps, "n_steps")
    _checks.check_progress(progress)
    methods = _methods(scene, method)
    cg_iterations = _checks.check_count(cg_iterations, "cg_iterations")
    if checkpoint_every is not None:
        _checks.check_count(checkpoint_every, "checkpoint_every")
    motion = (None,) * len(scene.bodies) if motion is None else tuple(motion)
    if len(motion) != len(scene.bodies):
        expected = f"{len(scene.bodies)} entries (one per body, None for no motion)"
        _checks.fail("motion", expected, len(motion))
    if not scene.bodies:
        return states
    h = _stable_dt_scene(scene, dt, methods)
    kernels = [_kernel(m, cg_iterations, b.lattice, h) for m, b in zip(methods, scene.bodies)]

    def advance(carry, k):
        node_f, _ = _contact_forces(scene, carry)
        t = (k + 1).astype(h.dtype) * h
        out = []
        for b, s, f, move, step in zip(scene.bodies, carry, node_f, motion, kernels):
            s = step(b.lattice, s, h, f, scene.gravity, (), None, None)  # no tools, rest lengths as built
            out.append(s if move is None else _prescribed(b.lattice, s, move, t))
        return tuple(out), None

    return _scan(advance, states, jnp.arange(n_steps), n_steps, checkpoint_every, progress)


def _prescribed(lattice: Lattice, state: State, move, t) -> State:
    """The fixed nodes at `R(t) X + T(t)` with velocity `Ṙ X + Ṫ` (rest positions `X`)."""
    x = lattice.rest_positions

    def pose(t):
        rotation, translation = move(t)
        return x @ jnp.asarray(rotation, x.dtype).T + jnp.asarray(translation, x.dtype)[None]

    position, velocity = jax.jvp(pose, (jnp.asarray(t, x.dtype),), (jnp.ones((), x.dtype),))
    held = lattice.fixed[:, None]
    return State(jnp.where(held, position, state.position), jnp.where(held, velocity, state.velocity))
