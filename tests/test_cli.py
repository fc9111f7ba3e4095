"""The `bsjax` command's one convention (`bsjax.cli._common`): comma-separated vectors, one-line
user errors with exit code 2, float64 unless `--float32`, valid JSON; and a light `import bsjax`."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide, io, shapes
from bsjax.cli import COMMANDS, _common
from bsjax.cli import main as bsjax

ROOT = Path(__file__).resolve().parents[1]


def _strict_json(text: str):
    """json.loads that refuses NaN / Infinity (which the standard json module accepts)."""

    def refuse(name):
        raise ValueError(f"not valid JSON: {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture
def files(tmp_path):
    """A 6×6 plate and two 5×4 plates side by side, as .json files; plus a bad .json."""
    io.save(shapes.plate(6, 6), tmp_path / "plate.json")
    a = shapes.plate(5, 4)
    io.save(a, tmp_path / "a.json")
    io.save(a.with_ctrl(np.asarray(a.ctrl) + np.array([1.0, 0.0, 0.0])), tmp_path / "b.json")
    (tmp_path / "bad.json").write_text('{"format": "something else"}')
    (tmp_path / "mesh.stl").write_text("solid x\nendsolid x\n")
    (tmp_path / "notes.txt").write_text("not a surface")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    (tmp_path / "garbage.step").write_text("ISO-10303-21;\nnot a step file\n")
    return tmp_path


# --- help ------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_subcommand_help_exits_0(command, capsys):
    assert bsjax([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: bsjax {command}") and "--debug" in out
    # the description is the command's line of `bsjax --help`, not a fragment of a docstring
    assert out.split("\n\n")[1].replace("\n", " ") == COMMANDS[command][1]


SERVERS = ("view", "studio")  # their address is their output: no result to print


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_but_the_servers_prints_its_result_as_json_on_request(command, capsys):
    help_of = [command, "symbols"] if command == "grammar" else [command]  # per subcommand there
    assert bsjax([*help_of, "--help"]) == 0
    assert ("--json " in capsys.readouterr().out) == (command not in SERVERS)


def test_result_alone_on_stdout_as_a_table_or_json(files, capsys):
    """`bsjax convert`: the summary is the result (stdout), the same as a table and as JSON."""
    a, target = str(files / "a.json"), str(files / "a.3dm")
    assert bsjax(["convert", a, target, "--json"]) == 0
    out, err = capsys.readouterr()
    result = _strict_json(out)
    assert err == "" and result == {
        "source": a,
        "target": target,
        "objects": 1,
        "trimmed": 0,
        "units": result["units"],
        "dtype": "float64",
    }
    assert bsjax(["convert", a, target]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out == _common.table(result) + "\n"
    assert out.splitlines()[2] == "objects  1"


def _on_a_terminal(argv: list[str]) -> tuple[int, str, str]:
    """Run a command with stderr on a terminal (an 80-column pty) and stdout on a pipe:
    `(exit code, stdout, what the terminal showed)`."""
    import fcntl
    import os
    import pty
    import struct
    import termios

    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))  # 80 columns
    proc = subprocess.Popen(
        [sys.executable, "-m", "bsjax.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=follower,
        cwd=ROOT,
        text=True,
    )
    os.close(follower)
    drawn = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        drawn += chunk
    out, _ = proc.communicate(timeout=300)
    os.close(leader)
    return proc.returncode, out, drawn.decode(errors="replace")


@pytest.mark.parametrize("command", ["simulate", "convert"])
def test_progress_bar_on_a_terminal_stderr_and_the_result_alone_on_stdout(files, command):
    """`bsjax simulate` / `bsjax convert` with stderr on a terminal (a pty) draw a bar of the
    steps / objects there; stdout (a pipe) holds the JSON result alone. With `--quiet`, no bar."""
    if command == "simulate":
        argv = ["simulate", str(files / "a.json"), "-o", str(files / "p.json"), "--samples", "5,5"]
        argv += ["--steps", "200", "--json"]
        key, value, counted = "steps", 200, ("steps", "200/200")
    else:
        both = files / "both.json"
        io.save([shapes.plate(4, 4), shapes.teardrop()], both)
        argv = ["convert", str(both), str(files / "both.obj"), "--samples", "5,5", "--json"]
        key, value, counted = "objects", 2, ("objects", "2/2")
    for quiet in (False, True):
        code, out, bar = _on_a_terminal(argv + (["--quiet"] if quiet else []))
        assert code == 0, bar
        assert _strict_json(out)[key] == value
        assert all(c in bar for c in counted) != quiet, bar


def test_table_layouts():
    assert _common.table({"a": 1.0 / 3, "long key": [1, 2.5e-9], "none": None}) == (
        "a         0.333333\nlong key  [1, 2.5e-09]\nnone      -"
    )
    rows = [{"curve": 0, "symbols": "M+m+M+m+"}, {"curve": 1, "symbols": ""}]
    assert _common.table(rows) == "curve  symbols\n0      M+m+M+m+\n1"
    assert _common.table(["M+m+", "m-M+"]) == "M+m+\nm-M+" and _common.table([]) == "(none)"


def test_top_level_help_and_unknown_command(capsys):
    assert bsjax(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {name} " in out for name in COMMANDS)
    assert bsjax(["nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope" in err


def test_no_command_is_a_usage_error(capsys):
    """`bsjax` alone: the usage on stderr and exit 2 (as git and pip), nothing on stdout."""
    assert bsjax([]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("usage: bsjax COMMAND") and all(f"  {n} " in err for n in COMMANDS)


# --- user errors: exit 2, one stderr line naming the argument or file, no traceback ----------
def _errors(d):
    p, a, b, bad, stl = (str(d / n) for n in ("plate.json", "a.json", "b.json", "bad.json", "mesh.stl"))
    missing, nodir = str(d / "missing.json"), str(d / "no" / "such" / "dir" / "out.json")
    return [
        # collide
        (["collide", missing, "--point", "0,0,0"], "missing.json"),
        (["collide", p, "--sphere", "0.5,0.5,0.3"], "--sphere"),  # 3 numbers, not 4
        (["collide", p, "--sphere", "0.5", "0.5", "0.05", "0.3"], "0.5"),  # the old spaced form
        (["collide", p, "--sphere", "0,0,0,-1"], "--sphere"),  # R > 0
        (["collide", p, "--ellipsoid", "0,0,0,1,0,1"], "--ellipsoid"),
        (["collide", p, "--plane", "0,0,0,0,0,0"], "--plane"),
        (["collide", p, "--point", "0,0,nan"], "--point"),
        (["collide", p, "--point", "0,0,0", "--samples", "1,5"], "--samples"),
        (["collide", p, "--point", "0,0,0", "--stiffness", "-1"], "--stiffness"),
        (["collide", bad, "--point", "0,0,0"], "bad.json"),  # read, not a surface
        (["collide", stl, "--point", "0,0,0"], "mesh.stl"),  # wrong extension
        # merge
        (["merge", a, missing, "-o", str(d / "m.json")], "missing.json"),
        (["merge", a, b, "-o", str(d / "m.txt")], "m.txt"),
        (["merge", a, b, "-o", nodir], "--output"),
        (["merge", a, b, "-o", str(d / "m.json"), "--continuity", "-1"], "--continuity"),
        (["merge", a, b, "-o", str(d / "m.json"), "--grid", "3x1"], "--grid"),
        (["merge", a, b, "-o", str(d / "m.json"), "--grid", "2by1"], "--grid"),
        (["merge", a, b, "-o", str(d / "m.json"), "--samples", "0"], "--samples"),
        (["merge", a, b, "-o", str(d / "m.json"), "--tolerance", "0"], "--tolerance"),
        # simulate
        (["simulate", a, "-o", str(d / "s.json"), "--dt", "0"], "--dt"),
        (["simulate", a, "-o", str(d / "s.json"), "--dt", "-1e-3"], "--dt"),
        (["simulate", a, "-o", str(d / "s.json"), "--steps", "0"], "--steps"),
        (["simulate", a, "-o", str(d / "s.json"), "--samples", "8", "8"], "8"),  # the old spaced form
        (["simulate", a, "-o", str(d / "s.json"), "--gravity", "0,-9.81"], "--gravity"),
        (["simulate", a, "-o", str(d / "s.json"), "--clamp", "-0.1,0,0,0,0,0"], "--clamp"),
        (["simulate", a, "-o", str(d / "s.json"), "--thickness", "abc"], "--thickness"),
        (["simulate", missing, "-o", str(d / "s.json")], "missing.json"),
        # haptics
        (["haptics", "--duration", "0"], "--duration"),
        (["haptics", "--duration", "-1"], "--duration"),
        (["haptics", "--rate", "fast"], "--rate"),
        (["haptics", "--hid", "zz:1"], "--hid"),
        (["haptics", "--replay", str(d / "missing.npz")], "missing.npz"),
        (["haptics", "--ellipsoid", "0.3,0.2"], "--ellipsoid"),
        (["haptics", "--record", str(d / "rec.csv")], "rec.csv"),
        # convert
        (["convert", missing, str(d / "o.json")], "missing.json"),
        (["convert", a, str(d / "o.xyz")], "o.xyz"),
        (["convert", stl, str(d / "o.json")], "mesh.stl"),
        (["convert", bad, str(d / "o.json")], "bad.json"),
        (["convert", a, str(d / "o.glb"), "--samples", "1"], "--samples"),
        (["convert", str(d / "absent.step"), str(d / "o.json")], "absent.step"),
        (["convert", str(d / "garbage.step"), str(d / "o.json")], "garbage.step"),
        (["convert", a, str(d / "o.json"), "--units", "furlong"], "--units"),
        # sketch
        (["sketch", missing, "--mode", "loft", "-o", str(d / "s.json")], "missing.json"),
        (["sketch", bad, "--mode", "loft", "-o", str(d / "s.json")], "bad.json"),
        (["sketch", bad, "--mode", "loft", "-o", str(d / "s.txt")], "s.txt"),
        (["sketch", bad, "--mode", "loft", "-o", str(d / "s.json"), "--tol", "0"], "--tol"),
        # grammar
        (["grammar", "symbols", missing], "missing.json"),
        (["grammar", "enumerate", "--max-extrema", "0"], "--max-extrema"),
        (["grammar", "enumerate"], "--max-extrema"),
        (["grammar", "symbols", p], "expected at least one curve"),
        # view
        (["view", missing], "missing.json"),
        (["view", str(d / "notes.txt")], "expected a .json"),
        (["view", str(d / "junk.npz")], "cannot read haptics recording"),
        (["haptics", "--proxy-only", "--view", "--port", "70000"], "--port"),
        (["haptics", "--sculpt", "knead"], "--sculpt"),
        (["haptics", "--sculpt", "drag", "--proxy-only"], "--sculpt"),
        # studio
        (["studio", "--dir", str(d / "no" / "such")], "--dir"),
        (["studio", "--port", "70000"], "--port"),
        (["studio", "--dir", str(d), "--open", "missing.json"], "--open"),
        # sweep
        (["sweep", "collide", "--param", "radius=0:1", "--out", str(d / "o")], "--param"),
        (["sweep", "collide", "--param", "depth=0:1:2", "--out", str(d / "o")], "--param"),
        (["sweep", "merge", "--param", "samples=10.5:12:2", "--out", str(d / "o")], "--param"),
        (["sweep", "collide", "--out", nodir], "--out"),
        # demo
        (["demo", "--out", a], "a.json"),  # a file, not a folder
        (["demo", "--out", str(d / "no" / "such" / "out")], "--out"),
    ]


def test_user_errors_are_one_line_with_exit_code_2(files, capsys):
    cases = _errors(files)
    assert {argv[0] for argv, _ in cases} == set(COMMANDS)
    for argv, name in cases:
        code = bsjax(argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert err.endswith("\n") and err.count("\n") == 1, (argv, err)
        assert re.match(rf"bsjax {argv[0]}( [a-z]+)?: ", err) and name in err, (argv, err)  # subcommand
        assert "Traceback" not in err
    assert not (files / "m.json").exists() and not (files / "s.json").exists()
    assert jax.config.read("jax_enable_x64")  # the test session's setting is untouched


def test_errors_in_a_real_process_and_debug_traceback(files):
    """The console entry point: one line, exit 2; `--debug` shows the traceback instead."""
    run = [sys.executable, "-m", "bsjax.cli", "collide", str(files / "bad.json"), "--point", "0,0,0"]
    plain = subprocess.run(run, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert plain.returncode == 2 and plain.stdout == ""
    assert plain.stderr.count("\n") == 1 and "bad.json" in plain.stderr and "Traceback" not in plain.stderr
    debug = subprocess.run(run + ["--debug"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert debug.returncode == 1 and "Traceback" in debug.stderr and "bad.json" in debug.stderr


def test_unstable_step_is_refused_in_the_options_words(files, capsys):
    """An unstable time step: one line naming `--dt` and `--method implicit` (not the library's
    `dt`/`method='implicit'`), with the largest stable step, which then runs."""
    argv = ["simulate", str(files / "a.json"), "-o", str(files / "s.json"), "--samples", "6,6", "--json"]
    assert bsjax(argv + ["--steps", "2", "--dt", "1.0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bsjax simulate: --dt: expected at most ")
    assert "--method implicit" in err and "method=" not in err
    limit = float(err.split("expected at most ")[1].split()[0])
    assert bsjax(argv + ["--steps", "2", "--dt", str(0.999 * limit)]) == 0
    assert _strict_json(capsys.readouterr().out)["stable_dt"] == pytest.approx(limit, rel=1e-2)
    with pytest.raises(_common.UserError, match="stable"):
        bsjax(argv + ["--steps", "2", "--dt", "1.0", "--debug"])


# --- dtype policy: float64 unless --float32 ------------------------------------------------------
def test_float32_flag_sets_the_dtype_written(files, capsys):
    a, b = str(files / "a.json"), str(files / "b.json")
    for flag, want in (([], "float64"), (["--float32"], "float32")):
        out = files / f"m_{want}.json"
        assert bsjax(["merge", a, b, "-o", str(out), "--samples", "12", "--continuity", "0", *flag]) == 0
        assert json.loads(out.read_text())["dtype"] == want and io.load(out).ctrl.dtype == want
        conv = files / f"c_{want}.json"
        assert bsjax(["convert", a, str(conv), *flag]) == 0
        assert json.loads(conv.read_text())["dtype"] == want
        capsys.readouterr()
        argv = ["collide", str(files / "plate.json"), "--sphere", "0.5,0.5,0.05,0.3", "--samples", "9,9"]
        assert bsjax([*argv, "--json", *flag]) == 0
        assert _strict_json(capsys.readouterr().out)["dtype"] == want
        sim = files / f"s_{want}.json"
        argv = ["simulate", a, "-o", str(sim), "--samples", "5,5", "--steps", "3", "--json", *flag]
        assert bsjax(argv) == 0
        assert _strict_json(capsys.readouterr().out)["dtype"] == want
        assert json.loads(sim.read_text())["dtype"] == want
    # the float32 merge rounds the float64 one to float32 precision, no more
    m64, m32 = io.load(files / "m_float64.json"), io.load(files / "m_float32.json")
    np.testing.assert_allclose(np.asarray(m32.ctrl), np.asarray(m64.ctrl), atol=1e-5)
    assert not np.array_equal(np.asarray(m32.ctrl, np.float64), np.asarray(m64.ctrl))
    assert jax.config.read("jax_enable_x64")  # restored after each command


# --- collide: the comma form is the library call ----------------------------------------------
@pytest.mark.parametrize(
    "flag, value, tool",
    [
        ("--sphere", "0.5,0.5,0.05,0.3", lambda: collide.Sphere(jnp.array([0.5, 0.5, 0.05]), jnp.array(0.3))),
        (
            "--ellipsoid",
            "0.4,0.6,0.02,0.3,0.2,0.1",
            lambda: collide.Ellipsoid(jnp.array([0.4, 0.6, 0.02]), jnp.array([0.3, 0.2, 0.1])),
        ),
        ("--point", "-0.5,0.5,0.0", lambda: collide.Point(jnp.array([-0.5, 0.5, 0.0]))),
    ],
)
def test_collide_comma_form_matches_the_library(files, flag, value, tool, capsys):
    surface_path = files / "plate.json"
    assert bsjax(["collide", str(surface_path), flag, value, "--samples", "15,11", "--json"]) == 0
    report = _strict_json(capsys.readouterr().out)
    surface = io.load(surface_path)
    c = collide.contacts(surface.blending(15, 11), surface.ctrl, tool())
    assert report["samples"] == [15, 11] and report["hit"] == bool(c.hit)
    assert report["samples_in_contact"] == int(c.mask.sum())
    assert report["max_depth"] == pytest.approx(float(c.depth.max()), rel=1e-12, abs=1e-15)
    assert report["total_depth"] == pytest.approx(float(c.depth.sum()), rel=1e-12, abs=1e-15)
    force = np.asarray(collide.contact_force(c, 100.0, "surface_normal"))
    np.testing.assert_allclose(report["force_surface_normal"], force, rtol=1e-12, atol=1e-12)


def test_json_is_valid_without_contact(files, capsys):
    """Far from the surface: no contact, and the report is still strict JSON."""
    assert bsjax(["collide", str(files / "plate.json"), "--point", "5,5,5", "--samples", "7", "--json"]) == 0
    report = _strict_json(capsys.readouterr().out)
    assert report["hit"] is False and report["samples_in_contact"] == 0 and report["max_depth"] == 0.0


def test_non_finite_numbers_become_null():
    text = _common.dumps({"a": float("inf"), "b": [1.0, float("nan")], "c": (2.0,)})
    assert _strict_json(text) == {"a": None, "b": [1.0, None], "c": [2.0]}


# --- import bsjax stays light -----------------------------------------------------------------
def test_import_bsjax_loads_no_file_or_picture_library():
    code = (
        "import bsjax, bsjax.collide, bsjax.merge, bsjax.mss, bsjax.vsofm, sys; "
        "print(sorted(m for m in ('rhino3dm','matplotlib','trimesh') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


# --- simulate: comma-form tools act like the library's ----------------------------------------
def test_simulate_free_fall_and_table(files, capsys):
    """Unclamped plate: semi-implicit Euler free fall, `g dt² n(n+1)/2` exactly; with
    `--table 0,0,-0.01` it stops on the table (the gap plus a small penalty penetration)."""
    argv = ["simulate", str(files / "a.json"), "-o", str(files / "s.json"), "--samples", "5,5", "--json"]
    assert bsjax([*argv, "--steps", "40"]) == 0
    free = _strict_json(capsys.readouterr().out)
    n, dt = free["steps"], free["dt"]
    assert free["max_displacement"] == pytest.approx(9.81 * dt**2 * n * (n + 1) / 2, rel=1e-9)
    assert free["mean_displacement"] == pytest.approx(free["max_displacement"], rel=1e-9)
    assert bsjax([*argv, "--steps", "40", "--table", "0,0,-0.01"]) == 0
    table = _strict_json(capsys.readouterr().out)
    assert 0.01 < table["max_displacement"] < 0.02 and table["finite"]  # free fall: 4.3 m
    z = np.asarray(io.load(files / "s.json").ctrl)[..., 2]
    assert np.all(z < -0.01) and np.all(z > -0.02)  # a flat plate: the refit net lies with the nodes


def test_convert_refuses_a_mesh_without_triangles(tmp_path, capsys):
    """2 × 2 samples of the teardrop all lie on its poles and seam: no triangle is left, so
    `convert` refuses (exit 2, naming `--samples`) instead of writing an empty STL; the library
    names its own arguments. 3 × 3 samples give a closed mesh."""
    pytest.importorskip("trimesh")
    io.save(shapes.teardrop(), tmp_path / "t.json")
    assert bsjax(["convert", str(tmp_path / "t.json"), str(tmp_path / "t.stl"), "--samples", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--samples" in err and not (tmp_path / "t.stl").exists()
    with pytest.raises(ValueError, match=r"^m, n: .*at least one triangle"):
        io.tessellate(shapes.teardrop(), 2, 2)
    assert bsjax(["convert", str(tmp_path / "t.json"), str(tmp_path / "t.stl"), "--samples", "3"]) == 0
    assert len(io.tessellate(shapes.teardrop(), 3, 3).faces) > 0
