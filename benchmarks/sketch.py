"""Stroke fitting and surface constructors as called: bsjax vs scipy and geomdl.

    .venv/bin/python benchmarks/sketch.py            # float64, about a minute on 2 quiet cores
    .venv/bin/python benchmarks/sketch.py --quick    # fewer repetitions

Fit: a 1 000-sample noisy stroke → a cubic of 20 control points. bsjax `sketch.fit_curve` (ends
interpolated, chord parameters, averaged knots) as a user calls it and inside the user's own
`jax.jit`; scipy `make_lsq_spline` on the same parameters and knots (plain least squares, its
ends not pinned); geomdl `fitting.approximate_curve` (the same algorithm, NURBS Book A9.7, in
pure Python). The stroke features (`features`, `corners`) and `unproject` as called and jitted.
Constructors: each `bsjax.construct` function as called on small fitted curves. Times per call:
median and p99; compile time (first call minus steady state) apart; ratio = peer / bsjax.
"""

from __future__ import annotations

import argparse
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _timing import paired, timed  # noqa: E402
from geomdl import fitting  # noqa: E402
from scipy.interpolate import make_lsq_spline  # noqa: E402

from bsjax import construct, sketch  # noqa: E402
from bsjax.basis import BSplineCurve, clamped_knots  # noqa: E402

N, N_CTRL = 1000, 20


def first_call(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def stroke(rng, n=N):
    t = np.linspace(0, 1, n)
    return np.stack([np.cos(3 * t), np.sin(2 * t), 0.5 * t**2], 1) + 1e-3 * rng.normal(size=(n, 3))


def row(rows, name, med, p99, compile_s=None, ratio=None):
    rows.append((name, med, p99, compile_s, ratio))


def bench_fit(rows, calls):
    points = jnp.asarray(stroke(np.random.default_rng(0)))
    as_called = lambda: sketch.fit_curve(points, N_CTRL).curve.ctrl.block_until_ready()
    jitted_fn = jax.jit(lambda p: sketch.fit_curve(p, N_CTRL))
    jitted = lambda: jitted_fn(points).curve.ctrl.block_until_ready()
    compile_s = first_call(as_called)
    first_call(jitted)
    med, p99, jmed, jp99 = paired(as_called, jitted, calls)
    row(rows, "fit_curve 1000 → 20 (as called)", med, p99, compile_s - med)
    row(rows, "fit_curve 1000 → 20 (user's jax.jit)", jmed, jp99, None, jmed / med)

    fit = sketch.fit_curve(points, N_CTRL)
    t, knots, pts = np.asarray(fit.params), np.asarray(fit.curve.knots), np.asarray(points)
    scipy_fn = lambda: make_lsq_spline(t, pts, knots, 3)
    smed, sp99 = timed(scipy_fn, calls)
    row(rows, "scipy make_lsq_spline (same t, knots)", smed, sp99, None, smed / med)
    plist = pts.tolist()
    geomdl_fn = lambda: fitting.approximate_curve(plist, 3, ctrlpts_size=N_CTRL)
    gmed, gp99 = timed(geomdl_fn, max(3, calls // 50), warmup=1)
    row(rows, "geomdl approximate_curve", gmed, gp99, None, gmed / med)
    theirs = np.asarray(geomdl_fn().evaluate_list(t.tolist()))
    print(
        f"max error: bsjax {float(fit.max_error):.2e}, geomdl at bsjax's params {np.abs(theirs - pts).max():.2e}"
    )


def bench_features(rows, calls):
    rng = np.random.default_rng(1)
    points = jnp.asarray(stroke(rng)[:, :2])
    times = jnp.asarray(np.cumsum(rng.uniform(0.5, 1.5, N)))
    cases = {
        "features": (sketch.features, lambda p, t: sketch.features(p, t).curvature),
        "corners": (sketch.corners, lambda p, t: sketch.corners(p, t)),
    }
    for name, (fn, kernel) in cases.items():
        as_called = lambda: jax.block_until_ready(fn(points, times))
        jitted_fn = jax.jit(kernel)
        jitted = lambda: jitted_fn(points, times).block_until_ready()
        compile_s = first_call(as_called)
        first_call(jitted)
        med, p99, jmed, jp99 = paired(as_called, jitted, calls)
        row(rows, f"{name} 1000 samples (as called)", med, p99, compile_s - med)
        row(rows, f"{name} 1000 samples (user's jax.jit)", jmed, jp99, None, jmed / med)
    camera = sketch.Camera([0.0, -5.0, 1.0], [0.0, 0.0, 0.0])
    plane = sketch.Plane([0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    xy = jnp.asarray(rng.uniform(0.2, 0.8, (N, 2)))
    as_called = lambda: sketch.unproject(xy, camera, plane).block_until_ready()
    jitted_fn = jax.jit(sketch.unproject)
    jitted = lambda: jitted_fn(xy, camera, plane).block_until_ready()
    compile_s = first_call(as_called)
    first_call(jitted)
    med, p99, jmed, jp99 = paired(as_called, jitted, calls)
    row(rows, "unproject 1000 points (as called)", med, p99, compile_s - med)
    row(rows, "unproject 1000 points (user's jax.jit)", jmed, jp99, None, jmed / med)


def curves():
    t = np.linspace(0, 1, 8)
    a = BSplineCurve(np.stack([t, 0.1 * np.sin(3 * t)], 1), clamped_knots(8, 3), 3)
    b = BSplineCurve(np.stack([t, 1 + 0.1 * np.cos(2 * t)], 1), clamped_knots(8, 3), 3)
    s = np.linspace(0, 1, 6)[:, None]
    line = lambda p, q: BSplineCurve(
        (1 - s) * np.asarray(p)[None] + s * np.asarray(q)[None], clamped_knots(6, 2), 2
    )
    return a, b, line(a.ctrl[0], b.ctrl[0]), line(a.ctrl[-1], b.ctrl[-1])


def bench_construct(rows, calls):
    a, b, left, right = curves()
    profile = BSplineCurve(np.stack([0.3 + 0.2 * np.linspace(0, 1, 8) ** 2, np.linspace(0, 2, 8)], 1),
                           clamped_knots(8, 3), 3)  # fmt: skip
    cases = {
        "ruled": lambda: construct.ruled(a, b),
        "extrude": lambda: construct.extrude(a, jnp.array([0.0, 0.0, 1.0])),
        "revolve": lambda: construct.revolve(profile, jnp.zeros(3), jnp.array([0.0, 1.0, 0.0])),
        "coons": lambda: construct.coons(a, b, left, right),
        "loft (3 sections)": lambda: construct.loft([a, b, a.with_ctrl(a.ctrl + 2.0)]),
    }
    if hasattr(construct, "sweep"):
        cases["sweep"] = lambda: construct.sweep(profile, a)
    if hasattr(construct, "boundary_rotation"):
        cases["boundary_rotation"] = lambda: construct.boundary_rotation(a, b, jnp.array([0.0, 0.0, 1.0]))
    for name, fn in cases.items():
        call = lambda: jax.block_until_ready(fn())
        compile_s = first_call(call)
        med, p99 = timed(call, calls)
        row(rows, f"construct.{name} (as called)", med, p99, compile_s - med)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    calls = 40 if args.quick else 200
    rows = []
    bench_fit(rows, calls)
    bench_features(rows, calls)
    bench_construct(rows, max(20, calls // 4))
    print(f"load average {os.getloadavg()[0]:.2f}; float64; {time.strftime('%Y-%m-%d %H:%M')}")
    print(f"{'case':<44} {'median ms':>10} {'p99 ms':>10} {'compile s':>10} {'ratio':>8}")
    for name, med, p99, compile_s, ratio in rows:
        c = "" if compile_s is None else f"{compile_s:.2f}"
        r = "" if ratio is None else f"{ratio:.2f}"
        print(f"{name:<44} {1e3 * med:>10.3f} {1e3 * p99:>10.3f} {c:>10} {r:>8}")


if __name__ == "__main__":
    main()
