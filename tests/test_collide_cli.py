"""`bsjax collide` end to end on a surface file."""

import json

import pytest

from bsjax import io, shapes
from bsjax.cli.collide import main


def test_cli_sphere_report(tmp_path, capsys):
    path = tmp_path / "plate.json"
    io.save(shapes.plate(6, 6), path)
    argv = [str(path), "--sphere", "0.5,0.5,0.05,0.3", "--samples", "15,15"]
    assert main([*argv, "--json"]) == 0
    out, err = capsys.readouterr()
    report = json.loads(out)  # the result alone on stdout
    assert report["hit"] and report["samples_in_contact"] > 0 and err == ""
    assert report["max_depth"] == pytest.approx(0.25, abs=1e-6)  # R − h at the sampled centre
    assert report["force_surface_normal"][2] == pytest.approx(100.0 * report["total_depth"], rel=1e-6)
    assert main(argv) == 0  # the same result as a table: one `key  value` line per entry
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(report) and lines[0].split()[0] == next(iter(report))
    row = next(line for line in lines if line.startswith("samples_in_contact "))
    assert row.split()[-1] == str(report["samples_in_contact"])


def test_cli_errors(tmp_path, capsys):
    assert main([str(tmp_path / "missing.json"), "--point", "0,0,0"]) == 2
    assert "missing.json" in capsys.readouterr().err
    io.save(shapes.plate(4, 4), tmp_path / "x.json")
    assert main([str(tmp_path / "x.json")]) == 2  # no tool
    assert "--sphere" in capsys.readouterr().err
