"""bsjax as a user installs it: the core works without any extra, a missing extra is named (by the
library and, in one line with exit code 2, by the command), and the built sdist and wheel carry
what they should (core dependencies, extras, floors, licence, `py.typed`, the tests).

"Without the extra" is simulated, not installed: a subprocess whose first import finder refuses
every optional module, so the test needs no network and no second environment.
"""

from __future__ import annotations

import email
import json
import re
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

from bsjax import _optional
from bsjax.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[1]
OPTIONAL = ("rhino3dm", "OCP", "trimesh", "matplotlib", "serial", "hid", "websockets", "tqdm")
CORE = {"jax", "jaxlib", "equinox", "optimistix", "lineax", "jaxtyping", "numpy", "scipy"}

# Runs first in the subprocess: importing any optional module fails as if it were not installed.
_BLOCK = f"""
import importlib.abc, sys
class _NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in {OPTIONAL!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, _NotInstalled())
"""

# The library without extras: what works, and the error each optional feature raises.
_LIBRARY = """
import json, sys, tempfile
from pathlib import Path
import numpy as np
import bsjax
from bsjax import basis, collide, merge, mss, shapes, vsofm, io, plot, device, view, batch, optimise
from bsjax.cli import _progress

out = {}
surface = shapes.plate(5, 4)
points = np.asarray(surface.blending(6, 5).points(surface.ctrl))
sphere = collide.Sphere(np.array([0.5, 0.5, 0.0]), 0.2)
contacts = collide.contacts(surface.blending(8, 8), surface.ctrl, sphere)
out["computed"] = [list(points.shape), bool(np.asarray(contacts.mask).any())]
tmp = Path(tempfile.mkdtemp())
io.save(surface, tmp / "plate.json")
out["json"] = io.load(tmp / "plate.json").ctrl.shape == surface.ctrl.shape
(tmp / "part.step").write_text("ISO-10303-21;")
(tmp / "part.3dm").write_bytes(b"")

def error(fn):
    try:
        fn()
    except ImportError as err:
        return [type(err).__name__, str(err)]
    return None

out["errors"] = {
    "step": error(lambda: io.load(tmp / "part.step")),
    "3dm": error(lambda: io.load_all(tmp / "part.3dm")),
    "stl": error(lambda: io.save(surface, tmp / "plate.stl")),
    "tessellate": error(lambda: io.tessellate(surface, 4, 4)),
    "mesh": error(lambda: collide.TriangleMesh.load(tmp / "x.obj")),
    "plot": error(lambda: plot.figure(1)),
    "serial": error(lambda: device.SerialDevice("/dev/null")),
    "hid": error(lambda: device.HidDevice(device.HidLayout.generic(1, 2))),
    "view": error(lambda: view.ViewServer(lambda: {}).start()),
}
with _progress.bar("steps", force=True) as progress:
    out["progress"] = progress is None
out["imported"] = sorted(m for m in sys.modules if m.partition(".")[0] in OPTIONAL)
print(json.dumps(out))
"""

# The command without extras: (argv, files to create) → exit code and output.
_COMMANDS = {
    "version": ["--version"],
    "help": ["--help"],
    "convert_step": ["convert", "part.step", "part.json"],
    "view_file": ["view", "plate.json", "--duration", "1"],
    "haptics_serial": ["haptics", "--serial", "/dev/null", "--duration", "1"],
    "demo": ["demo", "--quick"],
}
_CLI = """
import contextlib, io as _io, json, os, sys, tempfile
os.chdir(tempfile.mkdtemp())
open("part.step", "w").write("ISO-10303-21;")
from bsjax import io, shapes
io.save(shapes.plate(4, 4), "plate.json")
from bsjax.cli import COMMANDS as ALL, main
out = {}
for key, argv in [*COMMANDS.items(), *((f"{name}_help", [name, "--help"]) for name in ALL)]:
    stdout, stderr = _io.StringIO(), _io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(argv)
    out[key] = [code, stdout.getvalue(), stderr.getvalue()]
print(json.dumps(out))
"""


def _run_blocked(body: str, **names) -> dict:
    prelude = "".join(f"{k} = {v!r}\n" for k, v in names.items())
    code = _BLOCK + prelude + body
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def library():
    return _run_blocked(_LIBRARY, OPTIONAL=OPTIONAL)


@pytest.fixture(scope="module")
def cli():
    return _run_blocked(_CLI, COMMANDS=_COMMANDS)


def test_core_imports_and_computes_without_any_extra(library):
    assert library["computed"] == [[6, 5, 3], True]
    assert library["json"] is True
    assert library["imported"] == []  # no optional module was even attempted at import
    assert library["progress"] is True  # no tqdm: no bar, no error


@pytest.mark.parametrize(
    "feature, extra, words",
    [
        ("step", "cad", "reading 'part.step'"),
        ("3dm", "cad", "reading 'part.3dm'"),
        ("stl", "mesh", "writing 'plate.stl'"),
        ("tessellate", "mesh", "bsjax.io.tessellate"),
        ("mesh", "mesh", "bsjax.collide.TriangleMesh.load"),
        ("plot", "plot", "bsjax.plot.figure"),
        ("serial", "haptics", "bsjax.device.SerialDevice"),
        ("hid", "haptics", "bsjax.device.HidDevice"),
        ("view", "view", "bsjax.view.ViewServer"),
    ],
)
def test_a_missing_extra_is_one_import_error_naming_it(library, feature, extra, words):
    kind, message = library["errors"][feature]
    assert kind == "MissingExtraError"  # an ImportError
    assert message == f"{words} needs the {extra!r} extra: pip install 'bsjax[{extra}]'"


def test_require_returns_the_module_and_names_an_outdated_install():
    assert _optional.require("json", "view", "x") is json
    # installed, but without the submodule bsjax needs (websockets 12 has no websockets.asyncio)
    with pytest.raises(
        _optional.MissingExtraError, match=r"^x needs the 'view' extra at its declared"
    ) as err:
        _optional.require("json.asyncio", "view", "x")
    assert "(json " in str(err.value) and "pip install --upgrade 'bsjax[view]'" in str(err.value)
    with pytest.raises(ValueError, match="extra: expected one of"):
        _optional.require("json", "viewer", "x")


def test_the_command_without_extras(cli):
    code, out, err = cli["version"]
    assert (code, out, err) == (0, f"bsjax {_installed_version()}\n", "")
    for key in ("help", *(f"{name}_help" for name in COMMANDS)):  # every command's help
        code, out, err = cli[key]
        assert code == 0 and out.startswith("usage: bsjax") and err == "", key
    for key, extra, feature in (
        ("convert_step", "cad", "reading 'part.step'"),
        ("view_file", "view", "serving the view"),
        ("haptics_serial", "haptics", "--serial"),
        ("demo", "plot", "writing the demo's pictures and files"),
    ):
        code, out, err = cli[key]
        command = _COMMANDS[key][0]
        expected = f"bsjax {command}: {feature} needs the {extra!r} extra: pip install 'bsjax[{extra}]'\n"
        assert (code, err) == (2, expected), key  # one line on stderr, exit code 2, no traceback


def test_python_dash_m_bsjax_is_the_command():
    proc = subprocess.run(
        [sys.executable, "-m", "bsjax", "--version"], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert (proc.returncode, proc.stdout) == (0, f"bsjax {_installed_version()}\n")


def _installed_version() -> str:
    from importlib.metadata import version

    return version("bsjax")


def test_every_extra_the_library_names_is_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    for extra, packages in _optional.EXTRAS.items():
        declared = {_name(r) for r in extras[extra]}
        assert declared == set(packages), extra
    assert {_name(r) for r in project["dependencies"]} == CORE
    for module in OPTIONAL:
        assert _optional.extra_of(module) in _optional.EXTRAS


# --- the built distributions ------------------------------------------------------------------
def _name(requirement: str) -> str:
    return re.split(r"[<>=!~;\[ ]", requirement, maxsplit=1)[0].strip().lower()


@pytest.fixture(scope="module")
def dists(tmp_path_factory):
    """The sdist built from the checkout, and the wheel built from the unpacked sdist (what pip
    does with an sdist), both without network (`--no-build-isolation`)."""
    out = tmp_path_factory.mktemp("dist")
    build = "from setuptools import build_meta as b; print(b.build_sdist(sys.argv[1]))"
    proc = subprocess.run(
        [sys.executable, "-c", f"import sys; {build}", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    sdist = out / proc.stdout.strip().splitlines()[-1]
    with tarfile.open(sdist) as tar:
        tar.extractall(out / "src", filter="data")
    (tree,) = (out / "src").iterdir()
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out)]
    proc = subprocess.run([*cmd, str(tree)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = out.glob("bsjax-*.whl")
    return tree, wheel


def test_wheel_metadata_core_and_extras(dists):
    _, wheel = dists
    with zipfile.ZipFile(wheel) as whl:
        names = set(whl.namelist())
        (meta_name,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        meta = email.message_from_bytes(whl.read(meta_name))
        entry_points = whl.read(meta_name.replace("METADATA", "entry_points.txt")).decode()
    requires = meta.get_all("Requires-Dist")
    core = {_name(r): r for r in requires if "extra ==" not in r}
    assert set(core) == CORE  # nothing optional in the core
    floors = dict(
        line.split("==") for line in (ROOT / "constraints-min.txt").read_text().splitlines() if "==" in line
    )
    for requirement in requires:  # each declared floor is the tested one (core and extras)
        if _name(requirement) in floors:
            floor = floors[_name(requirement)]
            assert f">={floor}" in requirement.replace(" ", ""), (requirement, floor)
    assert CORE <= set(floors) and {p for ps in _optional.EXTRAS.values() for p in ps} <= set(floors)
    by_extra = {}
    for r in requires:
        if "extra ==" in r:
            extra = re.search(r'extra == "([^"]+)"', r).group(1)
            by_extra.setdefault(extra, set()).add(_name(r))
    for extra, packages in _optional.EXTRAS.items():
        assert by_extra[extra] == set(packages), extra
    assert {*_optional.EXTRAS, "all"} <= set(meta.get_all("Provides-Extra"))
    assert by_extra["all"] == {"bsjax"}  # bsjax[cad,mesh,...]: every extra, by name
    assert (meta["License-Expression"], meta["Author"]) == ("MIT", "the bsjax developers")
    assert "Typing :: Typed" in meta.get_all("Classifier") and "b-spline" in meta["Keywords"]
    assert "bsjax.cli:main" in entry_points
    assert {
        "bsjax/py.typed",
        "bsjax/__main__.py",
        "bsjax/_optional.py",
        "bsjax/view/static/index.html",
    } <= names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)


def test_all_extra_names_every_extra(dists):
    _, wheel = dists
    with zipfile.ZipFile(wheel) as whl:
        (meta_name,) = [n for n in whl.namelist() if n.endswith(".dist-info/METADATA")]
        meta = email.message_from_bytes(whl.read(meta_name))
    (everything,) = [r for r in meta.get_all("Requires-Dist") if r.startswith("bsjax[")]
    named = set(re.match(r"bsjax\[([^\]]+)\]", everything).group(1).split(","))
    assert named == set(_optional.EXTRAS)


def test_sdist_carries_the_tests_and_project_files(dists):
    tree, _ = dists
    for name in ("conftest.py", "helpers.py", "oracles.py", "__init__.py"):
        assert (tree / "tests" / name).is_file(), name
    tracked = subprocess.run(
        ["git", "ls-files", "tests", "benchmarks", "notebooks"], capture_output=True, text=True, cwd=ROOT
    ).stdout.split()
    missing = [p for p in tracked if not (tree / p).is_file()]
    assert not missing, missing
    for name in ("LICENSE", "README.md", "CHANGELOG.md", "CITATION.cff", "CONTRIBUTING.md"):
        assert (tree / name).is_file(), name
    assert (tree / "constraints-min.txt").is_file() and (tree / "bsjax" / "py.typed").is_file()
    assert "Copyright (c)" in (tree / "LICENSE").read_text()
