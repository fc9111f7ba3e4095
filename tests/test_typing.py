"""The jaxtyping annotations hold while tests run: the numeric tests of surfaces and blending
matrices (the kernels everything else is built on) run again in a subprocess under jaxtyping's
import hook with beartype, so every annotated argument and return value of `bsjax` they reach —
array shapes by name, dtypes, pytree types — is checked on every call. Left out: the bad-input
tests (there a wrong type or shape is refused by the annotation check first, with jaxtyping's
message instead of bsjax's own) and the jit/vmap/grad tests (the same calls again, traced: each
compiles its programs once more, a minute of the suite for no annotation the eager calls miss)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_annotations_hold_under_jaxtyping_and_beartype():
    pytest.importorskip("beartype")
    cmd = [
        sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider",
        "--jaxtyping-packages=bsjax,beartype.beartype",
        "tests/test_surface.py", "tests/test_blending.py",
        "-k", "not error and not raise and not bad and not refuse and not jit and not vmap and not grad",
    ]  # fmt: skip
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1500)
    tail = "\n".join(out.stdout.splitlines()[-30:])
    assert out.returncode == 0, tail
    passed = re.search(r"(\d+) passed", tail)
    assert passed and int(passed.group(1)) >= 40 and "failed" not in tail, tail  # the selection ran
