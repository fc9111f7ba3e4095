"""Optional dependencies: one place that imports them and says which extra to install.

`pip install bsjax` gives the core (JAX, equinox, optimistix, lineax, jaxtyping, numpy, scipy);
file formats, meshes, plots, devices, the live view and progress bars come with extras
(`pyproject.toml`, `[project.optional-dependencies]`). A function that needs one imports it through
`require` inside its body, so the core imports without any extra and a missing one is reported
once, naming the extra:

```python
trimesh = require("trimesh", "mesh", "bsjax.io.save('x.stl')")
# ImportError: bsjax.io.save('x.stl') needs the 'mesh' extra: pip install 'bsjax[mesh]'
```
"""

from __future__ import annotations

import importlib
import sys
from types import ModuleType

# extra → what it installs; the names `pyproject.toml` declares (tests/test_install.py checks it)
EXTRAS = {
    "cad": ("rhino3dm", "cadquery-ocp-novtk"),
    "mesh": ("trimesh",),
    "plot": ("matplotlib",),
    "haptics": ("pyserial", "hidapi"),
    "view": ("websockets",),
    "progress": ("tqdm",),
}
# top-level import name → the extra that installs it
_IMPORTS = {
    "rhino3dm": "cad",
    "OCP": "cad",
    "trimesh": "mesh",
    "matplotlib": "plot",
    "serial": "haptics",
    "hid": "haptics",
    "websockets": "view",
    "tqdm": "progress",
}


class MissingExtraError(ImportError):
    """An optional dependency is not installed: `feature` needs `pip install 'bsjax[extra]'`."""

    def __init__(self, module: str, extra: str, feature: str, outdated: str | None = None):
        if outdated is None:
            message = f"{feature} needs the {extra!r} extra: pip install 'bsjax[{extra}]'"
        else:  # installed, but a version without `module`
            message = (
                f"{feature} needs the {extra!r} extra at its declared versions ({outdated} is too old): "
                f"pip install --upgrade 'bsjax[{extra}]'"
            )
        super().__init__(message, name=module)
        self.extra = extra


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import `module` (e.g. `"OCP.STEPControl"`) or raise `MissingExtraError` naming `extra`.

    **Arguments:**
    - `module`: the dotted module name to import.
    - `extra`: the `bsjax[...]` extra that installs it (a key of `EXTRAS`).
    - `feature`: what the user asked for, in their words (`"bsjax.io.load('x.step')"`,
      `"bsjax view"`), the start of the message.

    **Returns:** the imported module. A module that is installed but fails to import for another
    reason (a broken build, a missing system library) raises its own error unchanged.
    """
    if extra not in EXTRAS:
        raise ValueError(f"extra: expected one of {', '.join(EXTRAS)}, got {extra!r}")
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        top = module.partition(".")[0]
        if err.name is None or err.name.partition(".")[0] != top:
            raise  # the module exists but one of *its* dependencies is missing: not ours to rename
        outdated = None
        if err.name != top and available(top):  # e.g. websockets 12 has no websockets.asyncio
            outdated = f"{top} {getattr(sys.modules[top], '__version__', '')}".strip()
        raise MissingExtraError(module, extra, feature, outdated) from None


def extra_of(module: str) -> str | None:
    """The extra that installs `module` (`"OCP.STEPControl"` → `"cad"`), or None for any other."""
    return _IMPORTS.get(module.partition(".")[0])


def available(module: str) -> bool:
    """Whether `module` can be imported (for optional conveniences such as progress bars)."""
    try:
        importlib.import_module(module)
    except ModuleNotFoundError:
        return False
    return True
