"""`bsjax demo` runs end to end through the CLI and writes what it promises."""

import json

import rhino3dm
import trimesh

from bsjax import cli, io


def test_demo_writes_pictures_surfaces_and_report(tmp_path, capsys):
    assert cli.main(["demo", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    for name in ("teardrop", "spoon_bowl", "spoon_handle"):
        row = report["shapes"][name]
        assert row["samples"] == [82, 82] and row["refit_max_error"] < 1e-10 and row["normals_finite"]
        assert io.load(tmp_path / f"{name}.json").shape == (8, 8)
    assert report["shapes"]["teardrop"]["periodic"] == [False, True]
    assert (tmp_path / "shapes.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(rhino3dm.File3dm.Read(str(tmp_path / "shapes.3dm")).Objects) == 3
    assert len(trimesh.load(tmp_path / "shapes.glb").geometry) >= 1
    assert "wrote" in capsys.readouterr().out


def test_cli_lists_commands_and_rejects_unknown(capsys):
    assert cli.main([]) == 0 and "demo" in capsys.readouterr().out
    assert cli.main(["nope"]) == 2
