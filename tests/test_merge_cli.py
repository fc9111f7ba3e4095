"""`bsjax merge` command: files in, merged file out, deviation report, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bsjax import io
from bsjax.basis import BSplineSurface, clamped_knots, greville
from bsjax.cli import main as bsjax_main
from tests.oracles import ndbspline_surface


def _plate(x0, x1, r, s, degree=3):
    ku, kv = clamped_knots(r, degree), clamped_knots(s, 3)
    x, y = np.meshgrid(
        x0 + (x1 - x0) * np.asarray(greville(ku, degree)), np.asarray(greville(kv, 3)), indexing="ij"
    )
    return BSplineSurface(np.stack([x, y, 0.4 * np.minimum(x, 2.0 - x)], -1), ku, kv, degree, 3)


def test_merge_command_writes_merged_surface(tmp_path, capsys):
    a, b = _plate(0.0, 1.0, 5, 4), _plate(1.0, 2.0, 5, 4)
    io.save(a, tmp_path / "a.json")
    io.save(b, tmp_path / "b.json")
    out = tmp_path / "merged.json"
    code = bsjax_main(
        [
            "merge",
            str(tmp_path / "a.json"),
            str(tmp_path / "b.json"),
            "--direction",
            "u",
            "--continuity",
            "0",
            "--samples",
            "16",
            "-o",
            str(out),
            "--report",
            "--json",
            "--report-samples",
            "12",
        ]
    )
    assert code == 0
    merged = io.load(out)
    assert merged.shape == (9, 4) and (merged.degree_u, merged.degree_v) == (3, 3)
    # a roof z = 0.4 min(x, 2 − x), x linear in u: the C⁰ merge keeps the crease exactly
    g = np.linspace(0, 1, 9)
    got = ndbspline_surface(merged, g, np.full_like(g, 0.3))
    np.testing.assert_allclose(got[:, 2], 0.4 * np.minimum(got[:, 0], 2.0 - got[:, 0]), atol=1e-9)
    report = json.loads(capsys.readouterr().out)
    assert report["total points"] == 2 * 12 * 12 and report["max"] < 1e-8
    # "close" by default: 0.1 % of the inputs' control-point box diagonal, not an absolute 0.1
    corners = np.concatenate([np.asarray(s.ctrl).reshape(-1, 3) for s in (a, b)])
    assert report["tolerance"] == pytest.approx(1e-3 * np.linalg.norm(corners.max(0) - corners.min(0)))


def test_merge_command_errors(tmp_path, capsys):
    a, b = _plate(0.0, 1.0, 5, 4), _plate(1.0, 2.0, 5, 4, degree=2)
    io.save([a, b], tmp_path / "ab.json")
    code = bsjax_main(["merge", str(tmp_path / "ab.json"), "-o", str(tmp_path / "m.json"), "--samples", "16"])
    assert code == 2 and "degrees" in capsys.readouterr().err
    code = bsjax_main(["merge", str(tmp_path / "ab.json"), "-o", str(tmp_path / "m.json"), "--grid", "3x1"])
    assert code == 2 and "--grid" in capsys.readouterr().err
    assert not (tmp_path / "m.json").exists()


def test_merge_command_reports_reduction_error(tmp_path, capsys):
    """`--degrees reduce --report`: the quadratic result and the reduction error of the cubic
    patch — zero while it is a plane (exactly quadratic), positive once a control point is bumped."""
    a, b = _plate(0.0, 1.0, 5, 4), _plate(1.0, 2.0, 5, 4, degree=2)
    io.save([a, b], tmp_path / "flat.json")
    code = bsjax_main(
        [
            "merge",
            str(tmp_path / "flat.json"),
            "-o",
            str(tmp_path / "f.json"),
            "--samples",
            "16",
            "--degrees",
            "reduce",
            "--continuity",
            "0",
            "--report",
            "--json",
            "--report-samples",
            "12",
        ]
    )
    assert code == 0 and json.loads(capsys.readouterr().out)["reduction error"] < 1e-9
    a = a.with_ctrl(np.asarray(a.ctrl) + np.where(np.arange(5)[:, None, None] == 2, [0.0, 0.0, 0.3], 0.0))
    io.save([a, b], tmp_path / "ab.json")
    out = tmp_path / "m.json"
    code = bsjax_main(
        [
            "merge",
            str(tmp_path / "ab.json"),
            "-o",
            str(out),
            "--samples",
            "16",
            "--degrees",
            "reduce",
            "--continuity",
            "0",
            "--report",
            "--json",
            "--report-samples",
            "12",
        ]
    )
    assert code == 0 and io.load(out).degree_u == 2
    report = json.loads(capsys.readouterr().out)
    assert report["reduction error"] > 1e-3 and report["max"] >= 0.0
