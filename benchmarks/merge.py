"""Merging patches: bsjax vs geomdl, and the seven cases of thesis §6.3 (Tables 6.3/6.4).

    .venv/bin/python benchmarks/merge.py            # a few minutes on 2 cores
    .venv/bin/python benchmarks/merge.py --quick    # fewer calls, fewer cases refitted

1. Speed: two 8×8 bicubic patches, 82×82 samples each. `merge.merge` as a user calls it (first
   call: plan + compile; then the cached layout and one compiled call: discretise both with the
   stored matrices, refit with the stored inverses, thesis eq. 3.7), beside the hand-jitted
   `layout.apply`; geomdl's `fitting.approximate_surface` fits the
   same 164×82 points with the same control counts (15×8) and degrees. Both run in this process;
   both results are measured by the same closest-point deviation from the original patches.
2. The seven cases (`bsjax.merge.cases`), merged with C² and C⁰ (the thesis's linear refit),
   deviations printed like thesis Tables 6.3/6.4 with the thesis's numbers beside them. The
   merged surfaces are written to .3dm (bsjax.io) and a deviation heat map to PNG in `--out`.
3. The nonlinear refit with parameter correction (`bsjax.merge.refit`, optimistix) on the
   harder cases: compile time (first call minus a second one) and run time apart, rounds and
   status, deviation linear vs refitted.
4. Degree reduction (case 6 with `degrees="reduce"`): each patch's reduction error
   (`MergeLayout.reduction_error`) beside the merge's deviation.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from _timing import timed  # noqa: E402  (benchmarks/ is on sys.path when run as a script)
from geomdl import fitting  # noqa: E402

from bsjax import io  # noqa: E402
from bsjax import merge as mg  # noqa: E402
from bsjax.basis import BSplineSurface  # noqa: E402
from bsjax.examples import merge_cases as cases  # noqa: E402

# Thesis Tables 6.3/6.4: (Rhino C2, proposed C2, proposed C0) mean and std; None = not given.
THESIS = {
    1: ((0.2242, 0.2704), (0.3568, 0.2452), (0.0104, 0.0164)),
    2: ((0.0778, 0.1708), (0.0837, 0.1093), (0.0458, 0.0621)),
    3: ((0.0259, 0.0364), (0.0273, 0.0283), (0.0110, 0.0096)),
    4: (None, (0.0215, 0.0263), (0.0233, 0.0228)),
    5: (None, (0.0423, 0.0792), (0.0451, 0.0771)),
    6: ((0.0126, 0.0125), (0.0139, 0.0117), (0.0157, 0.0154)),
    7: (None, (0.0882, 0.1218), (0.0454, 0.0525)),
}


def geomdl_fit(points: np.ndarray, r: int, s: int, k: int, l: int) -> BSplineSurface:
    m, n, _ = points.shape
    g = fitting.approximate_surface(
        points.reshape(-1, 3).tolist(), m, n, k, l, ctrlpts_size_u=r, ctrlpts_size_v=s
    )
    ctrl = np.asarray(g.ctrlpts).reshape(r, s, 3)
    return BSplineSurface(ctrl, np.asarray(g.knotvector_u), np.asarray(g.knotvector_v), k, l)


def _once(fn):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0


def speed(calls: int, geomdl_calls: int) -> None:
    a = cases._patch(0, 20, 0, 20, cases._hill, 8, 8)
    b = cases._patch(
        20, 40, 0, 20, lambda x, y: cases._hill(x, y) + 0.02 * (x - 20.0) * np.sin(y / 3.0), 8, 8
    )
    ctrls = [a.ctrl, b.ctrl]
    print("== Speed: merge two 8×8 bicubic patches, 82×82 samples each (164×82 points → 15×8 net)")
    print("   as called: `merge.merge([a, b], 'u', 2)` (orient='auto': edges read every call);")
    print("   the layout (knots, blending matrices, pseudo-inverses) is cached by the patches' bases")
    mg.clear_cache()
    merged, t_first = _once(lambda: mg.merge([a, b], "u", 2))
    _, t_second = _once(lambda: mg.merge([a, b], "u", 2))
    med, p99 = timed(lambda: jax.block_until_ready(mg.merge([a, b], "u", 2)), calls)
    g_med_as, g_p99_as = timed(
        lambda: jax.block_until_ready(mg.merge([a, b], "u", 2, orient="as_given")), calls
    )
    layout = mg.plan([a, b], "u", 2)
    apply = jax.jit(lambda lay, cs: lay.surface(lay.apply(cs)))
    _, t_jit_first = _once(lambda: apply(layout, ctrls))
    j_med, j_p99 = timed(lambda: jax.block_until_ready(apply(layout, ctrls)), calls)
    a_med, a_p99 = timed(lambda: jax.block_until_ready(layout.apply(ctrls)), calls)
    points = np.asarray(layout.points(ctrls))
    r, s = layout.merged.ctrl_shape
    t0 = time.perf_counter()
    ours_geomdl = geomdl_fit(points, r, s, 3, 3)
    g_first = time.perf_counter() - t0
    g_med, g_p99 = timed(lambda: geomdl_fit(points, r, s, 3, 3), geomdl_calls, warmup=0)
    dev_ours = mg.deviation([a, b], merged, samples=101)
    dev_geomdl = mg.deviation([a, b], ours_geomdl, samples=101)
    print(f"merge as called, first call (plan + compile):        {t_first * 1e3:9.1f} ms")
    print(f"merge as called, second call:                         {t_second * 1e3:9.3f} ms")
    print(f"merge as called, steady:  median {med * 1e3:8.3f} ms   p99 {p99 * 1e3:8.3f} ms   ({calls} calls)")
    print(f"  orient='as_given':      median {g_med_as * 1e3:8.3f} ms   p99 {g_p99_as * 1e3:8.3f} ms")
    print(f"layout.apply as called:   median {a_med * 1e3:8.3f} ms   p99 {a_p99 * 1e3:8.3f} ms")
    print(
        f"hand-jitted apply+surface: median {j_med * 1e3:8.3f} ms   p99 {j_p99 * 1e3:8.3f} ms"
        f"   (first {t_jit_first * 1e3:.1f} ms)"
    )
    print(
        f"geomdl approximate_surface: median {g_med * 1e3:8.1f} ms   p99 {g_p99 * 1e3:8.1f} ms   "
        f"({geomdl_calls} calls, first {g_first * 1e3:.1f} ms)"
    )
    print(f"speed-up geomdl / bsjax merge as called (median): {g_med / med:8.0f}×")
    print(f"deviation bsjax  C2: mean {dev_ours.mean:.5f}  std {dev_ours.std:.5f}  max {dev_ours.max:.5f}")
    print(
        f"deviation geomdl   : mean {dev_geomdl.mean:.5f}  std {dev_geomdl.std:.5f}  max {dev_geomdl.max:.5f}"
    )
    print()


def _fmt(x):
    return "      -" if x is None else f"{x:7.4f}"


def tables(out: Path, samples: int, dev_samples: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"== Seven cases (thesis §6.3.1): {samples}×{samples} merge samples per patch, deviation on "
        f"{dev_samples}×{dev_samples} per original, closest point; millimetres"
    )
    head = (
        f"{'case':<4} {'':<18} {'Rhino C2':>8} {'thes. C2':>8} {'thes. C0':>8} | "
        f"{'bsjax C2':>8} {'bsjax C0':>8}"
    )
    print(head)
    print("-" * len(head))
    heat = None
    for c in cases.all_cases():
        results = {}
        for cont in (2, 0):
            merged, _, rep = cases.run(c, cont, samples=samples, deviation_samples=dev_samples)
            results[(cont, False)] = rep
            io.save(merged, out / f"case{c.number}_C{cont}.3dm")
            if c.number == 2 and cont == 2:
                heat = results[(cont, False)]
        io.save(c.originals, out / f"case{c.number}_originals.3dm")
        th = THESIS[c.number]
        rows = [
            ("Total points", lambda r: f"{r.n_points:8d}", None),
            ("Close points", lambda r: f"{r.n_within:8d}", None),
            ("Average distance", lambda r: f"{r.mean:8.4f}", 0),
            ("Median distance", lambda r: f"{r.median:8.4f}", None),
            ("Standard deviation", lambda r: f"{r.std:8.4f}", 1),
            ("Maximum distance", lambda r: f"{r.max:8.4f}", None),
        ]
        print(f"{c.number}: {c.name}")
        for label, fmt, idx in rows:
            thesis = "".join(f" {_fmt(None if t is None or idx is None else t[idx]):>8}" for t in th)
            ours = " ".join(fmt(results[(cont, False)]) for cont in (2, 0))
            print(f"     {label:<18}{thesis} | {ours}")
    print(f"(close points: within {heat.tolerance} mm; .3dm files in {out})")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = mg.plot_deviation(heat, title="case 2, C² merge: distance to the merged surface (mm)")
    ax.figure.tight_layout()
    ax.figure.savefig(out / "case2_C2_deviation.png", dpi=110)
    plt.close(ax.figure)


def _layout(c, continuity: int, samples: int, **extra):
    options = {**c.options, **extra}
    windows = None
    if c.direction is None:
        return (
            mg.plan_grid(c.patches, continuity, samples=samples, **options),
            [[s.ctrl for s in r] for r in c.patches],
            None,
        )
    if options.pop("overlap", "keep") == "drop":
        trims = mg.overlap_trims(c.patches, c.direction, samples)
        options["trim"] = trims
        windows = [(lo, hi, 0.0, 1.0) if c.direction == "u" else (0.0, 1.0, lo, hi) for lo, hi in trims]
    layout = mg.plan(c.patches, c.direction, continuity, samples=samples, orient="as_given", **options)
    return layout, [s.ctrl for s in c.patches], windows


def refits(numbers, samples: int, dev_samples: int) -> None:
    solver = mg.RefitSolver()
    print(
        f"== Nonlinear refit with parameter correction (optimistix Gauss–Newton foot points + banded"
        f" normal equations; ≤ {solver.rounds} rounds, stop at < {solver.rtol:.0%} RMS gain),"
        f" {samples}² samples"
        f" per patch, deviation on {dev_samples}² per original, mm"
    )
    head = (
        f"{'case':<5}{'C':>2} {'net':>6} {'compile s':>10} {'run s':>7} {'rounds':>6} {'status':>9} |"
        f" {'mean lin':>9} {'mean nl':>9} {'max lin':>8} {'max nl':>8}"
    )
    print(head)
    print("-" * len(head))
    for number in numbers:
        c = cases.case(number)
        for cont in (2, 0):
            layout, ctrls, windows = _layout(c, cont, samples)
            linear = layout.surface(layout.apply(ctrls))
            t0 = time.perf_counter()
            sol = jax.block_until_ready(mg.refit(layout, ctrls, solver))
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            sol = jax.block_until_ready(mg.refit(layout, ctrls, solver))
            run = time.perf_counter() - t0
            dev = [
                mg.deviation(c.originals, s, samples=dev_samples, windows=windows)
                for s in (linear, layout.surface(sol.ctrl))
            ]
            status = "settled" if sol.result == optx.RESULTS.successful else "max rnds"
            r, s = layout.merged.ctrl_shape
            print(
                f"{number:<5}{cont:>2} {f'{r}x{s}':>6} {max(first - run, 0.0):10.2f} {run:7.2f}"
                f" {int(sol.rounds):6d}"
                f" {status:>9} | {dev[0].mean:9.5f} {dev[1].mean:9.5f} {dev[0].max:8.4f} {dev[1].max:8.4f}"
            )
    print(
        "(compile = first call minus the second; a C⁰ layout has the C² one's shapes, so it reuses"
        " the compiled refit and its compile column is ~0)"
    )
    print()


def reduction(samples: int, dev_samples: int) -> None:
    c = cases.case(6)
    print("== Degree reduction: case 6 merged with degrees='reduce' (bicubic result), C2")
    layout, ctrls, _ = _layout(c, 2, samples, degrees="reduce")
    merged = layout.surface(layout.apply(ctrls))
    dev = mg.deviation(c.originals, merged, samples=dev_samples)
    err = np.asarray(layout.reduction_error).ravel()
    for s, e in zip(c.originals, err):
        print(
            f"patch {s.shape[0]}x{s.shape[1]} degrees {s.degree_u}x{s.degree_v}: reduction error (max, on its"
            f" {samples}² samples) {e:.5f} mm"
        )
    print(
        f"merged {merged.shape[0]}x{merged.shape[1]} degrees {merged.degree_u}x{merged.degree_v}:"
        f" deviation mean {dev.mean:.5f}  max {dev.max:.5f} mm"
    )
    print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer calls; refit only cases 4 and 6")
    parser.add_argument("--out", default="bsjax-out/merge", help="folder for .3dm files and the heat map")
    args = parser.parse_args()
    print(f"jax {jax.__version__}, backend {jax.default_backend()}, float64")
    speed(calls=50 if args.quick else 300, geomdl_calls=1 if args.quick else 3)
    tables(Path(args.out), samples=82, dev_samples=101)
    print()
    refits((4, 6) if args.quick else (2, 3, 4, 6, 7), samples=82, dev_samples=101)
    reduction(samples=82, dev_samples=101)


if __name__ == "__main__":
    main()
