"""The slow loop's model: a deformable B-spline surface over a volumetric mass-spring lattice.

Dual representation (Gao & Gibson §4.1, Dachille & Qin): the lattice's outer layer is an `m × n`
grid of samples of the surface at fixed parameters, so after each physics tick the control net
is the least-squares refit of those nodes, `P = A_u^+ M (A_v^+)^T` (thesis eq. 3.7,
`Blending.refit`). Below the surface the lattice has `layers − 1` more layers shrunk towards
the axis of a body closed in v (the teardrop: each u-ring scaled about its centroid), or
extruded along −normal for an open sheet; the innermost layers are fixed. Dynamics: `bsjax.mss` —
`mss.hex_lattice` on the `m × n × layers` node grid (edges, face and body diagonals, dense-slice
kernel), plus, for a body closed in v, a small edge-list `mss.Lattice` of the springs across the
v seam. Each tick runs `substeps` times the chain `mss.coupled_step` (surface → contacts → forces
on the lattice nodes → semi-implicit Euler step, thesis eqs. 5.14–5.16 → refit) inside one
jitted call, with the surface layer mapped by `mss.SurfaceCoupling.on_nodes`; `mss.check_dt`
refuses an unstable step once, at construction; the seam springs (summed by dense slices) enter
as `external_force`, plasticity (the plastic set on release) as `rest_length`. For speed the tick
runs `mss.step`'s kernel without its per-call value checks (one check of every output instead)
and the refit once, after the last substep; `tests/test_mss_haptic.py` holds it equal to the
checked chain to 1e-12.

Sculpting (002 §4.2): while the stylus button is held, every node inside the tool (a
`collide.Sphere`, or a `collide.Ellipsoid` at the stylus pose) gets the penalty force
`k_tool · depth · normal` of the tool's `push` (closest-point depth, outward normal) — a push
from outside, a pull when the tool sits inside the body and moves out. When the button is
released the deformation is set: rest lengths become the current lengths (plastic set).

Haptic proxy: the refit surface is sampled on a denser grid. In contact, `bsjax.collide`
(`contacts` with an `Ellipsoid` tool, `contact_force`) gives the distributed-spring force of 002
§3.2 (`F = k Σ d_i` along `Σ N_i d_i`, surface-normal method) and the proxy is the plane along
that direction placed so that it renders exactly `F` at the tool centre. Out of contact, the
sample nearest the tool centre and its normal give the plane. The normal points to the side the
tool came from, latched while in contact (so passing through the wall keeps pushing back, 002
§3.2.3); the proxy's `tool_radius` is the tool's support distance along the normal. While the
button is held, the plane is moved back by the nodes' summed reaction on the tool (times
`reaction_gain`, over the proxy stiffness), so the user feels the material give way but push back.

Safety: a pose is validated where it enters `update` — a non-finite position or
orientation, or a tool centre farther than `reach` from the body, is dropped and counted
(`dropped_poses`) and never fed to the physics. After every tick the new lattice state, rest
lengths, control net and proxy data are checked inside the same jitted call; if anything went
non-finite the tick is rolled back (the last good state is kept, counted in `rollbacks`), so one
bad pose cannot poison the model: the next good pose renders the normal force. Either way
`update` returns the last good proxy; after `max_rollbacks` bad ticks in a row it raises (the
servo's physics thread stops and its watchdog ramps the force to zero).

`SculptModel` is the model interface the servo loop needs (`warmup()`, `update(sample) -> Proxy`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from bsjax import _checks, _safe, collide, mss, shapes
from bsjax._boundary import precise
from bsjax.device._model import AbstractHapticModel
from bsjax.device._protocol import DeviceSample, positive_number
from bsjax.device._proxy import Proxy
from bsjax.mss._forces import _grid_sum, _pair_force
from bsjax.mss._integrators import _position_step, _velocity_step


@runtime_checkable
class PhysicsModel(Protocol):
    """What `ServoLoop` runs in its physics thread."""

    def warmup(self) -> None:
        """Compile every jitted function (called once, before the threads start)."""
        ...

    def update(self, sample: DeviceSample) -> Proxy:
        """Advance one physics tick with the tool at `sample`'s pose; return the new proxy."""
        ...


def seam_edges(m: int, n: int, layers: int) -> np.ndarray:
    """`(E, 2)` springs of the `mss.HEX_DIRECTIONS` stencil that cross the v seam of a body
    closed in v (from column `b` to `(b + db) mod n` where `b + db` leaves `0..n−1`), node ids in
    C order of the `(m, n, layers)` grid. `mss.hex_lattice` has every other spring."""
    idx = np.arange(m * n * layers).reshape(m, n, layers)
    a, b, c = np.meshgrid(np.arange(m), np.arange(n), np.arange(layers), indexing="ij")
    pairs = []
    for da, db, dc in mss.HEX_DIRECTIONS:
        b2 = b + db
        ok = (a + da < m) & (c + dc >= 0) & (c + dc < layers) & ((b2 < 0) | (b2 >= n))
        pairs.append(np.stack([idx[ok], idx[a[ok] + da, b2[ok] % n, c[ok] + dc]], axis=-1))
    return np.concatenate(pairs).astype(np.int32)


def lattice_nodes(
    surface_points: np.ndarray, normals: np.ndarray, layers: int, periodic_v: bool, thickness: float
) -> np.ndarray:
    """`(m, n, layers, 3)` node positions; layer `layers − 1` is the surface grid itself."""
    rho = (np.arange(layers) + 1.0) / layers
    if periodic_v:
        centre = surface_points.mean(axis=1, keepdims=True)
        return centre[:, :, None] + rho[None, None, :, None] * (surface_points - centre)[:, :, None]
    return surface_points[:, :, None] - ((1.0 - rho) * thickness)[None, None, :, None] * normals[:, :, None]


def check_step(lattice, dt: float, tool_stiffness: float) -> None:
    """`ValueError` when `dt` exceeds the semi-implicit Euler limit (`mss.check_dt`) of the
    lattice with the tool's contact stiffness."""
    try:
        mss.check_dt(lattice, dt, contact_stiffness=tool_stiffness)
    except ValueError as err:
        raise ValueError(
            f"substeps: the explicit step is unstable for this material ({err}); "
            "raise substeps or lower the stiffness"
        ) from None


def _is_sphere(axes) -> bool:
    """Equal semi-axes: the tool is a `collide.Sphere` (its push is closed-form)."""
    return bool(np.all(np.asarray(axes) == np.asarray(axes)[0]))


def quat_to_matrix(q) -> np.ndarray:
    """Unit quaternion `w x y z` → rotation matrix."""
    w, x, y, z = (float(c) for c in q)
    n = w * w + x * x + y * y + z * z
    if not n > 0:
        return np.eye(3)
    s = 2.0 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
            [s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)],
            [s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)],
        ]
    )


class SculptModel(AbstractHapticModel):
    """Teardrop (or any surface) on a volumetric mass-spring lattice, sculpted by a sphere/ellipsoid.

    **Arguments:**
    - `surface`: a `BSplineSurface` (default `shapes.teardrop()`); its dtype is the model's dtype.
    - `grid`: `(m, n)` surface nodes (the lattice's outer layer; needs m ≥ r, n ≥ s for the refit);
      `layers`: lattice depth (12 → a 12×12×12 lattice for the default grid).
    - `physics_hz`: ticks per second the caller runs; `substeps`: integration steps per tick.
    - `node_mass`, `stiffness` (per spring), `damping` (per spring, along it), `drag` (1/s),
      `tool_stiffness` (per node): the material, in model units.
    - `tool_radius` or `tool_axes` (3 semi-axes, an ellipsoid aligned with the stylus).
    - `proxy_stiffness`, `proxy_damping`: the haptic proxy, N and N·s per model unit.
    - `proxy_grid`: samples per direction of the surface grid the proxy is taken from.
    - `reaction_gain`: newtons felt per unit of the summed tool force on the nodes while sculpting.
    - `contact_stiffness`: N per model unit of depth per contact sample of the `proxy_grid`
      (the distributed springs of 002 §3.2; the force grows with the contact area, Fig. 4).
    - `thickness`: lattice depth of an open (not closed-in-v) surface.
    - `reach`: model units; a tool centre farther than this from the centre of the surface's
      control-net bounding box is out of the workspace and dropped (default: 10 × the box's
      diagonal; `math.inf` turns the check off, non-finite poses are still dropped).
    - `max_rollbacks`: bad ticks in a row (rolled back) before `update` raises.

    Counters: `ticks` (physics ticks run), `dropped_poses`, `rollbacks`.
    """

    def __init__(
        self,
        surface=None,
        grid: tuple[int, int] = (12, 12),
        layers: int = 12,
        physics_hz: float = 100.0,
        substeps: int = 3,
        node_mass: float = 0.01,
        stiffness: float = 10.0,
        damping: float = 0.05,
        drag: float = 2.0,
        tool_stiffness: float = 100.0,
        tool_radius: float = 0.25,
        tool_axes=None,
        proxy_stiffness: float = 30.0,
        proxy_damping: float = 0.3,
        proxy_grid: int = 40,
        reaction_gain: float = 0.2,
        contact_stiffness: float = 4.0,
        fixed_layers: int = 2,
        thickness: float = 0.2,
        reach: float | None = None,
        max_rollbacks: int = 10,
    ):
        surface = shapes.teardrop() if surface is None else surface
        if not isinstance(grid, (tuple, list)) or len(grid) != 2:
            raise ValueError(f"grid: expected (m, n), two ints, got {grid!r}")
        m, n = (_checks.check_count(g, "grid") for g in grid)
        layers = _checks.check_count(layers, "layers", minimum=2)
        substeps = _checks.check_count(substeps, "substeps")
        proxy_grid = _checks.check_count(proxy_grid, "proxy_grid", minimum=2)
        fixed_layers = _checks.check_count(fixed_layers, "fixed_layers")
        r, s = surface.shape
        if m < r or n < s:
            raise ValueError(
                f"grid: expected at least the control net {surface.shape} for the refit, got {grid}"
            )
        if not fixed_layers < layers:
            raise ValueError(
                f"fixed_layers: expected 1 <= fixed_layers < layers = {layers}, got {fixed_layers}"
            )
        for name, value in dict(
            physics_hz=physics_hz,
            node_mass=node_mass,
            stiffness=stiffness,
            tool_stiffness=tool_stiffness,
            proxy_stiffness=proxy_stiffness,
            thickness=thickness,
        ).items():
            positive_number(value, name)
        for name, value in dict(
            damping=damping,
            drag=drag,
            proxy_damping=proxy_damping,
            reaction_gain=reaction_gain,
            contact_stiffness=contact_stiffness,
        ).items():
            positive_number(value, name, allow_zero=True)
        self._init_protocol(surface, reach, _checks.check_count(max_rollbacks, "max_rollbacks"))
        self.dtype = surface.ctrl.dtype
        self.grid, self.layers, self.substeps = (m, n), layers, int(substeps)
        self.dt = 1.0 / (physics_hz * substeps)
        self.proxy_stiffness, self.proxy_damping = float(proxy_stiffness), float(proxy_damping)
        self.reaction_gain, self.contact_stiffness = float(reaction_gain), float(contact_stiffness)
        params_u = np.linspace(0.0, 1.0, m + 2)[1:-1] if not surface.periodic_u else np.arange(m) / m
        params_v = np.arange(n) / n if surface.periodic_v else np.linspace(0.0, 1.0, n)
        self.blending = surface.blending(m, n, params_u.astype(self.dtype), params_v.astype(self.dtype))
        self.dense = surface.blending(proxy_grid, proxy_grid)
        pts, nrm = self.blending.points(surface.ctrl), self.blending.normals(surface.ctrl)
        self.surface0 = surface
        pts, nrm = np.asarray(pts, dtype=np.float64), np.asarray(nrm, dtype=np.float64)
        centre = pts.reshape(-1, 3).mean(axis=0)
        # Orient normals outwards (away from the centroid) once; the sign is a property of the basis.
        self.sign = 1.0 if np.mean(np.sum((pts - centre) * nrm, axis=-1)) >= 0 else -1.0
        x0 = lattice_nodes(pts, self.sign * nrm, layers, surface.periodic_v, thickness).astype(self.dtype)
        fixed = np.zeros((m, n, layers), bool)
        fixed[:, :, :fixed_layers] = True
        # Hexahedral stencil (edges, face and body diagonals) through mss's dense-slice kernel;
        # for a body closed in v the springs across the seam form a second, small edge-list
        # lattice on the same nodes whose forces enter `mss.step` as external force.
        self.lattice = mss.hex_lattice(
            x0, stiffness, damping, node_mass, fixed, node_damping=drag * node_mass
        )
        seam = seam_edges(m, n, layers) if surface.periodic_v else np.zeros((0, 2), np.int32)
        self.seam = mss.Lattice(x0.reshape(-1, 3), seam, stiffness, damping, node_mass) if len(seam) else None
        # The seam nodes' springs split between the two lattices add up to an interior node's
        # stencil, so the bound of the dense lattice covers them.
        check_step(self.lattice, self.dt, tool_stiffness)
        surface_nodes = np.arange(m * n * layers).reshape(m, n, layers)[:, :, -1]
        self.coupling = mss.SurfaceCoupling.on_nodes(self.blending, surface_nodes, self.lattice.n_nodes)
        self.tool_stiffness = tool_stiffness
        self.n_nodes = self.lattice.n_nodes
        self.n_springs = self.lattice.n_edges + (self.seam.n_edges if self.seam else 0)
        rest_seam = self.seam.rest_length if self.seam else jnp.zeros((0,), self.dtype)
        self._state = (mss.init(self.lattice), self.lattice.rest_length, rest_seam)
        self._initial = self._state
        self.ctrl = surface.ctrl
        if tool_axes is None:
            self.set_tool(radius=positive_number(tool_radius, "tool_radius"))
        else:
            self.set_tool(axes=tool_axes)
        self._tick = jax.jit(precise(self._tick_impl), static_argnums=2)  # one program per tool kind
        self._compiled: set[bool] = set()
        self._side: float | None = None  # +1 tool outside the body, −1 inside; latched in contact
        self._was_pressed = False

    # --- run-time tool ------------------------------------------------------------------------
    def set_tool(self, radius: float | None = None, axes=None) -> None:
        """Change the tool at run time: a sphere of `radius` or an ellipsoid of semi-`axes` (3,)."""
        if radius is not None:
            a = np.full(3, positive_number(radius, "radius"))
        else:
            try:
                a = np.asarray(axes, dtype=np.float64)
            except (TypeError, ValueError):
                raise TypeError(f"axes: expected 3 real tool semi-axes, got {axes!r}") from None
            if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise ValueError(f"axes: expected 3 tool semi-axes, finite and > 0, got {a.tolist()}")
        if hasattr(self, "_tick"):
            self._compile(_is_sphere(a))  # a new tool kind compiles here, not in the physics thread
        self.tool_axes = a  # one reference swap, picked up at the next tick

    # --- jitted kernels -----------------------------------------------------------------------
    def _tool(self, centre, axes, rot, sphere: bool):
        """The sculpting tool at the stylus pose: a `collide.Sphere` when the axes are equal
        (the cheaper exact push), else a `collide.Ellipsoid` aligned with the stylus."""
        return collide.Sphere(centre, axes[0]) if sphere else collide.Ellipsoid(centre, axes, rot)

    def _substeps(self, state, rest, rest_seam, tools, contact, count):
        """`substeps` semi-implicit Euler steps of the lattice (`mss.step`'s kernel, thesis eqs.
        5.14–5.16) with the seam springs as external force; returns the new `State`.

        The unchecked kernel: `mss.step` would check the state, forces and `dt` on every
        substep (a host callback each); the tick checks its outputs once instead (`ok`), and
        `dt` once at construction (`check_step`). The loop carries the position one step behind
        (`x_k = x_{k−1} + Δt v_k` at the start of step k, the same operations as `mss.step`):
        a step's spring sum then has one consumer, the velocity, and XLA computes it once. The
        step `count` (= `substeps`) comes in as a traced input: XLA inlines a loop it can prove
        runs once, and the position update after it would compute the sum a second time."""
        lattice, dt = self.lattice, self.dt

        def step(k, carry):
            x, v = carry
            x = jnp.where(k > 0, _position_step(lattice, x, v, dt), x)
            seam = self._seam_forces(x, v, rest_seam) if self.seam is not None else None
            return x, _velocity_step(lattice, mss.State(x, v), dt, seam, None, tools, contact, rest)

        x, v = jax.lax.fori_loop(0, count, step, (state.position, state.velocity))
        return mss.State(_position_step(lattice, x, v, dt), v)

    def _seam_forces(self, x, v, rest_seam):
        """The seam lattice's spring forces, `(N, 3)`, by `mss`'s grid kernel: columns
        `n − 1` and `0` side by side form an `(m, 2, layers)` grid whose springs across its two
        columns (`db ≠ 0`) are exactly the seam's, in the order of `seam_edges`; its springs
        within a column get zero parameters (they belong to the main lattice). No gather or
        scatter over the whole lattice."""
        m, n, layers = self.lattice.grid_shape
        sub = (m, 2, layers)

        def columns(a):  # (N, 3) -> (m·2·layers, 3): column n − 1, then column 0
            grid = a.reshape(m, n, layers, 3)
            return jnp.stack([grid[:, n - 1], grid[:, 0]], axis=1).reshape(-1, 3)

        params, start = [[], [], []], 0
        for da, db, dc in mss.HEX_DIRECTIONS:
            count = (m - da) * (2 - abs(db)) * (layers - abs(dc))
            for out, p in zip(params, (rest_seam, self.seam.stiffness, self.seam.damping)):
                out.append(jnp.zeros((count,), x.dtype) if db == 0 else p[start : start + count])
            start += 0 if db == 0 else count
        f = _grid_sum(sub, _pair_force, (columns(x), columns(v)), [jnp.concatenate(p) for p in params])
        f = f.reshape(m, 2, layers, 3)
        out = jnp.zeros((m, n, layers, 3), x.dtype).at[:, n - 1].add(f[:, 0]).at[:, 0].add(f[:, 1])
        return out.reshape(-1, 3)

    def _tick_impl(self, carry, inputs, sphere):
        """One physics tick: `substeps` steps of `mss.coupled_step`'s chain (the refit once, after
        the last one: the earlier refits are not used), then the proxy data from the new surface.

        `inputs (18,)`: tool centre (3), semi-axes (3), rotation (9, row-major), pressing (1:
        held, 0: not), settle (1: set the shape first) and the number of substeps; one host →
        device transfer a tick."""
        centre, axes, rot = inputs[0:3], inputs[3:6], inputs[6:15].reshape(3, 3)
        pressing, settle, count = inputs[15], inputs[16] > 0, inputs[17].astype(jnp.int32)
        tool = self._tool(centre, axes, rot, sphere)
        contact = mss.Penalty(self.tool_stiffness * pressing, jnp.zeros((), self.dtype))
        carry = self._settled(carry, settle)

        # The tool pushes with `tool_stiffness × pressing`: zero while the button is up (its
        # forces are then exactly 0; one branch-free program, cheaper than a `cond` here).
        state, rest, rest_seam = carry
        state = self._substeps(state, rest, rest_seam, (tool,), contact, count)
        carry = state, rest, rest_seam
        x = state.position
        # Newton's third law (002 §4.2.2): what the tool pushes into the nodes pushes back on it.
        f = mss.tool_forces((tool,), x, jnp.zeros_like(x), contact.stiffness)
        reaction = _safe.norm(jnp.ones(f.shape[0], f.dtype) @ f)  # Σ_i f_i: a dot; XLA:CPU's reduce is slower
        x = carry[0].position
        ctrl = self.coupling.ctrl(x)  # refit of the outer layer (thesis eq. 3.7)
        # Distributed springs of 002 §3.2 (eq. 3.3, surface-normal method) through bsjax.collide.
        # method="dense": 40×40 samples are cheap, and one branch-free program compiles faster.
        # Its samples and normals are the proxy grid's (`Blending.points`/`normals`, to rounding).
        contact = collide.contacts(self.dense, ctrl, tool, method="dense")
        pts = contact.points.reshape(-1, 3)
        nrm = self.sign * contact.normals.reshape(-1, 3)
        k = jnp.argmin(_safe.dot(pts - centre[None], pts - centre[None]))
        q, nq = pts[k], nrm[k]
        support = axes[0] if sphere else _safe.norm(axes * (nq @ rot))  # support distance along nq
        spring = self.sign * collide.contact_force(contact, self.contact_stiffness)
        hit = contact.hit.astype(x.dtype)
        out = jnp.concatenate([q, nq, support[None], reaction[None], spring, hit[None]])
        # checked here, in the same program: the host rolls the tick back when this is False
        ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves((carry, ctrl, out))]))
        return carry, ctrl, jnp.concatenate([out, ok.astype(x.dtype)[None]])

    def _settled(self, carry, settle):
        """Plastic set (on button release): rest lengths ← current lengths when `settle`."""

        def set_shape(carry):
            state, _, rest_seam = carry
            x = state.position
            seam = mss.edge_lengths(self.seam, x) if self.seam is not None else rest_seam
            return state, mss.edge_lengths(self.lattice, x), seam

        return jax.lax.cond(settle, set_shape, lambda c: c, carry)

    # --- model interface ----------------------------------------------------------------------
    def _inputs(self, position, orientation, pressed: bool, settle: bool) -> np.ndarray:
        """The tick's `(18,)` inputs (see `_tick_impl`) as one host array of the model's dtype."""
        out = np.empty(18, self.dtype)
        out[0:3] = position
        out[3:6] = self.tool_axes
        out[6:15] = quat_to_matrix(orientation).ravel()
        out[15], out[16], out[17] = float(pressed), float(settle), float(self.substeps)
        return out

    def _sphere(self) -> bool:
        return _is_sphere(self.tool_axes)

    def _compile(self, sphere: bool) -> None:
        """Compile the tick for one tool kind (a tick with the tool far away, result dropped)."""
        if sphere in self._compiled:
            return
        inputs = self._inputs(np.full(3, 10.0), (1.0, 0.0, 0.0, 0.0), False, False)
        jax.block_until_ready(self._tick(self._state, inputs, sphere))
        self._compiled.add(sphere)

    def warmup(self) -> None:
        """Compile the tick for the current tool kind (all shapes are fixed, so this happens once;
        `set_tool` compiles the other kind, sphere or ellipsoid, when it first changes to it)."""
        self._compile(self._sphere())

    def _advance(self, sample: DeviceSample) -> Proxy | None:
        """One tick (`AbstractHapticModel.update` gates the pose and rolls a bad tick back)."""
        pressed = sample.pressed
        settle = self._was_pressed and not pressed  # released: set the shape first
        inputs = self._inputs(sample.position, sample.orientation, pressed, settle)
        state, ctrl, out = self._tick(self._state, inputs, self._sphere())
        out = np.asarray(out, dtype=np.float64)  # blocks here, with the GIL released
        if not (out[-1] > 0 and np.all(np.isfinite(out))):
            return None
        self._was_pressed = pressed
        self._state, self.ctrl = state, ctrl
        return self._proxy(sample, out)

    def _proxy(self, sample: DeviceSample, out: np.ndarray) -> Proxy:
        """The plane proxy of one (finite) tick output."""
        q, normal, support, reaction = out[:3], out[3:6], float(out[6]), float(out[7])
        spring, hit = out[8:11], out[11] > 0
        gap = float(np.dot(np.asarray(sample.position) - q, normal))
        if self._side is None or abs(gap) >= support:  # out of contact: the tool's side may change
            self._side = 1.0 if gap >= 0 else -1.0
        n = self._side * normal
        magnitude = float(np.linalg.norm(spring))
        if hit and magnitude > 0:
            # In contact: the plane along the distributed-spring direction, placed so that the
            # servo renders exactly that force at the current tool centre and extrapolates it
            # with the proxy stiffness until the next physics tick.
            n = self._side * spring / magnitude
            q = np.asarray(sample.position) - n * (support - magnitude / self.proxy_stiffness)
        # While sculpting, the surface yields under the tool; shifting the plane back by
        # reaction / k makes the servo render the nodes' reaction on top of the contact force.
        q = q - n * (self.reaction_gain * reaction / self.proxy_stiffness)
        return self._plane(q.tolist(), n.tolist(), self.proxy_stiffness, self.proxy_damping, support)

    def surface(self):
        """The current surface (refit of the lattice's outer layer)."""
        return self.surface0.with_ctrl(self.ctrl)

    def reset(self) -> None:
        with self._lock:
            self._state, self.ctrl, self._was_pressed = self._initial, self.surface0.ctrl, False
            self._side, self._last_proxy, self._bad_ticks = None, Proxy(), 0
