"""Whole compiled programs of the public boundary on disk: a second process runs a public
function's first call without tracing, lowering or compiling it.

JAX's persistent compilation cache (`bsjax._cache`) skips XLA's compilation in a second
process, but JAX must still trace the Python function and lower it to find the entry (its key
is the lowered program): for `mss.simulate_scene` that is 0.6 s of the 0.9 s such a first
call took. Here the compiled executable itself is stored (`jax.experimental.serialize_executable`)
under a key built from the call, before anything is traced:

* the entry point (module and qualified name) and bsjax's source (a digest of every `.py` file
  of the installed package: an edited bsjax never loads an older program);
* the arguments' structure (pytree node types and their static fields), the static leaves
  (ints, strings, flags, `static=` arguments) and the shapes and dtypes of the traced ones;
* everything else that decides the program: JAX's trace context (x64, dtype promotion,
  PRNG implementation, …), the compiler options, `XLA_FLAGS`, `EQX_ON_ERROR`, the JAX,
  jaxlib, equinox, numpy and Python versions, and the device's platform and kind.

A call whose arguments hold anything that cannot be keyed by value — a user's own function or
class (its code may change between processes), an object known only by its address — is
compiled as usual and never stored. The store is on where the compilation cache is
(`bsjax.enable_compilation_cache`: the CLI, the test suite, a script that asks), in the same
directory (entries `*-exe`, trimmed with JAX's) and only on a single-device process. An entry
that cannot be read (truncated, say) is removed and the program compiled again.
Entries are pickles of compiled code: like JAX's cache, the directory must be the user's own.
"""

from __future__ import annotations

import enum
import functools
import hashlib
import io
import logging
import os
import pickle
import sys
import threading
import types
from pathlib import Path

import equinox as eqx
import jax
import jaxlib
import numpy as np

SUFFIX = "-exe"
_LOG = logging.getLogger(__name__)
_OWNERS = ("bsjax", "builtins", "numpy", "jax", "jaxlib", "equinox", "jaxtyping", "collections")
_MISMATCH = ("Argument types differ", "Function compiled with input pytree", "Computation compiled for")
_directory: Path | None = None


def use(directory: Path | None) -> None:
    """Store and load programs in `directory` (`None`: off); `bsjax.enable_compilation_cache`."""
    global _directory
    _directory = directory


class _Unkeyable(Exception):
    """A value that cannot be part of a key (module docstring)."""


def _spec(value) -> str:
    """A canonical text of `value` that determines it for tracing, or `_Unkeyable`."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes, np.generic)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, (tuple, list)):
        return f"{type(value).__name__}({','.join(_spec(v) for v in value)})"
    if isinstance(value, (frozenset, set)):
        return f"{type(value).__name__}({','.join(sorted(_spec(v) for v in value))})"
    if isinstance(value, dict):
        return f"dict({','.join(_spec(k) + ':' + _spec(v) for k, v in value.items())})"
    if isinstance(value, type):
        return f"type:{_owned(value)}"
    if isinstance(value, enum.Enum):
        return f"{_spec(type(value))}.{value.name}"
    if isinstance(value, np.dtype):
        return f"dtype:{value.str}"
    if isinstance(value, (types.FunctionType, types.BuiltinFunctionType)):
        return f"function:{_owned(value)}"
    if isinstance(value, functools.partial):
        return f"partial({_spec(value.func)},{_spec(value.args)},{_spec(value.keywords)})"
    if hasattr(value, "value") and type(value).__name__ == "_Static":  # bsjax._boundary's marker
        return f"static({_spec(value.value)})"
    if value is eqx._module._flatten.MISSING:  # pyright: ignore[reportAttributeAccessIssue]
        return "MISSING"
    if type(value).__name__ == "AxisEnv" and not value.axis_sizes:  # the empty axis environment
        return "AxisEnv()"
    raise _Unkeyable(type(value).__qualname__)


def _owned(obj) -> str:
    """`module.qualname` of a class or function of bsjax or a library (not the user's: its code
    may change between processes, its name would not)."""
    module, name = getattr(obj, "__module__", None) or "", obj.__qualname__
    if module.split(".")[0] not in _OWNERS or "<" in name:  # <locals>, <lambda>
        raise _Unkeyable(f"{module}.{name}")
    return f"{module}.{name}"


def _tree(treedef) -> str:
    """The text of a pytree structure: node types and their static data, recursively."""
    node = treedef.node_data()
    if node is None:
        return "*"
    kind, data = node
    return f"{_spec(kind)}[{_spec(data)}]({','.join(_tree(c) for c in treedef.children())})"


@functools.cache
def _source_digest() -> str:
    """A digest of every `.py` file of the installed bsjax package."""
    root = Path(__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _environment(options) -> str:
    from jax._src import config

    device = jax.devices()[0]
    return repr(
        (
            _source_digest(),
            sys.version,
            jax.__version__,
            jaxlib.__version__,  # pyright: ignore[reportPrivateImportUsage]
            eqx.__version__,
            np.__version__,
            device.platform,
            device.device_kind,
            device.client.platform_version,
            os.environ.get("XLA_FLAGS", ""),
            os.environ.get("EQX_ON_ERROR", ""),
            sorted((options or {}).items()),
            _spec(config.trace_context()),
        )
    )


def stored(jitted, fn, treedef, static, options):
    """`jitted` (a direct call's `jax.jit` of the boundary's core on its traced leaves, for the
    call structure `treedef` and static leaves `static`) as a `Stored` program, or `jitted`
    itself where the store is off, the process has several devices, JAX's jit is off or re-runs
    programs op by op (its NaN/Inf checks), or something in the call cannot be keyed by value."""
    cfg = jax.config
    if (
        _directory is None
        or jax.local_device_count() != 1
        or cfg.jax_disable_jit
        or cfg.jax_debug_nans
        or cfg.jax_debug_infs  # pyright: ignore[reportAttributeAccessIssue]
    ):
        return jitted
    try:
        signature = (fn.__module__, fn.__qualname__, _tree(treedef), _spec(static), _environment(options))
    except _Unkeyable as err:
        _LOG.debug("%s: not stored (%s cannot be keyed)", fn.__qualname__, err)
        return jitted
    return Stored(jitted, repr(signature), _directory)


class Stored:
    """A direct call's program, `jitted` (a `jax.jit` of the boundary's core on the list of
    traced leaves) compiled once per shape signature, each loaded from or saved to disk."""

    def __init__(self, jitted, signature: str, directory: Path):
        self.jitted, self._signature, self._directory = jitted, signature, directory
        self._compiled: dict = {}
        self._last = self._last_key = None

    def __call__(self, dynamic):
        from jax._src import config

        context = config.trace_context()
        if self._last is not None and context == self._last_key:
            try:
                return self._last(dynamic)
            except TypeError as err:  # another shape or dtype than the last call's
                if not str(err).startswith(_MISMATCH):
                    raise
        avals = tuple(jax.typeof(x) for x in dynamic)
        compiled = self._compiled.get((context, avals))
        if compiled is None:
            compiled = self._compiled[context, avals] = self._load_or_compile(dynamic, avals)
        self._last, self._last_key = compiled, context
        return compiled(dynamic)

    def _cache_size(self) -> int:
        """The number of programs held (compiled or loaded), as `jax.jit`'s method of that name."""
        return len(self._compiled)

    def _load_or_compile(self, dynamic, avals):
        from jax._src import config

        text = repr((self._signature, _spec(config.trace_context()), avals))
        path = self._directory / (hashlib.sha256(text.encode()).hexdigest() + SUFFIX)
        compiled = _load(path)
        if compiled is None:
            hits = _JAX_CACHE.hits
            compiled = self.jitted.lower(dynamic).compile()
            if _JAX_CACHE.hits == hits:  # compiled here, not loaded from JAX's cache (below)
                _save(path, compiled)
        return compiled


class _JaxCacheHits(threading.local):
    """This thread's count of JAX's persistent-cache hits. An executable JAX loaded from its cache
    is not stored: jaxlib 0.10's XLA:CPU serialises such an executable without its kernels (the
    copy fails with `NOT_FOUND: Function … not found`), so only programs compiled in this process
    are. A program already in JAX's cache but not here keeps loading from there."""

    hits = 0


_JAX_CACHE = _JaxCacheHits()


def _count_hits(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _JAX_CACHE.hits += 1


jax.monitoring.register_event_listener(_count_hits)


class _Pickler(pickle.Pickler):
    """Pickles equinox's `MISSING` sentinel (in a module's static data) by name: unflattening
    compares it by identity."""

    def persistent_id(self, obj):
        return "MISSING" if obj is eqx._module._flatten.MISSING else None  # pyright: ignore[reportAttributeAccessIssue]


class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid):
        if pid != "MISSING":
            raise pickle.UnpicklingError(pid)
        return eqx._module._flatten.MISSING  # pyright: ignore[reportAttributeAccessIssue]


def _save(path: Path, compiled) -> None:
    """Write `compiled` to `path` (atomically: another process reads the whole entry or none);
    a program JAX cannot serialise is left unstored."""
    from jax.experimental import serialize_executable

    try:
        payload, in_tree, out_tree = serialize_executable.serialize(compiled)
        buffer = io.BytesIO()
        _Pickler(buffer).dump((payload, in_tree, out_tree))
    except (ValueError, NotImplementedError, TypeError, pickle.PicklingError) as err:
        _LOG.debug("%s: not stored (%s)", path.name, err)
        return
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        partial.write_bytes(buffer.getvalue())
        os.replace(partial, path)
    except OSError as err:  # a full or read-only disk: the program still runs
        _LOG.debug("%s: not stored (%s)", path.name, err)
        partial.unlink(missing_ok=True)


def _load(path: Path):
    """The compiled program stored at `path`, or None (absent, or unreadable: then removed, and
    the program compiled again and stored, or loaded from JAX's cache)."""
    from jax.experimental import serialize_executable

    try:
        data = path.read_bytes()
    except OSError:
        return None
    try:
        payload, in_tree, out_tree = _Unpickler(io.BytesIO(data)).load()
        compiled = serialize_executable.deserialize_and_load(payload, in_tree, out_tree)
    except Exception as err:  # any unreadable entry is compiled again
        _LOG.debug("%s: unreadable, removed (%s)", path.name, err)
        path.unlink(missing_ok=True)
        return None
    os.utime(path)  # recently used: `bsjax._cache.trim` keeps it
    return compiled
