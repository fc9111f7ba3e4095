"""Triangle-mesh tool benchmark (the face hierarchy): a 3 476-face part against an 8×8 surface.

`collide.contacts(blending, ctrl, TriangleMesh(...))` as a user calls it (compiled at bsjax's
boundary, float64), second call on, `block_until_ready`, median and p99 with the compile time
apart, beside its peers in the same process on the same samples: trimesh (`contains` and
`proximity.closest_point` of the samples: the same inside test and exact closest points) and
python-fcl (tessellate the sampled surface, build its BVH, collide with the part's BVH built
beforehand, all contacts).

The part: trimesh's `featuretype.STL` is not bundled with the installed trimesh, so a
deterministic stand-in of the same face count is built with trimesh — a stepped flange with a
bore, a 22-segment closed profile revolved in 79 sections (`trimesh.creation.revolve`): 3 476
faces, watertight, with the long thin triangles of a CAD export on its flat rings. The surface:
an 8×8 bicubic bumped plate through the flange, sampled at 28×28 and 82×82.

    .venv/bin/python benchmarks/mesh_tool.py            # the issue's row
    .venv/bin/python benchmarks/mesh_tool.py --old 2    # also the all-faces tool (2 calls each;
                                                        # 5 s a call at 82×82)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _timing import paired, timed


def part():
    """The 3 476-face stand-in part (module doc)."""
    import trimesh

    r = [0.15, 0.45, 0.45, 0.30, 0.30, 0.55, 0.55, 0.35, 0.35, 0.25, 0.25, 0.15]
    z = [-0.4, -0.4, -0.3, -0.3, -0.05, -0.05, 0.05, 0.05, 0.3, 0.3, 0.4, 0.4]
    bore = [(0.15 + 0.01 * np.sin(np.pi * k / 11), 0.4 - 0.8 * k / 11) for k in range(1, 11)]
    profile = np.array(list(zip(r, z)) + bore + [(r[0], z[0])])
    return trimesh.creation.revolve(profile, sections=79)


def plate(dtype=np.float64):
    """An 8×8 bicubic bumped plate over [-0.8, 0.8]² through the flange (z ≈ 0)."""
    from bsjax.basis import BSplineSurface, clamped_knots

    rng = np.random.default_rng(3)
    x, y = np.meshgrid(np.linspace(-0.8, 0.8, 8), np.linspace(-0.8, 0.8, 8), indexing="ij")
    ctrl = np.stack([x, y, 0.01 + 0.03 * rng.normal(size=x.shape)], -1).astype(dtype)
    knots = clamped_knots(8, 3, dtype)
    return BSplineSurface(ctrl, knots, knots, 3, 3)


def _load(commit: str, path: str, name: str, edit=lambda src: src):
    """Module `path` as it was at `commit`, loaded under `name` (for before/after timings)."""
    import importlib.util
    import os
    import subprocess
    import sys
    import tempfile

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = subprocess.run(
        ["git", "show", f"{commit}:{path}"], cwd=root, capture_output=True, text=True, check=True
    ).stdout
    file = os.path.join(tempfile.mkdtemp(), os.path.basename(path))
    with open(file, "w") as f:
        f.write(edit(src))
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def old_tool_class(commit=None):
    """`TriangleMesh` as it was at `commit` — by default the one named by `BSJAX_OLD_MESH`
    (026a021: before the face hierarchy, every sample against every face) — with the face
    hierarchy of that commit where it had one, for the before/after ratio."""
    import os

    commit = commit or os.environ.get("BSJAX_OLD_MESH", "026a021")
    tag = f"_old_{commit}".replace("~", "_").replace("^", "_")
    try:
        _load(commit, "bsjax/collide/_mesh_bvh.py", f"bsjax.collide.{tag}_bvh")
    except Exception:  # before the hierarchy
        pass

    def edit(src):
        # the old classes derive from today's AbstractTool, so `contacts` accepts them
        src = src.replace(
            "class AbstractTool(eqx.Module):",
            "from bsjax.collide._tools import AbstractTool  # noqa: E402\n\n\nclass _OldAbstractTool(eqx.Module):",
        )
        return src.replace("from bsjax.collide._mesh_bvh import", f"from bsjax.collide.{tag}_bvh import")

    return _load(commit, "bsjax/collide/_tools.py", f"bsjax.collide.{tag}_tools", edit).TriangleMesh


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--sizes", default="28,82")
    parser.add_argument("--old", type=int, default=0, help="calls of the all-faces tool (0: skip)")
    parser.add_argument(
        "--prev",
        default="",
        help="a commit whose TriangleMesh to time interleaved with today's (e.g. c0b45dc)",
    )
    args = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    import fcl
    import jax.numpy as jnp
    import trimesh

    from bsjax import collide
    from bsjax.collide._hierarchy import grid_mesh

    mesh = part()
    tool = collide.TriangleMesh.from_trimesh(mesh)
    surf = plate()
    ctrl = jnp.asarray(surf.ctrl)
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.asarray(mesh.vertices), np.asarray(mesh.faces, np.int64))
    model.endModel()
    fcl_part = fcl.CollisionObject(model, fcl.Transform())
    print(
        f"mesh tool — jax {jax.__version__} {jax.devices()[0].platform}, float64; part {len(mesh.faces)} faces "
        f"(watertight {mesh.is_watertight}); 8x8 bicubic plate; ms median / p99, compile apart"
    )
    for m in (int(s) for s in args.sizes.split(",")):
        b = surf.blending(m, m)
        t0 = time.perf_counter()
        c = jax.block_until_ready(collide.contacts(b, ctrl, tool))
        compile_s = time.perf_counter() - t0
        pts = np.asarray(c.points).reshape(-1, 3)
        faces = np.asarray(grid_mesh(c.points)[1], np.int64)
        a_u, a_v, p = np.asarray(b.a_u[0]), np.asarray(b.a_v[0]), np.asarray(surf.ctrl)

        def fcl_query():
            sampled = np.einsum("ai,ijc,bj->abc", a_u, p, a_v).reshape(-1, 3)
            sm = fcl.BVHModel()
            sm.beginModel(len(sampled), len(faces))
            sm.addSubModel(sampled, faces)
            sm.endModel()
            req = fcl.CollisionRequest(num_max_contacts=100000, enable_contact=True)
            return fcl.collide(fcl.CollisionObject(sm, fcl.Transform()), fcl_part, req, fcl.CollisionResult())

        def trimesh_query():
            return mesh.contains(pts), trimesh.proximity.closest_point(mesh, pts)

        ours = lambda: jax.block_until_ready(collide.contacts(b, ctrl, tool))
        med, p99, f_med, f_p99 = paired(ours, fcl_query, args.calls)  # interleaved
        t_med, t_p99 = timed(trimesh_query, max(3, args.calls // 5), warmup=1)
        inside, (_, dist, _) = trimesh_query()
        agree = np.mean(np.asarray(c.mask).reshape(-1) == inside)
        depth_err = float(np.max(np.abs(np.asarray(c.depth).reshape(-1) - np.where(inside, dist, 0))))
        print(
            f"{m}x{m}: bsjax contacts {med * 1e3:8.2f} / {p99 * 1e3:8.2f} (compile {compile_s:5.1f} s, "
            f"{int(np.sum(c.mask))} samples inside) | fcl tess+BVH+collide {f_med * 1e3:7.2f} / {f_p99 * 1e3:7.2f} "
            f"({f_med / med:5.2f}x) | trimesh contains+closest {t_med * 1e3:7.1f} / {t_p99 * 1e3:7.1f} "
            f"({t_med / med:5.1f}x) | mask = trimesh contains on {agree:.2%}, depth - trimesh distance {depth_err:.1e}"
        )
        if args.prev:
            prev = old_tool_class(args.prev).from_trimesh(mesh)
            t0 = time.perf_counter()
            ref = jax.block_until_ready(collide.contacts(b, ctrl, prev))
            p_compile = time.perf_counter() - t0
            run_prev = lambda: jax.block_until_ready(collide.contacts(b, ctrl, prev))
            p_med, p_p99, n_med, n_p99 = paired(run_prev, ours, args.calls)
            searched = np.any(np.asarray(c.tool_normals) != 0, -1)  # zero: outside the box, not searched
            normal_err = np.abs(np.asarray(ref.tool_normals) - np.asarray(c.tool_normals))[searched].max()
            print(
                f"{m}x{m}: {args.prev} {p_med * 1e3:8.2f} / {p_p99 * 1e3:8.2f} (compile {p_compile:4.1f} s) vs now "
                f"{n_med * 1e3:8.2f} / {n_p99 * 1e3:8.2f} interleaved -> {p_med / n_med:5.2f}x; masks identical "
                f"{bool(np.array_equal(ref.mask, c.mask))}, depth max diff "
                f"{float(np.max(np.abs(np.asarray(ref.depth) - np.asarray(c.depth)))):.1e}, tool normals (searched "
                f"{int(searched.sum())}) {float(normal_err):.1e}"
            )
        if args.old:
            old = old_tool_class().from_trimesh(mesh)
            t0 = time.perf_counter()
            ref = jax.block_until_ready(collide.contacts(b, ctrl, old))
            o_compile = time.perf_counter() - t0
            o_med, o_p99 = timed(lambda: jax.block_until_ready(collide.contacts(b, ctrl, old)), args.old, 0)
            same = bool(np.array_equal(ref.mask, c.mask))
            err = float(np.max(np.abs(np.asarray(ref.depth) - np.asarray(c.depth))))
            print(
                f"{m}x{m}: all-faces tool (before) {o_med * 1e3:8.1f} / {o_p99 * 1e3:8.1f} (compile {o_compile:4.1f} s) "
                f"-> {o_med / med:6.1f}x faster now; masks identical {same}, depth max diff {err:.1e}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
