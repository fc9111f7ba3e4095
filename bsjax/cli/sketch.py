"""`bsjax sketch`: strokes from a JSON file → fitted curves → a surface (`bsjax.construct`).

    bsjax sketch STROKES.json --mode revolve -o bottle.3dm [--png bottle.png]
    bsjax sketch STROKES.json --mode loft -o hull.glb --tol 0.01
    bsjax sketch STROKES.json --mode extrude --vector 0,0,2 -o wall.json

Strokes file (JSON): `{"strokes": [STROKE, …]}` or a bare list of strokes; a STROKE is
`{"points": [[x, y], …] or [[x, y, z], …], "times": [t, …]}` (`times` optional, increasing) or
a bare list of points. Every stroke (≥ 3 samples) is fitted with the fewest control points
whose fit stays within `--tol` (`bsjax.sketch.fit_stroke`, one curve per stroke; planar strokes
lie at z = 0). Modes and the strokes they take, in order:

* `revolve`: profile [, axis]: the profile revolved about `--axis PX,PY,PZ,DX,DY,DZ` (default the
  z axis; a second stroke's first and last points give the axis instead). A planar profile is
  (radius, height).
* `extrude`: one curve, along `--vector X,Y,Z` (default 0,0,1).
* `ruled`: two curves. `loft`: two or more sections (`--ruled` for degree 1 across).
* `coons`: bottom, top, left, right; the four corners are snapped to the mean of the strokes'
  meeting end points (within 10 % of the largest stroke's size) before fitting.
* `sweep`: profile (in the path's moving frame), path.

Writes the surface and the fitted curves to `-o` (`.json`, `.3dm` keep both exactly; `.glb`,
`.obj`, `.stl`, `.ply` the tessellated surface) and, with `--png`, a matplotlib picture.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it

MODES = {
    "revolve": (1, 2),
    "extrude": (1, 1),
    "ruled": (2, 2),
    "loft": (2, 64),
    "coons": (4, 4),
    "sweep": (2, 2),
}
OUTPUTS = (".json", ".3dm", ".glb", ".obj", ".stl", ".ply")


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax sketch")
    p.add_argument(
        "strokes", type=c.input_file(".json"), help="strokes file (.json, format in the module doc)"
    )
    p.add_argument("--mode", choices=sorted(MODES), required=True, help="surface constructor")
    p.add_argument("-o", "--output", type=c.output_file(*OUTPUTS), required=True, help="output file")
    p.add_argument("--png", type=c.output_file(".png"), help="also write a picture")
    p.add_argument("--tol", type=c.positive, default=None, help="fit tolerance (default 0.5 %% of the size)")
    p.add_argument(
        "--axis",
        type=c.vector("PX,PY,PZ,DX,DY,DZ", nonzero=slice(3, 6)),
        default=(0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        metavar="PX,PY,PZ,DX,DY,DZ",
        help="revolve: a point on the axis and its direction (default the z axis)",
    )
    p.add_argument(
        "--vector", type=c.vector("X,Y,Z", nonzero=slice(0, 3)), default=(0.0, 0.0, 1.0), metavar="X,Y,Z"
    )
    p.add_argument("--ruled", action="store_true", help="loft: degree 1 across the sections")
    p.add_argument("--samples", type=c.grid, default=(41, 41), metavar="M,N", help="tessellation (41,41)")
    return p


def read_strokes(path: str, dtype) -> list[tuple]:
    """The strokes of a file as `(points (N, d), times (N,) or None)` (user errors name the file)."""
    import numpy as np

    try:
        data = json.loads(Path(path).read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise c.UserError(path, f"not a JSON file ({err})") from None
    strokes = data.get("strokes") if isinstance(data, dict) else data
    if not isinstance(strokes, list) or not strokes:
        raise c.UserError(path, 'expected {"strokes": [...]} or a non-empty list of strokes')
    out = []
    for i, stroke in enumerate(strokes):
        where = f"{path}: strokes[{i}]"
        raw = stroke.get("points") if isinstance(stroke, dict) else stroke
        times = stroke.get("times") if isinstance(stroke, dict) else None
        try:
            points = np.asarray(raw, dtype=dtype)
            times = None if times is None else np.asarray(times, dtype=dtype)
        except (TypeError, ValueError):
            raise c.UserError(where, "expected lists of numbers") from None
        if points.ndim != 2 or points.shape[1] not in (2, 3) or points.shape[0] < 3:
            raise c.UserError(
                where, f"expected at least 3 points of 2 or 3 coordinates, got shape {points.shape}"
            )
        if not np.all(np.isfinite(points)):
            raise c.UserError(where, "expected finite coordinates, got NaN or inf")
        if times is not None and (times.shape != points.shape[:1] or np.any(np.diff(times) <= 0)):
            raise c.UserError(where, f"expected {points.shape[0]} increasing times")
        out.append((points, times))
    return out


def _snap_corners(strokes: list, path: str) -> list:
    """Coons: the end points meeting at each corner moved to their mean (bottom/top run along u,
    left/right along v: B(0)=L(0), B(1)=R(0), T(0)=L(1), T(1)=R(1))."""
    import numpy as np

    pts = [np.array(p, copy=True) for p, _ in strokes]
    size = max(float(np.ptp(p, axis=0).max()) for p in pts)
    corners = [((0, 0), (2, 0)), ((0, -1), (3, 0)), ((1, 0), (2, -1)), ((1, -1), (3, -1))]
    for (a, ia), (b, ib) in corners:
        gap = float(np.linalg.norm(pts[a][ia] - pts[b][ib]))
        if gap > 0.1 * size:
            raise c.UserError(path, f"coons: strokes {a} and {b} do not meet at a corner (gap {gap:.3g})")
        mean = 0.5 * (pts[a][ia] + pts[b][ib])
        pts[a][ia], pts[b][ib] = mean, mean
    return [(p, t) for p, (_, t) in zip(pts, strokes)]


def fit(strokes: list, tol: float | None) -> list:
    """One `BSplineCurve` per stroke (`fit_stroke` without splitting)."""
    import numpy as np

    from bsjax import sketch

    curves = []
    for points, times in strokes:
        size = float(np.ptp(points, axis=0).max())
        curves += sketch.fit_stroke(points, times, tol=tol or 5e-3 * size, split=False)
    return curves


def build(mode: str, curves: list, args):
    """The surface of `mode` from the fitted curves."""
    import numpy as np

    from bsjax import construct

    dt = curves[0].ctrl.dtype
    if mode == "revolve":
        point, direction = np.asarray(args.axis[:3], dt), np.asarray(args.axis[3:], dt)
        if len(curves) == 2:
            ends = np.asarray(curves[1].evaluate(np.asarray([0.0, 1.0], dt)))
            ends = np.pad(ends, ((0, 0), (0, 3 - ends.shape[1])))
            point, direction = ends[0], ends[1] - ends[0]
        result = construct.revolve(curves[0], point, direction)
    elif mode == "extrude":
        result = construct.extrude(curves[0], np.asarray(args.vector, dt))
    elif mode == "ruled":
        result = construct.ruled(*curves)
    elif mode == "loft":
        result = construct.loft(curves, ruled=args.ruled)
    elif mode == "coons":
        result = construct.coons(*curves)
    else:
        result = construct.sweep(curves[0], curves[1])
    return getattr(result, "surface", result)  # sweep returns a SurfaceFit


def picture(surface, curves, path: str, samples) -> None:
    """The surface, its control net and the fitted curves, in one matplotlib panel."""
    import numpy as np

    from bsjax import plot

    fig, (ax,) = plot.figure(1, 5.0)
    grid = surface.blending(*samples).points(surface.ctrl)
    plot.draw_surface(ax, np.asarray(grid), ctrl=np.asarray(surface.ctrl), title="bsjax sketch")
    for curve in curves:
        pts = np.asarray(curve.evaluate(np.linspace(0.0, 1.0, 200)))
        pts = np.pad(pts, ((0, 0), (0, 3 - pts.shape[1])))
        ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], color="#2c3e50", linewidth=1.5)
    plot.save_figure(fig, path)


def _body(args) -> int:
    from bsjax import io

    strokes = read_strokes(args.strokes, c.dtype(args))
    low, high = MODES[args.mode]
    if not low <= len(strokes) <= high:
        expected = f"{low}" if low == high else f"{low} to {high}"
        raise c.UserError(args.strokes, f"--mode {args.mode} takes {expected} strokes, got {len(strokes)}")
    if args.mode == "coons":
        strokes = _snap_corners(strokes, args.strokes)
    curves = fit(strokes, args.tol)
    surface = build(args.mode, curves, args)
    exact = Path(args.output).suffix.lower() in (".json", ".3dm")
    io.save([surface, *curves] if exact else surface, args.output, *args.samples)
    if args.png:
        picture(surface, curves, args.png, args.samples)
    c.report(
        args,
        {
            "curves": len(curves),
            "curve control points": [cv.n_ctrl for cv in curves],
            "mode": args.mode,
            "surface control points": list(surface.ctrl.shape[:2]),
            "output": args.output,
            "png": args.png,
        },
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
