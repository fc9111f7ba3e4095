"""Shape optimisation of the spoon bowl: move a few control points of the bowl (rim fixed,
smoothness regularised) so that a jelly thrown sideways into the tilted spoon spills least.

The objective is differentiable end to end (issue #14, deliverable 3):

    bowl control net (free entries: heights of a few interior control points, bowl frame)
      → the bowl placed on the handle's neck → `bsjax.merge` (one C¹ patch, the layout's linear
        refit `P = A_u⁺ M A_v⁺ᵀ`, thesis eq. 3.7)
      → the merged surface sampled by its blending matrices → a height map (linear interpolation
        with weights fixed once: moving control points vertically moves samples vertically)
      → contact forces on a VSOFM jelly lattice → the mass-spring rollout (`spoon.drop`)
      → the time-averaged spill risk (`spoon.rim_risk`) + a smoothness term.

`study(...)` builds the fixed parts once (a `BowlStudy` pytree), `objective(offsets, study)` is
a module-level function (so `bsjax.optimise.minimise` compiles it once per study shape),
`optimise_bowl` runs BFGS, `nelder_mead` runs scipy's derivative-free baseline on the same number
of objective evaluations, and `gradient_check` compares `jax.grad` with central differences.
Sources: Gao & Gibson, *Haptic sculpting of multi-resolution B-spline surfaces with shaped
tools* (the dual control-net / sample representation); the merge of the thesis (§4.3); Nocedal
& Wright, *Numerical Optimization* (BFGS); Nelder & Mead, *A simplex method for function
minimization*.
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import merge, mss, optimise, shapes, vsofm
from bsjax.basis import Blending
from bsjax.examples import spoon

FULL = {"lattice": 5, "cycles": 60, "seconds": 0.1, "samples": (60, 30), "cells": (80, 50), "budget": 12}
QUICK = {"lattice": 4, "cycles": 40, "seconds": 0.04, "samples": (40, 20), "cells": (60, 40), "budget": 6}

# the heights that may move: rows 2..5 (along the bowl) of the two control columns on the side the
# jelly is thrown towards; the rim (first and last rows and columns) never moves
FREE = np.zeros((8, 8), bool)
FREE[2:6, 1:3] = True
LOWER, UPPER = -0.006, 0.004  # metres of vertical movement allowed per control point


class BowlStudy(eqx.Module):
    """The fixed parts of the study (a pytree: passed to the objective as traced data)."""

    bowl_ctrl: Float[Array, "8 8 3"]
    handle_ctrl: Float[Array, "8 8 3"]
    rotation: Float[Array, "3 3"]
    origin: Float[Array, " 3"]
    layout: merge.MergeLayout
    patch: Blending
    index: Int[Array, "gx gy 3"]
    weight: Float[Array, "gx gy 3"]
    height_map: spoon.HeightMap
    lattice: mss.Lattice
    tilt: Float[Array, ""]
    dt: Float[Array, ""]
    throw: Float[Array, " 3"]
    smoothing: Float[Array, ""]
    free: Bool[Array, "8 8"]
    steps: int = eqx.field(static=True)


def study(quick: bool = True, tilt_deg: float = 8.0, smoothing: float = 30.0) -> BowlStudy:
    """Build the study: unbent handle + bowl merged C¹, the height map's interpolation weights,
    a VSOFM jelly lattice, and the rollout's step.

    **Arguments:** `quick` (the sizes of `QUICK`, else `FULL`), `tilt_deg` (the bowl's sideways
    tilt), `smoothing` (weight of the smoothness term, per m² of second differences of the
    heights).
    """
    from scipy.spatial import Delaunay

    sizes = QUICK if quick else FULL
    handle, bowl = shapes.spoon_handle(), shapes.spoon_bowl()
    rotation, origin = spoon.bowl_frame(handle, bowl)
    placed = bowl.with_ctrl(bowl.ctrl @ rotation.T + origin[None, None])
    layout = merge.plan([handle, placed], "u", 1)
    merged = layout.surface(layout.apply([handle.ctrl, placed.ctrl]))
    m, n = sizes["samples"]
    patch = merged.blending(params_u=np.linspace(0.5, 1.0, m), params_v=np.linspace(0.0, 1.0, n), m=m, n=n)
    local = np.asarray((patch.points(merged.ctrl) - origin[None, None]) @ rotation).reshape(-1, 3)
    lo, hi = (-0.01, -0.035), (0.075, 0.035)
    hm = spoon.height_map(local, lo, hi, cells=sizes["cells"])
    gx = np.linspace(lo[0], hi[0], sizes["cells"][0])
    gy = np.linspace(lo[1], hi[1], sizes["cells"][1])
    index, weight = _linear_weights(Delaunay(local[:, :2]), np.stack(np.meshgrid(gx, gy, indexing="ij"), -1))
    nodes = _jelly(sizes)
    lattice = mss.hex_lattice(nodes, material=mss.JELLY, node_damping=5e-6)
    dt = 0.9 * float(mss.stable_dt(lattice, 2.0))
    steps = max(int(sizes["seconds"] / dt) // 10, 1) * 10
    return BowlStudy(
        bowl.ctrl,
        handle.ctrl,
        rotation,
        origin,
        layout,
        patch,
        jnp.asarray(index),
        jnp.asarray(weight),
        hm,
        lattice,
        jnp.deg2rad(jnp.asarray(tilt_deg)),
        jnp.asarray(dt),
        jnp.array([0.0, -0.45, 0.0]),
        jnp.asarray(smoothing),
        jnp.asarray(FREE),
        steps,
    )


def _linear_weights(tri, grid):
    """Per grid point, the 3 sample indices and barycentric weights of the Delaunay triangle that
    holds it (the linear interpolation of `scipy.interpolate.griddata`); zeros outside."""
    flat = grid.reshape(-1, 2)
    simplex = tri.find_simplex(flat)
    inside = simplex >= 0
    transform = tri.transform[np.maximum(simplex, 0)]
    b = np.einsum("gij,gj->gi", transform[:, :2], flat - transform[:, 2])
    weight = np.concatenate([b, 1 - b.sum(1, keepdims=True)], 1) * inside[:, None]
    index = tri.simplices[np.maximum(simplex, 0)] * inside[:, None]
    return index.reshape(*grid.shape[:2], 3), weight.reshape(*grid.shape[:2], 3)


def _jelly(sizes):
    ball = shapes.sphere(radius=0.007)
    samples = np.asarray(ball.blending(24, 24).points(ball.ctrl)).reshape(-1, 3)
    return vsofm.fit(samples + np.array([0.032, 0.0, 0.004]), (sizes["lattice"],) * 3, cycles=sizes["cycles"])


def height_map(offsets: Float[Array, "8 8"], s: BowlStudy) -> spoon.HeightMap:
    """The height map of the merged spoon whose bowl control points are raised by `offsets`
    (bowl frame, metres): differentiable in `offsets`."""
    bowl = s.bowl_ctrl.at[..., 2].add(offsets)
    ctrl = s.layout.apply([s.handle_ctrl, bowl @ s.rotation.T + s.origin[None, None]])
    local = (s.patch.points(ctrl) - s.origin[None, None]) @ s.rotation
    z_samples = local[..., 2].reshape(-1)
    hm = s.height_map
    inside = hm.mask > 0
    z = jnp.where(inside, jnp.sum(s.weight * z_samples[s.index], -1), hm.z)  # outside: far below
    dzdx, dzdy = jnp.gradient(z, hm.spacing[0], hm.spacing[1])
    return eqx.tree_at(lambda h: (h.z, h.dzdx, h.dzdy), hm, (z, dzdx, dzdy))


def smoothness(offsets: Float[Array, "8 8"]) -> Float[Array, ""]:
    """Sum of squared second differences of the offsets along both net directions (a discrete
    thin-plate energy of the change)."""
    du = offsets[2:] - 2 * offsets[1:-1] + offsets[:-2]
    dv = offsets[:, 2:] - 2 * offsets[:, 1:-1] + offsets[:, :-2]
    return jnp.sum(du**2) + jnp.sum(dv**2)


def spill_risk(offsets: Float[Array, "8 8"], s: BowlStudy) -> Float[Array, ""]:
    """The time-averaged rim risk of the thrown jelly in the reshaped bowl (`spoon.drop`)."""
    _, risk = spoon.drop(
        s.lattice, height_map(offsets, s), s.tilt, s.dt, s.steps, 2.0, 0.002, velocity=s.throw, chunk=10
    )
    return risk


def spill_risk_at(offsets: Float[Array, "8 8"], s: BowlStudy, tilt) -> Float[Array, ""]:
    """`spill_risk` with the bowl tilted by `tilt` radians instead of the study's tilt (for sweeps:
    `bsjax.batch.map(functools.partial(spill_risk_at, offsets, s), tilts)`)."""
    return spill_risk(offsets, eqx.tree_at(lambda t: t.tilt, s, jnp.asarray(tilt, s.tilt.dtype)))


def objective(offsets: Float[Array, "8 8"], s: BowlStudy) -> Float[Array, ""]:
    """`100 × (spill risk + smoothing × smoothness)`: the function the optimiser lowers, in percent
    points of risk (a scale at which BFGS's first step, along −∇ with the identity as Hessian,
    moves the free heights by about a millimetre)."""
    return 100.0 * (spill_risk(offsets, s) + s.smoothing * smoothness(offsets))


def optimise_bowl(s: BowlStudy, max_steps: int, progress=None) -> optimise.OptimiseResult:
    """BFGS on the free offsets (bounded to [LOWER, UPPER] m, rim fixed), from the original bowl."""
    return optimise.minimise(
        objective,
        jnp.zeros((8, 8)),
        s,
        lower=LOWER,
        upper=UPPER,
        free=s.free,
        max_steps=max_steps,
        throw=False,
        progress=progress,
    )


def nelder_mead(s: BowlStudy, budget: int) -> tuple[np.ndarray, float, int]:
    """scipy's Nelder–Mead on the same free offsets (clipped to the same bounds), `budget`
    objective evaluations. **Returns:** `(offsets, value, evaluations)`."""
    from scipy.optimize import minimize

    value = jax.jit(objective)
    free = np.asarray(s.free)

    def f(x):
        full = np.zeros((8, 8))
        full[free] = np.clip(x, LOWER, UPPER)
        return float(value(jnp.asarray(full), s))

    # the initial simplex steps 1 mm along each free entry (scipy's default 5 % of 0 is 0.00025)
    x0 = np.zeros(int(free.sum()))
    simplex = np.vstack([x0, x0 + 0.001 * np.eye(x0.size)])
    res = minimize(
        f, x0, method="Nelder-Mead", options={"maxfev": budget, "initial_simplex": simplex, "xatol": 1e-9}
    )
    full = np.zeros((8, 8))
    full[free] = np.clip(res.x, LOWER, UPPER)
    return full, float(res.fun), int(res.nfev)


def gradient_check(s: BowlStudy, eps: float = 1e-6, seed: int = 0, at: float = 1e-5) -> tuple[float, float]:
    """`(jax.grad · d, central difference along d)` of the objective at `at · d` beside the
    original bowl, for a random direction `d` over the free entries.

    Not at the original bowl itself: the rigid height map's contact there sits on a discrete
    event (along `d` the objective jumps by about 1e-3 and changes slope between `−1e-6 · d` and
    0), where a central difference measures the jump; 1e-5 along `d` it is smooth."""
    d = np.where(np.asarray(s.free), np.random.default_rng(seed).normal(size=(8, 8)), 0.0)
    d = jnp.asarray(d)
    value_and_grad = jax.jit(jax.value_and_grad(objective))
    _, g = value_and_grad(at * d, s)
    value = jax.jit(objective)
    fd = (value((at + eps) * d, s) - value((at - eps) * d, s)) / (2 * eps)
    return float(jnp.vdot(g, d)), float(fd)


def run(quick: bool = True, max_steps: int | None = None) -> dict:
    """The study end to end: gradient check, BFGS, Nelder–Mead on the same budget; a report."""
    sizes = QUICK if quick else FULL
    budget = max_steps or sizes["budget"]
    s = study(quick)
    analytic, fd = gradient_check(s)
    start = float(jax.jit(objective)(jnp.zeros((8, 8)), s))
    t0 = time.perf_counter()
    ours = optimise_bowl(s, budget)
    ours_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    nm_design, nm_value, nm_evals = nelder_mead(s, int(ours.evaluations))
    nm_s = time.perf_counter() - t0
    risk = jax.jit(spill_risk)
    return {
        "lattice": list(s.lattice.rest_positions.shape),
        "steps": s.steps,
        "gradient_check": {"jax_grad": analytic, "central_difference": fd},
        "start": {"objective": start, "spill_risk": float(risk(jnp.zeros((8, 8)), s))},
        "bfgs": {
            "objective": float(ours.value),
            "spill_risk": float(risk(ours.design, s)),
            "history": ours.accepted().tolist(),
            "evaluations": int(ours.evaluations),
            "seconds": ours_s,
            "max_offset_mm": 1e3 * float(jnp.abs(ours.design).max()),
        },
        "nelder_mead": {
            "objective": nm_value,
            "spill_risk": float(risk(jnp.asarray(nm_design), s)),
            "evaluations": nm_evals,
            "seconds": nm_s,
        },
    }


if __name__ == "__main__":
    import json
    import sys

    jax.config.update("jax_enable_x64", True)
    print(json.dumps(run(quick="--full" not in sys.argv), indent=2))
