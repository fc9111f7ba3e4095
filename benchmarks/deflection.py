"""Force-driven deformation (thesis §5.3.3, Figs 5.9 and 5.10): the deflection of a plasticine
model under a user's force, against the force and against the stiffness, beside two references.

The model is a cantilever — a plate of `L × W` with a shell lattice of thickness `T`
(`mss.Body.from_surface`), clamped along x = 0 — pulled down at the middle of its free edge by a
force `F` in newtons, spread to the nodes by `Body.point_load` (virtual work through the
coupling). `mss.relax` (linearised backward Euler, dissipative: it settles on the static shape)
gives the deflection of the free edge's middle. Beside it:

* **lattice, linear**: the same lattice's linearised stiffness `K u = f` solved by scipy (exact
  for vanishing loads; the relaxed lattice departs from it by its geometric nonlinearity);
* **beam**: Euler–Bernoulli's cantilever with a tip load, `δ = F L³ / (3 E I)`, `I = W T³ / 12`,
  with the material's Young's modulus — the continuum the lattice approximates (the lattice's
  springs, `K = E A / L` with the volume shared among them, make it softer by a constant factor).

Fig. 5.9: F = 5 … 30 N at plasticine's E = 13 MN/m² (ρ = 2500 kg/m³); Fig. 5.10: F = 30 N at
E = 6.5 … 52 MN/m². The thesis shows pictures (the model deforms more under a larger force and
with a softer spring); this prints the numbers, and `--figure PATH` draws both curves.

    .venv/bin/python benchmarks/deflection.py [--quick] [--figure deflection.png]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for tests/oracles.py
from bsjax import mss, shapes  # noqa: E402
from tests.oracles import lattice_linear_deflection  # noqa: E402

LENGTH, WIDTH, THICKNESS = 0.06, 0.04, 0.03  # m
FORCES = (5.0, 10.0, 20.0, 30.0)  # N (Fig. 5.9)
MODULI = (6.5e6, 13e6, 26e6, 52e6)  # N/m² (Fig. 5.10, at 30 N)


def cantilever(youngs_modulus: float, lattice: tuple[int, int, int]) -> mss.Body:
    plate = shapes.plate(4, 4)
    surface = plate.with_ctrl(np.asarray(plate.ctrl) * np.array([LENGTH, WIDTH, 1.0]))
    material = mss.Material(youngs_modulus, mss.PLASTICINE.density, mss.PLASTICINE.damping_ratio)
    return mss.Body.from_surface(
        surface, lattice, material, thickness=THICKNESS, fixed=lambda x: x[:, 0] < 1e-9
    )


def deflection(body: mss.Body, newtons: float) -> tuple[float, float, float, int]:
    """`(relaxed, linear, seconds, steps)`: the free edge's middle moves down by this much (m)."""
    load = body.point_load(1.0, 0.5, np.array([0.0, 0.0, -newtons]))
    tip = int(np.argmax(np.linalg.norm(np.asarray(load), axis=1)))  # the node the load centres on
    t0 = time.perf_counter()
    state, steps, converged = mss.relax(
        body.lattice, mss.init(body.lattice), 1e-2, external_force=load, tol=1e-16, max_steps=20_000,
        method="implicit", cg_iterations=100,
    )  # fmt: skip
    seconds = time.perf_counter() - t0
    if not bool(converged):
        raise RuntimeError(f"relax did not settle at F = {newtons} N")
    moved = np.asarray(state.position - body.lattice.rest_positions)
    linear = lattice_linear_deflection(body.lattice, np.asarray(load))
    return -float(moved[tip, 2]), -float(linear[tip, 2]), seconds, int(steps)


def beam(newtons: float, youngs_modulus: float) -> float:
    """Euler–Bernoulli's tip deflection of the cantilever, `F L³ / (3 E I)`."""
    return newtons * LENGTH**3 / (3 * youngs_modulus * WIDTH * THICKNESS**3 / 12)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="a coarser lattice (6 × 4 × 2)")
    parser.add_argument("--figure", default=None, help="draw both figures into this PNG")
    args = parser.parse_args()
    lattice = (6, 4, 2) if args.quick else (12, 8, 4)
    print(f"cantilever {LENGTH * 100:.0f} × {WIDTH * 100:.0f} cm, {THICKNESS * 100:.0f} cm thick, "
          f"shell lattice {lattice}, clamped at x = 0, pulled down at the free edge's middle")  # fmt: skip
    header = f"{'':>10} {'relaxed mm':>11} {'linear mm':>10} {'beam mm':>8} {'relaxed/beam':>13} {'s':>6} {'steps':>6}"
    rows = {"force": [], "modulus": []}
    print("\nFig. 5.9 — against the force, E = 13 MN/m²\n" + f"{'F N':>10}" + header[10:])
    body = cantilever(13e6, lattice)
    for f in FORCES:
        got, linear, s, steps = deflection(body, f)
        ref = beam(f, 13e6)
        rows["force"].append((f, got, linear, ref))
        print(
            f"{f:10.1f} {1e3 * got:11.3f} {1e3 * linear:10.3f} {1e3 * ref:8.3f} {got / ref:13.3f} {s:6.2f} {steps:6d}"
        )
    print("\nFig. 5.10 — against the stiffness, F = 30 N\n" + f"{'E MN/m²':>10}" + header[10:])
    for e in MODULI:
        got, linear, s, steps = deflection(cantilever(e, lattice), 30.0)
        ref = beam(30.0, e)
        rows["modulus"].append((e, got, linear, ref))
        print(
            f"{e / 1e6:10.1f} {1e3 * got:11.3f} {1e3 * linear:10.3f} {1e3 * ref:8.3f} {got / ref:13.3f} {s:6.2f} {steps:6d}"
        )
    if args.figure:
        draw(rows, args.figure)


def draw(rows, path: str) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 3.6))
    for ax, key, label, scale in zip(
        fig.subplots(1, 2), ("force", "modulus"), ("F (N)", "E (MN/m²)"), (1, 1e-6)
    ):
        x, got, linear, ref = (np.array(c) for c in zip(*rows[key]))
        ax.plot(x * scale, 1e3 * got, "o-", label="bsjax lattice (relaxed)")
        ax.plot(x * scale, 1e3 * linear, "s--", label="lattice, linear (scipy)")
        ax.plot(x * scale, 1e3 * ref, "k:", label="Euler–Bernoulli beam")
        ax.set_xlabel(label)
        ax.set_ylabel("deflection (mm)")
    fig.axes[0].set_title("Fig. 5.9: E = 13 MN/m²", fontsize=9)
    fig.axes[1].set_title("Fig. 5.10: F = 30 N", fontsize=9)
    fig.axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
