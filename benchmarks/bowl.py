"""Shape optimisation of the spoon bowl (`bsjax.examples.bowl`): bsjax's BFGS with `jax.grad`
through merge, contact and both lattices' rollout, against scipy's Nelder–Mead given the same
number of objective evaluations, on the same objective in the same process.

Prints, for each optimiser, the objective and spill risk reached, the evaluations and the wall
time (the first BFGS call includes its compilation, as a user meets it), and the ratio of the
objectives (bsjax / Nelder–Mead: below 1, gradients found the better bowl).

    .venv/bin/python benchmarks/bowl.py            # quick sizes (3³ jelly, 0.08 s, 6 steps)
    .venv/bin/python benchmarks/bowl.py --full     # 5³ jelly, 0.15 s, 12 steps
"""

from __future__ import annotations

import argparse
import os

import jax

jax.config.update("jax_enable_x64", True)

from bsjax.examples import bowl  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--full", action="store_true", help="the full sizes of bowl.FULL")
    parser.add_argument("--steps", type=int, default=None, help="BFGS steps (default: the sizes' budget)")
    args = parser.parse_args()
    report = bowl.run(quick=not args.full, max_steps=args.steps)
    print(
        f"bowl optimisation ({'full' if args.full else 'quick'} sizes), load average {os.getloadavg()[0]:.2f}"
    )
    print(f"  {report['jelly_nodes']} jelly nodes, {report['steps']} steps per rollout")
    check = report["gradient_check"]
    print(
        f"  gradient check: jax.jvp {check['jax_jvp']:.6e}, central difference {check['central_difference']:.6e}"
    )
    start = report["start"]
    print(f"  {'start':12s} objective {start['objective']:10.6f}  risk {start['spill_risk']:.6f}")
    for name, key in (("bsjax BFGS", "bfgs"), ("Nelder–Mead", "nelder_mead")):
        row = report[key]
        print(
            f"  {name:12s} objective {row['objective']:10.6f}  risk {row['spill_risk']:.6f}"
            f"  {row['evaluations']:3d} evaluations  {row['seconds']:7.1f} s"
        )
    ratio = report["bfgs"]["objective"] / report["nelder_mead"]["objective"]
    print(f"  objective ratio bsjax / Nelder–Mead: {ratio:.4f}")


if __name__ == "__main__":
    main()
