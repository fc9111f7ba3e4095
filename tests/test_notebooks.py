"""Every notebook in notebooks/ executes without error (small sizes), so none can rot.

The notebooks of one test process run one after another in one Jupyter kernel (started once:
a kernel's start and its imports of JAX, bsjax and matplotlib cost ~4 s per notebook). Each
starts from a clean slate: its own working folder, an empty namespace (`%reset -f`: every name
it uses it must define or import itself), JAX's float32 default, matplotlib's inline backend with
no figure open; a notebook whose cell fails (or times out) fails its own test, and the kernel is
restarted for the next one.
"""

from pathlib import Path

import nbformat
import pytest
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))

# what a fresh kernel is, restored before each notebook (the kernel's modules stay imported)
_CLEAN_SLATE = """\
%reset -f
import os as _os, sys as _sys
_os.chdir({folder!r})
if "jax" in _sys.modules:
    _sys.modules["jax"].config.update("jax_enable_x64", False)
if "matplotlib.pyplot" in _sys.modules:
    _sys.modules["matplotlib.pyplot"].close("all")
if "matplotlib" in _sys.modules:
    _sys.modules["matplotlib"].use(_os.environ.get("MPLBACKEND", "module://matplotlib_inline.backend_inline"))
del _os, _sys
"""


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    km = KernelManager(kernel_name="python3")
    km.start_kernel(cwd=str(tmp_path_factory.mktemp("kernel")))
    yield km
    km.shutdown_kernel(now=True)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path, kernel):
    nb = nbformat.read(path, as_version=4)
    nb.cells.insert(0, nbformat.v4.new_code_cell(_CLEAN_SLATE.format(folder=str(tmp_path))))
    client = NotebookClient(nb, km=kernel, timeout=300, kernel_name="python3")
    try:
        client.execute()
    except BaseException:
        kernel.restart_kernel(now=True)  # the next notebook gets a fresh kernel
        raise
    finally:
        if client.kc is not None:
            client.kc.stop_channels()
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"
    ]
    assert not errors


def test_there_is_a_tour():
    assert any(p.stem == "01_tour" for p in NOTEBOOKS)
