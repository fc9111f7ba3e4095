"""Shape optimisation of the spoon bowl on two deformable bodies: move a few control points of
the bowl (rim fixed, smoothness regularised) so that the jelly resting in the tilted steel spoon
spills least.

The objective is differentiable end to end:

    bowl control net (free entries: heights of a few control points near the neck, spoon frame)
      → `bsjax.merge` with the handle (one C¹ patch, the layout's linear refit `P = A_u⁺ M A_v⁺ᵀ`,
        thesis eq. 3.7)
      → the steel shell's rest shape (`mss.Body.with_ctrl`: nodes and rest lengths follow the net)
      → the two-body scene of `bsjax.examples.spoon` (surface–surface contact, the steel by
        `"linear_implicit"`, the jelly by symplectic Euler), tilted backwards
      → the jelly's spill risk at the end (`spoon.spill_risk`) + a smoothness term.

`study(...)` builds the fixed parts once (a `BowlStudy` pytree), `objective(offsets, study)` is
a module-level function (so `bsjax.optimise.minimise` compiles it once per study shape),
`optimise_bowl` runs BFGS (`jax.grad` in reverse mode through the rollout), `nelder_mead` runs
scipy's derivative-free baseline on the same number of objective evaluations, and
`gradient_check` compares `jax.grad` with central differences. Sources: the spoon study of the
thesis (§7.3); Gao & Gibson, *Haptic B-spline surface sculpting with a shaped
tool of implicit surface* (the dual control-net / sample representation); the merge of the thesis (§4.3);
Nocedal & Wright, *Numerical Optimization* (BFGS); Nelder & Mead, *A simplex method for
function minimization*.
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from bsjax import merge, optimise, shapes
from bsjax.examples import spoon

__all__ = [
    "FULL",
    "QUICK",
    "BowlStudy",
    "gradient_check",
    "objective",
    "optimise_bowl",
    "run",
    "spill_risk",
    "study",
]

FULL = {"lattice": 5, "cycles": 60, "jelly_samples": (12, 12), "seconds": 0.15, "budget": 12}
QUICK = {"lattice": 3, "cycles": 30, "jelly_samples": (10, 10), "seconds": 0.08, "budget": 6}

# the heights that may move: rows 1..2 (the bowl's end towards the neck, where a jelly in a spoon
# tilted backwards slides) of the four middle control columns; the rim never moves
FREE = np.zeros((8, 8), bool)
FREE[1:3, 2:6] = True
LOWER, UPPER = -0.002, 0.002  # metres of vertical movement allowed per control point


class BowlStudy(eqx.Module):
    """The fixed parts of the study (a pytree: passed to the objective as traced data)."""

    study: spoon.Study
    handle_ctrl: Float[Array, "8 8 3"]
    bowl_ctrl: Float[Array, "8 8 3"]
    layout: merge.MergeLayout
    tilt: Float[Array, ""]
    smoothing: Float[Array, ""]
    free: Bool[Array, "8 8"]
    dt: float = eqx.field(static=True)
    seconds: float = eqx.field(static=True)


def study(quick: bool = True, tilt_deg: float = 35.0, smoothing: float = 30.0) -> BowlStudy:
    """Build the study: handle + bowl merged C¹ (`merge.plan`), the jelly resting in the steel
    spoon (`spoon.study`), its step.

    **Arguments:** `quick` (the sizes of `QUICK`, else `FULL`), `tilt_deg` (the spoon tilted
    backwards), `smoothing` (weight of the smoothness term, per m² of second differences of the
    heights).
    """
    sizes = QUICK if quick else FULL
    handle, bowl = shapes.spoon_handle(), shapes.spoon_bowl()
    layout = merge.plan([handle, bowl], "u", 1)
    merged = layout.surface(layout.apply([handle.ctrl, bowl.ctrl]))
    s = spoon.study(
        merged,
        lattice=sizes["lattice"],
        jelly_samples=sizes["jelly_samples"],
        spoon_shape=(30, 8, 2),
        cycles=sizes["cycles"],
    )
    return BowlStudy(
        s,
        handle.ctrl,
        bowl.ctrl,
        layout,
        jnp.asarray(tilt_deg, handle.ctrl.dtype),
        jnp.asarray(smoothing, handle.ctrl.dtype),
        jnp.asarray(FREE),
        spoon.step_size(s),
        float(sizes["seconds"]),
    )


def reshaped(offsets: Float[Array, "8 8"], s: BowlStudy) -> spoon.Study:
    """The spoon study whose bowl control points are raised by `offsets` (m, spoon frame):
    differentiable in `offsets`."""
    ctrl = s.layout.apply([s.handle_ctrl, s.bowl_ctrl.at[..., 2].add(offsets)])
    return spoon.reshaped(s.study, ctrl)


def smoothness(offsets: Float[Array, "8 8"]) -> Float[Array, ""]:
    """Sum of squared second differences of the offsets along both net directions (a discrete
    thin-plate energy of the change)."""
    du = offsets[2:] - 2 * offsets[1:-1] + offsets[:-2]
    dv = offsets[:, 2:] - 2 * offsets[:, 1:-1] + offsets[:, :-2]
    return jnp.sum(du**2) + jnp.sum(dv**2)


def spill_risk(offsets: Float[Array, "8 8"], s: BowlStudy) -> Float[Array, ""]:
    """The spill risk of the jelly at the end of the rollout in the reshaped spoon, tilted by
    the study's tilt (`spoon.run`, `spoon.spill_risk`)."""
    return spill_risk_at(offsets, s, s.tilt)


def spill_risk_at(offsets: Float[Array, "8 8"], s: BowlStudy, tilt) -> Float[Array, ""]:
    """`spill_risk` with the spoon tilted backwards by `tilt` degrees instead of the study's
    tilt (for sweeps: `bsjax.batch.map(functools.partial(spill_risk_at, offsets, s), tilts)`)."""
    study = reshaped(offsets, s)
    states, t = spoon.run(study, tilt, seconds=s.seconds, dt=s.dt)
    return spoon.spill_risk(study, states[1].position, t)


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


def gradient_check(s: BowlStudy, eps: float = 1e-4, seed: int = 0) -> tuple[float, float]:
    """`(∇f · d, central difference along d)` of the objective `f` at the original bowl, for a
    random direction `d` over the free entries; `∇f · d` by forward mode (`jax.jvp`: one
    tangent, a quicker compilation than `jax.grad`'s reverse pass, the same number to rounding).

    The contact makes the objective piecewise smooth — small jumps where a jelly sample leaves
    the counted contact (beyond `reach`, or past the shell's edge): along `d` they add about
    7e-4 percent points per 1e-6 m, so a difference quotient with steps of 1 µm or less
    measures the jumps (it grows as 1/eps), while `eps` = 0.1 mm averages over them (the same
    with the contact's damper off)."""
    d = np.where(np.asarray(s.free), np.random.default_rng(seed).normal(size=(8, 8)), 0.0)
    d = jnp.asarray(d)
    zero = jnp.zeros((8, 8))
    tangent = jax.jit(lambda x: jax.jvp(lambda o: objective(o, s), (x,), (d,))[1])(zero)
    value = jax.jit(objective)
    fd = (value(eps * d, s) - value(-eps * d, s)) / (2 * eps)
    return float(tangent), float(fd)


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
        "jelly_nodes": s.study.scene.bodies[1].lattice.n_nodes,
        "steps": int(round(s.seconds / s.dt)),
        "gradient_check": {"jax_jvp": analytic, "central_difference": fd},
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
