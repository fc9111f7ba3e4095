"""The `bsjax` command: `bsjax demo`, `bsjax haptics …`, and batch subcommands.

Each subcommand lives in its own module of this package and exposes `main(argv) -> int`; this
file only dispatches, so importing it stays cheap. Every subcommand follows the convention of
`bsjax.cli._common`: comma-separated vectors (`--sphere CX,CY,CZ,R`), one-line user errors with
exit code 2 (`--debug` for the traceback), float64 unless `--float32`, valid JSON. A feature whose
extra is not installed is one line naming it (`bsjax convert: reading 'a.step' needs the 'cad'
extra: pip install 'bsjax[cad]'`), exit code 2.
"""

from __future__ import annotations

import importlib
import sys

from bsjax._optional import MissingExtraError, extra_of

__all__ = ["COMMANDS", "main"]

# name → (module with a `main(argv)`, one-line help)
COMMANDS = {
    "demo": ("bsjax.cli.demo", "the spoon case study: shapes, collision, merging, physics, optimisation"),
    "haptics": ("bsjax.cli.haptics", "haptic sculpting loop (--simulated, --serial PORT, --hid VID:PID)"),
    "merge": ("bsjax.cli.merge", "merge patches from .json/.3dm files into one surface"),
    "collide": ("bsjax.cli.collide", "collision query of a surface file against a tool"),
    "simulate": ("bsjax.cli.simulate", "mass-spring simulation of a surface file"),
    "convert": ("bsjax.cli.convert", "convert a surface between .json, .3dm, .obj, .stl, .ply, .glb"),
    "sketch": ("bsjax.cli.sketch", "strokes from a JSON file -> curves and a surface (.3dm/.glb + PNG)"),
    "grammar": ("bsjax.cli.grammar", "curve semantics: symbol string of a curve file; enumerate shapes"),
    "view": ("bsjax.cli.view", "live 3-D view in the browser of a surface, curve set or recording"),
    "studio": ("bsjax.cli.studio", "interactive modelling page: draw, recognise, construct, sculpt"),
    "sweep": ("bsjax.cli.sweep", "parameter study over a grid of designs (spoon, collide, merge)"),
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bsjax")
    except PackageNotFoundError:  # a source tree on sys.path, not installed
        return "unknown"


def _usage() -> str:
    lines = [
        "usage: bsjax COMMAND [options]   (bsjax COMMAND --help for its options; bsjax --version)",
        "",
        "commands:",
    ]
    lines += [f"  {name:<10} {text}" for name, (_, text) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run `bsjax COMMAND ARGS…`; returns the exit code (2 for a user error)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # no command: a usage error (as git, pip): the usage on stderr, exit 2
        print(_usage(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    if argv[0] in ("-V", "--version"):
        print(f"bsjax {_version()}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"bsjax: {name}: unknown command (one of {', '.join(COMMANDS)})", file=sys.stderr)
        return 2
    if not {"-h", "--help"} & set(rest):  # compiled programs kept for the next run (BSJAX_CACHE_DIR)
        from bsjax._cache import enable_compilation_cache
        from bsjax._xla import prefer_quick_compilation

        prefer_quick_compilation()  # before the first computation (bsjax._xla)
        enable_compilation_cache()
    try:
        return int(importlib.import_module(COMMANDS[name][0]).main(rest) or 0)
    except MissingExtraError as err:
        if "--debug" in rest:
            raise
        print(f"bsjax {name}: {err}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as err:  # an optional module imported without `require`: still named
        extra = extra_of(err.name or "")
        if extra is None or "--debug" in rest:
            raise  # not an extra: a broken installation, shown in full
        print(f"bsjax {name}: needs the {extra!r} extra: pip install 'bsjax[{extra}]'", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
