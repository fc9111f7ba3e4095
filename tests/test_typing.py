"""The jaxtyping annotations hold while tests run: the numeric tests of surfaces and blending
matrices (the kernels everything else is built on) run again in a subprocess under jaxtyping's
import hook with beartype, so every annotated argument and return value of `bsjax` they reach —
array shapes by name, dtypes, pytree types — is checked on every call. Left out: the bad-input
tests (there a wrong type or shape is refused by the annotation check first, with jaxtyping's
message instead of bsjax's own) and the jit/vmap/grad tests (the same calls again, traced: each
compiles its programs once more, a minute of the suite for no annotation the eager calls miss).

The tests re-run are the fewest of that selection (`-k "not error and not raise and not bad and
not refuse and not jit and not vmap and not grad"` over both files: 50 tests) that together reach
every bsjax function it reaches, with every combination of argument types, array dtypes and ranks
it reaches them with (390 in all: float32 and float64, rational, periodic and clamped, concrete
and traced; measured with a `sys.setprofile` hook per test, without a compilation cache): 15
tests, about a third of the 50's time."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SELECTION = (
    "tests/test_surface.py::test_periodic_surface_matches_ndbspline_and_closes",
    "tests/test_surface.py::test_evaluate_keeps_parameter_shape",
    "tests/test_surface.py::test_normal_is_unit_cross_product_of_tangents",
    "tests/test_surface.py::test_sphere_normals_point_outward_including_poles",
    "tests/test_surface.py::test_float32_stays_float32[False]",
    "tests/test_surface.py::test_float32_stays_float32[True]",
    "tests/test_surface.py::test_with_ctrl_keeps_basis_and_checks_shape",
    "tests/test_blending.py::test_teardrop_normals_outward_and_finite_on_the_82_grid",
    "tests/test_blending.py::test_refit_round_trip[grid1-periodic]",
    "tests/test_blending.py::test_lod_is_every_qth_row_and_keeps_the_last[1-2-9-8]",
    "tests/test_blending.py::test_surface_round_trip_and_custom_params",
    "tests/test_blending.py::test_float32_stays_float32[clamped]",
    "tests/test_blending.py::test_float32_stays_float32[periodic]",
    "tests/test_blending.py::test_float32_stays_float32[rational]",
    "tests/test_blending.py::test_periodic_refit_round_trip_with_as_many_samples_as_control_points",
)  # the eager tests that reach every annotated call of the whole eager selection (docstring)


@pytest.mark.slow
def test_annotations_hold_under_jaxtyping_and_beartype():
    pytest.importorskip("beartype")
    cmd = [
        sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider",
        "--jaxtyping-packages=bsjax,beartype.beartype",
        *SELECTION,
    ]  # fmt: skip
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1500)
    tail = "\n".join(out.stdout.splitlines()[-30:])
    assert out.returncode == 0, tail
    passed = re.search(r"(\d+) passed", tail)
    assert passed and int(passed.group(1)) == len(SELECTION) and "failed" not in tail, tail  # all of it ran
