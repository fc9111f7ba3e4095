"""The experiments of `bsjax sweep`: one function per design, evaluated over a grid of designs
with `bsjax.batch.map`.

* `spoon` — the jelly resting in the steel spoon, two deformable bodies in contact
  (`bsjax.examples.spoon.study`, thesis §7.3): parameters `tilt` and `roll` (degrees: the spoon
  pitched backwards, rolled about the handle), `shake_axis` (degrees from the handle: 0 along
  it, 90 across), `shake_amplitude` (m) and `shake_frequency` (Hz) of the hand → `spilled`,
  `front`, `back`, `side` (mass fractions of the jelly off the bowl, by exit,
  `spoon.spilled`) and `risk` (`spoon.spill_risk`).
* `collide` — a sphere of `radius` centred at `(x, y, z)` over a surface → `area` (the surface
  area in contact, m² or the surface's units²), `max_depth` and `force` (the magnitude of the
  contact force, Gao & Gibson, *Haptic B-spline surface sculpting with a shaped
  tool of implicit surface*, §3.2, at a stiffness of 1 per sample).
* `merge` — the two patches of the thesis's merge case 2 merged at C^`continuity` from `samples`
  samples per patch (thesis ch. 4) → `mean` and `max` deviation of the originals from the merged
  surface (thesis App. A).

A design's parameters are arrays, traced, except the static ones (`merge`'s `continuity` and
`samples` are ints that change the program: the knot layout and the sample grid). `evaluate`
groups the designs by their static values and maps each group's per-design function over its
array parameters; every merge design is its own group (one compilation per group).

Everything a design shares (the spoon study's two bodies and step, the sample grid of the
surface, the patches) is built once by the experiment's `setup` and bound to the per-design
function with `functools.partial`, so that `bsjax.batch.map` passes its arrays replicated.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import batch, collide, merge
from bsjax.basis import Blending, BSplineSurface
from bsjax.examples import spoon

__all__ = ["EXPERIMENTS", "Experiment", "Parameter", "evaluate", "grid"]


# --- parameters and grids ------------------------------------------------------------------------
@dataclass(frozen=True)
class Parameter:
    """One parameter of an experiment: its unit, the value used when the sweep leaves it out,
    its admissible range (`low` ≤ value ≤ `high`, `low` excluded when `open_low`) and whether it
    is a static int (a new value is a new program)."""

    name: str
    unit: str
    default: float
    low: float = -np.inf
    high: float = np.inf
    open_low: bool = False
    static: bool = False

    def check(self, values: np.ndarray) -> str | None:
        """None when every value is admissible, else what was expected."""
        lo = "> " if self.open_low else ">= "
        bad_low = values <= self.low if self.open_low else values < self.low
        if np.any(bad_low) or np.any(values > self.high) or not np.all(np.isfinite(values)):
            span = f"{lo}{self.low:g}" if np.isinf(self.high) else f"in [{self.low:g}, {self.high:g}]"
            return f"{self.name} values {span}"
        if self.static and np.any(values != np.round(values)):
            return f"integer {self.name} values (a static int)"
        return None


def grid(parameters: dict[str, Parameter], specs: dict[str, tuple[float, float, int]]) -> dict:
    """The designs of a full grid, in grid order: the first parameter varies slowest.

    **Arguments:**
    - `parameters`: the experiment's parameters, in their canonical order.
    - `specs`: `name → (start, stop, count)`, `count` evenly spaced values from `start` to
      `stop` (both included; `start` alone when `count == 1`); a parameter left out takes its
      default.

    **Returns:** `name → (D,)` float64 numpy array per parameter (in `parameters`' order), with
    `D = Π count` designs in the order of `itertools.product` over the specs' order.
    """
    axes = {name: np.linspace(*specs[name][:2], specs[name][2]) for name in specs}
    rows = list(itertools.product(*axes.values()))
    table = {name: np.array([row[i] for row in rows], np.float64) for i, name in enumerate(axes)}
    size = len(rows)
    return {name: table.get(name, np.full(size, p.default)) for name, p in parameters.items()}


# --- spoon ---------------------------------------------------------------------------------------
SPOON_SIZES = {
    "quick": {
        "lattice": 3,
        "cycles": 30,
        "jelly_samples": (10, 10),
        "spoon_shape": (30, 8, 2),
        "seconds": 0.02,
    },
    "full": {
        "lattice": 6,
        "cycles": 100,
        "jelly_samples": (12, 12),
        "spoon_shape": (30, 8, 2),
        "seconds": 0.3,
    },
}


class SpoonSetup(eqx.Module):
    """What every spoon design shares: the study (`spoon.study`: the jelly resting in the steel
    spoon, two deformable bodies), its step `dt` and the simulated `seconds`."""

    study: spoon.Study
    dt: float = eqx.field(static=True)
    seconds: float = eqx.field(static=True)


def spoon_setup(
    designs: dict, quick: bool, dtype, surface: BSplineSurface | None = None, progress=None
) -> SpoonSetup:
    """The spoon (`shapes.spoon_handle` merged C¹ with `shapes.spoon_bowl`, or with `surface`:
    a bowl in the same frame, its u = 0 edge at the handle's end) as a steel shell and a
    B-spline sphere jelly on a VSOFM lattice (`spoon.study`, sizes `SPOON_SIZES`; the fit's
    training cycles reported to `progress(done, total)`)."""
    from bsjax import merge, shapes

    sizes = SPOON_SIZES["quick" if quick else "full"]
    bowl = shapes.spoon_bowl(dtype) if surface is None else surface
    merged = merge.merge([shapes.spoon_handle(dtype), bowl], direction="u", continuity=1)
    study = spoon.study(
        merged,
        lattice=sizes["lattice"],
        jelly_samples=sizes["jelly_samples"],
        spoon_shape=sizes["spoon_shape"],
        cycles=sizes["cycles"],
        progress=progress,
    )
    return SpoonSetup(study, spoon.step_size(study), sizes["seconds"])


def spoon_design(
    setup: SpoonSetup, tilt, roll, shake_axis, shake_amplitude, shake_frequency
) -> dict[str, Array]:
    """The jelly in the spoon pitched by `tilt` and rolled by `roll` degrees (`spoon.tilted`),
    the hand shaking by `shake_amplitude` m at `shake_frequency` Hz along `shake_axis` degrees
    from the handle (`spoon.shake`; 0 along it, 90 across): the spilled fraction in total and
    by exit (`spoon.spilled`) and the smooth `risk` (`spoon.spill_risk`) at the end."""
    hand = spoon.shake(setup.study, shake_axis, shake_amplitude, shake_frequency)
    states, t = spoon.run(setup.study, tilt, hand, seconds=setup.seconds, dt=setup.dt, roll_deg=roll)
    where = spoon.spilled(setup.study, states[1].position, t, hand)
    return {**where, "risk": spoon.spill_risk(setup.study, states[1].position, t, hand)}


# --- collide -------------------------------------------------------------------------------------
class CollideSetup(eqx.Module):
    """The surface's sample grid and control net, and each sample's area element `|S_u × S_v|
    Δu Δv` (trapezoid weights over the sample parameters)."""

    blending: Blending
    ctrl: Float[Array, "r s 3"]
    area: Float[Array, "m n"]


def collide_setup(designs: dict, quick: bool, dtype, surface: BSplineSurface | None = None) -> CollideSetup:
    """The surface (default `shapes.teardrop`) sampled `24 × 24` quick or `82 × 82`."""
    from bsjax import shapes

    surface = shapes.teardrop(dtype) if surface is None else surface
    m = 24 if quick else 82
    blending = surface.blending(m, m)
    su, sv = blending.tangents(surface.ctrl)
    weight_u, weight_v = _trapezoid(blending.params_u), _trapezoid(blending.params_v)
    area = jnp.linalg.norm(jnp.cross(su, sv), axis=-1) * weight_u[:, None] * weight_v[None, :]
    return CollideSetup(blending, surface.ctrl, area)


def _trapezoid(params) -> Array:
    gaps = jnp.diff(params)
    return 0.5 * (jnp.pad(gaps, (1, 0)) + jnp.pad(gaps, (0, 1)))


def collide_design(setup: CollideSetup, radius, x, y, z) -> dict[str, Array]:
    """A sphere of `radius` at `(x, y, z)` against the surface: `{"area", "max_depth", "force"}`
    — the contact samples' area, their deepest penetration and `|F|` of `collide.contact_force`
    (stiffness 1 per sample, surface normals)."""
    tool = collide.Sphere(jnp.stack([x, y, z]), radius)
    contact = collide.contacts(setup.blending, setup.ctrl, tool)
    force = collide.contact_force(contact, 1.0)
    return {
        "area": jnp.sum(jnp.where(contact.mask, setup.area, 0.0)),
        "max_depth": jnp.max(contact.depth),
        "force": jnp.linalg.norm(force),
    }


# --- merge ---------------------------------------------------------------------------------------
class MergeSetup(eqx.Module):
    """The patches of merge case 2 (two bicubic 6 × 6 patches meeting along u), one merge plan
    (`merge.plan`, host-side) per `(continuity, samples)` of the designs, and the number of
    samples per original the deviation is measured on."""

    patches: tuple[BSplineSurface, ...]
    layouts: tuple[merge.MergeLayout, ...]
    keys: tuple[tuple[int, int], ...] = eqx.field(static=True)
    deviation_samples: int = eqx.field(static=True)


def merge_setup(designs: dict, quick: bool, dtype, surface: BSplineSurface | None = None) -> MergeSetup:
    """Merge case 2 of the thesis (`bsjax.examples.merge_cases.case(2)`), planned for every
    `(continuity, samples)` among `designs`; deviation on 21² (quick) or 101² samples per patch."""
    from bsjax.examples import merge_cases

    patches = tuple(p.with_ctrl(jnp.asarray(p.ctrl, dtype)) for p in merge_cases.case(2).patches)
    keys = tuple(dict.fromkeys(zip(_ints(designs["continuity"]), _ints(designs["samples"]))))
    layouts = tuple(merge.plan(list(patches), "u", c, samples=s, orient="as_given") for c, s in keys)
    return MergeSetup(patches, layouts, keys, 21 if quick else 101)


def _ints(values) -> list[int]:
    return [int(v) for v in np.asarray(values)]


def merge_design(setup: MergeSetup, ctrls, *, continuity: int, samples: int) -> dict[str, Array]:
    """The patches with control nets `ctrls` merged at C^`continuity` from `samples × samples`
    samples per patch (`MergeLayout.apply`, thesis eq. 3.7): `{"mean", "max"}` deviation of the
    originals from the merged surface (`merge.deviation`, closest points)."""
    layout = setup.layouts[setup.keys.index((continuity, samples))]
    originals = [p.with_ctrl(c) for p, c in zip(setup.patches, ctrls)]
    merged = layout.surface(layout.apply(list(ctrls)))
    report = merge.deviation(originals, merged, samples=setup.deviation_samples)
    return {"mean": report.mean, "max": report.max}


# --- the registry and the evaluation -------------------------------------------------------------
@dataclass(frozen=True)
class Experiment:
    """An experiment: its parameters (canonical order), outputs, the shared `setup(designs,
    quick, dtype, surface)` and the per-design function `design(setup, *arrays, **statics)`;
    `inputs(setup, arrays)` gives the design function's batched arguments (by default the
    array parameters); `setup_progress` names what a long setup reports to its `progress(done,
    total)` keyword (None: the setup is short and takes none)."""

    name: str
    parameters: dict[str, Parameter]
    outputs: tuple[str, ...]
    setup: Callable
    design: Callable
    inputs: Callable | None = None
    setup_progress: str | None = None

    @property
    def static(self) -> tuple[str, ...]:
        return tuple(n for n, p in self.parameters.items() if p.static)


def _merge_inputs(setup: MergeSetup, arrays: dict, size: int) -> tuple:
    """Merge designs have no array parameter: the batch is the patches' nets, once per design."""
    return (tuple(jnp.broadcast_to(p.ctrl, (size, *p.ctrl.shape)) for p in setup.patches),)


def _params(*items: Parameter) -> dict[str, Parameter]:
    return {p.name: p for p in items}


EXPERIMENTS = {
    "spoon": Experiment(
        "spoon",
        _params(
            Parameter("tilt", "deg", 0.0, -90.0, 90.0),
            Parameter("roll", "deg", 0.0, -90.0, 90.0),
            Parameter("shake_axis", "deg", 0.0, -360.0, 360.0),
            Parameter("shake_amplitude", "m", 0.0, 0.0, 0.05),
            Parameter("shake_frequency", "Hz", 4.0, 0.0, 50.0, open_low=True),
        ),
        ("spilled", "front", "back", "side", "risk"),
        spoon_setup,
        spoon_design,
        setup_progress="VSOFM cycles",
    ),
    "collide": Experiment(
        "collide",
        _params(
            Parameter("radius", "m", 0.2, 0.0, open_low=True),
            Parameter("x", "m", 0.6),
            Parameter("y", "m", 0.0),
            Parameter("z", "m", 0.0),
        ),
        ("area", "max_depth", "force"),
        collide_setup,
        collide_design,
    ),
    "merge": Experiment(
        "merge",
        _params(
            Parameter("continuity", "", 1, 0, 2, static=True),
            Parameter("samples", "", 41, 4, 400, static=True),
        ),
        ("mean", "max"),
        merge_setup,
        merge_design,
        _merge_inputs,
    ),
}


def evaluate(
    experiment: Experiment,
    setup,
    designs: dict[str, np.ndarray],
    *,
    chunk: int | None = None,
    progress: Callable[[int, int], object] | None = None,
) -> dict[str, np.ndarray]:
    """Every design's outputs, in design order, through `bsjax.batch.map`.

    **Arguments:**
    - `experiment`, `setup`: an `Experiment` and its `setup(...)`.
    - `designs`: `name → (D,)` parameter values (`grid`).
    - `chunk`: designs per `batch.map` call (see `bsjax.batch.map`); `progress(done, total)`
      after each chunk, counted over every design.

    **Returns:** `output → (D,)` float64 numpy array. Designs are grouped by their static values
    (in order of first appearance); each group is one `batch.map` of `experiment.design` with
    the setup and the static values bound (`functools.partial`), over the group's array
    parameters. Every process must call it (it gathers the results from all of them).
    """
    total = len(next(iter(designs.values())))
    static = experiment.static
    keys = [tuple(int(designs[n][i]) for n in static) for i in range(total)]
    groups = list(dict.fromkeys(keys))
    out = {name: np.zeros(total) for name in experiment.outputs}
    done = 0
    for key in groups:
        index = np.array([i for i, k in enumerate(keys) if k == key])
        fn = functools.partial(experiment.design, setup, **dict(zip(static, key)))
        arrays = {
            n: jnp.asarray(designs[n][index], _dtype(setup)) for n in experiment.parameters if n not in static
        }
        inputs = experiment.inputs(setup, arrays, len(index)) if experiment.inputs else tuple(arrays.values())
        step = None if progress is None else functools.partial(_shifted, progress, done, total)
        result = batch.gather(batch.map(fn, *inputs, chunk=chunk, progress=step))
        for name in experiment.outputs:
            out[name][index] = np.asarray(result[name], np.float64)
        done += len(index)
    return out


def _shifted(progress, offset: int, total: int, done: int, _: int):
    progress(offset + done, total)


def _dtype(setup) -> np.dtype:
    """The setup's floating dtype (float32 with `--float32`, else float64)."""
    floats = [x.dtype for x in jax.tree.leaves(setup) if jnp.issubdtype(x.dtype, jnp.floating)]
    return np.dtype(floats[0])
