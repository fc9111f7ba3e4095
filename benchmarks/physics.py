"""Mass-spring lattice step and VSOFM meshing: bsjax vs a vectorised numpy step vs warp-lang (CPU).

Runs all implementations on the same lattice in the same process and prints sizes, compile
time (separately), median and p99 per step, and ratios; thesis Table 6.6 (step) and 6.7 (VSOFM)
beside them. float32 (no x64), like a haptic loop.

    .venv/bin/python benchmarks/physics.py                 # everything (a few minutes)
    .venv/bin/python benchmarks/physics.py --quick         # small sizes only
    .venv/bin/python benchmarks/physics.py --only vsofm    # one section (lattice, contact, scene, haptic, vsofm)
    .venv/bin/python benchmarks/physics.py --only vsofm --sizes 40   # the 40³ VSOFM speed-goal row
    .venv/bin/python benchmarks/physics.py --only haptic --x64   # the haptic speed-goal row, float64
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
from _timing import paired

from bsjax import collide, mss, shapes, vsofm

THESIS_STEP_MS = {10: 0.1, 15: 0.4, 30: 3.0}  # Table 6.6, single iteration
THESIS_VSOFM_S = {10: 2.44, 12: 3.471, 15: 7.88, 20: 28.48, 25: 76.9, 30: 213.0, 40: 958.0}  # Table 6.7


def cube(n, spacing=0.01):
    g = np.stack(np.meshgrid(*[np.arange(float(n))] * 3, indexing="ij"), -1) * spacing
    return g.astype(np.float32)


def stats(samples_ms):
    a = np.asarray(samples_ms)
    return float(np.median(a)), float(np.percentile(a, 99))


def time_calls(fn, calls, per):
    """Median/p99 of per-step time over `calls` calls that each run `per` steps."""
    out = []
    for _ in range(calls):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e3 / per)
    return stats(out)


# --- bsjax ---------------------------------------------------------------------------------------------


def bench_bsjax(lat, dt, chunk, calls):
    state = mss.init(lat)
    # as a user calls them: compiled at bsjax's public boundary, no jax.jit here
    run = lambda s: mss.simulate(lat, s, dt, chunk, check_stability=False)
    one = lambda s: mss.step(lat, s, dt)
    t = time.perf_counter()
    s = run(state)
    jax.block_until_ready(s)
    compile_s = time.perf_counter() - t
    one(state).position.block_until_ready()
    box = [s]

    def scan_call():
        box[0] = run(box[0])
        box[0].position.block_until_ready()

    def step_call():
        box[0] = one(box[0])
        box[0].position.block_until_ready()

    return compile_s, time_calls(scan_call, calls, chunk), time_calls(step_call, calls * 5, 1)


# --- numpy reference -----------------------------------------------------------------------------------


def numpy_step(x, v, edges, rest, k, c, mass, dt):
    """The same semi-implicit Euler step (eqs. 5.11–5.16) vectorised with numpy (bincount scatter)."""
    i, j = edges[:, 0], edges[:, 1]
    d = x[i] - x[j]
    dv = v[i] - v[j]
    l = np.sqrt(np.einsum("ij,ij->i", d, d))
    inv = np.where(l > 0, 1.0 / np.where(l > 0, l, 1.0), 0.0)
    coef = k * (1.0 - rest * inv) + c * np.einsum("ij,ij->i", dv, d) * inv * inv
    f_edge = -coef[:, None] * d
    n = len(x)
    f = np.stack([np.bincount(i, f_edge[:, a], n) - np.bincount(j, f_edge[:, a], n) for a in range(3)], -1)
    v = v + dt * f / mass[:, None]
    return x + dt * v, v


def bench_numpy(lat, dt, calls):
    x = np.asarray(lat.rest_positions, np.float32)
    v = np.zeros_like(x)
    args = [np.asarray(a) for a in (lat.edges, lat.rest_length, lat.stiffness, lat.damping, lat.mass)]
    box = [(x, v)]

    def call():
        box[0] = numpy_step(*box[0], *args, dt)

    call()
    return time_calls(call, calls, 1)


# --- warp ----------------------------------------------------------------------------------------------


def make_warp():
    try:
        import warp as wp
    except ImportError:
        return None
    wp.config.quiet = True
    wp.init()

    @wp.kernel
    def springs(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        e: wp.array(dtype=int, ndim=2),
        rest: wp.array(dtype=float),
        k: wp.array(dtype=float),
        c: wp.array(dtype=float),
        f: wp.array(dtype=wp.vec3),
    ):
        t = wp.tid()
        i = e[t, 0]
        j = e[t, 1]
        d = x[i] - x[j]
        dv = v[i] - v[j]
        l = wp.length(d)
        inv = 0.0
        if l > 0.0:
            inv = 1.0 / l
        fs = -(k[t] * (1.0 - rest[t] * inv) + c[t] * wp.dot(dv, d) * inv * inv) * d
        wp.atomic_add(f, i, fs)
        wp.atomic_sub(f, j, fs)

    @wp.kernel
    def integrate(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        f: wp.array(dtype=wp.vec3),
        m: wp.array(dtype=float),
        dt: float,
    ):
        t = wp.tid()
        vv = v[t] + dt * f[t] / m[t]
        v[t] = vv
        x[t] = x[t] + dt * vv
        f[t] = wp.vec3(0.0, 0.0, 0.0)

    return wp, springs, integrate


def bench_warp(warp, lat, dt, chunk, calls):
    wp, springs, integrate = warp
    dev = "cpu"
    n = lat.n_nodes
    x = wp.array(np.asarray(lat.rest_positions), dtype=wp.vec3, device=dev)
    v = wp.zeros(n, dtype=wp.vec3, device=dev)
    f = wp.zeros(n, dtype=wp.vec3, device=dev)
    e = wp.array(np.asarray(lat.edges), dtype=int, device=dev)
    arrs = [
        wp.array(np.asarray(a), dtype=float, device=dev)
        for a in (lat.rest_length, lat.stiffness, lat.damping)
    ]
    m = wp.array(np.asarray(lat.mass), dtype=float, device=dev)

    def steps(count):
        for _ in range(count):
            wp.launch(springs, dim=lat.n_edges, inputs=[x, v, e, *arrs, f], device=dev)
            wp.launch(integrate, dim=n, inputs=[x, v, f, m, dt], device=dev)
        wp.synchronize()

    t = time.perf_counter()
    steps(1)
    compile_s = time.perf_counter() - t
    return compile_s, time_calls(lambda: steps(chunk), calls, chunk)


# --- sections ------------------------------------------------------------------------------------------


def lattice_section(sizes, calls):
    warp = make_warp()
    print(
        "\n== lattice step: semi-implicit Euler, 26-neighbour hex lattice (edges + face + body diagonals), float32"
    )
    print(
        f"{'size':>5} {'nodes':>6} {'springs':>8} | {'bsjax scan ms/step':>19} {'p99':>6} {'1-step call':>11} "
        f"{'compile s':>9} | {'numpy ms':>8} {'p99':>7} | {'warp ms':>7} {'p99':>6} {'load s':>6} | "
        f"{'np/bsjax':>8} {'bsjax/warp':>10} | thesis ms"
    )
    for n in sizes:
        lat = mss.hex_lattice(cube(n), material=mss.PLASTICINE)
        dt = 0.5 * float(mss.stable_dt(lat))
        chunk = 1000 if n <= 15 else 100
        comp, (med, p99), (one, _) = bench_bsjax(lat, dt, chunk, calls)
        np_med, np_p99 = bench_numpy(lat, dt, max(5, calls // 2))
        line = (
            f"{n:>4}³ {lat.n_nodes:>6} {lat.n_edges:>8} | {med:>19.3f} {p99:>6.3f} {one:>11.3f} {comp:>9.2f} | "
            f"{np_med:>8.3f} {np_p99:>7.3f} | "
        )
        if warp is not None:
            wcomp, (w_med, w_p99) = bench_warp(warp, lat, dt, chunk, calls)
            line += (
                f"{w_med:>7.3f} {w_p99:>6.3f} {wcomp:>6.2f} | {np_med / med:>8.1f} {med / w_med:>10.2f} | "
            )
        else:
            line += f"{'n/a':>7} {'':>6} {'':>6} | {np_med / med:>8.1f} {'n/a':>10} | "
        print(line + f"{THESIS_STEP_MS.get(n, '–')}", flush=True)
    print(
        "(bsjax scan ms/step: steady state inside a jitted lax.scan of 1000 (≤15³) or 100 steps; "
        "1-step call: one jitted step per Python call, dispatch included)"
    )


def contact_section(calls):
    print("\n== haptic case: 12³ jelly lattice + rigid sphere tool in penalty contact, float32")
    lat = mss.hex_lattice(cube(12, 0.005), material=mss.JELLY, fixed=cube(12)[..., 2] == 0)
    tool = collide.Sphere(jnp.array([0.0275, 0.0275, 0.06], jnp.float32), jnp.float32(0.01))
    contact = mss.Penalty(jnp.float32(50.0), jnp.float32(0.1))
    dt = jnp.float32(1e-4)
    state = mss.init(lat)
    one = lambda s, t: mss.step(lat, s, dt, tools=(t,), contact=contact)  # as called
    implicit = lambda s, t: mss.implicit_step(
        lat, s, jnp.float32(1e-3), tools=(t,), contact=contact, cg_iterations=10
    )
    for name, fn in (("semi-implicit step (dt 0.1 ms)", one), ("implicit step, 10 CG (dt 1 ms)", implicit)):
        t = time.perf_counter()
        fn(state, tool).position.block_until_ready()
        comp = time.perf_counter() - t
        box = [state]

        def call():
            box[0] = fn(box[0], tool)
            box[0].position.block_until_ready()

        med, p99 = time_calls(call, calls * 20, 1)
        ok = "yes" if med < 1.0 else "NO"
        print(
            f"  {name:<32} median {med:.3f} ms  p99 {p99:.3f} ms  compile {comp:.2f} s  < 1 ms (1 kHz): {ok}"
        )


def scene_section(calls, lattice=12, chunk=50):
    """The jelly-in-spoon scene (`bsjax.examples.spoon.study`): a `lattice³` VSOFM jelly with
    24 × 24 surface samples resting in a 40 × 10 × 2 steel shell spoon, surface–surface
    contact; the steel by backward Euler, the jelly by symplectic Euler. Per scene step against
    the jelly's lattice stepping alone (`mss.simulate`, same dt), timed in alternation; the
    thesis's real-time claim is ≥ 30 steps per second."""
    from bsjax import merge
    from bsjax.examples import spoon

    print(f"\n== scene: {lattice}³ jelly in a steel spoon, surface–surface contact ({chunk} steps per call)")
    merged = merge.merge([shapes.spoon_handle(), shapes.spoon_bowl()], direction="u", continuity=1)
    t = time.perf_counter()
    study = spoon.study(merged, lattice=lattice)
    build = time.perf_counter() - t
    scene = spoon.tilted(study, 0.0)
    dt = 0.9 * float(mss.scene_stable_dt(scene, spoon.METHODS))
    jelly = scene.bodies[1].lattice
    box = [mss.scene_init(scene), mss.init(jelly)]

    def scene_call():  # as a user calls it: no jax.jit here
        box[0] = mss.simulate_scene(scene, box[0], dt, chunk, method=spoon.METHODS)
        jax.block_until_ready(box[0])

    def lattice_call():
        box[1] = mss.simulate(jelly, box[1], dt, chunk)
        jax.block_until_ready(box[1])

    t = time.perf_counter()
    scene_call()
    first = time.perf_counter() - t
    lattice_call()
    med, p99, alone, alone_p99 = paired(scene_call, lattice_call, calls)
    step_ms, alone_ms = 1e3 * med / chunk, 1e3 * alone / chunk
    print(
        f"  bodies built in {build:.1f} s; {jelly.n_nodes} + {scene.bodies[0].lattice.n_nodes} nodes; "
        f"dt {1e6 * dt:.1f} µs (the jelly's explicit limit with the contact)"
    )
    print(f"  first call ({chunk} steps, compile included) {first:.1f} s")
    print(
        f"  scene step median {step_ms:.2f} ms  p99 {1e3 * p99 / chunk:.2f} ms  → {1e3 / step_ms:.0f} steps/s"
        f" (thesis ≥ 30: {'yes' if 1e3 / step_ms >= 30 else 'NO'}), {dt * 1e3 / step_ms:.4f} simulated s per s"
    )
    print(
        f"  jelly lattice alone median {alone_ms:.3f} ms  p99 {1e3 * alone_p99 / chunk:.3f} ms;"
        f" scene / lattice {step_ms / alone_ms:.0f}×"
    )


def stylus_samples(count: int, centre, period: int = 150):
    """`DeviceSample`s of a stylus that presses into the body from outside (+x) for `period` ticks
    with the button held, then releases (plastic set) and hovers for `period` ticks, and so on."""
    from bsjax.device._protocol import DeviceSample

    out = []
    for k in range(count):
        t = k / 100.0
        depth = min((k % (2 * period)) / period, 1.0)
        x = centre[0] + 0.95 - 0.3 * depth
        pressed = (k // period) % 2 == 0
        pos = np.array([x, centre[1] + 0.05 * np.sin(3 * t), centre[2] + 0.02])
        out.append(DeviceSample(pos, np.array([1.0, 0.0, 0.0, 0.0]), int(pressed), t, k, 0.0))
    return out


HAPTIC_RATES = ((500.0, 1), (100.0, 3))  # (physics_hz, substeps): the 500 Hz goal, the default


def haptic_section(calls, rates=HAPTIC_RATES):
    """Issue #11 row "haptic physics update": `SculptModel.update` as the servo's physics thread
    calls it (one `DeviceSample` per tick, a pressing stylus), beside the numpy step of the same
    springs (the same substeps of `numpy_step` over the lattice and seam springs: no contact, no
    refit). Per rate: at 500 Hz one 2 ms step per update (the goal: every update within its 2 ms
    period, p99 < 2 ms); at the default 100 Hz three 3.3 ms substeps per update (10 ms period)."""
    for physics_hz, substeps in rates:
        _haptic_rate(calls, physics_hz, substeps)


def _haptic_rate(calls, physics_hz, substeps):
    from bsjax.device._physics import SculptModel

    period_ms = 1e3 / physics_hz
    print(
        f"\n== haptic physics update at {physics_hz:g} Hz: SculptModel, 12×12 surface on a 12³ lattice, "
        f"{substeps} substep(s) of {period_ms / substeps:.2f} ms, 40×40 contact"
    )
    t = time.perf_counter()
    model = SculptModel(grid=(12, 12), layers=12, physics_hz=physics_hz, substeps=substeps)
    build = time.perf_counter() - t
    t = time.perf_counter()
    model.warmup()
    compile_s = time.perf_counter() - t
    samples = stylus_samples(max(300, calls * 30), model.centre)
    times = []
    for sample in samples:
        t = time.perf_counter()
        model.update(sample)
        times.append((time.perf_counter() - t) * 1e3)
    # the stylus sculpted: the plastic sets moved rest lengths
    moved = float(np.max(np.abs(np.asarray(model._state[1]) - np.asarray(model.lattice.rest_length))))
    med, p99 = stats(times[10:])
    edges = np.concatenate([np.asarray(model.lattice.edges), np.asarray(model.seam.edges)])
    rest = np.concatenate([np.asarray(model.lattice.rest_length), np.asarray(model.seam.rest_length)])
    k = np.concatenate([np.asarray(model.lattice.stiffness), np.asarray(model.seam.stiffness)])
    c = np.concatenate([np.asarray(model.lattice.damping), np.asarray(model.seam.damping)])
    x = np.asarray(model.lattice.rest_positions)
    mass = np.asarray(model.lattice.mass)
    box = [(x, np.zeros_like(x))]

    def numpy_tick():
        for _ in range(model.substeps):
            box[0] = numpy_step(*box[0], edges, rest, k, c, mass, model.dt)

    numpy_tick()
    np_med, np_p99 = time_calls(numpy_tick, max(20, calls * 5), 1)
    print(
        f"  {model.n_nodes} nodes, {model.n_springs} springs, dtype {model.dtype}; build {build:.2f} s, "
        f"compile {compile_s:.2f} s; {len(samples)} ticks ({model.ticks} run, {model.rollbacks} rolled back, "
        f"largest rest-length change {moved:.3g})"
    )
    print(f"  bsjax update (as called)   median {med:.3f} ms  p99 {p99:.3f} ms  max {max(times[10:]):.3f} ms")
    print(
        f"  numpy {model.substeps} spring step(s)     median {np_med:.3f} ms  p99 {np_p99:.3f} ms  (springs only)"
    )
    print(
        f"  ratio numpy/bsjax {np_med / med:.2f} (median); goal p99 < 2 ms (physics at 500 Hz): "
        f"{'met' if p99 < 2.0 else 'NOT met'}; p99 within the {period_ms:g} ms period: "
        f"{'yes' if p99 < period_ms else 'no'}; load average {os.getloadavg()}"
    )


def vsofm_section(sizes, shape_names=("teardrop", "sphere"), dtype=np.float32):
    """VSOFM on each shape's 82×82 blending samples, as a user calls `vsofm.fit` (no jax.jit
    here): compile + first call apart, then the median and the slowest (p99 of so few calls) of
    further calls with other PRNG keys; quality over all calls (the worst of them): inverted
    hexahedra, min scaled corner Jacobian; boundary → surface distance of the first call's nodes
    measured by `vsofm.report` against 3× denser samples (246×246) of the same surface, not the
    fitted ones. The peer is the thesis's own implementation (Table 6.7, teardrop)."""
    label = np.dtype(dtype).name
    print(f"\n== VSOFM: 300 cycles on 82×82 blending samples (thesis Table 6.7: teardrop), {label}")
    for name in shape_names:
        surf = getattr(shapes, name)(dtype=dtype)
        pts = np.asarray(surf.blending(82, 82).points(surf.ctrl)).reshape(-1, 3)
        dense = np.asarray(surf.blending(246, 246).points(surf.ctrl)).reshape(-1, 3)
        print(f"-- {name}")
        print(
            f"{'size':>5} {'compile+1st s':>13} {'median s':>8} {'p99 s':>6} {'keys':>4} {'inverted (worst)':>16} "
            f"{'min scaled J':>12} {'boundary→surface mean':>21} {'max':>8} | thesis s {'thesis/bsjax':>12}"
        )
        for n in sizes:
            t = time.perf_counter()
            nodes = vsofm.fit(pts, (n, n, n))
            nodes.block_until_ready()
            first = time.perf_counter() - t
            reps, times = [vsofm.report(pts, nodes)], []
            surface = vsofm.report(dense, nodes)
            for k in range(1, 8 if n <= 15 else 3):
                t = time.perf_counter()
                nodes = vsofm.fit(pts, (n, n, n), key=jax.random.PRNGKey(k))
                nodes.block_until_ready()
                times.append(time.perf_counter() - t)
                reps.append(vsofm.report(pts, nodes))
            inv = max(r.inverted for r in reps)
            med, p99 = float(np.median(times)), float(np.percentile(times, 99))
            thesis = THESIS_VSOFM_S.get(n) if name == "teardrop" else None
            ratio = f"{thesis / med:>11.0f}×" if thesis else f"{'–':>12}"
            print(
                f"{n:>4}³ {first:>13.2f} {med:>8.3f} {p99:>6.3f} {len(reps):>4} {inv:>7}/{reps[0].n_elements:<8} "
                f"{min(r.min_scaled_jacobian for r in reps):>12.3f} {surface.boundary_mean:>21.1e} "
                f"{surface.boundary_max:>8.1e} | {thesis or '–':>8} {ratio}",
                flush=True,
            )
    print(
        "(median/p99 s: the calls after the first, each with another key, as called; targets 12³ < 0.35 s, "
        "40³ < 30 s)"
    )


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes only")
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument(
        "--only", choices=("lattice", "contact", "scene", "haptic", "vsofm"), help="run one section"
    )
    parser.add_argument("--x64", action="store_true", help="float64 (the haptic speed-goal row's dtype)")
    parser.add_argument("--sizes", type=int, nargs="+", help="VSOFM lattice sizes (e.g. --sizes 12 40)")
    args = parser.parse_args()
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    print(f"jax {jax.__version__}, devices {jax.devices()}, x64 {jax.config.jax_enable_x64}")
    if args.only in (None, "lattice"):
        lattice_section((10, 15) if args.quick else (10, 15, 20, 30), args.calls)
    if args.only in (None, "contact"):
        contact_section(args.calls)
    if args.only in (None, "scene"):
        scene_section(max(args.calls // 4, 3), lattice=6 if args.quick else 12)
    if args.only in (None, "haptic"):
        haptic_section(args.calls)
    if args.only in (None, "vsofm"):
        vsofm_section(args.sizes or ((10, 12) if args.quick else (10, 12, 15, 20, 25, 30, 40)))


if __name__ == "__main__":
    main()
