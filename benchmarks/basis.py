"""Evaluate one 20×20 bicubic on 82×82 and 244×244 grids: bsjax vs scipy, geomdl, splinepy.

    .venv/bin/python benchmarks/basis.py            # float64, a few minutes on 2 cores
    .venv/bin/python benchmarks/basis.py --quick    # fewer repetitions

All libraries run in this process on the same control net, knots and sample parameters, after a
check that they agree. Times are per call (per net for the batched rows): median and p99 over
many calls; compile time (first call minus steady state) is reported separately. Ratios are
peer time / bsjax time, so > 1 means bsjax is faster. The previous kernel (the dense product
`A_u P A_v^T`, `Blending` with `banded=False`) is timed in alternation with the banded one.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _timing import paired, timed  # noqa: E402  (benchmarks/ is on sys.path when run as a script)
from geomdl import BSpline as GBSpline  # noqa: E402
from scipy.interpolate import NdBSpline  # noqa: E402

from bsjax.basis import BSplineSurface, clamped_knots  # noqa: E402

try:
    import splinepy
except ImportError:  # splinepy is an optional peer
    splinepy = None

R = 20  # control net R × R, bicubic
BATCH = 64


def first_call(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def make_surface(dtype):
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.linspace(0, 1, R), np.linspace(0, 1, R), indexing="ij")
    ctrl = np.stack([x, y, 0.2 * rng.normal(size=x.shape)], -1).astype(dtype)
    knots = clamped_knots(R, 3, dtype=dtype)
    return BSplineSurface(ctrl, knots, knots, 3, 3), rng


def bench_grid(m: int, calls: dict, rows: list, dtype=np.float64, peers=True):
    surface, rng = make_surface(dtype)
    ctrl = surface.ctrl
    knots = np.asarray(surface.knots_u, dtype=np.float64)
    b = surface.blending(m, m)
    # As a user calls it: `b.points(c)` is compiled at bsjax's public boundary (no jax.jit here).
    # The batch is the user's own vmap, which they jit themselves.
    points = lambda b, c: b.points(c)
    batched = jax.jit(jax.vmap(lambda b, c: b.points(c), in_axes=(None, 0)))
    nets = jnp.asarray(ctrl[None] + 0.01 * rng.normal(size=(BATCH, R, R, 3)), dtype=dtype)
    tag = f"{m}x{m}" + ("" if dtype == np.float64 else " float32")

    # The previous kernel, the dense product `A_u P A_v^T`, is the same Blending with banded=False:
    # timed in alternation with the banded one, so the ratio is the evidence on a loaded machine.
    dense = dataclasses.replace(b, banded=False)
    compile_single = first_call(lambda: points(b, ctrl).block_until_ready())
    compile_dense = first_call(lambda: points(dense, ctrl).block_until_ready())
    med, p99, dmed, dp99 = paired(
        lambda: points(b, ctrl).block_until_ready(),
        lambda: points(dense, ctrl).block_until_ready(),
        calls["bsjax"],
    )
    compile_single -= med
    compile_dense -= dmed
    compile_batch = first_call(lambda: batched(b, nets).block_until_ready())
    compile_dbatch = first_call(lambda: batched(dense, nets).block_until_ready())
    bmed, bp99, dbmed, dbp99 = paired(
        lambda: batched(b, nets).block_until_ready(),
        lambda: batched(dense, nets).block_until_ready(),
        max(20, calls["bsjax"] // 20),
    )
    compile_batch -= bmed
    compile_dbatch -= dbmed
    ref = np.asarray(points(b, ctrl), dtype=np.float64)
    check(tag, "the dense product", points(dense, ctrl), ref, 1e-9 if dtype == np.float64 else 1e-5)
    kernel = "banded" if b.banded else "dense"
    rows.append((tag, f"bsjax Blending.points (as called, {kernel})", med, p99, compile_single, None))
    rows.append((tag, "bsjax dense product (previous kernel)", dmed, dp99, compile_dense, dmed / med))
    rows.append(
        (tag, f"bsjax vmap over {BATCH} nets, per net", bmed / BATCH, bp99 / BATCH, compile_batch, None)
    )
    rows.append(
        (
            tag,
            f"bsjax vmap over {BATCH} nets, dense product, per net",
            dbmed / BATCH,
            dbp99 / BATCH,
            compile_dbatch,
            dbmed / bmed,
        )
    )
    if not peers:
        return med, bmed / BATCH

    u = np.linspace(0, 1, m)
    xi = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    ctrl64 = np.asarray(ctrl, dtype=np.float64)

    nd = NdBSpline((knots, knots), ctrl64, 3)
    check(tag, "scipy", nd(xi).reshape(m, m, 3), ref)
    smed, sp99 = timed(lambda: nd(xi), calls["scipy"])
    rows.append((tag, "scipy NdBSpline", smed, sp99, None, smed / med))
    # scipy's own batching: the 64 nets as one vector-valued spline (trailing dims of c).
    nd_batch = NdBSpline((knots, knots), np.moveaxis(np.asarray(nets), 0, 2).reshape(R, R, -1), 3)
    sbmed, sbp99 = timed(lambda: nd_batch(xi), max(3, calls["scipy"] // 20))
    rows.append(
        (
            tag,
            f"scipy NdBSpline, {BATCH} nets as one, per net",
            sbmed / BATCH,
            sbp99 / BATCH,
            None,
            (sbmed / BATCH) / (bmed / BATCH),
        )
    )

    if splinepy is not None:
        sp = splinepy.BSpline(
            degrees=[3, 3],
            knot_vectors=[knots.tolist()] * 2,
            control_points=ctrl64.transpose(1, 0, 2).reshape(-1, 3),
        )  # u fastest
        check(tag, "splinepy", sp.evaluate(xi).reshape(m, m, 3), ref)
        pmed, pp99 = timed(lambda: sp.evaluate(xi), calls["splinepy"])
        rows.append((tag, "splinepy BSpline.evaluate", pmed, pp99, None, pmed / med))
        pmed1, pp991 = timed(lambda: sp.evaluate(xi, nthreads=1), calls["splinepy"])
        rows.append((tag, "splinepy, nthreads=1", pmed1, pp991, None, pmed1 / med))

    g = GBSpline.Surface()
    g.degree_u = g.degree_v = 3
    g.ctrlpts_size_u = g.ctrlpts_size_v = R
    g.ctrlpts = ctrl64.reshape(-1, 3).tolist()
    g.knotvector_u = g.knotvector_v = knots.tolist()
    g.sample_size_u = g.sample_size_v = m

    def geomdl_eval():
        g.reset(evalpts=True)
        return g.evalpts

    check(tag, "geomdl", np.asarray(geomdl_eval()).reshape(m, m, 3), ref)
    gmed, gp99 = timed(geomdl_eval, calls["geomdl"], warmup=0)
    rows.append(
        (tag, f"geomdl BSpline.Surface.evaluate ({calls['geomdl']} calls)", gmed, gp99, None, gmed / med)
    )
    return med, bmed / BATCH


def check(tag, name, got, ref, tol=1e-9):
    err = float(np.abs(np.asarray(got) - ref).max())
    assert err < tol, f"{tag}: {name} disagrees with bsjax by {err}"


def bench_build(rows, calls):
    """Build the blending matrices and their pseudo-inverses (thesis: 1.434 s and 8 ms, C++)."""
    for r, m, thesis in ((50, 244, "1.434 s"), (8, 82, "8 ms")):
        rng = np.random.default_rng(1)
        surface = BSplineSurface(rng.normal(size=(r, r, 3)), clamped_knots(r, 3), clamped_knots(r, 3), 3, 3)
        first = first_call(lambda: jax.block_until_ready(surface.blending(m, m)))
        eager, eager_p99 = timed(
            lambda: jax.block_until_ready(surface.blending(m, m)), calls["build"], warmup=1
        )
        build = eqx.filter_jit(lambda s: s.blending(m, m))
        compile_jit = first_call(lambda: jax.block_until_ready(build(surface)))
        jitted, jit_p99 = timed(lambda: jax.block_until_ready(build(surface)), calls["build"] * 5)
        tag = f"{r}x{r} @ {m}x{m}"
        rows.append(
            (
                tag,
                f"build+invert, as called (1st call {first:.2f} s) [thesis {thesis}]",
                eager,
                eager_p99,
                None,
                None,
            )
        )
        rows.append((tag, "build+invert, jitted", jitted, jit_p99, compile_jit - jitted, None))


def fmt(seconds):
    if seconds is None:
        return "-"
    if seconds >= 1:
        return f"{seconds:.2f} s"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds * 1e6:.1f} µs"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args()
    q = 5 if args.quick else 1
    calls = {
        82: dict(bsjax=2000 // q, scipy=200 // q, splinepy=200 // q, geomdl=3 if not args.quick else 1),
        244: dict(bsjax=400 // q, scipy=40 // q, splinepy=40 // q, geomdl=1),
        "build": 10 // q,
    }
    print(
        f"bsjax basis benchmark: {R}x{R} bicubic, clamped uniform knots, float64, jax {jax.__version__}, "
        f"{jax.devices()[0].platform}, load average {os.getloadavg()[0]:.2f} at the start"
    )
    rows, summary = [], {}
    for m in (82, 244):
        summary[m] = bench_grid(m, calls[m], rows)
    summary["f32"] = bench_grid(82, calls[82], rows, dtype=np.float32, peers=False)
    bench_grid(244, calls[244], rows, dtype=np.float32, peers=False)
    bench_build(rows, calls)

    print("\n| grid | method | median | p99 | compile | peer / bsjax |")
    print("|---|---|---|---|---|---|")
    for tag, name, med, p99, comp, ratio in rows:
        print(
            f"| {tag} | {name} | {fmt(med)} | {fmt(p99)} | {fmt(comp)} | "
            f"{'-' if ratio is None else f'{ratio:.1f}x'} |"
        )

    by = {(t, n.split(" (")[0]): med for t, n, med, *_ in rows}
    s82, b82 = summary[82]
    scipy82 = by[("82x82", "scipy NdBSpline")]
    geomdl82 = [med for t, n, med, *_ in rows if t == "82x82" and n.startswith("geomdl")][0]
    print("\nDone-when targets (82x82):")
    print(f"  bsjax vs scipy NdBSpline: {scipy82 / s82:.1f}x (target >= 15x)")
    print(f"  bsjax vs geomdl:          {geomdl82 / s82:.0f}x (target >= 1000x)")
    print(f"  vmap per net vs scipy:    {scipy82 / b82:.1f}x (target >= 50x)")
    print(f"  load average at the end: {os.getloadavg()[0]:.2f}")
    s32, b32 = summary["f32"]
    print(f"  float32: single {scipy82 / s32:.1f}x, vmap per net {scipy82 / b32:.1f}x scipy (float64)")


if __name__ == "__main__":
    main()
