"""Sweep throughput (designs per second) of `bsjax sweep`'s spoon and collide experiments through
`bsjax.batch.map`, at 1, 2 and 4 forced host devices and at 1 vs 2 `jax.distributed` processes,
beside a plain Python loop over the designs (one jitted call per design), all in one run.

Each configuration is a fresh subprocess (`XLA_FLAGS=--xla_force_host_platform_device_count=D`;
two processes on 127.0.0.1 with one device each); it builds the experiment's setup, evaluates
the grid once (compilation), then times `experiments.evaluate` (sharded map + gather) `--repeat`
times and reports the median. Compilation is reported apart.

    .venv/bin/python benchmarks/batch.py              # spoon 64 designs (3³ jelly), collide 512 (82²)
    .venv/bin/python benchmarks/batch.py --quick      # fewer designs (a first look)
    .venv/bin/python benchmarks/batch.py --runs 3     # three whole runs; the median run is shown

On CPU the forced host devices share the machine's cores: D devices give at most
min(D, cores)× one device's throughput (XLA already uses several threads for one device).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "RESULT "
GRIDS = {
    "spoon": {"tilt": (0.0, 30.0, 8), "shake_amplitude": (0.0, 0.01, 8)},
    "collide": {"radius": (0.1, 0.4, 8), "x": (0.4, 0.8, 8), "z": (-0.5, 0.5, 8)},
}
QUICK_GRIDS = {
    "spoon": {"tilt": (0.0, 30.0, 4), "shake_amplitude": (0.0, 0.01, 4)},
    "collide": {"radius": (0.1, 0.4, 4), "x": (0.4, 0.8, 4), "z": (-0.5, 0.5, 4)},
}


# --- the worker (one configuration, in its own process) ---------------------------------------
def worker(config: dict) -> dict:
    from bsjax import batch

    if config.get("coordinator"):
        batch.initialize(config["coordinator"], config["processes"], config["process"])
    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from bsjax.examples import experiments

    experiment = experiments.EXPERIMENTS[config["experiment"]]
    designs = experiments.grid(experiment.parameters, config["grid"])
    size = len(next(iter(designs.values())))
    setup = experiment.setup(designs, config["quick_setup"], np.float64)
    t0 = time.perf_counter()
    first = experiments.evaluate(experiment, setup, designs)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(config["repeat"]):
        t0 = time.perf_counter()
        experiments.evaluate(experiment, setup, designs)
        times.append(time.perf_counter() - t0)
    found = {
        "devices": jax.device_count(),
        "platform": jax.default_backend(),
        "processes": jax.process_count(),
        "designs": size,
        "first_s": compile_s,
        "seconds": statistics.median(times),
    }
    if config.get("loop"):
        import functools

        one = jax.jit(functools.partial(experiment.design, setup))
        names = list(experiment.parameters)

        def item(i):
            return [jax.numpy.asarray(designs[n][i], jax.numpy.float64) for n in names]

        jax.block_until_ready(one(*item(0)))
        loops = []
        for _ in range(config["repeat"]):
            t0 = time.perf_counter()
            rows = [one(*item(i)) for i in range(size)]
            jax.block_until_ready(rows)
            loops.append(time.perf_counter() - t0)
        found["loop_seconds"] = statistics.median(loops)
        gap = max(
            abs(float(rows[i][k]) - float(first[k][i])) for i in range(size) for k in experiment.outputs
        )
        found["loop_gap"] = gap  # the sweep's table equals the loop's
    return found


# --- the driver ------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spawn(config: dict, devices: int) -> subprocess.Popen:
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    return subprocess.Popen(
        [sys.executable, __file__, "--worker", json.dumps(config)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _collect(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f"worker failed:\n{err[-3000:]}")
    return json.loads([line for line in out.splitlines() if line.startswith(MARK)][-1][len(MARK) :])


def one_run(args) -> list[dict]:
    grids = QUICK_GRIDS if args.quick else GRIDS
    rows = []
    for name in ("spoon", "collide"):
        quick_setup = args.quick or name == "spoon"  # the spoon study at its quick size (3³ jelly, 0.02 s)
        base = {"experiment": name, "grid": grids[name], "repeat": args.repeat, "quick_setup": quick_setup}
        for devices in args.devices:
            found = _collect(_spawn({**base, "loop": devices == args.devices[0]}, devices))
            rows.append({"experiment": name, "config": f"{devices} device(s), 1 process", **found})
        if args.processes:
            address = f"127.0.0.1:{_free_port()}"
            procs = [
                _spawn({**base, "coordinator": address, "processes": 2, "process": i}, 1) for i in range(2)
            ]
            found = [_collect(p) for p in procs][0]
            rows.append({"experiment": name, "config": "2 processes × 1 device", **found})
    return rows


def report(rows: list[dict]) -> None:
    for name in ("spoon", "collide"):
        mine = [r for r in rows if r["experiment"] == name]
        loop = next(r for r in mine if "loop_seconds" in r)
        base = loop["designs"] / loop["seconds"]  # the first configuration: `--devices`' first
        per_loop = loop["designs"] / loop["loop_seconds"]
        print(
            f"\n{name}: {loop['designs']} designs; plain Python loop of jitted per-design calls "
            f"{per_loop:9.1f} designs/s (table gap to the sweep {loop['loop_gap']:.1e})"
        )
        print(
            f"  {'configuration':<28} {'designs/s':>10} {'× 1 device':>11} {'× loop':>8} {'first call s':>13}"
        )
        for r in mine:
            rate = r["designs"] / r["seconds"]
            config = f"{r['config']} [{r.get('platform', 'cpu')}]"
            print(
                f"  {config:<28} {rate:10.1f} {rate / base:11.2f} {rate / per_loop:8.2f} {r['first_s']:13.1f}"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="small grids and the quick spoon")
    parser.add_argument("--repeat", type=int, default=3, help="timed evaluations per configuration")
    parser.add_argument("--runs", type=int, default=1, help="whole runs; the median run is reported")
    parser.add_argument(
        "--devices",
        type=lambda text: [int(d) for d in text.split(",")],
        default=[1, 2, 4],
        help="comma-separated forced host device counts (CPU; on a GPU build each worker sees its GPUs)",
    )
    parser.add_argument(
        "--no-processes", dest="processes", action="store_false", help="skip the 2-process configuration"
    )
    args = parser.parse_args()
    if args.worker:
        print(MARK + json.dumps(worker(json.loads(args.worker))), flush=True)
        return 0
    runs = []
    for k in range(args.runs):
        load = os.getloadavg()
        rows = one_run(args)
        total = sum(r["designs"] / r["seconds"] for r in rows)
        runs.append((total, k, rows, load, os.getloadavg()))
        print(f"\nrun {k + 1}: load average {load[0]:.1f} → {runs[-1][4][0]:.1f}", flush=True)
        report(rows)  # each run as it ends: a long run on a loaded machine still leaves figures
    runs.sort(key=lambda r: r[0])
    _, k, rows, before, after = runs[len(runs) // 2]
    print(
        f"\n=== median run {k + 1} of {args.runs} ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, "
        f"load average {before[0]:.1f} before, {after[0]:.1f} after; float64)"
    )
    report(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
