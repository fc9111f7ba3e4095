"""Smoke test of `benchmarks/api.py`: it runs, prints one well-formed row per entry and a summary,
writes its JSON, and turns a failing entry into an error row (no time is asserted)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "api.py"
CHEAP = ["basis.Blending.points", "collide.contact_force", "mss.stable_dt"]
NUMBER = r"-?\d+\.\d+"
ROW = re.compile(
    rf"^(?P<name>\S+) .* (?P<first>{NUMBER}) +(?P<med>{NUMBER}) +(?P<p99>{NUMBER}) +(?P<jit>{NUMBER})"
    rf" +(?P<ratio>{NUMBER}) +(?P<verdict>ok|SLOW) +(?P<calls>\d+)$"
)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "api.json"
    cmd = [
        sys.executable,
        str(SCRIPT),
        "--quick",
        "--calls",
        "5",
        "--only",
        ",".join(CHEAP),
        "--json",
        str(out),
    ]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout, json.loads(out.read_text())


def test_rows_columns_and_summary(quick_run):
    stdout, _ = quick_run
    lines = stdout.splitlines()
    header = next(line for line in lines if line.startswith("entry"))
    for column in ("size", "first s", "median ms", "p99 ms", "jitted ms", "ratio", "verdict", "calls"):
        assert column in header
    rows = {m["name"]: m for m in map(ROW.match, lines) if m}
    assert sorted(rows) == sorted(CHEAP), stdout
    for m in rows.values():
        med, p99, jit, ratio = (float(m[k]) for k in ("med", "p99", "jit", "ratio"))
        assert 0 < med <= p99 and jit > 0
        assert ratio == pytest.approx(med / jit, rel=0.05, abs=0.01)  # printed rounded
        assert int(m["calls"]) >= 5
    assert re.search(
        r"^load average \d+\.\d\d \d+\.\d\d \d+\.\d\d; \d{4}-\d\d-\d\d .*; jax \S+", stdout, re.M
    )
    summary = [line for line in lines if line.startswith("SUMMARY: ")]
    assert len(summary) == 1 and re.match(r"SUMMARY: \d+/3 ok; not ok: .*; errors: none", summary[0])


def test_json_rows(quick_run):
    _, data = quick_run
    assert [r["name"] for r in data["rows"]] == CHEAP
    for r in data["rows"]:
        assert r["median_s"] > 0 and r["jitted_s"] > 0 and r["verdict"] in ("ok", "SLOW")
        good = r["median_s"] / r["jitted_s"] <= 2 or r["median_s"] - r["jitted_s"] <= 3e-4
        assert (r["verdict"] == "ok") == good
    assert data["summary"].startswith("SUMMARY: ") and len(data["meta"]["load_average"]) == 3


def test_failing_entry_gives_error_row_and_summary(monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import api

    def broken(q):
        raise ValueError("ctrl: expected shape (r, s, 3)\nmore detail")

    row = api.run_entry(api.Entry("demo.broken", broken), api.QUICK, calls=5)
    assert api.format_row(row).endswith("ERROR: ValueError: ctrl: expected shape (r, s, 3)")
    fine = {"name": "demo.fine", "verdict": "ok"}
    slow = {"name": "demo.slow", "verdict": "SLOW"}
    assert api.summary([fine, slow, row]) == ("SUMMARY: 1/3 ok; not ok: demo.slow; errors: demo.broken")
