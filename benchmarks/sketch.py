"""Stroke fitting and surface constructors as called: bsjax vs scipy, geomdl and OCCT.

    .venv/bin/python benchmarks/sketch.py            # float64, about two minutes on 2 quiet cores
    .venv/bin/python benchmarks/sketch.py --quick    # fewer repetitions

Fit: a 1 000-sample noisy stroke → a cubic of 20 control points. bsjax `sketch.fit_curve` (ends
interpolated, chord parameters, averaged knots) as a user calls it and inside the user's own
`jax.jit`; scipy `make_lsq_spline` on the same parameters and knots (plain least squares, its
ends not pinned); geomdl `fitting.approximate_curve` (the same algorithm, NURBS Book A9.7, in
pure Python); OCCT `GeomAPI_PointsToBSpline` (cubic, C2, on bsjax's parameters, its tolerance
set to bsjax's max error: OCCT picks its own control count). The stroke features (`features`,
`corners`) and `unproject` as called and jitted.
Constructors: each `bsjax.construct` function as called on small fitted curves, against OCCT
where it has the construction (`GeomFill_BSplineCurves` Coons style for `coons`,
`Geom_SurfaceOfRevolution` + `GeomConvert` for `revolve`, `GeomFill_Pipe` in the corrected
Frenet frame at bsjax's sweep error for `sweep`), and `interpolate_grid` of a 20 × 20 grid
against two scipy `make_interp_spline` passes (same chord parameters and knots; the nets are
compared). OCCT's curves are built before the clock starts. Times per call:
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

from bsjax import collide, construct, sketch  # noqa: E402
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
    geomdl_error = np.linalg.norm(theirs - pts, axis=1).max()

    from OCP.GeomAbs import GeomAbs_C2
    from OCP.GeomAPI import GeomAPI_PointsToBSpline

    occ_pts, occ_t, tol = _occ_points(pts), _occ_doubles(t), float(fit.max_error)
    occ_fn = lambda: GeomAPI_PointsToBSpline(occ_pts, occ_t, 3, 3, GeomAbs_C2, tol).Curve()
    omed, op99 = timed(occ_fn, calls)
    occ = occ_fn()
    row(rows, f"OCCT PointsToBSpline (tol = bsjax's, {occ.NbPoles()} poles)", omed, op99, None, omed / med)
    print(
        f"max error: bsjax {tol:.2e} ({N_CTRL} control points), geomdl at bsjax's params "
        f"{geomdl_error:.2e}, OCCT {occ_max_error(occ, pts, t):.2e} ({occ.NbPoles()} poles)"
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
    plane = collide.Plane([0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
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
    peers = occ_peers(a, b, left, right, profile)
    for name, fn in cases.items():
        call = lambda: jax.block_until_ready(fn())
        compile_s = first_call(call)
        med, p99 = timed(call, calls)
        row(rows, f"construct.{name} (as called)", med, p99, compile_s - med)
        if name in peers:
            label, peer = peers[name](fn())
            pmed, pp99 = timed(peer, calls)
            row(rows, f"  OCCT {label}", pmed, pp99, None, pmed / med)
    bench_grid(rows, calls)


def occ_peers(a, b, left, right, profile):
    """OCCT's constructions of the same curves: {bsjax name: bsjax's result → (label, call)}."""
    from OCP.Geom import Geom_SurfaceOfRevolution
    from OCP.GeomConvert import GeomConvert
    from OCP.GeomFill import GeomFill_BSplineCurves, GeomFill_CoonsStyle, GeomFill_Pipe, GeomFill_Trihedron
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    oa, ob, ol, orr = (occ_curve(c) for c in (a, b, left, right))
    coons = lambda: GeomFill_BSplineCurves(oa, orr, ob, ol, GeomFill_CoonsStyle).Surface()
    oprofile = occ_curve(profile)  # (radius, height) at z = 0, about the y axis
    axis = gp_Ax1(gp_Pnt(0.0, 0.0, 0.0), gp_Dir(0.0, 1.0, 0.0))
    revolve = lambda: GeomConvert.SurfaceToBSplineSurface_s(Geom_SurfaceOfRevolution(oprofile, axis))
    # the profile placed in bsjax's start frame of the path: x → normal (+z), y → binormal T × z
    t0 = np.asarray(a.evaluate(jnp.zeros(1), 1))[0]
    tangent = np.append(t0, 0.0) / np.linalg.norm(t0)
    normal, start = np.array([0.0, 0.0, 1.0]), np.append(np.asarray(a.ctrl)[0], 0.0)
    binormal = np.cross(tangent, normal)
    section = occ_curve(profile, lambda c: start + c[:, :1] * normal + c[:, 1:2] * binormal)
    opath = occ_curve(a)

    def sweep(fit):  # OCCT approximates to bsjax's sweep error
        tol = float(fit.max_error)

        def call():
            pipe = GeomFill_Pipe(opath, section, GeomFill_Trihedron.GeomFill_IsCorrectedFrenet)
            pipe.Perform(tol, False)
            return pipe.Surface()

        return f"GeomFill_Pipe (tol = bsjax's {tol:.1e})", call

    return {
        "coons": lambda _: ("GeomFill_BSplineCurves (Coons style)", coons),
        "revolve": lambda _: ("SurfaceOfRevolution + GeomConvert", revolve),
        "sweep": sweep,
    }


def bench_grid(rows, calls, m=20, n=20):
    """`interpolate_grid` against scipy `make_interp_spline` along each axis, same parameters and knots."""
    from scipy.interpolate import make_interp_spline

    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, n), indexing="ij")
    grid = np.stack([u, v, 0.3 * np.sin(3 * u) * np.cos(2 * v)], -1)
    points = jnp.asarray(grid)
    call = lambda: construct.interpolate_grid(points).ctrl.block_until_ready()
    jitted_fn = jax.jit(construct.interpolate_grid)
    jitted = lambda: jitted_fn(points).ctrl.block_until_ready()
    compile_s = first_call(call)
    first_call(jitted)
    med, p99, jmed, jp99 = paired(call, jitted, calls)
    row(rows, f"construct.interpolate_grid {m}×{n} (as called)", med, p99, compile_s - med)
    row(rows, f"construct.interpolate_grid {m}×{n} (user's jax.jit)", jmed, jp99, None, jmed / med)
    surface = construct.interpolate_grid(points)
    knots_u, knots_v = (np.asarray(surface.direction(d).knots) for d in "uv")

    def chord(p, axis):  # averaged normalised chord lengths (The NURBS Book §9.2.5)
        steps = np.linalg.norm(np.diff(p, axis=axis), axis=-1)
        cum = np.concatenate([np.zeros_like(np.take(steps, [0], axis)), np.cumsum(steps, axis)], axis)
        return (cum / np.take(cum, [-1], axis)).mean(axis=1 - axis)

    def scipy_fn():
        rows_fit = make_interp_spline(chord(grid, 0), grid, k=3, t=knots_u, axis=0).c
        # a BSpline keeps its interpolation axis first in `c`
        return np.swapaxes(make_interp_spline(chord(grid, 1), rows_fit, k=3, t=knots_v, axis=1).c, 0, 1)

    smed, sp99 = timed(scipy_fn, calls)
    row(rows, "  scipy make_interp_spline ×2 (same t, knots)", smed, sp99, None, smed / med)
    print(
        f"interpolate_grid: largest difference to scipy's net {np.abs(scipy_fn() - surface.ctrl).max():.1e}"
    )


# --- peers: OCCT (OCP) and scipy, imported where used -------------------------------------------
def _occ_points(points):
    from OCP.gp import gp_Pnt
    from OCP.OCP.collections import Array1_gp_Pnt

    pts = np.pad(np.asarray(points, float), ((0, 0), (0, 3 - np.shape(points)[1])))
    array = Array1_gp_Pnt(1, pts.shape[0])
    for i, (x, y, z) in enumerate(pts.tolist(), 1):
        array.SetValue(i, gp_Pnt(x, y, z))
    return array


def _occ_doubles(values, kind="double"):
    from OCP.OCP.collections import Array1_double, Array1_int

    values = np.asarray(values).tolist()
    array = (Array1_double if kind == "double" else Array1_int)(1, len(values))
    for i, v in enumerate(values, 1):
        array.SetValue(i, v)
    return array


def occ_curve(curve: BSplineCurve, lift=None):
    """The same clamped polynomial curve as an OCCT `Geom_BSplineCurve` (planar → z = 0, or
    `lift(ctrl) → (n, 3)`)."""
    from OCP.Geom import Geom_BSplineCurve

    knots, mults = np.unique(np.asarray(curve.knots), return_counts=True)
    ctrl = np.asarray(curve.ctrl) if lift is None else lift(np.asarray(curve.ctrl))
    return Geom_BSplineCurve(
        _occ_points(ctrl), _occ_doubles(knots), _occ_doubles(mults.astype(int), "int"), curve.degree
    )


def occ_max_error(occ, points, params):
    """Largest distance between samples and an OCCT curve at the given parameters."""
    pts = np.pad(np.asarray(points, float), ((0, 0), (0, 3 - np.shape(points)[1])))
    first, last = occ.FirstParameter(), occ.LastParameter()
    values = [occ.Value(first + (last - first) * t) for t in np.asarray(params).tolist()]
    on = np.array([[p.X(), p.Y(), p.Z()] for p in values])
    return float(np.abs(on - pts).max())


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
    print("ratio = peer (or jitted) / bsjax as called; > 1: bsjax faster")
    print(f"{'case':<52} {'median ms':>10} {'p99 ms':>10} {'compile s':>10} {'ratio':>8}")
    for name, med, p99, compile_s, ratio in rows:
        c = "" if compile_s is None else f"{compile_s:.2f}"
        r = "" if ratio is None else f"{ratio:.2f}"
        print(f"{name:<52} {1e3 * med:>10.3f} {1e3 * p99:>10.3f} {c:>10} {r:>8}")


if __name__ == "__main__":
    main()
