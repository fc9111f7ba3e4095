"""The seven merging cases of thesis §6.3.1 (Tables 6.3/6.4), built from constructed patches.

The thesis's patches are not published; these are constructed to show the same situations, in
millimetres, each patch about 20 mm × 20 mm with a few mm of relief:

1. similar curvature and knot vectors (two Bézier bicubic patches sharing an edge);
2. different curvatures, similar (uniform) knot vectors (the edges differ by up to 0.4 mm);
3. similar curvature, different knot vectors;
4. similar curvature, different knot vectors and dimensions (24 mm vs 20 mm edges);
5. intersecting and trimmed (the first patch runs 3 mm past the second and cuts through it;
   the overlapping rows are found and dropped);
6. different degrees: a 6×6 bicubic and an 8×12 patch of degrees 4×5, merged along v;
7. four patches in a 2×2 grid with different curvatures and knot vectors.

`case(i)` returns a `Case`: the patches, how to merge them, and the originals (or their kept
windows) to measure the deviation against.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bsjax.basis import BSplineSurface, clamped_knots, greville

__all__ = ["Case", "all_cases", "case", "run"]

NAMES = {
    1: "Similar curvature and knot vectors",
    2: "Different curvatures but similar knot vectors",
    3: "Similar curvature but different knot vectors",
    4: "Similar curvatures but different knot vectors and dimensions",
    5: "Intersecting and trimmed surfaces",
    6: "Surfaces having different degrees",
    7: "Multiple surfaces having different curvature and knot vectors",
}


@dataclass(frozen=True)
class Case:
    """One thesis case: `patches` (a row, or rows for a grid), the merge keyword arguments, and
    per original patch the `(u0, u1, v0, v1)` window whose points the deviation is measured on."""

    number: int
    patches: list
    direction: str | None  # None for a grid
    options: dict = field(default_factory=dict)
    windows: list | None = None

    @property
    def name(self) -> str:
        return NAMES[self.number]

    @property
    def originals(self) -> list[BSplineSurface]:
        return [s for row in self.patches for s in row] if self.direction is None else list(self.patches)


def _patch(x0, x1, y0, y1, height, r=6, s=6, k=3, l=3, knots_u=None, knots_v=None) -> BSplineSurface:
    """Patch over `[x0, x1] × [y0, y1]` (control points at the Greville abscissae, so the
    parametrisation is close to uniform), heights `height(x, y)` at the control points."""
    ku = clamped_knots(r, k, np.float64) if knots_u is None else np.asarray(knots_u, np.float64)
    kv = clamped_knots(s, l, np.float64) if knots_v is None else np.asarray(knots_v, np.float64)
    gx = x0 + (x1 - x0) * np.asarray(greville(ku, k))
    gy = y0 + (y1 - y0) * np.asarray(greville(kv, l))
    x, y = np.meshgrid(gx, gy, indexing="ij")
    return BSplineSurface(np.stack([x, y, height(x, y)], -1), ku, kv, k, l)


def _hill(x, y):
    return 4.0 * np.sin(np.pi * x / 40.0) * np.sin(np.pi * y / 20.0)


def _knots(interior, k=3):
    return np.concatenate([np.zeros(k + 1), interior, np.ones(k + 1)])


def case(number: int) -> Case:
    """The thesis case `number` (1–7)."""
    if number == 1:
        a = _patch(0, 20, 0, 20, _hill, 4, 4)
        b = _patch(20, 40, 0, 20, _hill, 4, 4)
        return Case(1, [a, b], "u")
    if number == 2:
        a = _patch(0, 20, 0, 20, lambda x, y: 3.0 * np.sin(np.pi * y / 20.0) * (x / 20.0) ** 0.5)
        b = _patch(
            20, 40, 0, 20, lambda x, y: 2.6 * np.sin(np.pi * y / 20.0) - 0.05 * (x - 20.0) ** 1.5 / 20**0.5
        )
        return Case(2, [a, b], "u")
    if number == 3:
        kv_a = _knots([0.25, 0.49, 0.67, 0.75])
        kv_b = _knots([0.20, 0.45, 0.61, 0.71])
        a = _patch(0, 20, 0, 20, _hill, 6, 8, knots_v=kv_a)
        b = _patch(20, 40, 0, 20, _hill, 6, 8, knots_v=kv_b, knots_u=_knots([0.3, 0.55]))
        return Case(3, [a, b], "u")
    if number == 4:
        a = _patch(0, 20, 0, 20, _hill, 6, 7, knots_v=_knots([0.2, 0.45, 0.7]))
        b = _patch(20, 34, -2, 22, _hill, 5, 8, knots_v=_knots([0.15, 0.35, 0.55, 0.8]))
        return Case(4, [a, b], "u")
    if number == 5:
        # the first patch runs 3 mm past x = 20, tilted, and cuts through the second at x ≈ 21.5
        a = _patch(0, 23, 0, 20, lambda x, y: _hill(x, y) + 0.3 * (x - 21.5), 7, 6)
        b = _patch(20, 40, 0, 20, _hill, 6, 6)
        return Case(5, [a, b], "u", {"overlap": "drop"})
    if number == 6:
        a = _patch(0, 20, 0, 20, _hill, 6, 6, 3, 3)
        b = _patch(
            0,
            20,
            20,
            40,
            lambda x, y: (
                _hill(x, y) * 0.5 + 2.0 * np.sin(np.pi * x / 20.0) * np.sin(np.pi * (y - 20.0) / 40.0)
            ),
            8,
            12,
            4,
            5,
        )
        return Case(6, [a, b], "v", {"degrees": "elevate"})
    if number == 7:

        def bump(cx, cy, h):
            return lambda x, y: 0.4 * _hill(x, y) + h * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / 30.0)

        p11 = _patch(0, 20, 0, 20, bump(10, 10, 3.0), 6, 6)
        p12 = _patch(0, 20, 20, 40, bump(10, 30, 1.5), 6, 7, knots_v=_knots([0.2, 0.4, 0.7]))
        p21 = _patch(20, 40, 0, 20, bump(30, 10, -2.0), 7, 6, knots_u=_knots([0.3, 0.5, 0.8]))
        p22 = _patch(20, 40, 20, 40, bump(30, 30, 2.5), 6, 6)
        return Case(7, [[p11, p12], [p21, p22]], None)
    raise ValueError(f"number: expected a case in 1..7, got {number}")


def all_cases() -> list[Case]:
    """Cases 1–7."""
    return [case(i) for i in range(1, 8)]


def run(
    c: Case,
    continuity: int,
    *,
    refine: bool = False,
    samples: int = 82,
    deviation_samples: int = 101,
    tolerance: float = 0.1,
    overlap_method: str = "collide",
):
    """Merge case `c` with C^continuity and measure it.

    **Returns:** `(merged surface, layout, Deviation)`; for case 5 the deviation is measured on the
    kept (untrimmed) parts of the originals.
    """
    from bsjax import merge as mg

    options = dict(c.options)
    windows = None
    if c.direction is None:
        layout = mg.plan_grid(c.patches, continuity, samples=samples, **options)
        ctrls = [[s.ctrl for s in row] for row in c.patches]
    else:
        if options.pop("overlap", "keep") == "drop":
            trims = mg.overlap_trims(c.patches, c.direction, samples, method=overlap_method)
            options["trim"] = trims
            windows = [(lo, hi, 0.0, 1.0) if c.direction == "u" else (0.0, 1.0, lo, hi) for lo, hi in trims]
        layout = mg.plan(c.patches, c.direction, continuity, samples=samples, orient="as_given", **options)
        ctrls = [s.ctrl for s in c.patches]
    ctrl = mg.refine(layout, ctrls) if refine else layout.apply(ctrls)
    merged = layout.surface(ctrl)
    report = mg.deviation(
        c.originals, merged, samples=deviation_samples, tolerance=tolerance, windows=windows
    )
    return merged, layout, report
