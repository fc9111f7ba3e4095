"""Haptic servo loop: rate and jitter of the 1 kHz loop while the JAX physics runs beside it.

    .venv/bin/python benchmarks/haptics.py [--seconds 10] [--repeat 3] [--plot session.png]

Runs, in one process on the same simulated device and script:
1. peer: the same loop with a plain `time.sleep` wait, normal priority, default GIL switch
   interval, garbage collector untouched (what a straightforward Python loop gets), static
   proxy, 3 s;
2. bsjax `ServoLoop` (hybrid sleep/spin wait, SCHED_FIFO where permitted), static proxy, 3 s;
3. bsjax `ServoLoop` with the physics thread running `SculptModel` — a 12×12 surface grid that
   is the outer layer of a 12×12×12 (12³) mass-spring lattice, refit to the teardrop's 8×8 net,
   proxy from a 40×40 grid — for `--seconds` (10): the issue's "done when" figures.
Prints sizes, build/compile times, rate, period and jitter p50/p99/max, missed deadlines.
"""

from __future__ import annotations

import argparse
import time

from bsjax.device import Proxy, ServoLoop, SimulatedDevice, plot_recording
from bsjax.device.physics import SculptModel

WALL = Proxy.plane(
    (0.62, 0.0, 0.0), (1.0, 0.0, 0.0), stiffness=30.0, damping=0.3, tool_radius=0.25, stamp=0.0
)


def run(label, model, seconds, record=False, **kw):
    loop = ServoLoop(SimulatedDevice(), model, rate_hz=1000, max_force=3.0, record=record, **kw)
    t = time.perf_counter()
    loop.start()
    start_s = time.perf_counter() - t
    time.sleep(seconds)
    s = loop.stop()
    print(f"\n== {label}: {seconds:.0f} s (start incl. warm-up {start_s:.2f} s)")
    print(s.report())
    return loop, s


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--plot", help="PNG of the physics session")
    ap.add_argument("--repeat", type=int, default=1, help="physics sessions to run (spread of the figures)")
    args = ap.parse_args()

    _, peer = run(
        "peer: sleep-only wait, normal priority, default switch interval",
        WALL,
        3.0,
        spin_us=0.0,
        realtime=False,
        switch_interval=None,
        freeze_gc=False,
    )
    _, alone = run("bsjax ServoLoop, static proxy (no physics)", WALL, 3.0)

    t = time.perf_counter()
    model = SculptModel(grid=(12, 12), layers=12)
    build = time.perf_counter() - t
    t = time.perf_counter()
    model.warmup()
    compile_s = time.perf_counter() - t
    print(
        f"\nSculptModel: {model.grid[0]}×{model.grid[1]} surface nodes, {model.layers} layers → "
        f"{model.n_nodes} nodes, {model.n_springs} springs, {model.substeps} substeps/tick, dtype {model.dtype}; "
        f"build {build:.2f} s, compile {compile_s:.2f} s"
    )
    loop, s = run(
        "bsjax ServoLoop + JAX physics (12×12 surface on a 12³ lattice)",
        model,
        args.seconds,
        record=bool(args.plot),
    )
    repeats = [s]
    for k in range(1, args.repeat):
        model.reset()
        repeats.append(run(f"repeat {k + 1}/{args.repeat}", model, args.seconds)[1])
    if args.plot:
        plot_recording(loop.recording(), args.plot, "bsjax haptics: 10 s simulated sculpting session")
    ok = (
        s.rate_hz >= 990 and s.jitter_p99 < 0.5 and s.period_max <= 2.0 + 1.0
    )  # max period = 1 ms + 2 ms late
    print("\nsummary (rate Hz | jitter p50/p99/max ms | missed | latest start ms)")
    for name, x in (("peer sleep-only", peer), ("ServoLoop alone", alone), ("ServoLoop + physics", s)):
        print(
            f"  {name:<22} {x.rate_hz:7.1f} | {x.jitter_p50:.3f}/{x.jitter_p99:.3f}/{x.jitter_max:.3f} | "
            f"{x.missed_deadlines:4d} | {x.max_late_ms:.3f}"
        )
    print(
        f"  physics {s.physics_rate_hz:.1f} Hz (step p50 {s.physics_p50:.2f} ms, p99 {s.physics_p99:.2f} ms)"
    )
    if len(repeats) > 1:
        print(
            f"\n{len(repeats)} physics sessions of {args.seconds:.0f} s (rate Hz | p99 jitter ms | latest start ms | physics Hz):"
        )
        for x in repeats:
            print(f"  {x.rate_hz:7.1f} | {x.jitter_p99:.3f} | {x.max_late_ms:.3f} | {x.physics_rate_hz:.1f}")
    print(
        f"done-when (≥ 990 Hz, p99 jitter < 0.5 ms, no deadline missed by > 2 ms): {'met' if ok else 'NOT met'}"
        f"{'' if s.max_late_ms <= 2.0 else f' (latest start {s.max_late_ms:.2f} ms late)'}"
    )


if __name__ == "__main__":
    main()
