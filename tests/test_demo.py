"""`bsjax demo` runs end to end through the CLI (quick sizes) and writes what it promises."""

import json

import numpy as np
import pytest
import rhino3dm
import trimesh

from bsjax import cli, io


def test_demo_runs_the_spoon_case_study(tmp_path, capsys):
    assert cli.main(["demo", "--quick", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    for name in ("teardrop", "spoon_bowl", "spoon_handle"):
        row = report["shapes"][name]
        assert row["samples"] == [82, 82] and row["refit_max_error"] < 1e-10 and row["normals_finite"]
        assert io.load(tmp_path / f"{name}.json").shape == (8, 8)
    assert report["shapes"]["teardrop"]["periodic"] == [False, True]
    # the sphere pushed the neck up, and the handle stayed clamped behind the plane
    assert report["bend"]["neck_lift_m"] > 1e-3 and report["bend"]["fixed_nodes"] > 0
    # the merged spoon reproduces both patches to well under a millimetre on average
    merged = io.load(tmp_path / "spoon.json")
    assert merged.shape == tuple(report["merge"]["control_net"]) == (15, 8)
    assert report["merge"]["average"] < 2e-4 and report["merge"]["max"] < 2e-3
    # the jelly lattice is valid; the spill fractions (total and by exit) are fractions that add up
    jelly = report["jelly"]
    assert jelly["inverted_hexahedra"] == 0
    assert [row["tilt_deg"] for row in jelly["tilts"]] == [0.0, 10.0, 20.0]
    for row in jelly["tilts"]:
        assert 0.0 <= row["spilled"] <= 1.0 and 0.0 <= row["spill_risk"] <= 1.0
        assert sum(row[k] for k in ("front", "back", "side")) == pytest.approx(row["spilled"], abs=1e-12)
    # forward mode through contact and both lattices is the derivative of the risk: a central
    # difference agrees (the unrolled conjugate gradients of the steel gave 1e21 here)
    check = jelly["gradient_check"]
    assert abs(check["jax_jvp"]) > 1e-8
    assert check["jax_jvp"] == pytest.approx(check["central_difference"], rel=0.05)
    assert (tmp_path / "spoon.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(rhino3dm.File3dm.Read(str(tmp_path / "spoon.3dm")).Objects) == 3
    mesh = trimesh.load(tmp_path / "spoon.glb", force="mesh")
    assert np.ptp(mesh.vertices[:, 0]) > 0.15  # handle and bowl: a whole spoon
    out = capsys.readouterr().out  # the result: the folder and the files written
    assert out.startswith(f"folder   {tmp_path}\n") and "report.json" in out and "spoon.3dm" in out


def test_cli_lists_commands_and_rejects_unknown(capsys):
    assert cli.main(["--help"]) == 0 and "demo" in capsys.readouterr().out
    assert cli.main([]) == 2 and "demo" in capsys.readouterr().err  # no command: a usage error
    assert cli.main(["nope"]) == 2
