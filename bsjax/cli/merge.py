"""`bsjax merge`: merge patches from surface files into one surface (thesis ch. 4).

    bsjax merge a.json b.json --direction u --continuity 2 -o merged.json
    bsjax merge patches.3dm --grid 2x2 --continuity 0 -o merged.3dm --report

Every input file may hold several surfaces (`.json` or `.3dm`, read with `bsjax.io.load_all`);
they are taken in order. The output format follows the extension of `-o` (`bsjax.io.save`).
`--report` prints the point-set deviation of the merged surface from the inputs (Table A.1), and
with `--degrees reduce` the largest degree-reduction error of a patch (`MergeLayout.reduction_error`).
"""

from __future__ import annotations

import argparse
import json
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bsjax merge", description="Merge B-spline patches into one surface.")
    p.add_argument("inputs", nargs="+", help="surface files (.json, .3dm), patches in merge order")
    p.add_argument("-o", "--output", required=True, help="output file (.json, .3dm, .obj, .stl, .ply, .glb)")
    p.add_argument(
        "--direction", choices=("u", "v"), default="u", help="merge direction for a row of patches"
    )
    p.add_argument("--grid", default=None, metavar="RxC", help="merge R rows of C patches (row-major order)")
    p.add_argument("--continuity", type=int, default=2, help="C^c at the seams, 0 <= c < degree (default 2)")
    p.add_argument("--samples", type=int, default=82, help="samples per patch and direction (default 82)")
    p.add_argument("--cross-knots", choices=("average", "uniform"), default="average")
    p.add_argument(
        "--degrees",
        choices=("elevate", "reduce"),
        default=None,
        help="bring patches of different degrees together",
    )
    p.add_argument("--orient", choices=("auto", "as_given"), default="auto")
    p.add_argument(
        "--overlap",
        choices=("keep", "drop"),
        default="keep",
        help="drop the sample rows where patches intersect",
    )
    p.add_argument("--refine", action="store_true", help="nonlinear refit with parameter correction")
    p.add_argument("--report", action="store_true", help="print the deviation from the inputs (JSON)")
    p.add_argument("--tolerance", type=float, default=0.1, help="'close point' distance for --report")
    p.add_argument(
        "--report-samples", type=int, default=101, help="samples per patch and direction for --report"
    )
    p.add_argument("--float32", action="store_true", help="work in float32 (default float64)")
    return p


def _grid_shape(text: str, count: int) -> tuple[int, int]:
    try:
        rows, cols = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--grid: expected RxC such as 2x2, got {text!r}") from None
    if rows * cols != count or rows < 1 or cols < 1:
        raise ValueError(f"--grid: expected R*C equal to the {count} input patches, got {text!r}")
    return rows, cols


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    import jax

    if not args.float32:
        jax.config.update("jax_enable_x64", True)  # the CLI is an application: geometry in float64
    from bsjax import io
    from bsjax import merge as mg

    try:
        patches = [s for path in args.inputs for s in io.load_all(path)]
        if args.grid:
            r, c = _grid_shape(args.grid, len(patches))
            rows = [patches[i * c : (i + 1) * c] for i in range(r)]
            layout = mg.plan_grid(
                rows,
                args.continuity,
                samples=args.samples,
                degrees=args.degrees,
                orient=args.orient,
                overlap=args.overlap,
            )
            ctrls = [[s.ctrl for s in row] for row in rows]
        else:
            layout = mg.plan(
                patches,
                args.direction,
                args.continuity,
                samples=args.samples,
                cross_knots=args.cross_knots,
                degrees=args.degrees,
                orient=args.orient,
                overlap=args.overlap,
            )
            ctrls = [s.ctrl for s in patches]
        merged = layout.surface(mg.refine(layout, ctrls) if args.refine else layout.apply(ctrls))
    except (ValueError, TypeError) as err:
        print(f"bsjax merge: {err}", file=sys.stderr)
        return 2
    io.save(merged, args.output)
    r, s = merged.shape
    print(
        f"bsjax merge: {len(patches)} patches → {r}×{s} control points, degree "
        f"{merged.degree_u}×{merged.degree_v}, written to {args.output}",
        file=sys.stderr,
    )
    if args.report:
        report = mg.deviation(patches, merged, samples=args.report_samples, tolerance=args.tolerance)
        extra = {"tolerance": report.tolerance}
        if args.degrees == "reduce":  # what lowering the degrees alone costs (max over patches)
            extra["reduction error"] = float(layout.reduction_error.max())
        print(json.dumps({**report.row(), **extra}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
