"""`bsjax sketch`: strokes file → curves → surface file and picture, read back; user errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bsjax import io
from bsjax.cli import sketch as cli


def write(path, strokes):
    path.write_text(json.dumps({"strokes": strokes}))
    return str(path)


def profile():
    t = np.linspace(0, 1, 30)
    return {"points": np.stack([0.3 + 0.2 * np.sin(np.pi * t), 2 * t], 1).tolist(), "times": (2 * t).tolist()}


def test_revolve_writes_3dm_and_png(tmp_path, capsys):
    strokes = write(tmp_path / "bottle.json", [profile()])
    out, png = tmp_path / "bottle.3dm", tmp_path / "bottle.png"
    assert cli.main([strokes, "--mode", "revolve", "-o", str(out), "--png", str(png), "--tol", "0.01"]) == 0
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"
    objects = io.load_all(out)
    surfaces = [o for o in objects if hasattr(o, "knots_u")]
    curves = [o for o in objects if not hasattr(o, "knots_u")]
    assert len(surfaces) == 1 and len(curves) == 1
    # a surface of revolution about z: every sample at the profile's radius for its height
    s = surfaces[0]
    u, v = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 9), indexing="ij")
    pts = np.asarray(s.evaluate(u, v))
    radius = np.hypot(pts[..., 0], pts[..., 1])
    np.testing.assert_allclose(radius, np.broadcast_to(radius[:, :1], radius.shape), atol=1e-12)
    on_profile = np.asarray(curves[0].evaluate(np.linspace(0, 1, 7)))
    np.testing.assert_allclose(radius[:, 0], on_profile[:, 0], atol=1e-12)
    np.testing.assert_allclose(pts[:, 0, 2], on_profile[:, 1], atol=1e-12)
    out = capsys.readouterr().out
    assert "mode                    revolve" in out and "surface control points  [" in out


def test_loft_writes_json_read_back_through_the_sections(tmp_path):
    sections = []
    for z in (0.0, 1.0, 2.0):
        a = np.linspace(0, np.pi, 25)
        sections.append(np.stack([np.cos(a) * (1 + 0.2 * z), np.sin(a) - 1, z + 0 * a], 1).tolist())
    strokes = write(tmp_path / "hull.json", sections)
    out = tmp_path / "hull.json.out.json"
    assert cli.main([strokes, "--mode", "loft", "-o", str(out), "--tol", "0.005"]) == 0
    objects = io.load_all(out)
    surface, curves = objects[0], objects[1:]
    assert len(curves) == 3 and surface.ctrl.shape[1] == 3
    # each stroke's samples lie within tol of the lofted surface (it interpolates the fitted sections)
    uu, vv = np.meshgrid(np.linspace(0, 1, 400), np.linspace(0, 1, 201), indexing="ij")
    dense = np.asarray(surface.evaluate(uu, vv)).reshape(-1, 3)
    for section in sections:
        d = np.min(np.linalg.norm(np.asarray(section)[:, None] - dense[None], axis=2), axis=1)
        assert d.max() < 0.005 + 0.01  # fit tolerance + the dense sampling's spacing


@pytest.mark.parametrize(
    ("strokes", "argv", "message"),
    [
        (None, ["missing.json", "--mode", "loft", "-o", "x.json"], "missing.json: no such file"),
        (
            [[[0, 0], [1, 0], [2, 1]]],
            ["--mode", "loft", "-o", "x.json"],
            "--mode loft takes 2 to 64 strokes, got 1",
        ),
        (
            [[[0, 0], [1, float("nan")], [2, 1]]],
            ["--mode", "extrude", "-o", "x.json"],
            "strokes[0]: expected finite",
        ),
        ([[[0, 0], [1, 0]]], ["--mode", "extrude", "-o", "x.json"], "expected at least 3 points"),
        ([[[0, 0], [1, 0], [2, 1]]], ["--mode", "extrude", "-o", "x.txt"], "x.txt: expected an extension"),
        ([[[0, 0], [1, 0], [2, 1]]], ["--mode", "extrude", "-o", "x.json", "--tol", "-1"], "--tol"),
    ],
)
def test_user_errors_are_one_line(tmp_path, capsys, monkeypatch, strokes, argv, message):
    monkeypatch.chdir(tmp_path)
    args = argv if strokes is None else [write(tmp_path / "s.json", strokes), *argv]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bsjax sketch: ") and "\n" not in err and message in err


def test_help_mentions_debug(capsys):
    assert cli.main(["--help"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: bsjax sketch") and "--debug" in text
