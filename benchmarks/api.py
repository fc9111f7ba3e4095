"""Every public entry point timed as a user calls it, beside the same call under `jax.jit`.

    .venv/bin/python benchmarks/api.py                  # the documented sizes, float64
    .venv/bin/python benchmarks/api.py --quick          # small sizes, few calls (the test runs this)
    .venv/bin/python benchmarks/api.py --only collide   # entries whose name contains "collide"
    .venv/bin/python benchmarks/api.py --only mss.step,stable_dt   # several substrings
    .venv/bin/python benchmarks/api.py --calls 200 --json api.json
    .venv/bin/python benchmarks/api.py --cold           # each entry's first call in a new process

`--cold`: the first call as a new notebook kernel or script meets it. Per entry, two new
processes share an empty compilation cache (`bsjax.enable_compilation_cache`): the first pays
tracing and compilation (`first s`), the second loads the programs the first stored (`cached
s`: a direct call's whole program, untraced, and JAX's cache entries of the setup's programs); `setup s` builds the entry's inputs (other entries' first calls), `second ms` is the call
once more in the first process. The budgets are on what the first call adds to the call itself
— `compile s = first − second` ≤ 2 s, `load s = cached − second` ≤ 0.5 s — which is the whole
first call for every entry but those whose work takes a noticeable time of its own (`vsofm.fit`:
300 cycles of 1 728 nodes against 6 488 samples, ~0.3 s a call). One more process times
`import bsjax` and the subpackages (`import s`, budget 1 s for `import bsjax`).

One row per entry:

* **first s**: the first call on a fresh entry point (`bsjax._boundary.clear_caches()` and
  `jax.clear_caches()` just before it): trace + compile + run, what a new script or notebook pays.
* **median / p99 ms**: the entry called directly, exactly as the documentation shows it, from its second
  call on (same shapes and options), `block_until_ready` after each call.
* **jitted ms**: the median of the same call wrapped by this benchmark in its own `jax.jit`, with
  the same arguments passed as arguments (static options closed over).
* **ratio** = as-called median / jitted median, and the verdict: `ok` when the ratio is ≤ 2 or
  the two medians differ by ≤ 0.3 ms, `SLOW` otherwise; `n/a` for host-side entries
  that have no jitted equivalent (`merge.plan`, a cached host-side plan; `vsofm.report`, a
  summary of Python numbers). `merge.merge`/`merge_grid` cannot run inside a caller's jit (they
  plan on the host from concrete knots); their jitted twin is what the merging guide shows a user:
  `layout = plan(...)` once, then `layout.surface(layout.apply(nets))` under `jax.jit`.

An entry that raises prints `ERROR: <type>: <first line of the message>` and the run goes on, so
the table also works while the modules change. Each entry is a small function in `ENTRIES`
(registered with `@entry(name)`): it builds its inputs and returns a `Case`; add one the same way.

Sizes: a 12×12 bicubic plate sampled at 82×82 (basis, collide), a 6³ jelly lattice (mss; 200 steps
for the rollouts), two 8×8 patches (merge; a 2×2 grid of them for `merge_grid`), a 12³ VSOFM on
82×82 teardrop samples (300 cycles). `--quick` shrinks everything for the smoke test.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _timing import paired, timed  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

import bsjax  # noqa: E402
import bsjax._boundary  # noqa: E402
from bsjax import collide, merge, mss, shapes, vsofm  # noqa: E402

RATIO_OK = 2.0
DIFF_OK = 0.3e-3  # s
STEADY_BUDGET = 2.0  # s of steady-state calls per variant (fewer calls for slow entries)


# --- sizes -------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Sizes:
    net: int = 12  # plate control net (basis, collide)
    grid: int = 82  # samples per direction
    n_eval: int = 1000  # random (u, v) for evaluate / normal
    lattice: int = 6  # mss hex lattice per side
    steps: int = 200  # rollout steps
    patch: int = 8  # merge patches
    merge_samples: int = 82
    deviation: int = 41  # samples per direction of each original (the default 101: ~40 s a call)
    som: int = 12  # VSOFM lattice per side
    cycles: int = 300
    coupled_grid: int = 24  # surface lattice of simulate_coupled
    contact_grid: int = 24  # samples per direction of surface_penetration and the scene's shells
    shell: int = 8  # nodes across each shell of the scene (the physics guide: two 8×8×2 jelly shells)
    scene_steps: int = 40


FULL = Sizes()
QUICK = Sizes(net=6, grid=20, n_eval=100, lattice=3, steps=20, patch=4, merge_samples=16, deviation=11,
              som=4, cycles=10, coupled_grid=8, contact_grid=8, shell=4, scene_steps=5)  # fmt: skip


# --- the table of entries ----------------------------------------------------------------------
@dataclasses.dataclass
class Case:
    """One benchmark call: `call(*args)` is the user's call; `args` hold only arrays, Python
    floats and pytrees of arrays (static options are closed over in `call`), so `jax.jit(call)`
    is the same call compiled by the caller. `jit=False`: a host-side entry (no jitted twin).
    `twin`: for calls that plan on the host (a merge reads the knots and, with `orient="auto"`, the
    nets' edges), the hand-jitted equivalent a user writes, on the same arguments."""

    call: Callable
    args: tuple
    size: str
    jit: bool = True
    twin: Callable | None = None  # the jitted twin when `call` cannot be traced as written


@dataclasses.dataclass(frozen=True)
class Entry:
    name: str
    setup: Callable[[Sizes], Case]


ENTRIES: list[Entry] = []


def entry(name: str):
    """Register `setup(sizes) -> Case` as the entry `name` (group.function)."""

    def register(setup):
        ENTRIES.append(Entry(name, setup))
        return setup

    return register


# --- shared inputs (built once per size, outside the timings) ----------------------------------
@functools.cache
def plate(q: Sizes):
    s = shapes.plate(q.net, q.net)
    return s, s.blending(q.grid, q.grid)


@functools.cache
def sphere_contact(q: Sizes):
    s, b = plate(q)
    return collide.contacts(b, s.ctrl, collide.Sphere(jnp.array([0.5, 0.5, 0.1]), 0.25))


@functools.cache
def hex_model(q: Sizes):
    n = q.lattice
    axis = jnp.linspace(0.0, 0.05, n)
    nodes = jnp.stack(jnp.meshgrid(axis, axis, axis, indexing="ij"), -1)
    lattice = mss.hex_lattice(nodes, material=mss.JELLY, fixed=nodes[..., 2] < 1e-9)
    dt = 0.5 * float(mss.stable_dt(lattice))
    return lattice, mss.init(lattice), dt


@functools.cache
def patches(q: Sizes):
    a = shapes.plate(q.patch, q.patch)
    shift = lambda s, dx, dy: s.with_ctrl(s.ctrl + jnp.array([dx, dy, 0.0]))
    return a, shift(a, 1.0, 0.0), shift(a, 0.0, 1.0), shift(a, 1.0, 1.0)


@functools.cache
def teardrop_points(q: Sizes):
    s = shapes.teardrop()
    return s.blending(q.grid, q.grid).points(s.ctrl).reshape(-1, 3)


@functools.cache
def som_nodes(q: Sizes):
    return vsofm.fit(teardrop_points(q), (q.som,) * 3, cycles=q.cycles)


def torus(x):
    """A torus around (0.5, 0.5, 0) in the plate's plane (R = 0.3, r = 0.1): `< 0` inside."""
    rho = jnp.sqrt(jnp.sum((x[:2] - 0.5) ** 2) + 1e-30)
    return (rho - 0.3) ** 2 + x[2] ** 2 - 0.1**2


def grid_size(q: Sizes) -> str:
    return f"{q.net}x{q.net} net, {q.grid}x{q.grid}"


# --- basis ---------------------------------------------------------------------------------------
@entry("basis.Blending.points")
def _(q):
    s, b = plate(q)
    return Case(lambda b, c: b.points(c), (b, s.ctrl), grid_size(q))


@entry("basis.Blending.derivative")
def _(q):
    s, b = plate(q)
    return Case(lambda b, c: b.derivative(c, 1, 0), (b, s.ctrl), grid_size(q) + ", (1, 0)")


@entry("basis.Blending.tangents")
def _(q):
    s, b = plate(q)
    return Case(lambda b, c: b.tangents(c), (b, s.ctrl), grid_size(q))


@entry("basis.Blending.normals")
def _(q):
    s, b = plate(q)
    return Case(lambda b, c: b.normals(c), (b, s.ctrl), grid_size(q))


@entry("basis.Blending.refit")
def _(q):
    s, b = plate(q)
    return Case(lambda b, m: b.refit(m), (b, b.points(s.ctrl)), grid_size(q))


def _uv(q):
    rng = np.random.default_rng(0)
    return jnp.asarray(rng.uniform(size=q.n_eval)), jnp.asarray(rng.uniform(size=q.n_eval))


@entry("basis.BSplineSurface.evaluate")
def _(q):
    s, _ = plate(q)
    return Case(lambda s, u, v: s.evaluate(u, v), (s, *_uv(q)), f"{q.net}x{q.net} net, {q.n_eval} (u, v)")


@entry("basis.BSplineSurface.normal")
def _(q):
    s, _ = plate(q)
    return Case(lambda s, u, v: s.normal(u, v), (s, *_uv(q)), f"{q.net}x{q.net} net, {q.n_eval} (u, v)")


@entry("basis.BSplineSurface.blending")
def _(q):
    s, _ = plate(q)
    return Case(lambda s: s.blending(q.grid, q.grid), (s,), grid_size(q))


@entry("basis.BSplineSurface.iso_curve")
def _(q):
    s, _ = plate(q)
    return Case(lambda s, t: s.iso_curve("u", t), (s, jnp.asarray(0.3)), f"{q.net}x{q.net} net")


@functools.cache
def curve(q: Sizes):
    """A random planar cubic with `q.net` control points and its blending at `q.grid ** 2` samples."""
    rng = np.random.default_rng(1)
    c = bsjax.BSplineCurve(jnp.asarray(rng.normal(size=(q.net, 2))), bsjax.clamped_knots(q.net, 3), 3)
    return c, c.blending(q.grid * q.grid)


def _curve_size(q, what="samples"):
    return f"{q.net} ctrl, {q.grid * q.grid} {what}"


@entry("basis.BSplineCurve.evaluate")
def _(q):
    c, _ = curve(q)
    t = jnp.asarray(np.random.default_rng(0).uniform(size=q.n_eval))
    return Case(lambda c, t: c.evaluate(t, 1), (c, t), f"{q.net} ctrl, {q.n_eval} t, nu = 1")


@entry("basis.BSplineCurve.curvature")
def _(q):
    c, _ = curve(q)
    t = jnp.asarray(np.random.default_rng(0).uniform(size=q.n_eval))
    return Case(lambda c, t: c.curvature(t), (c, t), f"{q.net} ctrl, {q.n_eval} t")


@entry("basis.BSplineCurve.blending")
def _(q):
    c, _ = curve(q)
    return Case(lambda c: c.blending(q.grid * q.grid), (c,), _curve_size(q))


@entry("basis.CurveBlending.points")
def _(q):
    c, b = curve(q)
    return Case(lambda b, p: b.points(p), (b, c.ctrl), _curve_size(q))


@entry("basis.CurveBlending.derivative")
def _(q):
    c, b = curve(q)
    return Case(lambda b, p: b.derivative(p, 2), (b, c.ctrl), _curve_size(q) + ", nu = 2")


@entry("basis.CurveBlending.refit")
def _(q):
    c, b = curve(q)
    return Case(lambda b, m: b.refit(m), (b, b.points(c.ctrl)), _curve_size(q))


# --- collide -------------------------------------------------------------------------------------
def _tools():
    """name -> tool builder (called inside setup, after the sizes are known)."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=1, radius=0.25)
    ico.apply_translation([0.5, 0.5, 0.1])
    return {
        "Point": lambda: collide.Point(jnp.array([0.37, 0.61, -0.02])),
        "Sphere": lambda: collide.Sphere(jnp.array([0.5, 0.5, 0.1]), 0.25),
        "Ellipsoid": lambda: collide.Ellipsoid(jnp.array([0.5, 0.5, 0.05]), jnp.array([0.3, 0.2, 0.1])),
        "Plane": lambda: collide.Plane(jnp.array([0.0, 0.0, 0.05]), jnp.array([0.0, 0.0, 1.0])),
        "Implicit": lambda: collide.Implicit(torus),
        "TriangleMesh": lambda: collide.TriangleMesh.from_trimesh(ico),
    }


def _contacts_entry(tool_name: str):
    def setup(q):
        s, b = plate(q)
        tool = _tools()[tool_name]()
        size = grid_size(q) + (", icosphere 80 faces" if tool_name == "TriangleMesh" else "")
        return Case(collide.contacts, (b, s.ctrl, tool), size)

    return setup


for _name in ("Point", "Sphere", "Ellipsoid", "Plane", "Implicit", "TriangleMesh"):
    entry(f"collide.contacts({_name})")(_contacts_entry(_name))


@entry("collide.surface_contacts")
def _(q):
    s, b = plate(q)
    tilted = s.ctrl.at[..., 2].set(0.3 * (s.ctrl[..., 0] - 0.5))  # crosses the plate along x = 0.5
    return Case(collide.surface_contacts, (b, s.ctrl, b, tilted), grid_size(q) + " x2, crossing")


@entry("collide.surface_penetration")
def _(q):
    s = shapes.plate(q.net, q.net)
    b = s.blending(q.contact_grid, q.contact_grid)
    above = s.ctrl[:, ::-1] + jnp.array([0.3, 0.2, -0.01])  # facing it, 1 cm into it, shifted
    call = lambda ba, ca, bb, cb, reach: collide.surface_penetration(ba, ca, bb, cb, reach=reach)
    size = f"{q.net}x{q.net} nets, {q.contact_grid}x{q.contact_grid} x2, overlapping"
    return Case(call, (b, s.ctrl, b, above, 0.05), size)


@entry("collide.contact_force")
def _(q):
    return Case(lambda c, k: collide.contact_force(c, stiffness=k), (sphere_contact(q), 200.0), grid_size(q))


@entry("collide.sample_forces")
def _(q):
    return Case(lambda c, k: collide.sample_forces(c, k), (sphere_contact(q), 200.0), grid_size(q))


# --- merge ---------------------------------------------------------------------------------------
def _pair_size(q):
    return f"2 x {q.patch}x{q.patch}, {q.merge_samples} samples"


def _applied(layout, nets):
    """The hand-jitted merge a user writes (the merging guide): the layout planned once on the host, then
    `layout.apply` on the traced nets inside jit (`nets(*surfaces)` arranges them as `apply` wants)."""
    return lambda *surfaces: layout.surface(layout.apply(nets(*surfaces)))


@entry("merge.merge")
def _(q):
    a, b, _, _ = patches(q)
    n = q.merge_samples
    layout = merge.plan([a, b], "u", 0, samples=n)
    twin = _applied(layout, lambda a, b: [a.ctrl, b.ctrl])
    return Case(lambda a, b: merge.merge([a, b], "u", 0, samples=n), (a, b), _pair_size(q), twin=twin)


@entry("merge.merge_grid")
def _(q):
    a, b, c, d = patches(q)
    n = q.merge_samples
    layout = merge.plan_grid([[a, c], [b, d]], 0, samples=n)
    twin = _applied(layout, lambda a, b, c, d: [[a.ctrl, c.ctrl], [b.ctrl, d.ctrl]])
    call = lambda a, b, c, d: merge.merge_grid([[a, c], [b, d]], 0, samples=n)
    return Case(call, (a, b, c, d), f"2x2 x {q.patch}x{q.patch}, {n} samples", twin=twin)


@entry("merge.plan")
def _(q):
    a, b, _, _ = patches(q)
    n = q.merge_samples
    call = lambda a, b: merge.plan([a, b], "u", 0, samples=n)
    return Case(call, (a, b), _pair_size(q) + ", host-side, cached", jit=False)


@entry("merge.deviation")
def _(q):
    a, b, _, _ = patches(q)
    merged = merge.merge([a, b], "u", 0, samples=q.merge_samples)
    n = q.deviation
    call = lambda a, b, m: merge.deviation([a, b], m, samples=n)
    return Case(call, (a, b, merged), _pair_size(q) + f", {n}x{n} per patch")


@entry("merge.refit")
def _(q):
    a, b, _, _ = patches(q)
    layout = merge.plan([a, b], "u", 0, samples=q.merge_samples)
    return Case(lambda lay, ca, cb: merge.refit(lay, [ca, cb]), (layout, a.ctrl, b.ctrl), _pair_size(q))


# --- mss -----------------------------------------------------------------------------------------
def _lat_size(q, steps=None):
    return f"{q.lattice}^3 jelly" + ("" if steps is None else f", {steps} steps")


GRAVITY = jnp.array([0.0, 0.0, -9.81])


@entry("mss.step")
def _(q):
    lat, st, dt = hex_model(q)
    return Case(lambda lat, st, dt, g: mss.step(lat, st, dt, gravity=g), (lat, st, dt, GRAVITY), _lat_size(q))


@entry("mss.implicit_step")
def _(q):
    lat, st, dt = hex_model(q)
    call = lambda lat, st, dt, g: mss.implicit_step(lat, st, 10 * dt, gravity=g)
    return Case(call, (lat, st, dt, GRAVITY), _lat_size(q) + ", 20 CG")


@entry("mss.simulate")
def _(q):
    lat, st, dt = hex_model(q)
    call = lambda lat, st, dt, g: mss.simulate(lat, st, dt, q.steps, gravity=g)
    return Case(call, (lat, st, dt, GRAVITY), _lat_size(q, q.steps))


@entry("mss.trajectory")
def _(q):
    lat, st, dt = hex_model(q)
    call = lambda lat, st, dt, g: mss.trajectory(lat, st, dt, q.steps, gravity=g, save_every=10)
    return Case(call, (lat, st, dt, GRAVITY), _lat_size(q, q.steps) + ", every 10")


@entry("mss.relax")
def _(q):
    lat, st, dt = hex_model(q)
    n = 10 * q.steps
    call = lambda lat, st, dt, g: mss.relax(lat, st, dt, gravity=g, tol=1e-12, max_steps=n)
    return Case(call, (lat, st, dt, GRAVITY), _lat_size(q, f"<= {n}"))


@entry("mss.simulate_plastic")
def _(q):
    lat, st, dt = hex_model(q)
    tool = collide.Sphere(jnp.array([0.025, 0.025, 0.06]), 0.02)
    contact = mss.Penalty(1e3, 1.0)
    plastic = mss.Plasticity(0.01)
    n = q.steps

    def call(lat, st, dt, tool, contact, plastic):
        return mss.simulate_plastic(lat, st, dt, n, plastic, tools=(tool,), contact=contact)

    return Case(call, (lat, st, dt, tool, contact, plastic), _lat_size(q, n) + ", sphere")


@entry("mss.simulate_coupled")
def _(q):
    s, _ = plate(q)
    blend = s.blending(q.coupled_grid, q.coupled_grid)
    hang = np.broadcast_to(np.arange(q.coupled_grid)[:, None] < 2, (q.coupled_grid,) * 2)
    slat, coupling = mss.surface_lattice(blend, s.ctrl, mss.PLASTICINE, thickness=0.01, fixed=hang)
    dt = 0.5 * float(mss.stable_dt(slat))
    n = q.steps

    def call(slat, coupling, st, dt, g):
        return mss.simulate_coupled(slat, coupling, st, dt, n, refit_every=20 if n >= 20 else n, gravity=g)

    size = f"{q.coupled_grid}^2 surface lattice, {n} steps"
    return Case(call, (slat, coupling, mss.init(slat), dt, GRAVITY), size)


@entry("mss.simulate_scene")
def _(q):
    plate = shapes.plate(5, 5, size=0.1)  # the physics guide's two jelly shells, one falling on the other
    shape = (q.shell, q.shell, 2)
    below = mss.Body.from_surface(plate, shape, mss.JELLY, thickness=0.01)
    moved = plate.with_ctrl(plate.ctrl[:, ::-1] + jnp.array([0, 0, 0.002]))
    above = mss.Body.from_surface(moved, shape, mss.JELLY, thickness=0.01)
    scene = mss.Scene((below, above), contact=collide.DistributedSprings(200.0, 0.5))
    start = mss.scene_init(scene)
    start = (start[0], mss.State(start[1].position, start[1].velocity.at[:, 2].set(-0.5)))
    dt = 0.5 * float(mss.scene_stable_dt(scene))
    n = q.scene_steps
    call = lambda scene, states, dt: mss.simulate_scene(scene, states, dt, n)
    return Case(call, (scene, start, dt), f"two {q.shell}x{q.shell}x2 shells, {n} steps")


@entry("mss.stable_dt")
def _(q):
    lat, _, _ = hex_model(q)
    return Case(mss.stable_dt, (lat,), _lat_size(q))


# --- vsofm ---------------------------------------------------------------------------------------
@entry("vsofm.fit")
def _(q):
    # distinct samples: a direct call drops repeats (pole, seam) first, a jitted one cannot, so
    # both get the same distinct cloud and do the same work
    pts = np.unique(teardrop_points(q), axis=0)
    shape, cycles = (q.som,) * 3, q.cycles
    call = lambda p, k: vsofm.fit(p, shape, cycles=cycles, key=k)
    size = f"{q.som}^3, {cycles} cycles, {pts.shape[0]} distinct samples"
    return Case(call, (pts, jax.random.PRNGKey(0)), size)


@entry("vsofm.report")
def _(q):
    pts = teardrop_points(q)
    return Case(vsofm.report, (pts, som_nodes(q)), f"{q.som}^3, {pts.shape[0]} samples", jit=False)


@entry("mss.hex_lattice")
def _(q):
    return Case(lambda n: mss.hex_lattice(n, material=mss.JELLY), (som_nodes(q),), f"{q.som}^3")


# --- running -------------------------------------------------------------------------------------
def fresh():
    """Forget every compiled entry point and every jax compilation (the next call compiles)."""
    bsjax._boundary.clear_caches()
    jax.clear_caches()


def first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:160]


def budget(fn, calls: int, per_call: int = 1) -> int:
    """How many calls (at least 5, at most `calls`) fit the time budget, from one timed call of
    `fn` (the second call: the first after compilation); `per_call` functions run per count."""
    t0 = time.perf_counter()
    fn()
    once = time.perf_counter() - t0
    return int(min(calls, max(5, STEADY_BUDGET / max(per_call * once, 1e-6))))


def steady(fn, calls: int):
    """(median, p99, n) of `fn()` from its second call on; fewer calls when one takes long."""
    n = budget(fn, calls)
    med, p99 = timed(fn, n, warmup=1)
    return med, p99, n


def run_entry(e: Entry, q: Sizes, calls: int) -> dict[str, Any]:
    row: dict[str, Any] = {"name": e.name}
    try:
        case = e.setup(q)
        row["size"] = case.size
        jax.block_until_ready(case.args)
        call, args = case.call, case.args
        as_called = lambda: jax.block_until_ready(call(*args))
        fresh()
        t0 = time.perf_counter()
        as_called()
        row["first_s"] = time.perf_counter() - t0
    except Exception as exc:  # one failing entry must not stop the table
        row["error"] = first_line(exc)
        return row
    if not case.jit:
        row["median_s"], row["p99_s"], row["calls"] = steady(as_called, calls)
        row["jitted_s"] = row["ratio"] = None
        row["verdict"] = "n/a"
        return row
    try:
        jitted = jax.jit(case.twin or call)
        jax.block_until_ready(jitted(*args))  # compile
        hand = lambda: jax.block_until_ready(jitted(*args))
        n = budget(as_called, calls, per_call=2)
        # as called and hand-jitted in alternation: the machine's load falls on both alike
        row["median_s"], row["p99_s"], row["jitted_s"], _ = paired(as_called, hand, n)
        row["calls"] = n
    except Exception as exc:
        row["error"] = "jitted: " + first_line(exc)
        return row
    row["ratio"] = row["median_s"] / row["jitted_s"]
    good = row["ratio"] <= RATIO_OK or row["median_s"] - row["jitted_s"] <= DIFF_OK
    row["verdict"] = "ok" if good else "SLOW"
    return row


HEADER = (
    f"{'entry':34} {'size':40} {'first s':>8} {'median ms':>10} {'p99 ms':>9} {'jitted ms':>10} "
    f"{'ratio':>7} {'verdict':>7} {'calls':>5}"
)


def format_row(row: dict[str, Any]) -> str:
    head = f"{row['name']:34} {row.get('size', ''):40}"
    if "error" in row and "median_s" not in row:
        return f"{head} ERROR: {row['error']}"
    ms = lambda s: "-" if s is None else f"{1e3 * s:.3f}"
    line = f"{head} {row['first_s']:8.2f} {ms(row['median_s']):>10} {ms(row['p99_s']):>9}"
    if "error" in row:
        return f"{line} ERROR: {row['error']}"
    ratio = "-" if row["ratio"] is None else f"{row['ratio']:.2f}"
    return f"{line} {ms(row['jitted_s']):>10} {ratio:>7} {row['verdict']:>7} {row['calls']:5d}"


def summary(rows: list[dict[str, Any]]) -> str:
    ok = [r["name"] for r in rows if r.get("verdict") == "ok"]
    slow = [r["name"] for r in rows if r.get("verdict") == "SLOW"]
    na = [r["name"] for r in rows if r.get("verdict") == "n/a"]
    err = [r["name"] for r in rows if "error" in r]
    parts = [f"SUMMARY: {len(ok)}/{len(rows)} ok", f"not ok: {', '.join(slow) or 'none'}"]
    parts.append(f"errors: {', '.join(err) or 'none'}")
    if na:
        parts.append(f"n/a (host-side): {', '.join(na)}")
    return "; ".join(parts)


FIRST_BUDGET, CACHED_BUDGET, IMPORT_BUDGET = 2.0, 0.5, 1.0  # s


def cold_child(name: str, q: Sizes) -> dict[str, Any]:
    """In this (new) process: `setup_s`, `first_s`, `second_s` of the entry `name`."""
    e = next(e for e in ENTRIES if e.name == name)
    t0 = time.perf_counter()
    case = e.setup(q)
    jax.block_until_ready(case.args)
    t1 = time.perf_counter()
    jax.block_until_ready(case.call(*case.args))
    t2 = time.perf_counter()
    jax.block_until_ready(case.call(*case.args))
    t3 = time.perf_counter()
    return {"name": name, "size": case.size, "setup_s": t1 - t0, "first_s": t2 - t1, "second_s": t3 - t2}


_IMPORT = """
import time
t0 = time.perf_counter(); import bsjax; t1 = time.perf_counter()
from bsjax import basis, collide, merge, mss, shapes, vsofm; t2 = time.perf_counter()
print(f"{t1 - t0} {t2 - t1}")
"""


def _child(args: list[str], cache) -> dict[str, Any]:
    env = {**os.environ, "BSJAX_CACHE_DIR": str(cache)}
    for key in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"):
        env.pop(key, None)
    out = subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, timeout=900)
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["?"])[-1][:160]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _added(row: dict[str, Any]) -> tuple[float, float]:
    """What the first call adds to the call itself (`second s`): in a new process with an empty
    cache (trace, compile) and with the first process's cache (loading the stored programs)."""
    return row["first_s"] - row["second_s"], row["cached_s"] - row["second_s"]


def _within(row: dict[str, Any]) -> bool:
    compile_s, load_s = _added(row)
    return compile_s <= FIRST_BUDGET and load_s <= CACHED_BUDGET


def run_cold(entries: list[Entry], quick: bool) -> list[dict[str, Any]]:
    """Each entry in two new processes sharing a fresh compilation cache (module docstring)."""
    times = subprocess.run([sys.executable, "-c", _IMPORT], capture_output=True, text=True, check=True)
    bare, subpackages = (float(t) for t in times.stdout.split())
    print(f"import bsjax {bare:.3f} s ({'ok' if bare <= IMPORT_BUDGET else 'SLOW'}); "
          f"basis, collide, merge, mss, shapes, vsofm {subpackages:.2f} s", flush=True)  # fmt: skip
    print(f"{'entry':34} {'size':40} {'setup s':>8} {'first s':>8} {'cached s':>8} {'second ms':>10} "
          f"{'compile s':>9} {'load s':>7} verdict")  # fmt: skip
    rows = []
    for e in entries:
        args = [__file__, "--child", e.name] + (["--quick"] if quick else [])
        with tempfile.TemporaryDirectory() as cache:
            row = _child(args, cache)
            if "error" not in row:
                warm = _child(args, cache)
                row["cached_s"] = warm.get("first_s", float("nan"))
        row["name"] = e.name
        rows.append(row)
        if "error" in row:
            print(f"{e.name:34} ERROR: {row['error']}", flush=True)
            continue
        compile_s, load_s = _added(row)
        print(f"{e.name:34} {row['size']:40} {row['setup_s']:8.2f} {row['first_s']:8.2f} "
              f"{row['cached_s']:8.2f} {1e3 * row['second_s']:10.2f} {compile_s:9.2f} {load_s:7.2f} "
              f"{'ok' if _within(row) else 'OVER'}", flush=True)  # fmt: skip
    over = [r["name"] for r in rows if "error" in r or not _within(r)]
    print(f"COLD: {len(rows) - len(over)}/{len(rows)} within {FIRST_BUDGET} s first / {CACHED_BUDGET} s "
          f"cached (added to the call itself); over or failed: {', '.join(over) or 'none'}")  # fmt: skip
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes and few calls (smoke test)")
    parser.add_argument("--calls", type=int, default=None, help="steady-state calls per variant (max)")
    parser.add_argument(
        "--only", default=None, help="run the entries whose name contains this (several: comma-separated)"
    )
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument("--cold", action="store_true", help="first calls in new processes (see module doc)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)  # one entry of --cold
    args = parser.parse_args(argv)
    q = QUICK if args.quick else FULL
    if args.child:
        bsjax.enable_compilation_cache()  # BSJAX_CACHE_DIR from the parent
        print(json.dumps(cold_child(args.child, q)))
        return 0
    calls = args.calls or (5 if args.quick else 100)
    wanted = None if args.only is None else [w for w in args.only.split(",") if w]
    entries = [e for e in ENTRIES if wanted is None or any(w in e.name for w in wanted)]
    if not entries:
        parser.error(
            f"--only {args.only!r}: no entry matches (entries: {', '.join(e.name for e in ENTRIES)})"
        )

    print(f"bsjax public entry points, float64, {'--quick' if args.quick else 'full'} sizes", flush=True)
    if args.cold:
        rows = run_cold(entries, args.quick)
    else:
        print(HEADER, flush=True)
        rows = []
        for e in entries:
            rows.append(run_entry(e, q, calls))
            print(format_row(rows[-1]), flush=True)

    load = os.getloadavg()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; {date}; jax {jax.__version__}; "
          f"{jax.devices()[0].platform}")  # fmt: skip
    line = "cold" if args.cold else summary(rows)
    if not args.cold:
        print(line, flush=True)
    if args.json:
        meta = {"load_average": load, "date": date, "jax": jax.__version__, "quick": args.quick}
        with open(args.json, "w") as f:
            json.dump({"meta": meta, "rows": rows, "summary": line}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
