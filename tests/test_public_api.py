"""The public API as a contract: every public name of every public module, listed in
`tests/public_api.txt`, so a change to the public surface is a visible diff of that file; one
name means one object across bsjax.

A public module is one whose dotted path has no part starting with `_`. Its public names are
its `__all__`, or, for a module without one (none today: the test below requires it), the names
it defines that do not start with `_`. Regenerate the snapshot after an intended change with
`python -m tests.test_public_api > tests/public_api.txt`.
"""

from __future__ import annotations

import importlib
import pkgutil
import types
from collections import defaultdict
from pathlib import Path

import bsjax

SNAPSHOT = Path(__file__).with_name("public_api.txt")


def public_modules() -> list[str]:
    found = pkgutil.walk_packages(bsjax.__path__, "bsjax.")
    names = [m.name for m in found if not any(p.startswith("_") for p in m.name.split("."))]
    return ["bsjax", *sorted(names)]


def public_names(module: types.ModuleType) -> list[str]:
    """`__all__`, else the names the module itself defines (no `_`, no modules)."""
    if hasattr(module, "__all__"):
        return sorted(module.__all__)
    own = module.__name__
    return sorted(
        name
        for name, obj in vars(module).items()
        if not name.startswith("_")
        and not isinstance(obj, types.ModuleType)
        and getattr(obj, "__module__", own) == own
        and name != "TYPE_CHECKING"
    )


def snapshot() -> str:
    lines = []
    for name in public_modules():
        module = importlib.import_module(name)
        marker = "" if hasattr(module, "__all__") else "  # no __all__"
        lines += [f"{name}:{n}{marker}" for n in public_names(module)]
    return "\n".join(lines) + "\n"


def test_the_public_api_is_the_snapshot():
    live, kept = snapshot().splitlines(), SNAPSHOT.read_text().splitlines()
    added, removed = sorted(set(live) - set(kept)), sorted(set(kept) - set(live))
    assert not added and not removed, (
        f"public API changed: added {added}, removed {removed} "
        "(if intended: python -m tests.test_public_api > tests/public_api.txt)"
    )


def test_every_exported_name_exists_and_one_name_is_one_object():
    """Across the library one name is one object; the CLI's commands each export their own
    `main` (the command convention) and each case study its own `run`, `study`, …, so those are
    checked for existence only."""
    objects: dict[str, dict[int, list[str]]] = defaultdict(lambda: defaultdict(list))
    for name in public_modules():
        module = importlib.import_module(name)
        for n in getattr(module, "__all__", []):
            assert hasattr(module, n), f"{name}.__all__ lists {n}, which {name} does not define"
            if not name.startswith(("bsjax.cli", "bsjax.examples")):
                objects[n][id(getattr(module, n))].append(name)
    clashes = {
        n: sorted(m for ms in by_id.values() for m in ms) for n, by_id in objects.items() if len(by_id) > 1
    }
    assert not clashes, f"one name, several objects: {clashes}"


def test_every_public_module_declares_all():
    """Every package and module of the library, every command of the CLI (`main` alone) and every
    example module has `__all__`."""
    without = [name for name in public_modules() if not hasattr(importlib.import_module(name), "__all__")]
    assert without == [], without


if __name__ == "__main__":
    print(snapshot(), end="")
