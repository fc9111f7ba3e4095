"""The spoon study of the thesis (§7.3, Figs 7.15–7.19) on two deformable bodies: the jelly
resting in the steel spoon (`bsjax.examples.spoon.study`), each scenario one design of
`bsjax sweep spoon` (`bsjax.examples.experiments`), beside the thesis's statements.

(a) the bowl level, tilted 10° and 20° backwards (Figs 7.15–7.17; 30° and 40° beyond them);
(b) the spoon rolled about its handle by 10°, 20°, 30° (Fig. 7.18; 45° beyond); (c) the hand
shaking along the handle and across it, 5 and 10 mm at 6 Hz (Fig. 7.19). Prints the spilled mass fraction, where it left, the smooth risk, and the wall
time of the batch with the simulated seconds per wall-clock second.

    .venv/bin/python benchmarks/spoon_study.py            # 6³ jelly, 0.3 s (a few minutes)
    .venv/bin/python benchmarks/spoon_study.py --quick    # 3³ jelly, 0.02 s (seconds)
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from bsjax.examples import experiments  # noqa: E402

#: (label, tilt, roll, shake_axis, shake_amplitude, shake_frequency, the thesis's statement)
SCENARIOS = (
    ("(a) level", 0.0, 0.0, 0.0, 0.0, 4.0, "spills from the front"),
    ("(a) 10° backwards", 10.0, 0.0, 0.0, 0.0, 4.0, "holds: spreads evenly"),
    ("(a) 20° backwards", 20.0, 0.0, 0.0, 0.0, 4.0, "spills from the back"),
    ("(a) 30° backwards", 30.0, 0.0, 0.0, 0.0, 4.0, "(not in the thesis)"),
    ("(a) 40° backwards", 40.0, 0.0, 0.0, 0.0, 4.0, "(not in the thesis)"),
    ("(b) rolled 10°", 0.0, 10.0, 0.0, 0.0, 4.0, "spills"),
    ("(b) rolled 20°", 0.0, 20.0, 0.0, 0.0, 4.0, "spills more"),
    ("(b) rolled 30°", 0.0, 30.0, 0.0, 0.0, 4.0, "spills most"),
    ("(b) rolled 45°", 0.0, 45.0, 0.0, 0.0, 4.0, "(not in the thesis)"),
    ("(c) shaken along the handle", 0.0, 0.0, 0.0, 0.005, 6.0, "spills more than across"),
    ("(c) shaken across", 0.0, 0.0, 90.0, 0.005, 6.0, "spills less than along"),
    ("(c) shaken along, 10 mm", 0.0, 0.0, 0.0, 0.01, 6.0, "spills more than across"),
    ("(c) shaken across, 10 mm", 0.0, 0.0, 90.0, 0.01, 6.0, "spills less than along"),
)


def table(quick: bool) -> tuple[list[dict], dict]:
    """Every scenario's outputs (one `experiments.evaluate` over the eight designs) and the run's
    sizes and times."""
    experiment = experiments.EXPERIMENTS["spoon"]
    names = list(experiment.parameters)
    designs = {n: np.array([row[1 + i] for row in SCENARIOS]) for i, n in enumerate(names)}
    # every scenario's parameters are traced: the twelve are one vmapped program
    t0 = time.perf_counter()
    setup = experiment.setup(designs, quick, np.float64)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    found = experiments.evaluate(experiment, setup, designs)
    wall = time.perf_counter() - t0
    rows = [
        {"scenario": row[0], "thesis": row[-1], **{k: float(found[k][i]) for k in experiment.outputs}}
        for i, row in enumerate(SCENARIOS)
    ]
    jelly, steel = (b.lattice for b in reversed(setup.study.scene.bodies))
    info = {
        "jelly_nodes": jelly.n_nodes,
        "spoon_nodes": steel.n_nodes,
        "dt": setup.dt,
        "steps": int(round(setup.seconds / setup.dt)),
        "seconds": setup.seconds,
        "build_s": build,
        "wall_s": wall,
    }
    return rows, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the sweep's quick sizes")
    args = parser.parse_args()
    rows, info = table(args.quick)
    print(
        f"jax {jax.__version__}, {jax.devices()[0].platform}, x64; load {os.getloadavg()[0]:.2f}\n"
        f"jelly {info['jelly_nodes']} nodes, steel spoon {info['spoon_nodes']} nodes; {info['steps']} steps of "
        f"{1e6 * info['dt']:.0f} µs = {info['seconds']} s simulated; bodies built in {info['build_s']:.1f} s"
    )
    print("| scenario | spilled | front | back | side | risk | thesis |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        cells = " | ".join(f"{100 * r[k]:.0f} %" for k in ("spilled", "front", "back", "side"))
        print(f"| {r['scenario']} | {cells} | {r['risk']:.3f} | {r['thesis']} |")
    simulated = len(rows) * info["seconds"]
    print(
        f"{len(rows)} scenarios as one vmapped batch in {info['wall_s']:.1f} s (compilation included): "
        f"{simulated / info['wall_s']:.4f} simulated s per wall-clock s"
    )


if __name__ == "__main__":
    main()
