"""`bsjax sweep` (issue #14): the spoon, collide and merge tables equal a plain Python loop over
the designs (the merge one also the public `merge.merge` + `merge.deviation`), grid order,
`results.csv` and `sweep.png` read back, two `jax.distributed` processes write the same table as
one, bad `--param` specs, and the progress bar of `bsjax.cli._progress`.
"""

from __future__ import annotations

import csv
import functools
import io as stdio
import itertools
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax.cli import _progress
from bsjax.cli import sweep as sweep_cli
from bsjax.examples import experiments

ROOT = Path(__file__).resolve().parents[1]
COLLIDE = ["--param", "radius=0.1:0.3:2", "--param", "z=-0.2:0.2:3", "--quick", "--quiet"]


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=np.float64)


@pytest.fixture(scope="module")
def collide_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("collide")
    assert sweep_cli.main(["collide", *COLLIDE, "--chunk", "4", "--out", str(out)]) == 0
    return out


def _scalars(designs: dict, i: int, names, dtype=jnp.float64) -> list:
    return [jnp.asarray(designs[n][i], dtype) for n in names]


# --- tables equal a loop over the designs ---------------------------------------------------
def test_collide_table_is_a_loop_over_the_grid_in_grid_order(collide_run):
    header, table = read_csv(collide_run / "results.csv")
    assert header == ["radius", "x", "y", "z", "area", "max_depth", "force"]
    grid = list(itertools.product([0.1, 0.3], [-0.2, 0.0, 0.2]))  # radius slowest, as given
    np.testing.assert_array_equal(table[:, [0, 3]], np.array(grid))
    np.testing.assert_array_equal(table[:, 1:3], np.tile([0.6, 0.0], (6, 1)))  # the defaults
    experiment = experiments.EXPERIMENTS["collide"]
    designs = {n: table[:, i] for i, n in enumerate(header[:4])}
    setup = experiment.setup(designs, True, np.float64)
    for i, row in enumerate(table):
        found = experiments.collide_design(setup, *_scalars(designs, i, header[:4]))
        np.testing.assert_allclose(row[4:], [float(found[k]) for k in header[4:]], rtol=0, atol=1e-10)
    assert np.all(table[:, 5] >= 0) and np.all((table[:, 5] > 0) == (table[:, 6] > 0))
    assert table[:, 4].max() > 0  # some spheres touch the teardrop's side
    # a bigger sphere at the same centre touches more area, and deeper
    assert np.all(table[3:, 4] >= table[:3, 4]) and np.all(table[3:, 5] >= table[:3, 5])


def test_collide_area_of_a_plate_is_the_disc_under_the_sphere():
    """On the unit plate a sphere of radius r at height h cuts a disc of radius √(r² − h²)."""
    from bsjax import shapes

    plate = shapes.plate(4, 4)
    setup = experiments.collide_setup({}, False, np.float64, plate)
    r, h = 0.3, 0.1
    found = experiments.collide_design(setup, *map(jnp.asarray, (r, 0.5, 0.5, h)))
    disc = np.pi * (r**2 - h**2)
    assert abs(float(found["area"]) - disc) < 0.05 * disc  # samples 1/81 apart
    assert r - h - 1e-3 < float(found["max_depth"]) <= r - h  # at the sample nearest the axis


def test_spoon_table_is_a_loop_over_the_designs():
    experiment = experiments.EXPERIMENTS["spoon"]
    specs = {"tilt": (0.0, 25.0, 2), "shake_amplitude": (0.0, 0.01, 2)}
    designs = experiments.grid(experiment.parameters, specs)
    reports = []  # the set-up's VSOFM training cycles (the CLI's set-up bar)
    setup = experiment.setup(designs, True, np.float64, progress=lambda *a: reports.append(a))
    cycles = experiments.SPOON_SIZES["quick"]["cycles"]
    assert experiment.setup_progress == "VSOFM cycles" and reports[-1] == (cycles, cycles)
    assert [d for d, _ in reports] == sorted({d for d, _ in reports}) and len(reports) > 1
    calls = []
    found = experiments.evaluate(experiment, setup, designs, chunk=2, progress=lambda *a: calls.append(a))
    one = jax.jit(functools.partial(experiments.spoon_design, setup))
    for i in range(4):
        expected = one(*_scalars(designs, i, experiment.parameters))
        for name in experiment.outputs:
            assert abs(found[name][i] - float(expected[name])) <= 1e-10
    assert calls == [(2, 4), (4, 4)]
    assert np.all((found["spilled"] >= 0) & (found["spilled"] <= 1))
    exits = found["front"] + found["back"] + found["side"]
    np.testing.assert_allclose(exits, found["spilled"], rtol=0, atol=1e-12)
    assert len(set(np.round(found["risk"], 12))) == 4  # every parameter changes the outcome


def test_merge_groups_static_values_and_equals_the_public_merge(tmp_path):
    from bsjax import merge
    from bsjax.examples import merge_cases

    argv = ["merge", "--param", "continuity=1:2:2", "--param", "samples=12:12:1", "--quick", "--quiet"]
    assert sweep_cli.main([*argv, "--out", str(tmp_path)]) == 0
    header, table = read_csv(tmp_path / "results.csv")
    assert header == ["continuity", "samples", "mean", "max"]
    np.testing.assert_array_equal(table[:, :2], [[1, 12], [2, 12]])
    patches = merge_cases.case(2).patches
    for row in table:
        merged = merge.merge(patches, "u", int(row[0]), samples=12, orient="as_given")
        dev = merge.deviation(patches, merged, samples=21)
        np.testing.assert_allclose(row[2:], [float(dev.mean), float(dev.max)], rtol=0, atol=1e-10)
    assert table[0, 3] > 0 and table[0, 3] != table[1, 3]


# --- files ----------------------------------------------------------------------------------
def test_png_is_written_and_readable(collide_run):
    import matplotlib.image

    image = matplotlib.image.imread(collide_run / "sweep.png")
    assert image.ndim == 3 and image.shape[1] > 2 * image.shape[0]  # three heat maps side by side
    assert np.ptp(image[..., :3]) > 0.5  # not blank


def test_csv_round_trips_floats_exactly(tmp_path):
    designs = {"a": np.array([0.1, 1 / 3]), "b": np.array([1e-300, -2.5])}
    results = {"out": np.array([np.pi, np.nextafter(1.0, 2.0)])}
    sweep_cli.write_csv(tmp_path / "r.csv", designs, results)
    header, table = read_csv(tmp_path / "r.csv")
    assert header == ["a", "b", "out"]
    np.testing.assert_array_equal(table, np.c_[designs["a"], designs["b"], results["out"]])


def test_grid_order_first_parameter_slowest():
    params = experiments.EXPERIMENTS["spoon"].parameters
    designs = experiments.grid(params, {"roll": (0.0, 1.0, 2), "tilt": (0.0, 10.0, 3)})
    # columns in the experiment's order
    assert list(designs) == ["tilt", "roll", "shake_axis", "shake_amplitude", "shake_frequency"]
    np.testing.assert_array_equal(designs["roll"], [0, 0, 0, 1, 1, 1])
    np.testing.assert_array_equal(designs["tilt"], [0, 5, 10, 0, 5, 10])
    default = params["shake_frequency"].default
    np.testing.assert_array_equal(designs["shake_frequency"], np.full(6, default))


# --- several processes ----------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_write_the_table_of_one(collide_run, tmp_path):
    address = f"127.0.0.1:{_free_port()}"
    outs = [tmp_path / "p0", tmp_path / "p1"]
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "bsjax.cli", "sweep", "collide", *COLLIDE, "--out", str(out),
             "--coordinator", address, "--num-processes", "2", "--process-id", str(i)],
            cwd=ROOT,
            env={**os.environ, "XLA_FLAGS": ""},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i, out in enumerate(outs)
    ]  # fmt: skip
    try:
        for p in procs:
            _, err = p.communicate(timeout=240)
            assert p.returncode == 0, err[-3000:]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    assert not (outs[1] / "results.csv").exists()  # process 0 writes the files
    header, table = read_csv(outs[0] / "results.csv")
    expected_header, expected = read_csv(collide_run / "results.csv")
    assert header == expected_header
    np.testing.assert_allclose(table, expected, rtol=0, atol=1e-12)


# --- errors ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "argv",
    [
        ["collide", "--param", "radius=0.1:0.3"],  # no COUNT
        ["collide", "--param", "radius=a:0.3:2"],
        ["collide", "--param", "radius=0.1:0.3:0"],  # COUNT >= 1
        ["collide", "--param", "depth=0:1:2"],  # not a parameter of collide
        ["collide", "--param", "radius=-1:1:3"],  # radius > 0
        ["collide", "--param", "x=0:1:2", "--param", "x=0:1:3"],
        ["spoon", "--param", "tilt=0:inf:2"],
        ["merge", "--param", "continuity=0:3:4"],  # C^c with c < degree 3
        ["merge", "--param", "samples=10.5:12:2"],  # a static int
    ],
)
def test_bad_param_exits_2_naming_param(argv, tmp_path, capsys):
    assert sweep_cli.main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bsjax sweep: --param") and err.count("\n") == 1
    assert not (tmp_path / "results.csv").exists()


def test_other_user_errors(tmp_path, capsys):
    cases = [
        (["nope", "--out", str(tmp_path)], "experiment"),
        (["collide", "--out", str(tmp_path / "no" / "dir")], "--out"),
        (["collide", "--out", str(tmp_path), "--coordinator", "127.0.0.1:1"], "--num-processes"),
        (
            [
                "collide",
                "--out",
                str(tmp_path),
                "--coordinator",
                "x",
                "--num-processes",
                "2",
                "--process-id",
                "0",
            ],
            "--coordinator",
        ),
        (
            [
                "collide",
                "--out",
                str(tmp_path),
                "--coordinator",
                "h:1",
                "--num-processes",
                "2",
                "--process-id",
                "2",
            ],
            "--process-id",
        ),
        (["merge", "--out", str(tmp_path), "--surface", str(tmp_path / "none.json")], "none.json"),
    ]
    for argv, name in cases:
        assert sweep_cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("bsjax sweep: ") and name in err and err.count("\n") == 1, (argv, err)


# --- the progress bar -----------------------------------------------------------------------
class _Terminal(stdio.StringIO):
    def isatty(self):
        return True


def test_progress_bar_on_a_terminal_only():
    with _progress.bar("designs", stream=stdio.StringIO()) as progress:
        assert progress is None  # not a terminal
    with _progress.bar("designs", stream=_Terminal(), quiet=True) as progress:
        assert progress is None
    shown = _Terminal()
    with _progress.bar("designs", stream=shown) as progress:
        assert progress is not None
        progress(3, 7)
        progress(7, 7)
    text = shown.getvalue()
    assert text.startswith("\rdesigns") and "100%" in text and "7/7" in text and "<00:00" in text  # ETA
