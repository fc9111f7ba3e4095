"""`bsjax sweep`: a parameter study over a full grid of designs, sharded with `bsjax.batch`.

    bsjax sweep spoon --param tilt=0:30:4 --param shake_amplitude=0:0.01:3 --out study/ [--quick]
    bsjax sweep collide --param radius=0.1:0.4:4 --param z=0:1:5 [--surface s.json] --out study/
    bsjax sweep merge --param continuity=0:2:3 --param samples=20:60:3 --out study/
    bsjax sweep collide … --coordinator 10.0.0.1:12355 --num-processes 2 --process-id I

Experiments (`bsjax.examples.experiments`): `spoon` (the jelly in the steel spoon: tilt and
roll deg, shake_axis deg from the handle, shake_amplitude m, shake_frequency Hz → spilled,
front, back, side, risk), `collide` (radius, x, y, z of a sphere over `--surface`, default the teardrop →
area, max_depth, force) and `merge` (continuity, samples: static ints, one compilation per
value pair → mean, max deviation). `--param NAME=START:STOP:COUNT` gives COUNT evenly spaced
values from START to STOP; parameters left out take their defaults; the grid is the product of
the `--param` axes, the first one varying slowest (grid order).

Writes `results.csv` (a column per parameter, then per output; a row per design in grid order)
and `sweep.png` (a heat map per output for two varied parameters, lines for one) to `--out`.
A progress bar with the time left on a terminal (none with `--quiet` or when stderr is not a
terminal). With `--coordinator/--num-processes/--process-id` (or the `BSJAX_*` variables of
`bsjax.batch.initialize`) every process runs the same command and evaluates its share of the
designs; process 0 writes the files, which are the same as one process writes.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

from bsjax._optional import require
from bsjax.cli import _common as c
from bsjax.cli import _progress

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it

NAMES = ("spoon", "collide", "merge")
_PLOT = "drawing sweep.png"


def _spec(text: str) -> tuple[str, tuple[float, float, int]]:
    """`NAME=START:STOP:COUNT` → `(name, (start, stop, count))`."""
    name, sep, values = text.partition("=")
    parts = values.split(":")
    expected = f"expected NAME=START:STOP:COUNT (e.g. tilt=0:20:5), got {text!r}"
    if not sep or not name.strip() or len(parts) != 3:
        raise argparse.ArgumentTypeError(expected)
    try:
        start, stop = c.real(parts[0]), c.real(parts[1])
        count = c.count(1)(parts[2])
    except argparse.ArgumentTypeError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err}") from None
    return name.strip(), (start, stop, count)


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax sweep")
    p.add_argument("experiment", choices=NAMES, help="spoon, collide or merge")
    p.add_argument(
        "--param",
        action="append",
        type=_spec,
        default=[],
        metavar="NAME=START:STOP:COUNT",
        help="a swept parameter (repeat for a grid): spoon tilt, roll, shake_axis (deg), "
        "shake_amplitude (m), shake_frequency (Hz); "
        "collide radius, x, y, z; merge continuity, samples (ints)",
    )
    p.add_argument("--out", required=True, type=c.output_folder, metavar="DIR", help="output folder")
    p.add_argument("--quick", action="store_true", help="small sizes (tests, a first look)")
    p.add_argument(
        "--surface",
        type=c.input_file(*c.SURFACE_INPUTS),
        metavar="FILE",
        help="collide: the surface (default the built-in teardrop); spoon: the bowl, in its frame",
    )
    p.add_argument(
        "--chunk", type=c.count(), default=None, metavar="N", help="designs per sharded call (default all)"
    )
    p.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address (several processes)")
    p.add_argument("--num-processes", type=c.count(), metavar="N", help="number of processes")
    p.add_argument("--process-id", type=c.count(0), metavar="I", help="this process, 0 <= I < N")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    return p


def _specs(experiment, given: list) -> dict:
    """The `--param` specs by name, checked against the experiment's parameters and ranges."""
    import numpy as np

    specs: dict = {}
    for name, (start, stop, count) in given:
        if name not in experiment.parameters:
            known = ", ".join(experiment.parameters)
            raise c.UserError("--param", f"{experiment.name} has no parameter {name!r} (one of {known})")
        if name in specs:
            raise c.UserError("--param", f"{name} given twice")
        values = np.linspace(start, stop, count)
        problem = experiment.parameters[name].check(values)
        if problem is not None:
            raise c.UserError("--param", f"{name}={start:g}:{stop:g}:{count}: expected {problem}")
        specs[name] = (start, stop, count)
    return specs


def _distributed(args) -> None:
    from bsjax import batch

    given = {
        "--coordinator": args.coordinator,
        "--num-processes": args.num_processes,
        "--process-id": args.process_id,
    }
    if any(v is not None for v in given.values()) and any(v is None for v in given.values()):
        missing = ", ".join(k for k, v in given.items() if v is None)
        raise c.UserError(
            missing.split(", ")[0], f"expected together with the other options ({missing} missing)"
        )
    if args.process_id is not None and args.process_id >= args.num_processes:
        raise c.UserError(
            "--process-id", f"expected an int in [0, {args.num_processes}), got {args.process_id}"
        )
    if args.coordinator is not None:
        host, sep, port = args.coordinator.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise c.UserError("--coordinator", f"expected HOST:PORT, got {args.coordinator!r}")
    batch.initialize(args.coordinator, args.num_processes, args.process_id)


def _body(args) -> int:
    require("matplotlib", "plot", _PLOT)  # before the designs run, not after
    if args.surface and args.experiment == "merge":
        raise c.UserError("--surface", "the merge experiment has its own patches (spoon or collide only)")
    _distributed(args)  # first: importing the library creates arrays, which starts JAX's backend
    import jax

    from bsjax.examples import experiments

    experiment = experiments.EXPERIMENTS[args.experiment]
    specs = _specs(experiment, args.param)

    leader = jax.process_index() == 0
    designs = experiments.grid(experiment.parameters, specs)
    surface = c.load_surface(args.surface, args) if args.surface else None
    t0 = time.perf_counter()
    setup_args = (designs, args.quick, c.dtype(args), surface)
    if experiment.setup_progress is None:
        setup = experiment.setup(*setup_args)
    else:  # a long set-up (the spoon's VSOFM jelly): a bar of what it reports
        label = f"{experiment.name} set-up, {experiment.setup_progress}"
        with _progress.bar(label, quiet=args.quiet or not leader) as progress:
            setup = experiment.setup(*setup_args, progress=progress)
    t1 = time.perf_counter()
    with _progress.bar(f"{experiment.name} designs", quiet=args.quiet or not leader) as progress:
        results = experiments.evaluate(experiment, setup, designs, chunk=args.chunk, progress=progress)
    t2 = time.perf_counter()
    if leader:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "results.csv", designs, results)
        plot(out / "sweep.png", experiment, specs, designs, results)
    if not args.quiet and leader:
        c.report(
            args,
            {
                "experiment": experiment.name,
                "designs": len(next(iter(designs.values()))),
                "devices": jax.device_count(),
                "processes": jax.process_count(),
                "setup s": t1 - t0,
                "designs s": t2 - t1,  # compilation included
                "results": str(Path(args.out) / "results.csv"),
                "plot": str(Path(args.out) / "sweep.png"),
            },
        )
    return 0


def write_csv(path: Path, designs: dict, results: dict) -> None:
    """`results.csv`: the parameters' columns, then the outputs'; floats written exactly (repr)."""
    columns = {**designs, **results}
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in zip(*columns.values()):
            writer.writerow([repr(float(x)) for x in row])


def plot(path: Path, experiment, specs: dict, designs: dict, results: dict) -> None:
    """A heat map per output over the first two varied parameters (the others at their first
    value), or lines over the one varied parameter, or one point per output."""
    matplotlib = require("matplotlib", "plot", _PLOT)
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np

    varied = [n for n, (_, _, count) in specs.items() if count > 1]
    outputs = experiment.outputs
    fig, axes = plt.subplots(1, len(outputs), figsize=(4.2 * len(outputs), 3.6), squeeze=False)
    counts = [specs[n][2] for n in specs]
    for ax, name in zip(axes[0], outputs):
        values = np.asarray(results[name]).reshape(counts or [1])
        if len(varied) >= 2:
            a, b = varied[:2]
            order = list(specs)
            index = tuple(slice(None) if n in (a, b) else 0 for n in order)
            image = values[index]
            if order.index(a) > order.index(b):
                image = image.T
            xs, ys = np.linspace(*specs[b][:2], specs[b][2]), np.linspace(*specs[a][:2], specs[a][2])
            mesh = ax.pcolormesh(xs, ys, image, shading="nearest", cmap="viridis")
            fig.colorbar(mesh, ax=ax)
            ax.set_xlabel(_label(experiment, b))
            ax.set_ylabel(_label(experiment, a))
        elif len(varied) == 1:
            (a,) = varied
            ax.plot(designs[a], values.ravel(), "o-")
            ax.set_xlabel(_label(experiment, a))
        else:
            ax.plot([0], values.ravel()[:1], "o")
            ax.set_xticks([])
        ax.set_title(f"{experiment.name}: {name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _label(experiment, name: str) -> str:
    unit = experiment.parameters[name].unit
    return f"{name} ({unit})" if unit else name


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
