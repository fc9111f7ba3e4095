"""The suite's scheduling over xdist workers (`tests/xdist_scheduling.py`): a file's tests on one
worker, slowest files first, and a worker that dies (a segfault) costs one failed test, not a hung
run. Real pytest runs in a subprocess, on files written here; one of their tests kills its worker."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FILES = {
    "test_a.py": "def test_a1():\n    pass\n\ndef test_a2():\n    pass\n",
    "test_b.py": (
        "import os, signal\n\ndef test_b1():\n    pass\n\n"
        "def test_crash():\n    os.kill(os.getpid(), signal.SIGSEGV)\n\n"
        "def test_b_after():\n    pass\n\ndef test_b_last():\n    pass\n"
    ),
    "test_c.py": "def test_c1():\n    pass\n",
    "test_d.py": "def test_d1():\n    pass\n",
}


def _run(tmp_path, files):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [
        sys.executable, "-m", "pytest", "-p", "tests.xdist_scheduling", "-p", "no:cacheprovider",
        "-n", "2", "-v", "--rootdir", str(tmp_path), str(tmp_path),
    ]  # fmt: skip
    return subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


def test_a_dead_worker_fails_its_test_once_and_the_rest_of_its_file_runs(tmp_path):
    out = _run(tmp_path, FILES)
    assert out.returncode == 1, out.stdout[-3000:]
    summary = out.stdout.splitlines()[-1]
    assert re.search(r"\b1 failed, 7 passed\b", summary), out.stdout[-3000:]
    assert re.search(r"FAILED .*test_b.py::test_crash", out.stdout), out.stdout[-3000:]
    for test in ("test_b_after", "test_b_last", "test_c1", "test_d1"):  # after the crash, still run
        assert re.search(rf"PASSED .*::{test}\b|::{test} PASSED", out.stdout), (test, out.stdout[-3000:])


def test_a_files_tests_run_on_one_worker(tmp_path):
    files = {
        name: text.replace("os.kill(os.getpid(), signal.SIGSEGV)", "pass") for name, text in FILES.items()
    }
    out = _run(tmp_path, files)
    assert out.returncode == 0, out.stdout[-3000:]
    where: dict[str, set[str]] = {}
    for worker, test in re.findall(r"\[(gw\d+)\] \[\s*\d+%\] PASSED (\S+)", out.stdout):
        where.setdefault(test.split("::")[0], set()).add(worker)
    assert len(where) == 4 and all(len(w) == 1 for w in where.values()), out.stdout[-3000:]
    assert len(set().union(*where.values())) == 2  # both workers had work


def test_a_worker_dying_on_its_files_last_test_leaves_no_empty_work(tmp_path):
    """The file it died in has nothing left to run: it must not go back on the queue (xdist
    would send it as empty work and the run would hang)."""
    files = {**FILES, "test_b.py": FILES["test_b.py"].split("\n\ndef test_b_after")[0] + "\n"}
    out = _run(tmp_path, files)
    assert out.returncode == 1, out.stdout[-3000:]
    assert re.search(r"\b1 failed, 5 passed\b", out.stdout.splitlines()[-1]), out.stdout[-3000:]
