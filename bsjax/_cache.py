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

Several processes may share the directory (two notebook kernels, the workers of a test run): the
cache's size is bounded (`MAX_BYTES`, least recently used entries evicted first), which also makes
JAX guard every read and write with a file lock (`filelock`), so no process reads an entry another
is still writing.
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

    where = cache_dir()
    if where is None:
        return None
    where = Path(path).expanduser() if path is not None else where
    where.mkdir(parents=True, exist_ok=True)
    if jax.config.jax_compilation_cache_dir != str(where):  # pyright: ignore[reportAttributeAccessIssue]
        compilation_cache.reset_cache()  # JAX decides once whether it uses a cache: ask again
        jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)  # eviction on: file-locked I/O
    return where
