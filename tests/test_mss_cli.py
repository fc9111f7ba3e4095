"""`bsjax simulate`: a clamped jelly plate sags under gravity; an unstable dt is refused."""

import json

import numpy as np

from bsjax import io, shapes
from bsjax.cli import main


def test_simulate_cli_clamped_plate_sags(tmp_path, capsys):
    src, out = tmp_path / "plate.json", tmp_path / "sagged.json"
    io.save(shapes.plate(5, 5, 0.2), src)
    rc = main(
        [
            "simulate",
            str(src),
            "-o",
            str(out),
            "--clamp",
            "0.02,0,0,1,0,0",
            "--steps",
            "300",
            "--samples",
            "8,8",
            "--json",
        ]
    )
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["fixed"] == 8 and report["finite"] and report["dt"] <= report["stable_dt"]
    sagged = io.load(out)
    z = np.asarray(sagged.ctrl)[..., 2]
    assert abs(z[0]).max() < 1e-3  # the clamped edge stays
    assert z[-1].mean() < -0.01  # the free edge drops
    rc = main(["simulate", str(src), "-o", str(out), "--steps", "5", "--samples", "8,8", "--dt", "1.0"])
    assert rc == 2
    assert "largest stable step" in capsys.readouterr().err
