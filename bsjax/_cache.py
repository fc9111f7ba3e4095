"""JAX's persistent compilation cache, in the user's cache directory: a second process (a new
notebook kernel, the next CLI run, the next script) loads what an earlier one compiled instead of
compiling it again.

    import bsjax
    bsjax.enable_compilation_cache()      # once, at the top of a script or notebook

The CLI turns it on for every command. Importing bsjax changes nothing: the cache is JAX's global
configuration (`jax_compilation_cache_dir`), so it is on only where it is asked for.

Where: `$BSJAX_CACHE_DIR` when set (`BSJAX_CACHE_DIR=off` disables the cache everywhere, the
CLI included), else the platform's user cache directory — `$XDG_CACHE_HOME/bsjax/jax` or
`~/.cache/bsjax/jax` on Linux, `~/Library/Caches/bsjax/jax` on macOS,
`%LOCALAPPDATA%\\bsjax\\Cache\\jax` on Windows.

What is stored: every program bsjax's compiled boundary builds (its value checks are part of the
program's result, not host callbacks, so JAX can store it), however short its compilation; JAX
keys each entry by the program, the compiler options and the JAX/XLA version, so a stale entry is
never loaded.

Several processes may share the directory (two notebook kernels, the workers of a test run). The
cache's size is bounded (`MAX_BYTES`): each `enable_compilation_cache` call removes the least
recently written entries beyond it (`trim`), once. JAX's own bound is not used: it scans the whole
directory on every write (a write into a cache of 3 000 entries took 140 ms, so a run that
compiles thousands of programs spent most of its cache time there). Without it JAX writes entries
unlocked; a process that reads an entry another is still writing fails to decompress it, warns
and compiles the program itself.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

_DISABLED = ("off", "0", "false", "no", "none", "")
MAX_BYTES = 4 << 30  # the cache's bound on disk (4 GiB); bsjax's programs are ~10 kB-10 MB each


def default_cache_dir() -> Path:
    """The platform's user cache directory for bsjax's compiled programs (module docstring)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
        return base / "bsjax" / "Cache" / "jax"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "bsjax" / "jax"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bsjax" / "jax"


def cache_dir() -> Path | None:
    """Where the cache lives: `$BSJAX_CACHE_DIR`, `None` when it says `off`, else the default."""
    env = os.environ.get("BSJAX_CACHE_DIR")
    if env is None:
        return default_cache_dir()
    return None if env.strip().lower() in _DISABLED else Path(env).expanduser()


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache for this process (module docstring).

    **Arguments:** `path`: the directory (default: `$BSJAX_CACHE_DIR`, else the platform's user
    cache directory). `BSJAX_CACHE_DIR=off` disables it whatever `path` says.

    **Returns:** the directory in use, or `None` when disabled. Idempotent; takes effect for
    programs compiled from now on.
    """
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    from bsjax import _executables

    where = cache_dir()
    if where is None:
        _executables.use(None)
        return None
    where = Path(path).expanduser() if path is not None else where
    where.mkdir(parents=True, exist_ok=True)
    if jax.config.jax_compilation_cache_dir != str(where):  # pyright: ignore[reportAttributeAccessIssue]
        compilation_cache.reset_cache()  # JAX decides once whether it uses a cache: ask again
        jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", -1)  # JAX's bound scans the directory per write
    _executables.use(where)
    if where not in _TRIMMED:
        trim(where)
        _TRIMMED.add(where)
    return where


_TRIMMED: set[Path] = set()  # directories this process has trimmed


def trim(directory: str | os.PathLike, max_bytes: int = MAX_BYTES) -> int:
    """Remove the least recently written entries of the cache in `directory` until it holds at most
    `max_bytes`. **Returns:** the number of entries removed (entries another process removes at
    the same time are skipped)."""
    from bsjax._executables import SUFFIX

    entries = []
    for path in (*Path(directory).glob("*-cache"), *Path(directory).glob("*" + SUFFIX)):
        try:
            st = path.stat()
        except FileNotFoundError:
            continue
        entries.append((st.st_mtime_ns, st.st_size, path))
    total = sum(size for _, size, _ in entries)
    removed = 0
    for _, size, path in sorted(entries):
        if total <= max_bytes:
            break
        path.unlink(missing_ok=True)
        if path.name.endswith("-cache"):
            path.with_name(path.name[: -len("-cache")] + "-atime").unlink(missing_ok=True)  # JAX's LRU stamp
        total -= size
        removed += 1
    return removed
