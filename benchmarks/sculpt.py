"""Target-curve sculpting per drag event on the Table 6-2 configurations of the thesis
*Interactive shape modeling and dynamic deformation based on spline sculpting* (control nets
21×10 … 18×135, 10–22 key points, polygon meshes 15×5 … 41×50).

    .venv/bin/python benchmarks/sculpt.py            # float64, a few minutes on 2 cores
    .venv/bin/python benchmarks/sculpt.py --quick    # fewer repetitions

For each configuration, timed as a user calls it (no jax.jit of ours around bsjax; median and
p99 per event, compile time = first call minus steady state, reported apart):

* `drag`: `factor.drag([keys])` — the interaction's factor reused, `d = C b` (thesis §6.1);
* `drag+mesh`: the same plus the new polygon mesh (`Blending.points`, the mesh of Table 6-2);
* `sculpt`: a whole `target_sculpt` per event (key points, foot-point projection, solve);
* `numpy`: a numpy re-solve per event (`np.linalg.pinv` of the key rows, `d = F⁺ b`, mesh by
  two matrix products) in the same process;
* `jit(drag)`: the drag inside a caller's own `jax.jit` (as-called ≈ jitted is the contract).

Beside the thesis's update times (0.094–3.75 s, Table 6-2). "Done when": the 21×10 net with 12
key points updates at ≥ 50 Hz as called.
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _timing import timed  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

from bsjax import sculpt  # noqa: E402
from bsjax.basis import BSplineCurve, BSplineSurface, clamped_knots, closest_points  # noqa: E402

# (r, s, key points, mesh m × n, thesis update time in s) — Table 6-2
CONFIGS = [
    (21, 10, 12, (40, 40), 0.203),
    (20, 20, 14, (40, 40), 0.219),
    (26, 26, 14, (40, 40), 0.313),
    (28, 10, 22, (40, 40), 0.328),
    (24, 8, 12, (15, 5), 0.094),
    (35, 8, 10, (15, 15), 0.125),
    (18, 135, 13, (41, 50), 3.75),
]


def first_call(fn):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def make(r, s, keys):
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.linspace(0, 1, r), np.linspace(0, 1, s), indexing="ij")
    ctrl = np.stack([x, y, 0.05 * rng.normal(size=x.shape)], -1)
    surface = BSplineSurface(ctrl, clamped_knots(r, 3), clamped_knots(s, 3), 3, 3)
    pts = np.array([[0.15, 0.2, 0.2], [0.4, 0.45, 0.3], [0.6, 0.55, 0.3], [0.85, 0.75, 0.2]])
    target = BSplineCurve(pts, clamped_knots(4, 3), 3)
    t = np.linspace(0.0, 1.0, keys)
    key_pts = np.asarray(target.evaluate(t))
    uv = np.asarray(closest_points(surface, key_pts).params)
    return surface, target, key_pts, uv


def bench(r, s, keys, mesh, thesis, calls):
    surface, target, key_pts, uv = make(r, s, keys)
    cons = [sculpt.Position(uv[:, 0], np.asarray(surface.evaluate(uv[:, 0], uv[:, 1])), v=uv[:, 1])]
    factor = sculpt.prefactor(surface, cons)
    blend = surface.blending(*mesh)
    moves = [jnp.asarray(key_pts), jnp.asarray(key_pts + 0.01)]
    state = {"i": 0}

    def next_keys():
        state["i"] ^= 1
        return moves[state["i"]]

    def drag():
        return jax.block_until_ready(factor.drag([next_keys()]).ctrl)

    def drag_mesh():
        return jax.block_until_ready(blend.points(factor.drag([next_keys()]).ctrl))

    def whole():
        return jax.block_until_ready(sculpt.target_sculpt(surface, target, 1.0, n_keys=keys).surface.ctrl)

    jitted = jax.jit(lambda f, k: f.drag([k]).ctrl)

    def drag_jit():
        return jax.block_until_ready(jitted(factor, next_keys()))

    # numpy: the same rows, re-solved per event with a pseudo-inverse
    f = np.asarray(factor.rows)
    ctrl0 = np.asarray(surface.ctrl).reshape(-1, 3)
    a_u, a_v = np.asarray(blend.a_u[0]), np.asarray(blend.a_v[0])
    current = f @ ctrl0

    def numpy_event():
        b = np.asarray(moves[state["i"] ^ 1]) - current
        ctrl = (ctrl0 + np.linalg.pinv(f) @ b).reshape(r, s, 3)
        return np.einsum("mi,ijc,nj->mnc", a_u, ctrl, a_v)

    out = {"config": f"{r}×{s}", "keys": keys, "mesh": f"{mesh[0]}×{mesh[1]}", "thesis_s": thesis}
    for name, fn, n in (
        ("drag", drag, calls),
        ("drag+mesh", drag_mesh, calls),
        ("jit(drag)", drag_jit, calls),
        ("sculpt", whole, max(3, calls // 20)),
        ("numpy", numpy_event, max(3, calls // 4)),
    ):
        first = first_call(fn)
        med, p99 = timed(fn, n)
        out[name] = (med, p99, max(first - med, 0.0))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args(argv)
    calls = 50 if args.quick else 300
    print(
        f"jax {jax.__version__}, float64, load average {os.getloadavg()[0]:.1f}, {time.strftime('%Y-%m-%d %H:%M')}"
    )
    head = (
        f"{'net':>7} {'keys':>4} {'mesh':>6} | {'drag ms (p99)':>15} {'+mesh ms':>9} {'jit(drag)':>9} "
        f"| {'sculpt ms':>9} {'numpy ms':>9} | {'thesis s':>8} | {'compile drag/sculpt s':>21}"
    )
    print(head)
    print("-" * len(head))
    for r, s, keys, mesh, thesis in CONFIGS:
        o = bench(r, s, keys, mesh, thesis, calls)
        ms = {k: tuple(1e3 * x for x in v) for k, v in o.items() if isinstance(v, tuple)}
        print(
            f"{o['config']:>7} {keys:>4} {o['mesh']:>6} | {ms['drag'][0]:7.3f} ({ms['drag'][1]:6.3f}) "
            f"{ms['drag+mesh'][0]:9.3f} {ms['jit(drag)'][0]:9.3f} | {ms['sculpt'][0]:9.2f} "
            f"{ms['numpy'][0]:9.3f} | {thesis:8.3f} | {o['drag'][2]:9.2f} / {o['sculpt'][2]:9.2f}"
        )
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
