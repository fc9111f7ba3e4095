"""`bsjax collide`: collision query of a surface file against a tool or a second surface.

    bsjax collide SURFACE.json --sphere CX,CY,CZ,R [--samples 82,82] [--stiffness 100] [--json]
    bsjax collide SURFACE.json --plane PX,PY,PZ,NX,NY,NZ
    bsjax collide SURFACE.json --ellipsoid CX,CY,CZ,A,B,C
    bsjax collide SURFACE.json --point X,Y,Z
    bsjax collide SURFACE.json --mesh TOOL.stl
    bsjax collide SURFACE.json --surface OTHER.json [--capacity N]

Prints a report (contact, samples in contact, parametric window, maximum and total depth, the
force on the tool by both force methods) as a table, or as JSON with `--json`. float64 unless
`--float32` (the report's `dtype`).
"""

from __future__ import annotations

import argparse
import sys

from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax collide")
    p.add_argument("surface", type=c.input_file(*c.SURFACE_INPUTS), help="surface file (.json, .3dm)")
    tool = p.add_mutually_exclusive_group(required=True)
    tool.add_argument("--sphere", type=c.vector("CX,CY,CZ,R", positive_at=(3,)), metavar="CX,CY,CZ,R")
    tool.add_argument(
        "--ellipsoid", type=c.vector("CX,CY,CZ,A,B,C", positive_at=(3, 4, 5)), metavar="CX,CY,CZ,A,B,C"
    )
    tool.add_argument(
        "--plane",
        type=c.vector("PX,PY,PZ,NX,NY,NZ", nonzero=slice(3, 6)),
        metavar="PX,PY,PZ,NX,NY,NZ",
        help="a half-space: a point on the plane and the outward normal",
    )
    tool.add_argument("--point", type=c.vector("X,Y,Z"), metavar="X,Y,Z")
    tool.add_argument(
        "--mesh", type=c.input_file(), metavar="FILE", help="closed triangle mesh tool (any trimesh format)"
    )
    tool.add_argument(
        "--surface",
        dest="other",
        type=c.input_file(*c.SURFACE_INPUTS),
        metavar="FILE",
        help="a second (deformable) surface",
    )
    p.add_argument("--samples", type=c.grid, default=(82, 82), metavar="M,N", help="sample grid (82,82)")
    p.add_argument("--stiffness", type=c.positive, default=100.0, help="spring stiffness per contact sample")
    p.add_argument(
        "--capacity",
        type=c.count(),
        default=None,
        help="candidate cell pairs (surface vs surface; default 64 per sample of the longest grid side)",
    )
    return p


def _tool(args):
    from bsjax import collide

    dt = c.dtype(args)

    def arr(values):
        import numpy as np

        return np.asarray(values, dtype=dt)

    if args.sphere:
        return collide.Sphere(arr(args.sphere[:3]), arr(args.sphere[3]))
    if args.ellipsoid:
        return collide.Ellipsoid(arr(args.ellipsoid[:3]), arr(args.ellipsoid[3:]))
    if args.plane:
        return collide.Plane(arr(args.plane[:3]), arr(args.plane[3:]))
    if args.point:
        return collide.Point(arr(args.point))
    return collide.TriangleMesh.load(args.mesh)


def run(args) -> dict:
    """The report of one query (a dict of plain numbers)."""
    import numpy as np

    from bsjax import collide

    surface = c.load_surface(args.surface, args)
    blending = surface.blending(*args.samples)
    head = {"surface": args.surface, "samples": list(args.samples), "dtype": str(surface.ctrl.dtype)}
    if args.other:
        other = c.load_surface(args.other, args)
        b2 = other.blending(*args.samples)
        res = collide.surface_contacts(blending, surface.ctrl, b2, other.ctrl, capacity=args.capacity)
        return {
            **head,
            "other": args.other,
            "hit": bool(res.hit),
            "samples_in_contact_a": int(res.mask_a.sum()),
            "samples_in_contact_b": int(res.mask_b.sum()),
            "contact_cell_pairs": int(res.pair_hit.sum()),
            "overflow": bool(res.overflow),
            "hulls_apart": bool(res.apart),
        }
    contact = collide.contacts(blending, surface.ctrl, _tool(args))
    report = {
        **head,
        "hit": bool(contact.hit),
        "samples_in_contact": int(contact.mask.sum()),
        "window_uv": [float(x) for x in np.asarray(contact.window)],
        "max_depth": float(contact.depth.max()),
        "total_depth": float(contact.depth.sum()),
        "hulls_apart": bool(contact.apart),
        "stiffness": args.stiffness,
    }
    for method in ("surface_normal", "probe_normal"):  # both of contact_force's methods
        force = collide.contact_force(contact, args.stiffness, method)
        report[f"force_{method}"] = [float(x) for x in np.asarray(force)]
    return report


def _body(args) -> int:
    c.report(args, run(args))
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
