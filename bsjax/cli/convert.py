"""`bsjax convert IN OUT`: convert splines between .json, .3dm, STEP, IGES and meshes (`bsjax.io`).

    bsjax convert patches.3dm patches.step
    bsjax convert part.step part.3dm --units mm
    bsjax convert teardrop.json teardrop.glb --samples 120,60

The B-spline formats (.json, .3dm, .step/.stp, .iges/.igs) keep every surface and curve exactly,
with its trims, orientation, name, layer and the file's unit system (float64 unless `--float32`);
the mesh formats (.obj, .stl, .ply, .glb) hold the tessellated `--samples` grid of the surfaces.
A file holding objects bsjax cannot load (meshes, points, SubD, …) is refused with a list of
them unless `--skip-unsupported`. On a terminal a progress bar counts the objects converted for
the target (`--quiet`: none); the result goes to stdout (`--json` for machines).
"""

from __future__ import annotations

import sys

from bsjax.cli import _common as c
from bsjax.cli import _progress

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it

INPUTS = (".json", ".3dm", ".step", ".stp", ".iges", ".igs")
OUTPUTS = (*INPUTS, ".obj", ".stl", ".ply", ".glb")


def _parser():
    p = c.Parser("bsjax convert")
    p.add_argument("source", type=c.input_file(*INPUTS), help="spline file (" + ", ".join(INPUTS) + ")")
    p.add_argument("target", type=c.output_file(*OUTPUTS), help="output (" + ", ".join(OUTPUTS) + ")")
    p.add_argument("--samples", type=c.grid, default=(82, 82), metavar="M,N", help="mesh sample grid (82,82)")
    p.add_argument(
        "--units", default=None, metavar="UNIT", help="convert lengths into this unit (mm, cm, m, in, ft, …)"
    )
    p.add_argument(
        "--skip-unsupported", action="store_true", help="load what bsjax can and warn about the rest"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _body(args) -> int:
    import equinox as eqx
    import numpy as np

    from bsjax import io
    from bsjax.basis import BSplineSurface

    if args.units is not None and args.units not in io.UNITS:
        raise c.UserError("--units", f"expected one of {', '.join(io.UNITS)}, got {args.units!r}")
    on_unsupported = "skip" if args.skip_unsupported else "raise"
    loaded = io.load_all(args.source, units=args.units, on_unsupported=on_unsupported, trims=True)
    if not loaded:
        raise c.UserError(args.source, f"no surface or curve to convert (the file holds {loaded.holding()})")
    dt = c.dtype(args)

    def _cast(g):  # a polycurve is a tuple of curves
        return tuple(map(_cast, g)) if isinstance(g, tuple) else g.with_ctrl(np.asarray(g.ctrl, dt))

    cast = [eqx.tree_at(lambda o: o.geometry, o, _cast(o.geometry)) for o in loaded]
    items = io.CadList(cast, loaded.units, cast, loaded.held, loaded.annotations)
    if args.target.lower().endswith(io.MESH_FORMATS):
        surfaces = [o for o in cast if isinstance(o.geometry, BSplineSurface)]
        if not surfaces:
            raise c.UserError(args.source, "no surface to tessellate (a mesh format holds surfaces only)")
        items = io.CadList(surfaces, loaded.units, surfaces, loaded.held)
    try:
        with _progress.bar("objects", quiet=args.quiet) as progress:
            io.save(items, args.target, *args.samples, progress=progress)
    except ValueError as err:  # the library's sample counts are this command's --samples
        if not str(err).startswith("m, n:"):
            raise
        raise c.UserError("--samples", str(err).removeprefix("m, n: ")) from None
    c.report(
        args,
        {
            "source": args.source,
            "target": args.target,
            "objects": len(items),
            "trimmed": sum(o.trim is not None for o in items),
            "units": loaded.units,
            "dtype": str(np.dtype(dt)),
        },
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
