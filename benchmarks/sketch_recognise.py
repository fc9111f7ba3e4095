"""Single-stroke recognition (`bsjax.sketch.recognise`) on synthetic hand-drawn strokes.

    .venv/bin/python benchmarks/sketch_recognise.py                 # 1 000 strokes per class, timed
    .venv/bin/python benchmarks/sketch_recognise.py --untimed       # without time stamps
    .venv/bin/python benchmarks/sketch_recognise.py --count 200     # quicker
    .venv/bin/python benchmarks/sketch_recognise.py --figure docs/sketch_recognise.png

The strokes come from tests/strokes.py (noise, wobble, jitter, speed variation, over-tracing,
random rotation, a scale between 10⁻² and 10³ and a random position; the same generator as the
tests, another seed). Prints the confusion matrix (rows: the drawn class, columns: the
recognised one), the per-class accuracy, and the time per `recognise` call as a user calls it
(median and p99 of every call after a warm-up that compiles `corners` and `fit_stroke`; the
warm-up's time reported apart). float64.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for tests/strokes.py

from bsjax import sketch  # noqa: E402
from tests import strokes as gen  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1000, help="strokes per class (default 1000)")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--untimed", action="store_true", help="recognise without the time stamps")
    parser.add_argument("--figure", default=None, help="only draw one stroke per class and its result (PNG)")
    args = parser.parse_args()
    if args.figure:
        figure(args.figure, args.seed)
        return
    data = gen.strokes(args.count, seed=args.seed)
    start = time.perf_counter()
    for s in gen.strokes(2, seed=args.seed + 1):  # warm-up: every compiled shape
        sketch.recognise(s.points, None if args.untimed else s.times)
    warmup = time.perf_counter() - start
    matrix = np.zeros((len(gen.KINDS), len(gen.KINDS)), int)
    seconds = np.empty(len(data))
    for i, s in enumerate(data):
        t0 = time.perf_counter()
        kind = sketch.recognise(s.points, None if args.untimed else s.times).kind
        seconds[i] = time.perf_counter() - t0
        matrix[gen.KINDS.index(s.kind), gen.KINDS.index(kind)] += 1
    _report(matrix, seconds, warmup, args)


def _report(matrix, seconds, warmup: float, args) -> None:
    timing = "without time stamps" if args.untimed else "with time stamps"
    print(f"bsjax.sketch.recognise: {args.count} synthetic strokes per class, {timing}, seed {args.seed}\n")
    print("confusion matrix (rows: drawn, columns: recognised)")
    print(" " * 11 + "".join(f"{k[:6]:>7}" for k in gen.KINDS))
    for kind, row in zip(gen.KINDS, matrix):
        print(f"{kind:>10} " + "".join(f"{c:7d}" for c in row))
    accuracy = np.diag(matrix) / matrix.sum(axis=1)
    print("\nper-class accuracy: " + ", ".join(f"{k} {a:.1%}" for k, a in zip(gen.KINDS, accuracy)))
    print(f"overall accuracy: {np.trace(matrix) / matrix.sum():.2%}; lowest: {accuracy.min():.1%}")
    print(
        f"time per stroke: median {np.median(seconds) * 1e3:.2f} ms, p99 {np.percentile(seconds, 99) * 1e3:.2f} ms"
        f" ({len(seconds)} calls); warm-up (compiles) {warmup:.1f} s"
    )


def figure(path: str, seed: int) -> None:
    """One synthetic stroke per class (grey) and the regularised curve `recognise` returns (red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 5, figsize=(15, 6.4))
    for ax, s in zip(axes.ravel(), gen.strokes(1, seed=seed)):
        r = sketch.recognise(s.points, s.times)
        curve = np.asarray(r.curve.evaluate(np.linspace(0, 1, 400)))
        ax.plot(s.points[:, 0], s.points[:, 1], ".", ms=2.5, color="0.55", label="stroke")
        ax.plot(curve[:, 0], curve[:, 1], "-", lw=1.8, color="C3", label="regularised")
        ax.set_title(f"drawn {s.kind} → {r.kind} ({r.score:.2f})", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle("bsjax.sketch.recognise: synthetic hand-drawn strokes (grey), the regularised curve (red)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
