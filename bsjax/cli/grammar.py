"""`bsjax grammar`: curve semantics from the shell (thesis ch. 7, `bsjax.grammar`).

    bsjax grammar symbols CURVE.json|CURVE.3dm [--closed | --open] [--rel 0.01] [--json]
    bsjax grammar enumerate --max-extrema N [--json]

`symbols` prints, for every curve of the file, its symbol string (e.g. `M+m+M+m+` for an
ellipse; a closed curve read counter-clockwise in canonical spelling), with `--json` also its
characteristic points (parameter, symbol, curvature) and its aesthetic measures. Curves must be
planar: 2-D, or 3-D lying in a plane z = constant (as Rhino stores planar curves).
`enumerate` prints the closed shapes Leyton's grammar allows with at most N curvature extrema
(21 for N = 8, as in the thesis §7.1), one per line, or a JSON list.
"""

from __future__ import annotations

import argparse
import sys

from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it

MAX_EXTREMA = 16  # 4^8 sign patterns: the enumeration stays under a second


class _Sub(c.Parser):
    """A subcommand's parser: the common one-line errors and `--debug`."""

    def __init__(self, prog=None, description=None, **_):
        super().__init__(prog or "bsjax grammar", description or "", precision=False)


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax grammar", result=False)  # each subcommand has its own --json (`_Sub`)
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Sub, metavar="{symbols,enumerate}")
    s = sub.add_parser("symbols", description="symbol string of every curve in a file")
    s.add_argument("curve", type=c.input_file(".json", ".3dm"), help="curve file (.json, .3dm)")
    side = s.add_mutually_exclusive_group()
    side.add_argument("--closed", dest="closed", action="store_const", const=True, help="read as closed")
    side.add_argument("--open", dest="closed", action="store_const", const=False, help="read as open")
    s.add_argument("--rel", type=_fraction, default=0.01, help="merging threshold of spurious extrema (0.01)")
    e = sub.add_parser("enumerate", description="closed shapes of the grammar up to N extrema")
    e.add_argument(
        "--max-extrema", type=_extrema, required=True, metavar="N", help=f"1..{MAX_EXTREMA} extrema"
    )
    return p


def _fraction(text: str) -> float:
    value = c.real(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1), got {text!r}")
    return value


def _extrema(text: str) -> int:
    value = c.count(1)(text)
    if value > MAX_EXTREMA:
        raise argparse.ArgumentTypeError(f"expected an integer in 1..{MAX_EXTREMA}, got {text!r}")
    return value


def _planar(curve, path: str, index: int):
    """The curve as a 2-D curve: 2-D as is, 3-D when it lies in a plane z = constant."""
    import numpy as np

    if curve.dim == 2:
        return curve
    ctrl = np.asarray(curve.ctrl)
    size = float(np.ptp(ctrl[:, :2], axis=0).max()) or 1.0
    if float(np.ptp(ctrl[:, 2])) > 1e-9 * size:
        raise c.UserError(path, f"curve {index} is not planar: expected curves in a plane z = constant")
    return _drop_z(curve, ctrl)


def _drop_z(curve, ctrl):
    from bsjax.basis import BSplineCurve

    return BSplineCurve.from_direction(ctrl[:, :2], curve.direction, curve.weights)


def _describe(curve, args) -> dict:
    import numpy as np

    from bsjax import grammar

    closed = grammar.is_closed(curve) if args.closed is None else args.closed
    name = grammar.symbols(curve, closed, rel=args.rel)
    report: dict = {"closed": closed, "symbols": name, "valid": grammar.is_valid(name, closed)}
    if args.json:
        points = grammar.simplify(grammar.characteristic_points(curve, closed), args.rel)
        n = int(points.count)
        report["points"] = [
            {"t": float(t), "symbol": s, "curvature": float(k)}
            for t, s, k in zip(
                np.asarray(points.params)[:n], points.symbols(), np.asarray(points.curvature)[:n]
            )
        ]
        m = grammar.measures(curve, closed)
        report["measures"] = {
            k: float(getattr(m, k)) for k in ("acceleration", "softness", "flatness", "convexity", "tension")
        }
    return report


def _symbols(args) -> int:
    from bsjax import io

    curves = io.load_all(args.curve, kind="curve")
    if not curves:
        raise c.UserError(
            args.curve, f"expected at least one curve, got none (the file holds {curves.holding()})"
        )
    reports = [_describe(_planar(curve, args.curve, i), args) for i, curve in enumerate(curves)]
    none = "(no characteristic points: the curvature has no extremum and no zero)"
    c.report(args, reports if args.json else [r["symbols"] or none for r in reports])
    return 0


def _enumerate(args) -> int:
    from bsjax import grammar

    shapes = grammar.enumerate_shapes(args.max_extrema)
    if shapes or args.json:
        c.report(args, shapes)
    else:  # a valid query with no answer: nothing on stdout, and why on stderr
        c.note("bsjax grammar", f"no closed shape has at most {args.max_extrema} extrema (the fewest is 4)")
    return 0


def _body(args) -> int:
    return _symbols(args) if args.command == "symbols" else _enumerate(args)


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
