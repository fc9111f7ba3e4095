"""`bsjax demo`: the spoon case study of the thesis (§7.3), end to end (`bsjax.examples.demo`).

    bsjax demo [--out bsjax-out] [--quick] [--json]

The study's account of each step goes to stderr as it runs; the result, the folder and the
files written (their numbers in `report.json`), to stdout.

Runs in float64 (the geometry of the study is in metres, down to micrometre deviations).
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

from bsjax._optional import require
from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _parser():
    p = c.Parser("bsjax demo", precision=False)
    p.add_argument(
        "--out", type=c.output_folder, default="bsjax-out", help="output folder (default ./bsjax-out)"
    )
    p.add_argument("--quick", action="store_true", help="small sizes (a 6³ jelly, short runs) for tests")
    return p


def _body(args) -> int:
    for module, extra in (("matplotlib", "plot"), ("rhino3dm", "cad"), ("trimesh", "mesh")):
        require(module, extra, "writing the demo's pictures and files")  # before minutes of work, not after
    from bsjax.cli import _progress
    from bsjax.examples import demo

    out = Path(args.out)
    # the study's account of each step is progress (stderr); the files written are the result
    with c.precision(float32=False), contextlib.redirect_stdout(sys.stderr):
        report = demo.run(out, quick=args.quick, bar=_progress.bar)  # bars on a terminal only
    files = sorted(p.name for p in out.iterdir())
    c.report(args, {"folder": str(out), "files": files, "seconds": report["total_seconds"]})
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
