"""`bsjax merge`: merge patches from surface files into one surface (thesis ch. 4).

    bsjax merge a.json b.json --direction u --continuity 2 -o merged.json
    bsjax merge patches.3dm --grid 2x2 --continuity 0 -o merged.3dm --report [--float32]

Every input file may hold several surfaces (`.json` or `.3dm`, read with `bsjax.io.load_all`);
they are taken in order. The output format follows the extension of `-o` (`bsjax.io.save`).
Prints what was merged (patches, control points, degrees, the output file) as a table, or as JSON
with `--json`; `--report` adds the point-set deviation of the merged surface from the inputs
(Table A.1), and with `--degrees reduce` the largest degree-reduction error of a patch
(`MergeLayout.reduction_error`). float64 unless `--float32`.
"""

from __future__ import annotations

import argparse
import sys

from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _grid(text: str) -> tuple[int, int]:
    try:
        rows, cols = (int(x) for x in text.lower().split("x"))
    except ValueError:
        rows = cols = 0
    if rows < 1 or cols < 1:
        raise argparse.ArgumentTypeError(f"expected RxC such as 2x2, got {text!r}")
    return rows, cols


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax merge")
    p.add_argument(
        "inputs",
        nargs="+",
        type=c.input_file(*c.SURFACE_INPUTS),
        help="surface files (.json, .3dm), patches in merge order",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        type=c.output_file(*c.SURFACE_OUTPUTS),
        help="output file (.json, .3dm, .obj, .stl, .ply, .glb)",
    )
    p.add_argument(
        "--direction", choices=("u", "v"), default="u", help="merge direction for a row of patches"
    )
    p.add_argument(
        "--grid", type=_grid, default=None, metavar="RxC", help="merge R rows of C patches (row-major order)"
    )
    p.add_argument(
        "--continuity", type=c.count(0), default=2, help="C^c at the seams, 0 <= c < degree (default 2)"
    )
    p.add_argument(
        "--samples", type=c.count(2), default=82, help="samples per patch and direction (default 82)"
    )
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
    p.add_argument("--report", action="store_true", help="add the deviation from the inputs")
    p.add_argument(
        "--tolerance",
        type=c.positive,
        default=None,
        help="'close point' distance for --report (default 0.1 %% of the inputs' bounding-box diagonal)",
    )
    p.add_argument(
        "--report-samples",
        type=c.count(2),
        default=101,
        help="samples per patch and direction for --report",
    )
    return p


def _layout(args, patches):
    from bsjax import merge as mg

    if args.grid:
        r, k = args.grid
        if r * k != len(patches):
            raise c.UserError(
                "--grid", f"expected R*C equal to the {len(patches)} input patches, got {r}x{k}"
            )
        rows = [patches[i * k : (i + 1) * k] for i in range(r)]
        layout = mg.plan_grid(
            rows,
            args.continuity,
            samples=args.samples,
            degrees=args.degrees,
            orient=args.orient,
            overlap=args.overlap,
        )
        return layout, [[s.ctrl for s in row] for row in rows]
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
    return layout, [s.ctrl for s in patches]


def _body(args) -> int:
    from bsjax import io
    from bsjax import merge as mg

    patches = [s for path in args.inputs for s in c.load_surfaces(path, args)]
    layout, ctrls = _layout(args, patches)
    merged = layout.surface(mg.refine(layout, ctrls) if args.refine else layout.apply(ctrls))
    io.save(merged, args.output)
    result = {
        "patches": len(patches),
        "control points": list(merged.shape),
        "degrees": [merged.degree_u, merged.degree_v],
        "output": args.output,
    }
    if args.report:
        tolerance = _relative_tolerance(patches) if args.tolerance is None else args.tolerance
        deviation = mg.deviation(patches, merged, samples=args.report_samples, tolerance=tolerance)
        result.update(deviation.row(), tolerance=deviation.tolerance)
        if args.degrees == "reduce":  # what lowering the degrees alone costs (max over patches)
            result["reduction error"] = float(layout.reduction_error.max())
    c.report(args, result)
    return 0


def _relative_tolerance(patches) -> float:
    """0.1 % of the diagonal of the inputs' control-point box: a size-free "close" (an absolute
    default would call every point of a 12 cm spoon close at 0.1, or none of a building)."""
    import numpy as np

    points = np.concatenate([np.asarray(s.ctrl).reshape(-1, 3) for s in patches])
    return 1e-3 * float(np.linalg.norm(points.max(0) - points.min(0))) or 1e-3


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
