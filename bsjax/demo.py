"""`bsjax demo`: the thesis's shapes through the blending-matrix pipeline, written to files.

Steps (each prints its progress): build the blending matrices of the built-in shapes at 82×82
(the thesis's standard resolution), evaluate points and normals, check the least-squares refit,
and write a PNG picture, the exact surfaces (.3dm, .json) and a tessellation (.glb), plus a JSON
report. Later capabilities (collision, merging, physics) add their steps here.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

SAMPLES = 82


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

    named = {"teardrop": shapes.teardrop(), "spoon_bowl": shapes.spoon_bowl(), "spoon_handle": shapes.spoon_handle()}
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
            "control_net": list(surface.shape), "degrees": [surface.degree_u, surface.degree_v],
            "periodic": [surface.periodic_u, surface.periodic_v], "samples": [SAMPLES, SAMPLES],
            "blending_build_ms": 1e3 * build, "points_first_call_ms": 1e3 * first,
            "points_steady_us": 1e6 * steady, "refit_max_error": refit_error,
            "normals_finite": bool(np.isfinite(np.asarray(normals)).all()),
            "extent": np.ptp(np.asarray(points).reshape(-1, 3), axis=0).tolist(),
        }
        plot.draw_surface(ax, points, surface.ctrl, values=np.asarray(normals)[..., 2], title=f"{name} {surface.shape}")
        io.save(surface, out / f"{name}.json")
        print(f"  {name:<13} net {surface.shape}  points {1e6 * steady:7.1f} µs  refit error {refit_error:.1e}")
    plot.save(fig, out / "shapes.png")
    io.save(list(named.values()), out / "shapes.3dm")
    io.save(list(named.values()), out / "shapes.glb")
    report["shapes"] = rows
    return named


def run(out: Path) -> dict:
    jax.config.update("jax_enable_x64", True)  # the demo works in float64 (geometry precision)
    out.mkdir(parents=True, exist_ok=True)
    report: dict = {"jax_backend": jax.default_backend(), "float64": True}
    t0 = time.perf_counter()
    print(f"[1/1] shapes through the blending matrices at {SAMPLES}×{SAMPLES} …")
    shapes_step(out, report)
    report["total_seconds"] = time.perf_counter() - t0
    (out / "report.json").write_text(json.dumps(report, indent=2))
    return report


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bsjax demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bsjax-out", help="output folder (default ./bsjax-out)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    report = run(out)
    files = sorted(p.name for p in out.iterdir())
    print(f"\nwrote {len(files)} files to {out}/: {', '.join(files)}")
    print(f"done in {report['total_seconds']:.1f} s")
    return 0
