"""Every Python block of the README and of the documentation runs as written.

Per page, its ```` ```python ```` blocks run in order as one script in a new process, as a reader
pastes them into a file (a block may use what an earlier block of its page defined); each block
sits at its own line numbers of the page, so a failure's traceback names the page's lines. A
block whose first line is `# NAME.py: …` is a script of its own that the page starts from the
shell: it is left out of the page's script and run here as the page says (the batches guide's
sweep: once as one process, once as two processes on 127.0.0.1 through the `BSJAX_*` variables,
both writing the same table). Pages are found by a glob, so a new page's blocks are tested
without a change here.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```", re.MULTILINE | re.DOTALL)
SCRIPT = re.compile(r"#\s*([\w-]+\.py)\b")  # the first line of a script of its own


def _blocks(page: Path) -> list[tuple[int, str]]:
    """`(line index of the block's first line, code)` of every Python block of `page`."""
    text = page.read_text()
    return [(text.count("\n", 0, m.start(1)), m.group(1)) for m in BLOCK.finditer(text)]


def _scripts(page: Path) -> dict[str, str]:
    """The page's scripts of their own: file name → code."""
    return {m.group(1): code for _, code in _blocks(page) if (m := SCRIPT.match(code))}


def _page_script(page: Path) -> str:
    """The page's other blocks, each at its own lines of the page (blank lines between)."""
    lines = [""] * (page.read_text().count("\n") + 1)
    for start, code in _blocks(page):
        if not SCRIPT.match(code):
            lines[start : start + code.count("\n")] = code.splitlines()
    return "\n".join(lines) + "\n"


def _env(**changes) -> dict[str, str]:
    """This process's environment with `changes` (None: removed)."""
    env = {**os.environ, **changes}
    return {k: v for k, v in env.items() if v is not None}


def _run(script: Path, cwd: Path, env=None, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(script)],
        cwd=cwd,
        env=env or _env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _failure(page: Path, proc) -> str:
    """The traceback, its script's lines named as the page's."""
    return f"{page.relative_to(ROOT)} (lines are the page's):\n{proc.stdout[-2000:]}\n{proc.stderr[-6000:]}"


RUN = [p for p in PAGES if any(not SCRIPT.match(code) for _, code in _blocks(p))]


@pytest.mark.parametrize("page", RUN, ids=[str(p.relative_to(ROOT)) for p in RUN])
def test_page_blocks_run_as_written(page: Path, tmp_path: Path):
    script = tmp_path / page.with_suffix(".py").name
    script.write_text(_page_script(page))
    proc = _run(script, tmp_path)
    assert proc.returncode == 0, _failure(page, proc)


def test_every_block_is_run_here():
    """Each block is in a page script or is a script of its own that a test below runs."""
    own = {name for page in PAGES for name in _scripts(page)}
    assert own == {"my_sweep.py"}, own
    blocks = sum(len(_blocks(p)) for p in PAGES)
    assert blocks >= 30  # the README and docs' blocks (30 on 2026-12-07): a broken glob finds none


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_batches_guide_sweep_on_one_and_on_two_processes(tmp_path: Path):
    """The guide's `my_sweep.py` as one process (a no-op `initialize`) and as the two processes
    of its shell lines: the same contact areas, written by process 0 only."""
    page = ROOT / "docs" / "guide" / "batches.md"
    text = page.read_text()
    assert "BSJAX_NUM_PROCESSES=2 BSJAX_PROCESS_ID=1 python my_sweep.py" in text  # as run below
    single, multi = tmp_path / "one", tmp_path / "two"
    for folder in (single, multi):
        folder.mkdir()
        (folder / "my_sweep.py").write_text(_scripts(page)["my_sweep.py"])
    proc = _run(
        single / "my_sweep.py",
        single,
        _env(BSJAX_COORDINATOR=None, BSJAX_NUM_PROCESSES=None, BSJAX_PROCESS_ID=None),
    )
    assert proc.returncode == 0, _failure(page, proc)
    coordinator = f"127.0.0.1:{_free_port()}"
    procs = [
        subprocess.Popen(
            [sys.executable, "my_sweep.py"],
            cwd=multi,
            env=_env(BSJAX_COORDINATOR=coordinator, BSJAX_NUM_PROCESSES="2", BSJAX_PROCESS_ID=str(i)),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    try:
        outs = [p.communicate(timeout=300) for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, f"{out[-2000:]}\n{err[-6000:]}"
    one = np.loadtxt(single / "results.csv", delimiter=",")
    two = np.loadtxt(multi / "results.csv", delimiter=",")
    assert one.shape == (16,) and np.all(one > 0) and len(set(one.tolist())) > 1  # areas that vary
    np.testing.assert_array_equal(one, two)
