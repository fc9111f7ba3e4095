"""The spoon case study of the thesis (§7.3), end to end (run it with `bsjax demo`).

1. The built-in shapes (teardrop, spoon bowl, spoon handle) through their blending matrices at
   82×82 (points, normals, refit).
2. Bend the spoon handle: plasticine mass-spring lattice, one end clamped by a plane, pushed by a
   sphere; merge the bent handle and the bowl into one patch, with a deviation report.
3. Throw a jelly (B-spline sphere + 12³ VSOFM lattice) into the bowl tilted 0°, 10°, 20° and
   report the spill; then the derivative through the simulation (forward mode: the tilt is one
   number) finds the tilt that keeps it in.
4. Pictures (PNG), surfaces (.3dm, .json, .glb) and a JSON report in the output folder.
"""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

SAMPLES = 82

# Sizes of the full case study and of the quick one the test suite runs (same code path).
FULL = {"bend_steps": 200, "relax_steps": 3000, "lattice": 12, "cycles": 300, "seconds": 0.3, "opt_steps": 8}
QUICK = {"bend_steps": 40, "relax_steps": 100, "lattice": 6, "cycles": 60, "seconds": 0.05, "opt_steps": 2}


def _timed(fn, *args, repeat: int = 50):
    """(result, first-call seconds, median steady-state seconds) of a jitted call."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return out, first, float(np.median(times))


def shapes_step(out: Path, report: dict) -> dict:
    """Blending matrices, points, normals and refit of the teardrop, spoon bowl and spoon handle."""
    from bsjax import io, plot, shapes

    named = {
        "teardrop": shapes.teardrop(),
        "spoon_bowl": shapes.spoon_bowl(),
        "spoon_handle": shapes.spoon_handle(),
    }
    fig, axes = plot.figure(len(named))
    rows = {}
    for ax, (name, surface) in zip(axes, named.items()):
        t0 = time.perf_counter()
        blending = surface.blending(SAMPLES, SAMPLES)
        build = time.perf_counter() - t0
        points, first, steady = _timed(jax.jit(lambda c, b=blending: b.points(c)), surface.ctrl)
        normals = jax.jit(lambda c, b=blending: b.normals(c))(surface.ctrl)
        refit_error = float(np.abs(np.asarray(blending.refit(points)) - np.asarray(surface.ctrl)).max())
        rows[name] = {
            "control_net": list(surface.shape),
            "degrees": [surface.degree_u, surface.degree_v],
            "periodic": [surface.periodic_u, surface.periodic_v],
            "samples": [SAMPLES, SAMPLES],
            "blending_build_ms": 1e3 * build,
            "points_first_call_ms": 1e3 * first,
            "points_steady_us": 1e6 * steady,
            "refit_max_error": refit_error,
            "normals_finite": bool(np.isfinite(np.asarray(normals)).all()),
            "extent": np.ptp(np.asarray(points).reshape(-1, 3), axis=0).tolist(),
        }
        plot.draw_surface(
            ax, points, surface.ctrl, values=np.asarray(normals)[..., 2], title=f"{name} {surface.shape}"
        )
        io.save(surface, out / f"{name}.json")
        print(
            f"  {name:<13} net {surface.shape}  points {1e6 * steady:7.1f} µs  refit error {refit_error:.1e}"
        )
    plot.save(fig, out / "shapes.png")
    io.save(list(named.values()), out / "shapes.3dm")
    io.save(list(named.values()), out / "shapes.glb")
    report["shapes"] = rows
    return named


def bend_and_merge_step(out: Path, report: dict, handle, bowl, sizes: dict):
    """Bend the handle (mass-spring, plane clamp, sphere push), attach and merge the bowl."""
    from bsjax import merge
    from bsjax.examples import spoon

    t0 = time.perf_counter()
    bent, info = spoon.bend_handle(handle, steps=sizes["bend_steps"], relax_steps=sizes["relax_steps"])
    info["seconds"] = time.perf_counter() - t0
    print(
        f"  handle: {info['lattice_nodes']} nodes, {info['springs']} springs, {info['fixed_nodes']} clamped; "
        f"neck lifted {1e3 * info['neck_lift_m']:.1f} mm ({info['seconds']:.1f} s)"
    )
    placed = spoon.attach_bowl(bent, bowl)
    t0 = time.perf_counter()
    merged = merge.merge([bent, placed], direction="u", continuity=1)
    merge_s = time.perf_counter() - t0
    dev = merge.deviation([bent, placed], merged, samples=41, tolerance=5e-4)
    print(
        f"  merged handle + bowl → one {merged.shape} patch (C¹ seam) in {1e3 * merge_s:.0f} ms; "
        f"deviation mean {1e3 * dev.mean:.3f} mm, max {1e3 * dev.max:.3f} mm over {dev.n_points} points"
    )
    report["bend"] = info
    report["merge"] = {
        "control_net": list(merged.shape),
        "continuity": 1,
        "seconds": merge_s,
        **dev.row(),
        "tolerance_m": dev.tolerance,
    }
    return bent, placed, merged, dev


def no_bar(label: str):
    """The default progress bar of `run`: none (the library prints no bars; `bsjax demo` passes
    its terminal bars, `bsjax.cli._progress.bar`). A bar factory takes a label and returns a
    context manager giving a `progress(done, total)` callback, or None."""
    return contextlib.nullcontext(None)


def jelly_step(out: Path, report: dict, bent, bowl, merged, sizes: dict, tilts=(0.0, 10.0, 20.0), bar=no_bar):
    """Throw a jelly (sphere surface + 12³ VSOFM lattice) into the tilted bowl; optimise the tilt."""
    from bsjax import mss, optimise, shapes, vsofm
    from bsjax.examples import spoon

    rot, origin = spoon.bowl_frame(bent, bowl)
    patch = merged.blending(
        params_u=np.linspace(0.5, 1.0, 160), params_v=np.linspace(0.0, 1.0, 80), m=160, n=80
    )
    local = (patch.points(merged.ctrl) - origin[None, None]) @ rot  # world → bowl frame
    hm = spoon.height_map(local, (-0.01, -0.035), (0.075, 0.035))
    ball = shapes.sphere(radius=0.007)
    centre = np.array([0.032, 0.0, 0.004])
    samples = np.asarray(ball.blending(40, 40).points(ball.ctrl)).reshape(-1, 3) + centre
    t0 = time.perf_counter()
    shape = (sizes["lattice"],) * 3
    with bar("VSOFM cycles") as progress:
        nodes = vsofm.fit(samples, shape, cycles=sizes["cycles"], progress=progress)
    vs_s = time.perf_counter() - t0
    quality = vsofm.report(samples, nodes)
    # A jelly damped at ζ = 0.3 (JELLY's E and ρ; its ζ = 0.1 rang so long after the landing that
    # the tangent jax.grad carries back grew 1e15-fold in 300 steps: a gradient of 3e23 per rad
    # against a central difference of −0.1, and BFGS could not take a step). At ζ = 0.3 the
    # gradient matches the central difference to 2 % at 0°, 3° and 6° of tilt.
    jelly = mss.Material(mss.JELLY.youngs_modulus, mss.JELLY.density, 0.3)
    lattice = mss.hex_lattice(nodes, material=jelly, node_damping=5e-6)
    dt = 0.9 * float(mss.stable_dt(lattice, 2.0))
    steps = max(int(sizes["seconds"] / dt) // 50, 1) * 50
    print(
        f"  jelly: {shape[0]}³ VSOFM lattice in {vs_s:.2f} s ({quality.inverted} inverted hexahedra); "
        f"{lattice.n_edges} springs; {steps} steps of {1e3 * dt:.3f} ms"
    )
    throw = (0.0, -0.45, 0.0)  # thrown sideways: untilted, it flies over the far rim

    def outcome(tilt):
        state, risk = spoon.drop(lattice, hm, tilt, dt, steps, 2.0, 0.002, velocity=throw)
        return spoon.spill(hm, state.position), risk, state.position

    run = jax.jit(outcome)
    rows, finals = [], {}
    for deg in tilts:
        sp, risk, pos = run(jnp.deg2rad(deg))
        rows.append({"tilt_deg": deg, "spill_fraction": float(sp), "spill_risk": float(risk)})
        finals[deg] = np.asarray(pos)
        print(
            f"  tilt {deg:4.1f}°: spilled {100 * float(sp):5.1f} % of the jelly, spill risk {float(risk):.4f}"
        )
    # One design variable: forward mode (one tangent pass) costs a fifth of reverse mode here
    # (3.3 s against 17 s through the 4 350 steps); both are the exact derivative of the rollout.
    risk_of = lambda t: outcome(t)[1]
    zero = jnp.asarray(0.0)
    grad = float(jax.jit(lambda t: jax.jvp(risk_of, (t,), (jnp.ones_like(t),))[1])(zero))
    eps = 1e-4  # rad
    central = (float(run(jnp.asarray(eps))[1]) - float(run(jnp.asarray(-eps))[1])) / (2 * eps)
    print(f"  d risk / d tilt at 0°: jax.jvp {grad:.5f}, central difference {central:.5f} per rad")
    print("  derivatives through the drop: BFGS (Armijo line search) on the tilt, bounded to [-10°, 20°] …")
    found = optimise.minimise(
        lambda t, _: risk_of(t),
        zero,
        lower=float(np.deg2rad(-10.0)),
        upper=float(np.deg2rad(20.0)),
        max_steps=sizes["opt_steps"],
        throw=False,  # a fixed budget of evaluations: keep the last accepted tilt
        progress=_print_step,
        autodiff_mode="fwd",
    )
    values = found.accepted()
    history = [{"step": k, "spill_risk": float(v)} for k, v in enumerate(values)]
    tilt = found.design
    print(
        f"    {optimise.STATUS[int(found.status)]}: {int(found.steps)} accepted steps in"
        f" {int(found.evaluations)} evaluations, risk {' → '.join(f'{v:.4f}' for v in values)}"
    )
    sp, risk, pos = run(tilt)
    best = {"tilt_deg": float(jnp.rad2deg(tilt)), "spill_fraction": float(sp), "spill_risk": float(risk)}
    finals[best["tilt_deg"]] = np.asarray(pos)
    print(
        f"  best tilt {best['tilt_deg']:.2f}°: spilled {100 * best['spill_fraction']:.1f} %,"
        f" risk {best['spill_risk']:.4f}"
    )
    report["jelly"] = {
        "lattice": list(shape),
        "vsofm_seconds": vs_s,
        "inverted_hexahedra": quality.inverted,
        "min_scaled_jacobian": quality.min_scaled_jacobian,
        "dt": dt,
        "steps": steps,
        "throw_velocity": list(throw),
        "tilts": rows,
        "gradient_check": {"jax_jvp": grad, "central_difference": central, "step_rad": eps},
        "optimisation": history,
        "optimiser": {
            "method": "bfgs",
            "status": optimise.STATUS[int(found.status)],
            "accepted_steps": int(found.steps),
            "evaluations": int(found.evaluations),
        },
        "best": best,
    }
    return hm, finals


def _print_step(step: int, value: float) -> None:
    print(f"    step {step}: spill risk {value:.4f}", flush=True)


def pictures_step(out: Path, bent, placed, merged, dev, hm, finals):
    """spoon.png: the bent handle and bowl, the merged spoon coloured by deviation, the jelly."""
    from bsjax import plot

    fig, axes = plot.figure(3, size=4.5)
    grids = [np.asarray(s.blending(40, 12).points(s.ctrl)) for s in (bent, placed)]
    for surface, points in zip((bent, placed), grids):
        plot.draw_surface(axes[0], points, surface.ctrl, title="bent handle + bowl (two patches)")
    plot.equal_axes(axes[0], np.concatenate([g.reshape(-1, 3) for g in grids]))
    grid = merged.blending(82, 82)
    plot.draw_surface(axes[1], grid.points(merged.ctrl), None, title=f"merged {merged.shape}, C¹ seam")
    ax = axes[2]
    x = np.asarray(
        jnp.linspace(hm.origin[0], hm.origin[0] + hm.spacing[0] * (hm.z.shape[0] - 1), hm.z.shape[0])
    )
    y = np.asarray(
        jnp.linspace(hm.origin[1], hm.origin[1] + hm.spacing[1] * (hm.z.shape[1] - 1), hm.z.shape[1])
    )
    X, Y = np.meshgrid(x, y, indexing="ij")
    Z = np.where(np.asarray(hm.mask) > 0, np.asarray(hm.z), np.nan)
    ax.plot_surface(X, Y, Z, color="#cccccc", alpha=0.5, linewidth=0)
    for (deg, pos), c in zip(finals.items(), ("#1f77b4", "#2ca02c", "#d62728", "#9467bd")):
        ax.scatter(pos[::3, 0], pos[::3, 1], pos[::3, 2], s=1, color=c, label=f"{deg:.1f}°")
    jelly = np.concatenate(list(finals.values()))
    bowl_pts = np.stack([X, Y, Z], -1).reshape(-1, 3)
    plot.equal_axes(ax, np.concatenate([jelly, bowl_pts[np.isfinite(bowl_pts[:, 2])]]))
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("jelly after the throw, per tilt (bowl frame)", fontsize=9)
    plot.save(fig, out / "spoon.png")


def _finite_or_none(value):
    """The report with non-finite floats as None, so report.json stays valid JSON."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


def run(out: Path, quick: bool = False, bar=no_bar) -> dict:
    """Run the four steps, write the files into `out` and return the report (also `report.json`).
    `bar`: the progress bars of the steps and of the VSOFM fit (`no_bar`: none).

    The study is meant for float64 (`jax_enable_x64`, which `bsjax demo` turns on; this function
    leaves the configuration as it finds it). `quick` uses the small sizes of `QUICK`.
    """
    out.mkdir(parents=True, exist_ok=True)
    sizes = QUICK if quick else FULL
    float64 = bool(jax.config.read("jax_enable_x64"))
    report: dict = {"jax_backend": jax.default_backend(), "float64": float64, "quick": quick, "sizes": sizes}
    t0 = time.perf_counter()
    with bar("demo steps") as progress:
        tick = progress or (lambda done, total: None)
        print(f"[1/4] shapes through the blending matrices at {SAMPLES}×{SAMPLES} …")
        named = shapes_step(out, report)
        tick(1, 4)
        print(
            "[2/4] bend the spoon handle (plasticine lattice, plane clamp, sphere push) and merge the bowl …"
        )
        bent, placed, merged, dev = bend_and_merge_step(
            out, report, named["spoon_handle"], named["spoon_bowl"], sizes
        )
        from bsjax import io

        io.save([bent, placed, merged], out / "spoon.3dm")
        io.save(merged, out / "spoon.glb")
        io.save(merged, out / "spoon.json")
        tick(2, 4)
        print("[3/4] jelly thrown into the tilted bowl; its derivative finds the tilt that keeps it in …")
        hm, finals = jelly_step(out, report, bent, placed, merged, sizes, bar=bar)
        tick(3, 4)
        print("[4/4] pictures …")
        pictures_step(out, bent, placed, merged, dev, hm, finals)
        tick(4, 4)
    report["total_seconds"] = time.perf_counter() - t0
    (out / "report.json").write_text(json.dumps(_finite_or_none(report), indent=2, allow_nan=False))
    return report
