"""`bsjax collide`: collision query of a surface file against a tool or a second surface.

    bsjax collide SURFACE.json --sphere X Y Z R [--samples 82 82] [--stiffness 100] [--json out.json]
    bsjax collide SURFACE.json --plane PX PY PZ NX NY NZ
    bsjax collide SURFACE.json --ellipsoid CX CY CZ A B C
    bsjax collide SURFACE.json --point X Y Z
    bsjax collide SURFACE.json --mesh TOOL.stl
    bsjax collide SURFACE.json --surface OTHER.json [--capacity 2048]

Prints a report (contact, samples in contact, parametric window, maximum and total depth, the
force on the tool by both force methods) and optionally writes it as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bsjax collide", description="collision query of a surface file against a tool"
    )
    p.add_argument("surface", help="surface file (.json, .3dm; see bsjax.io)")
    tool = p.add_mutually_exclusive_group(required=True)
    tool.add_argument("--sphere", nargs=4, type=float, metavar=("X", "Y", "Z", "R"))
    tool.add_argument("--ellipsoid", nargs=6, type=float, metavar=("CX", "CY", "CZ", "A", "B", "C"))
    tool.add_argument("--plane", nargs=6, type=float, metavar=("PX", "PY", "PZ", "NX", "NY", "NZ"))
    tool.add_argument("--point", nargs=3, type=float, metavar=("X", "Y", "Z"))
    tool.add_argument("--mesh", metavar="FILE", help="closed triangle mesh tool (any trimesh format)")
    tool.add_argument("--surface", dest="other", metavar="FILE", help="a second (deformable) surface")
    p.add_argument("--samples", nargs=2, type=int, default=(82, 82), metavar=("M", "N"))
    p.add_argument("--stiffness", type=float, default=100.0, help="spring stiffness per contact sample")
    p.add_argument("--capacity", type=int, default=2048, help="candidate cell pairs (surface vs surface)")
    p.add_argument("--json", metavar="OUT", help="also write the report as JSON")
    return p


def _tool(args):
    from bsjax import collide

    if args.sphere:
        return collide.Sphere(args.sphere[:3], args.sphere[3])
    if args.ellipsoid:
        return collide.Ellipsoid(args.ellipsoid[:3], args.ellipsoid[3:])
    if args.plane:
        return collide.Plane(args.plane[:3], args.plane[3:])
    if args.point:
        return collide.Point(args.point)
    return collide.TriangleMesh.load(args.mesh)


def run(args) -> dict:
    import numpy as np

    from bsjax import collide, io

    surface = io.load(args.surface)
    blending = surface.blending(*args.samples)
    if args.other:
        other = io.load(args.other)
        b2 = other.blending(*args.samples)
        res = collide.surface_contacts(blending, surface.ctrl, b2, other.ctrl, capacity=args.capacity)
        return {
            "surface": args.surface,
            "other": args.other,
            "samples": list(args.samples),
            "hit": bool(res.hit),
            "samples_in_contact_a": int(res.mask_a.sum()),
            "samples_in_contact_b": int(res.mask_b.sum()),
            "contact_cell_pairs": int(res.pair_hit.sum()),
            "overflow": bool(res.overflow),
            "hulls_apart": bool(res.apart),
        }
    c = collide.contacts(blending, surface.ctrl, _tool(args))
    report = {
        "surface": args.surface,
        "samples": list(args.samples),
        "hit": bool(c.hit),
        "samples_in_contact": int(c.mask.sum()),
        "window_uv": [float(x) for x in np.asarray(c.window)],
        "max_depth": float(c.depth.max()),
        "total_depth": float(c.depth.sum()),
        "hulls_apart": bool(c.apart),
        "stiffness": args.stiffness,
    }
    for method in collide.force.METHODS:
        report[f"force_{method}"] = [
            float(x) for x in np.asarray(collide.contact_force(c, args.stiffness, method))
        ]
    return report


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        report = run(args)
    except (ValueError, OSError) as err:
        print(f"bsjax collide: {err}", file=sys.stderr)
        return 1
    width = max(len(k) for k in report)
    for key, value in report.items():
        print(f"{key:<{width}}  {value}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
