"""The programs of a direct call of a public function (`Program`), kept whole on disk: a
second process runs a public function's first call without tracing, lowering or compiling it.

A `Program` compiles one program per trace context and shape signature ahead of time
(`jax.jit(...).lower(...).compile()`) and calls it through JAX's compiled fast path (the same
per-call cost as `jax.jit`'s). Each program carries the failure messages of its value checks
(`bsjax._checks.collecting`: code k is the program's k-th message), so a program compiled in
another process reports its failures in the same words.

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
_MISMATCH = (
    "Argument types differ",
    "Function compiled with input pytree",
    "Computation compiled for",
    "Computation was compiled for input",  # shardings: an array on another device
)
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
        )
    )


class Program:
    """The programs of one direct call structure of a public function (`bsjax._boundary`): one
    compiled program per trace context, shape signature and argument placement (an array
    committed to another device gets a program there, as under `jax.jit`), with the failure
    messages of its value checks (`bsjax._checks.collecting`), each loaded from the store or
    compiled (and stored) on its first call.

    `make_core()` returns a new function of the list of traced leaves (a new function per
    lowering, so JAX traces it afresh and its `messages` — set while tracing — belong to that
    lowering); `key_parts` `(fn, treedef, static)` key the store (static leaves unwrapped);
    `options` are the compiler options. A call returns `(the program's result, its failure
    messages)`.
    """

    def __init__(self, make_core, key_parts, options):
        self._make_core, self._key_parts, self.compiler_options = make_core, key_parts, options
        self._compiled: dict = {}
        self._last = self._last_context = None
        # one device: the last call's program takes the call whenever its shapes fit (a compiled
        # program would move an uncommitted array to its own device: with several, look up each)
        self._fast = jax.device_count() == 1

    def __call__(self, dynamic):
        from jax._src import config

        if jax.config.jax_disable_jit:  # pyright: ignore[reportAttributeAccessIssue]  (JAX's debugging switch)
            core = self._make_core()
            return core(dynamic), tuple(core.messages)
        context = config.trace_context()
        if self._fast and self._last is not None and context == self._last_context:
            try:
                return self._last[0](dynamic), self._last[1]
            except (TypeError, ValueError) as err:  # another shape, dtype or device than the last call's
                if not str(err).startswith(_MISMATCH):
                    raise
        avals = tuple((jax.typeof(x), x.sharding if isinstance(x, jax.Array) else None) for x in dynamic)
        entry = self._compiled.get((context, avals))
        if entry is None:
            entry = self._compiled[context, avals] = self._load_or_compile(dynamic, avals)
        self._last, self._last_context = entry, context
        return entry[0](dynamic), entry[1]

    def lower(self, dynamic):
        """The lowered program of a call on `dynamic` (traced afresh; `jax.stages.Lowered`)."""
        return self._lower(dynamic)[0]

    def _lower(self, dynamic):
        core = self._make_core()
        lowered = jax.jit(core, compiler_options=self.compiler_options).lower(dynamic)
        return lowered, tuple(core.messages)

    def _cache_size(self) -> int:
        """The number of programs held (compiled or loaded), as `jax.jit`'s method of that name."""
        return len(self._compiled)

    def _load_or_compile(self, dynamic, avals):
        path = self._path(avals)
        if path is not None and (entry := _load(path)) is not None:
            return entry
        lowered, messages = self._lower(dynamic)
        hits = _JAX_CACHE.hits
        compiled = lowered.compile()
        if path is not None and _JAX_CACHE.hits == hits:  # compiled here, not loaded from JAX's cache
            _save(path, compiled, messages)
        return compiled, messages

    def _path(self, avals) -> Path | None:
        """Where the program of `avals` is stored, or None where the store is off, the process
        has several devices, JAX re-runs programs op by op (its NaN/Inf checks), or something
        in the call cannot be keyed by value."""
        from jax._src import config

        cfg = jax.config
        if _directory is None or jax.local_device_count() != 1 or cfg.jax_debug_nans or cfg.jax_debug_infs:  # pyright: ignore[reportAttributeAccessIssue]
            return None
        if self._signature is None:
            return None
        try:
            text = repr((self._signature, _spec(config.trace_context()), avals))
        except _Unkeyable:  # a trace context of another kind than JAX's own (not at the top level)
            return None
        return _directory / (hashlib.sha256(text.encode()).hexdigest() + SUFFIX)

    @functools.cached_property
    def _signature(self) -> str | None:
        """The part of the store's key fixed by the call structure (module docstring), or None
        when something in it cannot be keyed by value."""
        fn, treedef, static = self._key_parts
        try:
            parts = (fn.__module__, fn.__qualname__, _tree(treedef), _spec(static))
        except _Unkeyable as err:
            _LOG.debug("%s: not stored (%s cannot be keyed)", fn.__qualname__, err)
            return None
        return repr((*parts, _environment(self.compiler_options)))


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


def _save(path: Path, compiled, messages: tuple[str, ...]) -> None:
    """Write `compiled` to `path` (atomically: another process reads the whole entry or none);
    a program JAX cannot serialise is left unstored."""
    from jax.experimental import serialize_executable

    try:
        payload, in_tree, out_tree = serialize_executable.serialize(compiled)
        lapack = b"lapack_" in payload  # a custom call of jaxlib's LAPACK kernels (by name)
        buffer = io.BytesIO()
        _Pickler(buffer).dump((payload, in_tree, out_tree, messages, lapack))
    except Exception as err:  # a host callback, a constant argument, …: JAX cannot serialise it
        _LOG.debug("%s: not stored (%s)", path.name, err)
        return
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        partial.write_bytes(buffer.getvalue())
        os.replace(partial, path)
    except OSError as err:  # a full or read-only disk: the program still runs
        _LOG.debug("%s: not stored (%s)", path.name, err)
        partial.unlink(missing_ok=True)


@functools.cache
def _ensure_kernels() -> None:
    """Give jaxlib's CPU LAPACK kernels their function pointers (from scipy), as lowering a
    linear-algebra operation does: a program loaded untraced that calls one would otherwise
    jump to a null pointer (what `jax.export` does before running a deserialised program).
    Only for the programs that call one (each entry says so): it imports scipy's LAPACK, 0.08 s."""
    from jax._src.lax import linalg

    linalg.initialize_lapack()


def _load(path: Path):
    """`(compiled program, failure messages)` stored at `path`, or None (absent, or unreadable:
    then removed, and the program compiled again and stored, or loaded from JAX's cache)."""
    from jax.experimental import serialize_executable

    try:
        data = path.read_bytes()
    except OSError:
        return None
    try:
        payload, in_tree, out_tree, messages, lapack = _Unpickler(io.BytesIO(data)).load()
        if lapack:  # the program calls jaxlib's LAPACK kernels
            _ensure_kernels()
        compiled = serialize_executable.deserialize_and_load(payload, in_tree, out_tree)
    except Exception as err:  # any unreadable entry is compiled again
        _LOG.debug("%s: unreadable, removed (%s)", path.name, err)
        path.unlink(missing_ok=True)
        return None
    os.utime(path)  # recently used: `bsjax._cache.trim` keeps it
    return compiled, tuple(messages)
