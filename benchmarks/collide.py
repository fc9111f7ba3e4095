"""Collision benchmark: the thesis's experiments (thesis ch. 3 and ch. 6; CAD&A 2013 Tables 1–2) against python-fcl.

Same process, same surfaces: bsjax (jitted, steady state, `block_until_ready`) and python-fcl on
the tessellated 82×82 (…) sample grid, once rebuilding the BVH every query (the surface deforms
every frame, so a real loop must) and once with a BVH built beforehand. Both sides do the whole
query: bsjax returns the per-sample mask, depth and normals; fcl all contacts.

    .venv/bin/python benchmarks/collide.py            # float32, the full tables (a few minutes)
    .venv/bin/python benchmarks/collide.py --quick    # fewer sizes
    .venv/bin/python benchmarks/collide.py --x64      # float64
    .venv/bin/python benchmarks/collide.py --x64 --tables issue   # only the two speed-goal rows
    .venv/bin/python benchmarks/collide.py --x64 --tables issue --prev HEAD~1   # and a commit's
                                      # bsjax.collide timed interleaved with today's, same results

The last lines print the speed-goal rows (sphere/ellipsoid/plane/point vs a bumped 20×20 plate at
82×82 with `contacts`; two 20×20 surfaces at 82×82 with `surface_contacts`) against their goals.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

THESIS_TABLE1 = {
    4: ("<1", "<1", "2"),
    8: ("<1", "3", "4"),
    12: ("4", "5", "10"),
    16: ("6", "12", "22"),
    20: ("10", "17", "31"),
}
THESIS_TABLE2 = {28: ("<1", "~1", "1"), 82: ("~1", "3", "4"), 244: ("3", "6", "15")}
THESIS_SURF = {4: "6", 8: "15", 20: "91"}


def timeit(fn, n, warm=2):
    for _ in range(warm):
        fn()
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    t = np.array(times) * 1e3
    return float(np.median(t)), float(np.percentile(t, 99))


def previous_collide(commit: str):
    """`bsjax.collide` as it was at `commit` (git), importable beside today's: its files are
    written to a temporary package whose imports of `bsjax.collide` point to itself (the rest of
    bsjax is today's)."""
    import importlib
    import pathlib
    import subprocess
    import tempfile

    root = pathlib.Path(__file__).resolve().parents[1]
    name = "collide_" + "".join(c if c.isalnum() else "_" for c in commit)
    folder = pathlib.Path(tempfile.mkdtemp()) / name
    folder.mkdir()
    files = subprocess.run(
        ["git", "ls-tree", "--name-only", commit, "bsjax/collide/"],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    for path in files:
        text = subprocess.run(
            ["git", "show", f"{commit}:{path}"], cwd=root, capture_output=True, text=True, check=True
        )
        (folder / pathlib.Path(path).name).write_text(text.stdout.replace("bsjax.collide", name))
    sys.path.insert(0, str(folder.parent))
    return importlib.import_module(name)


def paired(run_a, run_b, n):
    """Median and p99 (ms) of two callables timed in alternation (load drift hits both alike)."""
    ta, tb = [], []
    for _ in range(n):
        for run, times in ((run_a, ta), (run_b, tb)):
            t = time.perf_counter()
            run()
            times.append(time.perf_counter() - t)
    stats = lambda t: (float(np.median(t) * 1e3), float(np.percentile(t, 99) * 1e3))
    return stats(ta), stats(tb)


def same(old, new, name):
    """Masks identical and floats to 1e-12 between two results of one query."""
    for field in old.__dataclass_fields__:
        a, b = np.asarray(getattr(old, field)), np.asarray(getattr(new, field))
        ok = np.array_equal(a, b) if a.dtype.kind in "bi" else np.allclose(a, b, rtol=0, atol=1e-12)
        if not ok:
            raise AssertionError(f"{name}: {field} differs from the previous commit's")


def bumpy(size: int, seed: int, dtype):
    from bsjax.basis import BSplineSurface, clamped_knots

    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 1, size), np.linspace(0, 1, size), indexing="ij")
    ctrl = np.stack([x, y, 0.02 * rng.normal(size=x.shape)], -1).astype(dtype)
    knots = clamped_knots(size, 3, dtype)
    return BSplineSurface(ctrl, knots, knots, 3, 3)


def fcl_mesh(points, faces, build=True):
    import fcl

    model = fcl.BVHModel()
    model.beginModel(len(points), len(faces))
    model.addSubModel(points, faces)
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def fcl_query(obj, other):
    import fcl

    req = fcl.CollisionRequest(num_max_contacts=100000, enable_contact=True)
    res = fcl.CollisionResult()
    return fcl.collide(obj, other, req, res)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--x64", action="store_true")
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument(
        "--tables",
        default="1,2,s,f",
        help="which experiments: 1, 2, s (surface vs surface), f (flat contact), issue (the speed-goal rows)",
    )
    parser.add_argument("--capacity", type=int, default=2048, help="surface_contacts capacity")
    parser.add_argument(
        "--prev",
        default=None,
        help="a git commit: with --tables issue, time its bsjax.collide interleaved with today's",
    )
    args = parser.parse_args(argv)
    import jax

    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import fcl
    import jax.numpy as jnp

    from bsjax.collide import Ellipsoid, Plane, Point, Sphere, contacts, surface_contacts
    from bsjax.collide._hierarchy import grid_mesh

    dtype = np.float64 if args.x64 else np.float32
    print(
        f"bsjax collide benchmark — jax {jax.__version__} on {jax.devices()[0].platform}, "
        f"{'float64' if args.x64 else 'float32'}; fcl {getattr(fcl, '__version__', '')}; times in ms (median / p99)"
    )
    tools = {
        "point": (
            Point([0.5, 0.5, -0.005]),
            lambda: fcl.CollisionObject(fcl.Sphere(1e-6), fcl.Transform(np.array([0.5, 0.5, -0.005]))),
        ),
        "sphere": (
            Sphere([0.5, 0.5, 0.1], 0.15),
            lambda: fcl.CollisionObject(fcl.Sphere(0.15), fcl.Transform(np.array([0.5, 0.5, 0.1]))),
        ),
        "ellipsoid": (
            Ellipsoid([0.5, 0.5, 0.08], [0.2, 0.15, 0.12]),
            lambda: fcl.CollisionObject(
                fcl.Ellipsoid(0.2, 0.15, 0.12), fcl.Transform(np.array([0.5, 0.5, 0.08]))
            ),
        ),
        "plane": (
            Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            lambda: fcl.CollisionObject(fcl.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0), fcl.Transform()),
        ),
    }
    rows = []
    issue_rows = []

    def run(net, m, kind, label, thesis):
        surf = bumpy(net, 0, dtype)
        b = surf.blending(m, m)
        ctrl = jnp.asarray(surf.ctrl)
        tool, fcl_tool = tools[kind]
        query = lambda c, t: contacts(b, c, t)  # as a user calls it (compiled at bsjax's boundary)
        t0 = time.perf_counter()
        jax.block_until_ready(query(ctrl, tool))
        compile_s = time.perf_counter() - t0
        med, p99 = timeit(lambda: jax.block_until_ready(query(ctrl, tool)), args.calls)
        a_u, a_v = np.asarray(b.a_u[0], np.float64), np.asarray(b.a_v[0], np.float64)
        p = np.asarray(surf.ctrl, np.float64)
        faces = np.asarray(grid_mesh(b.points(ctrl))[1], np.int64)
        other = fcl_tool()

        def fcl_rebuild():  # the surface deformed: sample it and rebuild the BVH
            pts = np.einsum("ai,ijc,bj->abc", a_u, p, a_v).reshape(-1, 3)
            return fcl_query(fcl_mesh(pts, faces), other)

        pts = np.einsum("ai,ijc,bj->abc", a_u, p, a_v).reshape(-1, 3)
        prebuilt = fcl_mesh(pts, faces)
        n_fcl = max(10, args.calls // 10)
        f_med, _f_p99 = timeit(fcl_rebuild, n_fcl)
        g_med, _ = timeit(lambda: fcl_query(prebuilt, other), n_fcl)
        contacts_n = int(query(ctrl, tool).mask.sum())
        rows.append((label, kind, med, p99, compile_s, f_med, g_med))
        if net == 20 and m == 82:
            issue_rows.append((f"{kind} vs a bumped 20x20 plate at 82x82", med, p99, compile_s, f_med, g_med))
        print(
            f"{label:<22} {kind:<6} bsjax {med:7.3f} / {p99:7.3f}  (compile {compile_s:5.1f} s, {contacts_n:5d} samples in contact)"
            f" | fcl rebuild {f_med:7.3f} ({f_med / med:6.1f}x)  fcl prebuilt {g_med:7.3f} ({g_med / med:5.1f}x) | thesis {thesis}"
        )

    tables = set(args.tables.split(","))
    nets = [4, 8, 20] if args.quick else [4, 8, 12, 16, 20]
    print("\nTable 1 — control net r×r at 82×82 samples")
    for net in nets if "1" in tables else []:
        for k, kind in enumerate(("point", "sphere", "plane")):
            run(net, 82, kind, f"{net}x{net} net, 82x82", THESIS_TABLE1[net][k])
    print("\nTable 2 — 8×8 net, maximum samples m×m")
    for m in ([28, 244] if args.quick else [28, 82, 244]) if "2" in tables else []:
        for k, kind in enumerate(("point", "sphere", "plane")):
            run(8, m, kind, f"8x8 net, {m}x{m}", THESIS_TABLE2[m][k])

    def surface_row(label, bl_a, ca, bl_b, cb, thesis):
        query = lambda x, y: surface_contacts(bl_a, x, bl_b, y, capacity=args.capacity)  # as called
        t0 = time.perf_counter()
        res = jax.block_until_ready(query(ca, cb))
        compile_s = time.perf_counter() - t0
        med, p99 = timeit(lambda: jax.block_until_ready(query(ca, cb)), args.calls // 2)
        grids = []
        for bl, c in ((bl_a, ca), (bl_b, cb)):
            a_u, a_v, p = (np.asarray(x, np.float64) for x in (bl.a_u[0], bl.a_v[0], c))
            grids.append((a_u, p, a_v, np.asarray(grid_mesh(bl.points(c))[1], np.int64)))

        def fcl_meshes():  # both surfaces deformed: sample them and rebuild both BVHs
            return [
                fcl_mesh(np.einsum("ai,ijc,bj->abc", a_u, p, a_v).reshape(-1, 3), f)
                for a_u, p, a_v, f in grids
            ]

        f_med, _ = timeit(lambda: fcl_query(*fcl_meshes()), max(10, args.calls // 10))
        prebuilt = fcl_meshes()
        g_med, _ = timeit(lambda: fcl_query(*prebuilt), max(10, args.calls // 10))
        if "20x20 vs 20x20" in label:
            issue_rows.append(("two 20x20 surfaces at 82x82", med, p99, compile_s, f_med, g_med))
        print(
            f"{label} (capacity {args.capacity})  bsjax {med:7.3f} / {p99:7.3f}  (compile {compile_s:5.1f} s, "
            f"{int(res.pair_hit.sum())} contact cell pairs, {int(res.flat_pairs)} flat pairs, overflow {bool(res.overflow)})"
            f" | fcl rebuild {f_med:7.3f} ({f_med / med:6.1f}x)  fcl prebuilt {g_med:7.3f} ({g_med / med:5.1f}x)"
            f" | thesis {thesis}",
            flush=True,
        )

    print("\nB-spline vs B-spline — both deformable, 82×82 samples each")
    for net in ([4, 20] if args.quick else [4, 8, 12, 16, 20]) if "s" in tables else []:
        a = bumpy(net, 1, dtype)
        b_surf = bumpy(net, 2, dtype)
        ctrl_b = np.asarray(b_surf.ctrl).copy()
        ctrl_b[..., 2] = (ctrl_b[..., 0] - 0.5) * 0.8 + ctrl_b[..., 2]
        ctrl_b[..., 0] = 0.1 + 0.8 * ctrl_b[..., 0]
        bl = a.blending(82, 82)
        surface_row(
            f"{net}x{net} vs {net}x{net}, 82x82",
            bl,
            jnp.asarray(a.ctrl),
            bl,
            jnp.asarray(ctrl_b),
            THESIS_SURF.get(net, "—"),
        )

    print("\nFlat contact — two 8×8 plates at 82×82 lying on each other (every sphere intersects)")
    if "f" in tables:
        from bsjax import shapes

        plate = shapes.plate(8, 8, size=1.0)
        bl = plate.blending(82, 82)
        pc = jnp.asarray(plate.ctrl, dtype)
        shift = jnp.asarray([0.3, 0.2, 0.0], dtype)
        surface_row("coplanar, overlapping  ", bl, pc, bl, pc + shift, "—")
        tilted = pc.at[..., 2].set(0.02 * (pc[..., 0] - 0.6)) + shift
        surface_row("crossing at 1.1°       ", bl, pc, bl, tilted, "—")
    if "issue" in tables and not issue_rows:
        for kind in ("sphere", "ellipsoid", "plane", "point"):
            run(20, 82, kind, "20x20 net, 82x82", "—")
        a = bumpy(20, 1, dtype)
        ctrl_b = np.asarray(bumpy(20, 2, dtype).ctrl).copy()
        ctrl_b[..., 2] = (ctrl_b[..., 0] - 0.5) * 0.8 + ctrl_b[..., 2]
        ctrl_b[..., 0] = 0.1 + 0.8 * ctrl_b[..., 0]
        bl = a.blending(82, 82)
        surface_row(
            "20x20 vs 20x20, 82x82", bl, jnp.asarray(a.ctrl), bl, jnp.asarray(ctrl_b), THESIS_SURF[20]
        )
    if args.prev and "issue" in tables:
        compare_previous(args, dtype, tools)
    if issue_rows:
        import os

        print(
            f"\nIssue #11 rows (as called, {'float64' if args.x64 else 'float32'}; load average {os.getloadavg()[0]:.2f}):"
        )
        for label, med, p99, compile_s, f_med, g_med in issue_rows:
            surface = label.startswith("two")
            goal = (
                "goal < 5 ms, >= 10x fcl+rebuild"
                if surface
                else "goal median < 1 ms, p99 < 2 ms, >= 20x fcl+rebuild, >= 1x fcl static"
            )
            print(
                f"  {label:<42} bsjax {med:.3f} ms / p99 {p99:.3f} ms (compile {compile_s:.1f} s) | "
                f"fcl+rebuild {f_med:.3f} ms = {f_med / med:.1f}x | fcl static {g_med:.3f} ms = {g_med / med:.2f}x | {goal}"
            )
    return 0


def compare_previous(args, dtype, tools):
    """Issue #11's rows with `--prev`'s `bsjax.collide` and today's, interleaved in one process."""
    import os

    import jax
    import jax.numpy as jnp

    from bsjax import collide

    old = previous_collide(args.prev)
    print(f"\nIssue #11 rows, {args.prev} vs now (interleaved, as called; ms median / p99):")
    surf = bumpy(20, 0, dtype)
    b = surf.blending(82, 82)
    ctrl = jnp.asarray(surf.ctrl)
    rows = []
    for kind, (tool, _) in tools.items():
        old_tool = getattr(old, type(tool).__name__)(*[np.asarray(a) for a in _tool_args(tool)])
        rows.append(
            (kind, lambda t=old_tool: old.contacts(b, ctrl, t), lambda t=tool: collide.contacts(b, ctrl, t))
        )
    a = bumpy(20, 1, dtype)
    ctrl_b = np.asarray(bumpy(20, 2, dtype).ctrl).copy()
    ctrl_b[..., 2] = (ctrl_b[..., 0] - 0.5) * 0.8 + ctrl_b[..., 2]
    ctrl_b[..., 0] = 0.1 + 0.8 * ctrl_b[..., 0]
    ca, cb = jnp.asarray(a.ctrl), jnp.asarray(ctrl_b)
    rows.append(
        (
            "surface_contacts",
            lambda: old.surface_contacts(b, ca, b, cb, capacity=args.capacity),
            lambda: collide.surface_contacts(b, ca, b, cb, capacity=args.capacity),
        )
    )
    from bsjax._boundary import clear_caches

    for kind, run_old, run_new in rows:
        clear_caches()  # both compile here, timed apart
        jax.clear_caches()
        compile_s = []
        results = []
        for run in (run_old, run_new):
            t = time.perf_counter()
            results.append(jax.block_until_ready(run()))
            compile_s.append(time.perf_counter() - t)
        same(*results, kind)
        calls = args.calls // 2 if kind == "surface_contacts" else args.calls
        (o_med, o_p99), (n_med, n_p99) = paired(
            lambda r=run_old: jax.block_until_ready(r()), lambda r=run_new: jax.block_until_ready(r()), calls
        )
        print(
            f"  {kind:<17} {args.prev} {o_med:7.3f} / {o_p99:7.3f} (compile {compile_s[0]:5.1f} s) | now "
            f"{n_med:7.3f} / {n_p99:7.3f} (compile {compile_s[1]:5.1f} s) | {o_med / n_med:4.2f}x, same results"
            f" | load {os.getloadavg()[0]:.2f}",
            flush=True,
        )


def _tool_args(tool):
    """The constructor arguments of a benchmark tool (to build the previous commit's twin)."""
    from bsjax.collide import Ellipsoid, Plane, Point, Sphere

    if isinstance(tool, Point):
        return (tool.position,)
    if isinstance(tool, Sphere):
        return tool.center, tool.radius
    if isinstance(tool, Ellipsoid):
        return tool.center, tool.radii, tool.rotation
    if isinstance(tool, Plane):
        return tool.point, tool.normal
    raise TypeError(type(tool).__name__)


if __name__ == "__main__":
    sys.exit(main())
