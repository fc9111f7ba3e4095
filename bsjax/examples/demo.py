"""The spoon case study of the thesis (§7.3), end to end (run it with `bsjax demo`).

1. The built-in shapes (teardrop, spoon bowl, spoon handle) through their blending matrices at
   82×82 (points, normals, refit).
2. Bend the spoon handle: plasticine mass-spring lattice, one end clamped by a plane, pushed by a
   sphere; merge the bent handle and the bowl into one patch, with a deviation report.
3. A jelly (B-spline sphere + VSOFM volume lattice) resting in the merged spoon, itself a steel
   shell lattice held at the handle: two deformable bodies in surface–surface contact
   (`bsjax.examples.spoon.study`), the spoon tilted 0°, 10° and 20° backwards (thesis Figs
   7.15–7.17); the spill and where it leaves, and the derivative of the spill risk with respect
   to the tilt through the whole rollout (forward mode), beside a central difference.
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

__all__ = ["FULL", "QUICK", "run"]

SAMPLES = 82

# Sizes of the full case study and of the quick one the test suite runs (same code path).
FULL = {
    "bend_steps": 200,
    "relax_steps": 3000,
    "lattice": 6,
    "jelly_samples": 12,
    "spoon_shape": (30, 8, 2),
    "cycles": 100,
    "seconds": 0.3,
}
QUICK = {
    "bend_steps": 40,
    "relax_steps": 100,
    "lattice": 4,
    "jelly_samples": 12,
    "spoon_shape": (30, 8, 2),
    "cycles": 60,
    "seconds": 0.03,
}


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
    plot.save_figure(fig, out / "shapes.png")
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


def jelly_step(out: Path, report: dict, merged, sizes: dict, tilts=(0.0, 10.0, 20.0), bar=no_bar):
    """The jelly in the merged steel spoon, two deformable bodies (`spoon.study`): tilted 0°,
    10° and 20° backwards (thesis Figs 7.15–7.17); the derivative of the spill risk with
    respect to the tilt through contact and both lattices, beside a central difference."""
    from bsjax import vsofm
    from bsjax.examples import spoon

    t0 = time.perf_counter()
    with bar("VSOFM cycles") as progress:
        s = spoon.study(
            merged,
            lattice=sizes["lattice"],
            jelly_samples=(sizes["jelly_samples"],) * 2,
            spoon_shape=sizes["spoon_shape"],
            cycles=sizes["cycles"],
            progress=progress,
        )
    build = time.perf_counter() - t0
    steel, jelly = s.scene.bodies
    ball = jelly.coupling.blending.points(jelly.surface.ctrl).reshape(-1, 3)
    quality = vsofm.report(ball, jelly.lattice.rest_positions.reshape((sizes["lattice"],) * 3 + (3,)))
    dt = spoon.step_size(s)
    seconds = sizes["seconds"]
    print(
        f"  jelly: {sizes['lattice']}³ VSOFM lattice ({quality.inverted} inverted hexahedra), "
        f"{jelly.lattice.n_edges} springs; steel spoon {steel.lattice.n_nodes} nodes; built in {build:.1f} s;"
        " "
        f"{int(round(seconds / dt))} steps of {1e6 * dt:.0f} µs ({seconds} s)"
    )
    rows, finals = [], {}
    for deg in tilts:
        t0 = time.perf_counter()
        with bar(f"tilt {deg:g}°") as progress:
            states, t = spoon.run(s, deg, seconds=seconds, progress=progress)
        where = {k: float(v) for k, v in spoon.spilled(s, states[1].position, t).items()}
        risk = float(spoon.spill_risk(s, states[1].position, t))
        rows.append({"tilt_deg": deg, **where, "spill_risk": risk, "seconds": time.perf_counter() - t0})
        finals[deg] = np.asarray(states[1].position)
        exits = ", ".join(f"{k} {100 * where[k]:.0f} %" for k in spoon.EXITS if where[k] > 0) or "none"
        print(
            f"  tilt {deg:4.1f}° backwards: spilled {100 * where['spilled']:5.1f} % ({exits}),"
            f" risk {risk:.4f}"
        )
    # One design variable: forward mode (one tangent pass through the rollout) is the cheap
    # exact derivative; a central difference of two more rollouts checks it.
    at = float(tilts[-1])

    def risk_of(tilt):
        states, t = spoon.run(s, tilt, seconds=seconds, dt=dt)
        return spoon.spill_risk(s, states[1].position, t)

    t0 = time.perf_counter()
    tangent = float(jax.jvp(risk_of, (jnp.asarray(at),), (jnp.ones(()),))[1])
    jvp_s = time.perf_counter() - t0
    eps = 0.05  # degrees
    central = (float(risk_of(at + eps)) - float(risk_of(at - eps))) / (2 * eps)
    print(
        f"  d risk / d tilt at {at:g}°: jax.jvp {tangent:.3e}, central difference {central:.3e} per degree"
        f" ({jvp_s:.1f} s for the derivative)"
    )
    report["jelly"] = {
        "lattice": [sizes["lattice"]] * 3,
        "inverted_hexahedra": quality.inverted,
        "min_scaled_jacobian": quality.min_scaled_jacobian,
        "spoon_nodes": steel.lattice.n_nodes,
        "dt": dt,
        "steps": int(round(seconds / dt)),
        "seconds_simulated": seconds,
        "tilts": rows,
        "gradient_check": {
            "tilt_deg": at,
            "jax_jvp": tangent,
            "central_difference": central,
            "step_deg": eps,
        },
    }
    return s, finals


def pictures_step(out: Path, bent, placed, merged, dev, study, finals):
    """spoon.png: the bent handle and bowl, the merged spoon, the jelly after each tilt."""
    from bsjax import plot

    fig, axes = plot.figure(3, size=4.5)
    grids = [np.asarray(s.blending(40, 12).points(s.ctrl)) for s in (bent, placed)]
    for surface, points in zip((bent, placed), grids):
        plot.draw_surface(axes[0], points, surface.ctrl, title="bent handle + bowl (two patches)")
    plot.equal_axes(axes[0], np.concatenate([g.reshape(-1, 3) for g in grids]))
    grid = merged.blending(82, 82)
    plot.draw_surface(axes[1], grid.points(merged.ctrl), None, title=f"merged {merged.shape}, C¹ seam")
    ax = axes[2]
    bowl = np.asarray(
        merged.blending(
            params_u=np.linspace(0.5, 1.0, 30), params_v=np.linspace(0, 1, 20), m=30, n=20
        ).points(merged.ctrl)
    )
    ax.plot_wireframe(bowl[..., 0], bowl[..., 1], bowl[..., 2], color="#999999", linewidth=0.4)
    for (deg, pos), c in zip(finals.items(), ("#1f77b4", "#2ca02c", "#d62728", "#9467bd")):
        ax.scatter(pos[:, 0], pos[:, 1], pos[:, 2], s=2, color=c, label=f"{deg:g}° backwards")
    plot.equal_axes(ax, np.concatenate([bowl.reshape(-1, 3), *finals.values()]))
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("jelly after each tilt (spoon frame)", fontsize=9)
    plot.save_figure(fig, out / "spoon.png")


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
        print("[3/4] a jelly in the steel spoon, tilted: two deformable bodies in contact …")
        study, finals = jelly_step(out, report, merged, sizes, bar=bar)
        tick(3, 4)
        print("[4/4] pictures …")
        pictures_step(out, bent, placed, merged, dev, study, finals)
        tick(4, 4)
    report["total_seconds"] = time.perf_counter() - t0
    (out / "report.json").write_text(json.dumps(_finite_or_none(report), indent=2, allow_nan=False))
    return report
