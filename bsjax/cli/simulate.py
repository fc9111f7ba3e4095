"""`bsjax simulate`: mass-spring simulation of a surface file (thesis ch. 5, paper 002 §4).

    bsjax simulate plate.json -o sagged.json --material jelly --clamp 0,0,0,1,0,0 --steps 2000
    bsjax simulate drop.3dm -o out.glb --table 0,0,-1.05 --sphere 0,0,1.2,0.3 --method implicit --dt 1e-3

The surface's blending samples (`--samples M N`) become the nodes of a surface lattice
(structural, shear and bending springs, `bsjax.mss.surface_lattice`); after the run the control
points come back by the stored least-squares refit and the surface is written with
`bsjax.io.save` (format from the extension of `-o`). A JSON report goes to stdout.
"""

from __future__ import annotations

import argparse
import json
import sys


def _floats(text: str, count: int, name: str) -> list[float]:
    try:
        values = [float(t) for t in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count:
        raise SystemExit(f"bsjax simulate: {name}: expected {count} comma-separated numbers, got {text!r}")
    return values


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bsjax simulate", description="Mass-spring simulation of a B-spline surface."
    )
    p.add_argument("input", help="surface file (.json or .3dm)")
    p.add_argument(
        "-o", "--output", required=True, help="deformed surface (.json, .3dm, .obj, .stl, .ply, .glb)"
    )
    p.add_argument("--material", choices=("jelly", "plasticine", "steel"), default="jelly")
    p.add_argument("--thickness", type=float, default=0.01, help="shell thickness in m (default 0.01)")
    p.add_argument(
        "--samples",
        type=int,
        nargs=2,
        default=(12, 12),
        metavar=("M", "N"),
        help="sample grid = lattice nodes (default 12 12)",
    )
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument(
        "--dt",
        type=float,
        default=None,
        help="time step in s (default: half the stable step, or 1e-3 for --method implicit)",
    )
    p.add_argument("--method", choices=("semi_implicit", "implicit"), default="semi_implicit")
    p.add_argument("--gravity", default="0,0,-9.81", help="gravity vector in m/s² (default 0,0,-9.81)")
    p.add_argument(
        "--clamp",
        default=None,
        metavar="PX,PY,PZ,NX,NY,NZ",
        help="hold every node on the solid side of this plane (point, normal towards the free side)",
    )
    p.add_argument(
        "--table", default=None, metavar="PX,PY,PZ", help="rigid horizontal table (normal +z) at this point"
    )
    p.add_argument("--sphere", default=None, metavar="CX,CY,CZ,R", help="rigid sphere tool")
    p.add_argument("--contact-stiffness", type=float, default=1e3, help="penalty stiffness in N/m")
    p.add_argument("--float32", action="store_true", help="work in float32 (default float64)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    import jax

    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from bsjax import io, mss

    dtype = np.float32 if args.float32 else np.float64
    try:
        surface = io.load(args.input)
    except (OSError, ValueError) as err:
        print(f"bsjax simulate: {err}", file=sys.stderr)
        return 2
    surface = surface.with_ctrl(np.asarray(surface.ctrl, dtype=dtype))
    blending = surface.blending(*args.samples)
    points = np.asarray(blending.points(surface.ctrl))
    fixed = None
    if args.clamp:
        c = _floats(args.clamp, 6, "--clamp")
        fixed = np.asarray(mss.behind_plane(points.reshape(-1, 3), c[:3], c[3:])).reshape(points.shape[:2])
    lattice, coupling = mss.surface_lattice(
        blending, surface.ctrl, mss.PRESETS[args.material], thickness=args.thickness, fixed=fixed
    )
    tools = []
    if args.table:
        tools.append(
            mss.RigidPlane(
                jnp.asarray(_floats(args.table, 3, "--table"), dtype), jnp.asarray([0, 0, 1], dtype)
            )
        )
    if args.sphere:
        s = _floats(args.sphere, 4, "--sphere")
        tools.append(mss.RigidSphere(jnp.asarray(s[:3], dtype), jnp.asarray(s[3], dtype)))
    contact = (
        mss.Contact(jnp.asarray(args.contact_stiffness, dtype), jnp.asarray(0.0, dtype)) if tools else None
    )
    limit = float(mss.stable_dt(lattice, args.contact_stiffness if tools else 0.0))
    dt = args.dt if args.dt is not None else (0.5 * limit if args.method == "semi_implicit" else 1e-3)
    gravity = jnp.asarray(_floats(args.gravity, 3, "--gravity"), dtype)
    try:
        final = mss.simulate(
            lattice,
            mss.init(lattice),
            dt,
            args.steps,
            gravity=gravity,
            tools=tuple(tools),
            contact=contact,
            method=args.method,
        )
    except ValueError as err:
        print(f"bsjax simulate: {err}", file=sys.stderr)
        return 2
    ctrl = coupling.ctrl(final.position)
    io.save(surface.with_ctrl(ctrl), args.output)
    kinetic, potential = mss.energy(lattice, final)
    disp = np.linalg.norm(np.asarray(final.position - lattice.rest_positions), axis=-1)
    print(
        json.dumps(
            {
                "input": args.input,
                "output": args.output,
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
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
