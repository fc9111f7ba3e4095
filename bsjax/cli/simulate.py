"""`bsjax simulate`: mass-spring simulation of a surface file.

The surface lattice and its dual B-spline representation follow the thesis (ch. 5) and Gao &
Gibson, *Haptic B-spline surface sculpting with a shaped tool of implicit surface* (§4).

    bsjax simulate plate.json -o sagged.json --material jelly --clamp 0,0,0,1,0,0 --steps 2000
    bsjax simulate drop.3dm -o out.glb --table 0,0,-1.05 --sphere 0,0,1.2,0.3 --method implicit --dt 1e-3

The surface's blending samples (`--samples M,N`) become the nodes of a surface lattice
(structural, shear and bending springs, `bsjax.mss.surface_lattice`); after the run the control
points come back by the stored least-squares refit and the surface is written with
`bsjax.io.save` (format from the extension of `-o`). A report goes to stdout (a table, JSON
with `--json`). float64 unless `--float32`.
"""

from __future__ import annotations

import argparse
import sys

from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax simulate")
    p.add_argument("input", type=c.input_file(*c.SURFACE_INPUTS), help="surface file (.json or .3dm)")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        type=c.output_file(*c.SURFACE_OUTPUTS),
        help="deformed surface (.json, .3dm, .obj, .stl, .ply, .glb)",
    )
    p.add_argument("--material", choices=("jelly", "plasticine", "steel"), default="jelly")
    p.add_argument("--thickness", type=c.positive, default=0.01, help="shell thickness in m (default 0.01)")
    p.add_argument(
        "--samples", type=c.grid, default=(12, 12), metavar="M,N", help="sample grid = lattice nodes (12,12)"
    )
    p.add_argument("--steps", type=c.count(), default=1000, help="time steps (default 1000)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--dt",
        type=c.positive,
        default=None,
        help="time step in s (default: half the stable step, or 1e-3 for --method implicit)",
    )
    p.add_argument("--method", choices=("semi_implicit", "implicit"), default="semi_implicit")
    p.add_argument(
        "--gravity",
        type=c.vector("GX,GY,GZ"),
        default=(0.0, 0.0, -9.81),
        metavar="GX,GY,GZ",
        help="gravity vector in m/s² (default 0,0,-9.81)",
    )
    p.add_argument(
        "--clamp",
        type=c.vector("PX,PY,PZ,NX,NY,NZ", nonzero=slice(3, 6)),
        default=None,
        metavar="PX,PY,PZ,NX,NY,NZ",
        help="hold every node on the solid side of this plane (point, normal towards the free side)",
    )
    p.add_argument(
        "--table",
        type=c.vector("PX,PY,PZ"),
        default=None,
        metavar="PX,PY,PZ",
        help="rigid horizontal table (normal +z) at this point",
    )
    p.add_argument(
        "--sphere",
        type=c.vector("CX,CY,CZ,R", positive_at=(3,)),
        default=None,
        metavar="CX,CY,CZ,R",
        help="rigid sphere tool",
    )
    p.add_argument("--contact-stiffness", type=c.positive, default=1e3, help="penalty stiffness in N/m")
    return p


def _tools(args, dtype):
    import jax.numpy as jnp

    from bsjax import collide

    tools = []
    if args.table:
        tools.append(collide.Plane(jnp.asarray(args.table, dtype), jnp.asarray([0, 0, 1], dtype)))
    if args.sphere:
        s = args.sphere
        tools.append(collide.Sphere(jnp.asarray(s[:3], dtype), jnp.asarray(s[3], dtype)))
    return tuple(tools)


def _body(args) -> int:
    import jax.numpy as jnp
    import numpy as np

    from bsjax import io, mss
    from bsjax.cli import _progress

    dtype = c.dtype(args)
    surface = c.load_surface(args.input, args)
    blending = surface.blending(*args.samples)
    points = np.asarray(blending.points(surface.ctrl))
    fixed = None
    if args.clamp:
        p = args.clamp
        fixed = np.asarray(mss.behind_plane(points.reshape(-1, 3), p[:3], p[3:])).reshape(points.shape[:2])
    lattice, coupling = mss.surface_lattice(
        blending, surface.ctrl, mss.PRESETS[args.material], thickness=args.thickness, fixed=fixed
    )
    tools = _tools(args, dtype)
    contact = (
        mss.Penalty(jnp.asarray(args.contact_stiffness, dtype), jnp.asarray(0.0, dtype)) if tools else None
    )
    limit = float(mss.stable_dt(lattice, args.contact_stiffness if tools else 0.0))
    dt = args.dt if args.dt is not None else (0.5 * limit if args.method == "semi_implicit" else 1e-3)
    if args.method == "semi_implicit" and dt > limit:  # said in the options' words, before the run
        raise c.UserError(
            "--dt",
            f"expected at most {limit:.3g} s, the largest stable step of --method semi_implicit for "
            f"this lattice (stiffest spring, lightest node); use a smaller --dt or --method implicit, "
            f"got {dt:g}",
        )
    with _progress.bar("steps", quiet=args.quiet) as progress:  # on a terminal: stderr
        final = mss.simulate(
            lattice,
            mss.init(lattice),
            dt,
            args.steps,
            gravity=jnp.asarray(args.gravity, dtype),
            tools=tools,
            contact=contact,
            method=args.method,
            progress=progress,
        )
    ctrl = coupling.ctrl(final.position)
    io.save(surface.with_ctrl(ctrl), args.output)
    kinetic, potential = mss.energy(lattice, final)
    disp = np.linalg.norm(np.asarray(final.position - lattice.rest_positions), axis=-1)
    report = {
        "input": args.input,
        "output": args.output,
        "dtype": str(np.asarray(ctrl).dtype),
        "material": args.material,
        "method": args.method,
        "nodes": lattice.n_nodes,
        "springs": lattice.n_edges,
        "fixed": int(np.sum(np.asarray(lattice.fixed))),
        "dt": dt,
        "stable_dt": limit,
        "steps": args.steps,
        "time": dt * args.steps,
        "max_displacement": float(disp.max()),
        "mean_displacement": float(disp.mean()),
        "kinetic_energy": float(kinetic),
        "spring_energy": float(potential),
        "finite": bool(np.all(np.isfinite(np.asarray(ctrl)))),
    }
    c.report(args, report)
    return 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
