"""`bsjax convert IN OUT`: convert surfaces between .json, .3dm and mesh formats (`bsjax.io`).

    bsjax convert patches.3dm patches.json
    bsjax convert teardrop.json teardrop.glb --samples 120,60

The B-spline formats (.json, .3dm) keep every surface exactly, in float64 unless `--float32`;
the mesh formats (.obj, .stl, .ply, .glb) hold the tessellated `--samples` grid.
"""

from __future__ import annotations

import sys

from bsjax.cli import _common as c


def _parser():
    p = c.Parser("bsjax convert", __doc__.splitlines()[0].strip("`"))
    p.add_argument("source", type=c.input_file(*c.SURFACE_INPUTS), help="surface file (.json, .3dm)")
    p.add_argument(
        "target", type=c.output_file(*c.SURFACE_OUTPUTS), help="output (.json, .3dm, .obj, .stl, .ply, .glb)"
    )
    p.add_argument("--samples", type=c.grid, default=(82, 82), metavar="M,N", help="mesh sample grid (82,82)")
    return p


def _body(args) -> int:
    from bsjax import io

    surfaces = c.load_surfaces(args.source, args)
    io.save(surfaces, args.target, *args.samples)
    print(f"{args.source} → {args.target}: {len(surfaces)} surface(s)", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
