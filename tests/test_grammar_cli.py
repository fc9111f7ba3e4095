"""`bsjax grammar` end to end: symbols of curve files (.json, .3dm), enumeration, user errors."""

import json

import numpy as np
import pytest

from bsjax import io, shapes
from bsjax.basis import BSplineCurve
from bsjax.cli.grammar import main

W = np.sqrt(0.5)
KNOTS = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]
CTRL = np.array([[2, 0], [2, 1], [0, 1], [-2, 1], [-2, 0], [-2, -1], [0, -1], [2, -1], [2, 0]], float)


def ellipse(z=None):
    """The exact rational ellipse x = 2 cos θ, y = sin θ, optionally in the plane z = const."""
    ctrl = CTRL if z is None else np.c_[CTRL, np.full(9, z)]
    return BSplineCurve(ctrl, KNOTS, 2, weights=[1, W, 1, W, 1, W, 1, W, 1])


def test_symbols_plain_and_json(tmp_path, capsys):
    io.save([ellipse()], tmp_path / "e.json")
    assert main(["symbols", str(tmp_path / "e.json")]) == 0
    assert capsys.readouterr().out.strip() == "M+m+M+m+"
    io.save([ellipse(z=1.5)], tmp_path / "e.3dm")  # Rhino keeps planar curves in 3-D
    assert main(["symbols", str(tmp_path / "e.3dm"), "--json"]) == 0
    (report,) = json.loads(capsys.readouterr().out)
    assert report["symbols"] == "M+m+M+m+" and report["closed"] and report["valid"]
    np.testing.assert_allclose([p["curvature"] for p in report["points"]], [2, 0.25, 2, 0.25], rtol=1e-12)
    assert report["measures"]["softness"] == pytest.approx(0.5, rel=1e-12)  # b² / a


def test_enumerate(capsys):
    assert main(["enumerate", "--max-extrema", "8"]) == 0
    lines = capsys.readouterr().out.split()
    assert len(lines) == 21 and lines[0] == "M+m+M+m+"  # the thesis's twenty-one shapes
    assert main(["enumerate", "--max-extrema", "4", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == ["M+m+M+m+", "M+m+M+0m-0", "M+0m-0M+0m-0"]
    # fewer than 4 extrema: no closed shape — no empty line on stdout, the reason on stderr
    assert main(["enumerate", "--max-extrema", "3"]) == 0
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "at most 3 extrema" in err
    assert main(["enumerate", "--max-extrema", "3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == []


def test_errors(tmp_path, capsys):
    assert main(["symbols", str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err
    assert main(["enumerate", "--max-extrema", "0"]) == 2
    assert "--max-extrema" in capsys.readouterr().err
    assert main(["enumerate", "--max-extrema", "40"]) == 2
    assert "--max-extrema" in capsys.readouterr().err
    twisted = BSplineCurve(np.c_[CTRL, np.arange(9.0)], KNOTS, 2)
    io.save([twisted], tmp_path / "space.json")
    assert main(["symbols", str(tmp_path / "space.json")]) == 2
    err = capsys.readouterr().err
    assert "space.json" in err and "not planar" in err and "\n" == err[-1] and err.count("\n") == 1
    io.save(shapes.plate(4, 4), tmp_path / "plate.json")
    assert main(["symbols", str(tmp_path / "plate.json")]) == 2
    assert "expected at least one curve" in capsys.readouterr().err
    assert main(["symbols", str(tmp_path / "plate.json"), "--rel", "2"]) == 2
    assert "--rel" in capsys.readouterr().err


def test_help_mentions_debug(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: bsjax grammar") and "--debug" in out
