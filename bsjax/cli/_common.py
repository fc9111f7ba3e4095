"""The one convention every `bsjax` subcommand follows (argument types, errors, dtype, JSON).

* Vectors are one comma-separated argument: `--sphere CX,CY,CZ,R`, `--center X,Y,Z`; a sample
  grid is `M,N` (or `N` for `N,N`).
* A user error — a bad number, a missing or unreadable input file, a wrong extension, an
  unwritable output, a value out of range — is one line on stderr,
  `bsjax CMD: ARGUMENT or FILE: problem`, and exit code 2, without a traceback; `--debug` shows
  the traceback instead.
* Geometry is float64 unless `--float32`: the command (an application, never the library) sets
  `jax_enable_x64` for its run and restores the previous setting when it returns.
* JSON written by a command is always valid JSON: a non-finite number becomes `null`.
* Output: a command's result goes to stdout (`report`): a table to read, or with `--json` the
  same result as one JSON document for a program; diagnostics and progress go to stderr
  (`note`, the progress bars of `bsjax.cli._progress`), so `bsjax CMD … --json > out.json` holds
  the result alone. The servers (`view`, `studio`) print their address, their only result.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

SURFACE_INPUTS = (".json", ".3dm")
SURFACE_OUTPUTS = (".json", ".3dm", ".obj", ".stl", ".ply", ".glb")


class UserError(Exception):
    """A mistake in the command line or its files: `what` (an argument or a file) and the problem."""

    def __init__(self, what: str, problem: str):
        super().__init__(f"{what}: {problem}")


_NEGATIVE_VALUE = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,[^ ]*)?$|^-(inf|nan)", re.I)


class Parser(argparse.ArgumentParser):
    """`argparse` with the common options (`--float32`, `--debug`) and one-line errors (exit 2);
    the description of `bsjax NAME` is, unless given, the command's line of `bsjax --help`
    (`cli.COMMANDS`)."""

    def __init__(
        self, prog: str, description: str | None = None, *, precision: bool = True, result: bool = True
    ):
        from bsjax.cli import COMMANDS

        if description is None:
            description = COMMANDS[prog.split()[-1]][1]
        super().__init__(prog=prog, description=description)
        if precision:
            self.add_argument("--float32", action="store_true", help="work in float32 (default float64)")
        if result:
            self.add_argument(
                "--json", action="store_true", help="print the result as JSON (default: a table)"
            )
        self.add_argument("--debug", action="store_true", help="show the traceback of an error")
        # A vector may start with a minus sign (`--center -1,0,0`): a value, not an option.
        self._negative_number_matcher = _NEGATIVE_VALUE

    def error(self, message: str):
        # argparse writes "argument --x: problem"; the convention is "--x: problem" on one line.
        message = message.removeprefix("argument ")
        self.exit(2, f"{self.prog}: {_one_line(message)}\n")


_EQX_MESSAGE = re.compile(r"EquinoxRuntimeError: (.*?)(?:\n\n|\n-{5}|\Z)", re.S)


def _one_line(text) -> str:
    """The message of `text` on one line: an equinox check's own message, else the first paragraph
    (JAX and equinox append stacks and advice after a blank line)."""
    text = str(text).strip()
    found = _EQX_MESSAGE.search(text)
    return " ".join((found.group(1) if found else text.split("\n\n")[0]).split())


class _QuietCallbackErrors(logging.Filter):
    """Drop JAX's "jax.pure_callback failed" log (with a traceback) that a failing value check
    (`eqx.error_if`) prints before its error is raised; the error itself is reported."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("jax.pure_callback failed")


@contextlib.contextmanager
def _quiet_callbacks(enabled: bool) -> Iterator[None]:
    logger, quiet = logging.getLogger("jax._src.callback"), _QuietCallbackErrors()
    if enabled:
        logger.addFilter(quiet)
    try:
        yield
    finally:
        logger.removeFilter(quiet)


# --- argument types -------------------------------------------------------------------------
def _number(text: str, kind=float):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def real(text: str) -> float:
    """Any finite number."""
    return _number(text)


def positive(text: str) -> float:
    """A finite number > 0 (durations, steps, stiffnesses, radii)."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def count(minimum: int = 1) -> Callable[[str], int]:
    """An integer >= `minimum` (counts, steps, sample numbers)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value

    return parse


def vector(metavar: str, positive_at: Sequence[int] = (), nonzero: slice | None = None):
    """A comma-separated vector such as `CX,CY,CZ,R` (its length is that of `metavar`).

    `positive_at`: indices that must be > 0 (a radius, semi-axes); `nonzero`: a slice that must
    not be the zero vector (a plane normal).
    """
    size = len(metavar.split(","))

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(t) for t in text.split(","))
        except ValueError:
            values = ()
        if len(values) != size or not all(math.isfinite(x) for x in values):
            raise argparse.ArgumentTypeError(
                f"expected {size} comma-separated finite numbers {metavar}, got {text!r}"
            )
        names = metavar.split(",")
        for i in positive_at:
            if values[i] <= 0:
                raise argparse.ArgumentTypeError(f"expected {names[i]} > 0, got {text!r}")
        if nonzero is not None and not any(values[nonzero]):
            raise argparse.ArgumentTypeError(f"expected a non-zero {','.join(names[nonzero])}, got {text!r}")
        return values

    parse.__name__ = "vector"
    return parse


def grid(text: str) -> tuple[int, int]:
    """A sample grid `M,N` (or `N` for `N,N`), each >= 2."""
    parts = text.split(",")
    try:
        values = tuple(int(t) for t in parts)
    except ValueError:
        values = ()
    if len(values) == 1:
        values = values * 2
    if len(values) != 2 or min(values) < 2:
        raise argparse.ArgumentTypeError(f"expected M,N (or N) with integers >= 2, got {text!r}")
    return values  # type: ignore[return-value]


def input_file(*extensions: str) -> Callable[[str], str]:
    """An existing, readable file with one of `extensions` (any extension when none is given)."""

    def parse(text: str) -> str:
        path = Path(text)
        if extensions and path.suffix.lower() not in extensions:
            raise argparse.ArgumentTypeError(f"{text}: expected a {' or '.join(extensions)} file")
        if not path.exists():
            raise argparse.ArgumentTypeError(f"{text}: no such file")
        if not path.is_file() or not os.access(path, os.R_OK):
            raise argparse.ArgumentTypeError(f"{text}: not a readable file")
        return text

    parse.__name__ = "input file"
    return parse


def output_file(*extensions: str) -> Callable[[str], str]:
    """A file that can be written: one of `extensions`, in an existing writable folder."""

    def parse(text: str) -> str:
        path = Path(text)
        if extensions and path.suffix.lower() not in extensions:
            raise argparse.ArgumentTypeError(f"{text}: expected an extension in {', '.join(extensions)}")
        _check_writable(path, text)
        return text

    parse.__name__ = "output file"
    return parse


def output_folder(text: str) -> str:
    """A folder to write into: existing, or creatable in an existing writable parent."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is not a folder")
    if path.is_dir():
        if not os.access(path, os.W_OK):
            raise argparse.ArgumentTypeError(f"{text}: folder is not writable")
        return text
    _check_writable(path, text)
    return text


def _check_writable(path: Path, text: str) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder")
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise argparse.ArgumentTypeError(f"{text}: not writable")


# --- running a command ----------------------------------------------------------------------
@contextlib.contextmanager
def precision(float32: bool) -> Iterator[None]:
    """float64 unless `float32`, for the duration of one command (the previous setting comes back)."""
    import jax

    before = bool(jax.config.read("jax_enable_x64"))
    jax.config.update("jax_enable_x64", not float32)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", before)


def dtype(args: argparse.Namespace):
    """The numpy dtype of this run: float32 with `--float32`, else float64."""
    import numpy as np

    return np.dtype(np.float32 if getattr(args, "float32", False) else np.float64)


def run(
    parser: argparse.ArgumentParser,
    body: Callable[[argparse.Namespace], int | None],
    argv: Sequence[str] | None,
    errors: tuple[type[BaseException], ...] = (),
) -> int:
    """Parse `argv`, run `body(args)` at the chosen precision; the exit code (never SystemExit).

    `UserError`, `ValueError`, `TypeError`, `OSError`, a value check that fired
    (`equinox.EquinoxRuntimeError`) and the command's own `errors` are reported
    as one line `PROG: message` (exit 2); with `--debug` they propagate with their traceback.
    """
    try:
        args = parser.parse_args(sys.argv[1:] if argv is None else list(argv))
    except SystemExit as stop:  # --help (0) or an argparse error (2, already reported)
        return stop.code if isinstance(stop.code, int) else 2
    import equinox as eqx  # a value check (`eqx.error_if`) that fires outside a compiled boundary

    context = precision(args.float32) if hasattr(args, "float32") else contextlib.nullcontext()
    try:
        with context, _quiet_callbacks(not args.debug):
            return int(body(args) or 0)
    except (UserError, ValueError, TypeError, OSError, eqx.EquinoxRuntimeError, *errors) as err:
        if args.debug:
            raise
        print(f"{parser.prog}: {_one_line(err) or type(err).__name__}", file=sys.stderr)
        return 2


# --- files ----------------------------------------------------------------------------------
def load_surfaces(path: str, args: argparse.Namespace) -> list:
    """Every surface in `path`, in the dtype of this run (see `dtype`)."""
    from bsjax import io

    return [_cast(s, dtype(args)) for s in io.load_all(path, kind="surface")]


def load_surface(path: str, args: argparse.Namespace):
    """The single surface in `path`, in the dtype of this run."""
    surfaces = load_surfaces(path, args)
    if len(surfaces) != 1:
        raise UserError(path, f"expected exactly one surface, got {len(surfaces)}")
    return surfaces[0]


def _cast(surface, dt):
    import numpy as np

    return surface.with_ctrl(np.asarray(surface.ctrl, dtype=dt))


def finite_or_none(value):
    """`value` with every non-finite float replaced by None (nested dicts, lists, tuples)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    return value


def dumps(report, indent: int | None = 2) -> str:
    """Valid JSON (no `Infinity`/`NaN`: non-finite numbers are written as null)."""
    return json.dumps(finite_or_none(report), indent=indent, allow_nan=False)


def report(args: argparse.Namespace, result, text: str | None = None) -> None:
    """The command's result on stdout (module docstring): with `--json` valid JSON (`dumps`),
    otherwise `text` when given (a command's own layout of the same result), else a table — a
    dict as aligned `key  value` lines, a list of dicts as columns under a header, a list of
    strings one per line (`(none)` for an empty list)."""
    if getattr(args, "json", False):
        print(dumps(result))
    else:
        print(table(finite_or_none(result)) if text is None else text)


def table(result) -> str:
    """`result` (a dict, a list of dicts or a list of values) as text (`report`)."""
    if isinstance(result, dict):
        width = max((len(str(k)) for k in result), default=0)
        return "\n".join(f"{k!s:<{width}}  {_cell(v)}" for k, v in result.items())
    if not result:
        return "(none)"
    if all(isinstance(row, dict) for row in result):
        keys = list(dict.fromkeys(k for row in result for k in row))
        rows = [keys, *([_cell(row.get(k, "")) for k in keys] for row in result)]
        widths = [max(len(r[i]) for r in rows) for i in range(len(keys))]
        return "\n".join("  ".join(f"{c:<{w}}" for c, w in zip(r, widths)).rstrip() for r in rows)
    return "\n".join(_cell(row) for row in result)


def _cell(value) -> str:
    """A table cell: floats to 6 significant digits, lists in brackets, None as `-`."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_cell(v) for v in value) + "]"
    return str(value)


def note(prog: str, message: str) -> None:
    """A diagnostic line on stderr: `PROG: message` (module docstring)."""
    print(f"{prog}: {message}", file=sys.stderr, flush=True)


def serve(server, name: str, duration: float | None) -> int:
    """Start `server` (a `ViewServer`, as a context manager) and serve until `duration` seconds
    pass (None: until Ctrl-C), printing its address first; the exit code (130 after Ctrl-C)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    with server:
        print(f"bsjax {name}: {server.url} (Ctrl-C to stop)", flush=True)
        deadline = time.monotonic() + (duration if duration is not None else float("inf"))
        try:
            while time.monotonic() < deadline:
                time.sleep(min(0.2, max(deadline - time.monotonic(), 0.0)))
        except KeyboardInterrupt:
            return 130
    return 0
