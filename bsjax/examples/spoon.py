"""The spoon case study of the thesis (§7.3), as composable steps.

1. `bend_handle`: a surface mass-spring lattice on the handle's blending grid (plasticine,
   plastic yield), one end clamped by a plane, the neck pushed up by a `collide.Sphere`; each
   step is the chain `mss.coupled_step` (surface → contacts by the tool's `push` → forces on the
   lattice nodes → step → refit, the dual representation of Gao & Gibson, *Haptic B-spline surface
   sculpting with a shaped tool of implicit surface*, §4.1).
2. `attach_bowl` + `bsjax.merge.merge`: the bowl follows the bent neck and the two patches
   become one surface.
3. `study`, `tilted`, `shake`, `run`, `spilled`, `spill_risk`: the jelly resting in the
   merged spoon, two deformable bodies in surface–surface contact (`mss.Scene`: the steel
   spoon a shell lattice held at the handle, the jelly a VSOFM volume lattice), tilted,
   rolled or shaken (thesis Figs 7.14–7.19); where the jelly leaves the bowl and a smooth
   risk, differentiable in the tilt and the hand (`bsjax.examples.demo`,
   `bsjax sweep spoon`, `benchmarks/spoon_study.py`).
4. `reshaped`: the study with the spoon's rest shape following a new control net, for the
   bowl's shape optimisation on the same two-body physics (`bsjax.examples.bowl`).

All lengths in metres, times in seconds. The spoon's frame has x along the handle towards the
bowl (the bowl at x ∈ [0, 0.06]), z up out of the bowl; a tilt or a roll turns gravity in it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import collide, mss, shapes
from bsjax.basis import BSplineSurface

__all__ = ["Hand", "Study", "run", "shake", "spill_risk", "spilled", "study", "tilted"]

GRAVITY = 9.81


# --- 1. bending the handle -------------------------------------------------------------------
def bend_handle(
    handle: BSplineSurface,
    push: float = 0.012,
    clamp_x: float = -0.085,
    samples: tuple[int, int] = (25, 8),
    dt: float = 1e-3,
    steps: int = 200,
    yield_strain: float = 0.01,
    node_damping: float = 3e-3,
    relax_steps: int = 3000,
):
    """Bend the handle plastically: nodes behind the plane `x = clamp_x` are fixed (the clamp),
    a 6 mm sphere rises `push` metres under the handle near the neck; then the lattice relaxes
    to rest and the control net is refit from the nodes.

    **Returns:** `(bent_handle, info)` with the neck lift and the simulation sizes.
    """
    m, n = samples
    blending = handle.blending(m, n)
    grid = np.asarray(blending.points(handle.ctrl))
    # a 3 mm plasticine strip on the sample grid; ground damping (N·s/m per node) settles the
    # strip's slow bending mode after the push
    lattice, coupling = mss.surface_lattice(
        blending,
        handle.ctrl,
        mss.PLASTICINE,
        thickness=0.003,
        fixed=grid[..., 0] < clamp_x,
        node_damping=node_damping,
    )
    dtype = handle.ctrl.dtype
    lift = jnp.minimum(jnp.linspace(0.0, 1.5, steps), 1.0)[:, None]
    start = jnp.array([-0.03, 0.0, -0.0065], dtype=dtype)
    path = jax.vmap(collide.Sphere)(  # the rising ball, one tool per step
        start[None] + lift * jnp.array([0.0, 0.0, push], dtype=dtype)[None], jnp.full((steps,), 0.006, dtype)
    )
    plastic, state = _push(lattice, coupling, path, dt, mss.Penalty(5e3, 1.0), mss.Plasticity(yield_strain))
    rest, taken, converged = mss.relax(
        plastic,
        mss.State(state.position, jnp.zeros_like(state.velocity)),
        dt,
        method="implicit",
        tol=1e-10,
        max_steps=relax_steps,
    )
    ctrl = coupling.ctrl(rest.position)
    lift_neck = float(jnp.mean(coupling.grid(rest.position)[-1, :, 2] - grid[-1, :, 2]))
    info = {
        "lattice_nodes": lattice.n_nodes,
        "springs": lattice.n_edges,
        "steps": steps,
        "dt": dt,
        "neck_lift_m": lift_neck,
        "relaxed": bool(converged),
        "relax_steps": int(taken),
        "fixed_nodes": int(np.sum(np.asarray(lattice.fixed))),
    }
    return handle.with_ctrl(ctrl), info


@jax.jit
def _push(lattice, coupling, path, dt, contact, plasticity):
    """The tool path through the coupled chain (implicit steps, a plastic yield after each);
    returns the lattice with its yielded rest lengths and the final state."""

    def body(carry, ball):
        state, rest = carry
        state, _ = mss.coupled_step(
            lattice, coupling, state, dt, (ball,), contact, rest_length=rest, method="implicit"
        )
        return (state, mss.yield_rest_lengths(lattice, state.position, plasticity, rest)), None

    (state, rest), _ = jax.lax.scan(body, (mss.init(lattice), lattice.rest_length), path)
    return eqx.tree_at(lambda lat: lat.rest_length, lattice, rest), state


def attach_bowl(handle: BSplineSurface, bowl: BSplineSurface) -> BSplineSurface:
    """Move the bowl rigidly so that its u = 0 edge sits on the handle's u = 1 edge and it
    continues the handle's end direction (a pitch about y)."""
    rot, origin = bowl_frame(handle, bowl)
    return bowl.with_ctrl(bowl.ctrl @ rot.T + origin[None, None])


def bowl_frame(handle: BSplineSurface, bowl: BSplineSurface):
    """`(rotation, origin)` of the attached bowl: world = rotation @ local + origin."""
    edge = handle.ctrl[-1].mean(0)
    direction = handle.ctrl[-1].mean(0) - handle.ctrl[-2].mean(0)
    pitch = jnp.arctan2(direction[2], direction[0])
    c, s = jnp.cos(pitch), jnp.sin(pitch)
    rot = jnp.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]], dtype=bowl.ctrl.dtype)
    return rot, edge - rot @ bowl.ctrl[0].mean(0)


# --- 3. the jelly in the spoon: two deformable bodies (thesis §7.3, Figs 7.14–7.19) -----------
#: The jelly of the study: `mss.JELLY`'s E and ρ, damped at ζ = 0.3 (at ζ = 0.1 it rings so long
#: that the tangent `jax.grad` carries back through a rollout grows without bound).
JELLY = mss.Material(mss.JELLY.youngs_modulus, mss.JELLY.density, 0.3)


class Study(eqx.Module):
    """The jelly resting in the bowl of a steel spoon held by its handle (thesis §7.3).

    **Fields:** `scene`: an `mss.Scene` of two bodies, the spoon (a steel shell lattice of the
    merged surface, the nodes near the handle's end held: the hand) and the jelly (a VSOFM
    volume lattice of a B-spline sphere); `rows (R, 3)`: the bowl's footprint at rest, one row
    per sample row along the spoon, `(x, y_low, y_high)`; `neck`, `tip`: the bowl's x range
    at rest (m).
    """

    scene: mss.Scene
    rows: Float[Array, "R 3"]
    neck: float = eqx.field(static=True)
    tip: float = eqx.field(static=True)


def study(
    spoon: BSplineSurface,
    *,
    lattice: int = 12,
    jelly_samples: tuple[int, int] = (24, 24),
    radius: float = 0.007,
    spoon_shape: tuple[int, int, int] = (40, 10, 2),
    thickness: float = 0.001,
    hand: float = 0.015,
    neck: float = 0.0,
    contact: collide.DistributedSprings | None = None,
    cycles: int = 300,
    progress=None,
) -> Study:
    """Build the study: the spoon surface (x along the handle towards the bowl, z up, the bowl's
    neck at `x = neck`) as a steel shell lattice of `spoon_shape` nodes through `thickness`,
    held along its first `hand` metres; a jelly sphere of `radius` on a `lattice³` VSOFM lattice
    (`cycles` training cycles reported to `progress(done, total)`, `jelly_samples` surface
    samples) resting just above the bowl's lowest point; the contact
    `collide.DistributedSprings` (default k = 20 N/m per sample, c = 0.002 N·s/m: a larger
    damper on the jelly's 1 mg nodes, not its spring, sets the step)."""
    start = float(np.asarray(spoon.ctrl)[..., 0].min())
    steel = mss.Body.from_surface(
        spoon, spoon_shape, mss.STEEL, thickness=thickness, fixed=lambda x: x[:, 0] < start + hand
    )
    rest = np.asarray(steel.coupling.blending.points(spoon.ctrl))
    bowl = rest[rest[..., 0].mean(1) >= neck]
    rows = np.stack([bowl[..., 0].mean(1), bowl[:, 0, 1], bowl[:, -1, 1]], 1)
    rows[:, 1:3] = np.sort(rows[:, 1:3], 1)
    lowest = bowl.reshape(-1, 3)[np.argmin(bowl[..., 2])]
    ball = shapes.sphere(radius, dtype=spoon.ctrl.dtype)
    centre = jnp.asarray(lowest + np.array([0.0, 0.0, radius + 0.2 * thickness]), spoon.ctrl.dtype)
    jelly = mss.Body.from_surface(
        ball.with_ctrl(ball.ctrl + centre[None, None]),
        (lattice,) * 3,
        JELLY,
        samples=jelly_samples,
        cycles=cycles,
        progress=progress,
    )
    contact = collide.DistributedSprings(20.0, 0.002) if contact is None else contact
    scene = mss.Scene((steel, jelly), gravity=jnp.array([0.0, 0.0, -GRAVITY]), contact=contact)
    return Study(scene, jnp.asarray(rows), float(neck), float(rows[:, 0].max()))


def reshaped(s: Study, spoon_ctrl) -> Study:
    """The study with the spoon's rest shape following the control net `spoon_ctrl` of its
    surface (`mss.Body.with_ctrl`; the jelly, the footprint and the contact kept): differentiable
    in `spoon_ctrl`, for the bowl's shape optimisation (`bsjax.examples.bowl`)."""
    steel = s.scene.bodies[0].with_ctrl(spoon_ctrl)
    return eqx.tree_at(lambda t: t.scene.bodies[0], s, steel)


#: Each body's integrator: the steel spoon by backward Euler linearised about its rest shape and
#: solved exactly (`"linear_implicit"`: its explicit limit is ~100 times smaller than the
#: jelly's, and 20 conjugate-gradient iterations of `"implicit"` leave 99 % of its velocity
#: change unsolved), the jelly by symplectic Euler; the contact explicitly.
METHODS = ("linear_implicit", "semi_implicit")


def tilted(s: Study, tilt_deg, roll_deg=0.0) -> mss.Scene:
    """The study's scene with the spoon pitched by `tilt_deg` degrees about the handle's
    crosswise axis, positive backwards (the tip up), then rolled by `roll_deg` degrees about the
    handle, positive lowering the spoon's −y side. In the spoon's frame a steady pose is
    gravity turned, `g (−sin θ, −cos θ sin φ, −cos θ cos φ)` (differentiable in θ and φ)."""
    theta, phi = (jnp.deg2rad(jnp.asarray(a, s.rows.dtype)) for a in (tilt_deg, roll_deg))
    g = GRAVITY * jnp.stack([-jnp.sin(theta), -jnp.cos(theta) * jnp.sin(phi), -jnp.cos(theta) * jnp.cos(phi)])
    return eqx.tree_at(lambda scene: scene.gravity, s.scene, g)


class Hand(eqx.Module):
    """A shaking hand, the held nodes' motion `t ↦ (I, T(t))`: `T(t) = amplitude · sin(2π f t)
    · axis`, eased in over the first period (smoothstep), so the spoon's acceleration
    oscillates with amplitude `amplitude (2π f)²`."""

    axis: Float[Array, " 3"]
    amplitude: Float[Array, ""]
    frequency: Float[Array, ""]

    def __call__(self, t):
        e = jnp.clip(t * self.frequency, 0.0, 1.0)
        offset = self.amplitude * e * e * (3.0 - 2.0 * e) * jnp.sin(2.0 * jnp.pi * self.frequency * t)
        return jnp.eye(3, dtype=self.axis.dtype), offset * self.axis


#: Named shaking directions of `shake` (degrees from the handle in the spoon's plane).
AXES = {"handle": 0.0, "across": 90.0}


def shake(s: Study, axis="handle", amplitude=0.0, frequency=1.0) -> Hand:
    """The `Hand` shaking the spoon by `amplitude` m at `frequency` Hz along `axis`: `"handle"`,
    `"across"` (`AXES`) or an angle in degrees from the handle towards +y in the spoon's plane
    (traced: a sweep over directions is one program)."""
    if isinstance(axis, str):
        if axis not in AXES:
            raise ValueError(
                f"shake_axis: expected one of {sorted(AXES)} or an angle in degrees, got {axis!r}"
            )
        axis = AXES[axis]
    dtype = s.rows.dtype
    a = jnp.deg2rad(jnp.asarray(axis, dtype))
    direction = jnp.stack([jnp.cos(a), jnp.sin(a), jnp.zeros_like(a)])
    return Hand(direction, jnp.asarray(amplitude, dtype), jnp.asarray(frequency, dtype))


def step_size(s: Study) -> float:
    """The study's step in s: 0.9 × `mss.scene_stable_dt(scene, METHODS)` (a tilt or a hand
    does not change it)."""
    return 0.9 * float(mss.scene_stable_dt(s.scene, METHODS))


def run(
    s: Study,
    tilt_deg=0.0,
    hand: Hand | None = None,
    seconds: float = 0.3,
    dt: float | None = None,
    progress=None,
    roll_deg=0.0,
):
    """The study's scene from rest, pitched by `tilt_deg` and rolled by `roll_deg` (`tilted`),
    the hand shaking (`hand`, or held still) for `seconds`: `(states, t_end)`, with the step
    `step_size(s)` unless `dt` is given. Differentiable in the tilt, the roll and the hand."""
    scene = tilted(s, tilt_deg, roll_deg)
    dt = step_size(s) if dt is None else dt
    n = max(int(round(seconds / dt)), 1)
    states = mss.simulate_scene(
        scene, mss.scene_init(scene), dt, n, motion=(hand, None), method=METHODS, progress=progress
    )
    return states, n * dt


def _in_hand_frame(hand: Hand | None, t, x):
    """Positions `x (N, 3)` at time `t` in the spoon's rest frame: `x − T(t)`."""
    return x if hand is None else x - hand(t)[1][None]


def _margins(s: Study, x):
    """Signed distances (m, positive inside) `(N, 3)` of rest-frame points `x (N, 3)` to the
    bowl's footprint: to the tip, to the neck, and across (`y_low(x)`..`y_high(x)`)."""
    lo = jnp.interp(x[:, 0], s.rows[:, 0], s.rows[:, 1])
    hi = jnp.interp(x[:, 0], s.rows[:, 0], s.rows[:, 2])
    return jnp.stack([s.tip - x[:, 0], x[:, 0] - s.neck, jnp.minimum(x[:, 1] - lo, hi - x[:, 1])], -1)


#: Where a spilled node left the bowl, by the footprint side it is furthest beyond.
EXITS = ("front", "back", "side")


def spilled(s: Study, position, t=0.0, hand: Hand | None = None) -> dict:
    """Mass fraction of the jelly outside the bowl's footprint at time `t` (node positions
    `(N, 3)`, in the rest frame of the spoon moved by `hand`), in total (`"spilled"`) and by
    where it left (`EXITS`): scalars, jittable and vmappable (a count: its gradient is 0; the
    smooth counterpart is `spill_risk`)."""
    mass = s.scene.bodies[1].lattice.mass
    margins = _margins(s, _in_hand_frame(hand, t, position))
    out = jnp.min(margins, 1) < 0
    side = jnp.argmin(margins, 1)
    total = jnp.sum(mass)
    where = {name: jnp.sum(jnp.where(out & (side == k), mass, 0)) / total for k, name in enumerate(EXITS)}
    return {"spilled": jnp.sum(jnp.where(out, mass, 0)) / total, **where}


def spill_risk(s: Study, position, t=0.0, hand: Hand | None = None, scale: float = 0.002):
    """Smooth spill risk: the mass-weighted mean over the jelly's nodes of `σ(−margin / scale)`
    (½ on the rim, → 1 beyond it, → 0 deep inside), differentiable in the positions and the
    motion."""
    mass = s.scene.bodies[1].lattice.mass
    margin = jnp.min(_margins(s, _in_hand_frame(hand, t, position)), 1)
    return jnp.sum(mass * jax.nn.sigmoid(-margin / scale)) / jnp.sum(mass)
