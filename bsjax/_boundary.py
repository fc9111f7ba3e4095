"""The compiled public boundary: every public function that computes is traced once per static
configuration and then dispatched as one XLA call, so a direct call (in a notebook or a script)
is as fast as the same call inside the caller's own `jax.jit`.

The rule for what is static and what is traced (the same for every public function):

* traced: JAX and numpy arrays, numpy floating scalars and Python floats (a new value never
  recompiles: a sweep over `dt` or a radius given as Python floats reuses one compilation);
* array-likes: a list (or a tuple holding at least one float) of numbers, nested, becomes a
  numpy array first, so `contacts(b, ctrl.tolist(), …)` works like the array (a tuple of ints,
  e.g. a lattice `shape`, stays static);
* static: everything else — ints (counts, degrees, derivative orders), bools, strings, `None`,
  callables, and the static fields of equinox modules (degrees, grid sizes, method choices).
  A new static value compiles once more. Arguments named in `static=` stay static even when
  they are floats (tolerances used in Python control flow);
* a direct call's `progress` callback (a host-side report, not part of the computation) is
  keyed as "a callback" whatever the callable: the program calls a stand-in (`_RELAY`) that
  forwards to the callback of the call now running, so a new progress bar per call (the CLI's,
  a user's tqdm) reuses the compilation; such a call returns once its results are ready. While
  one call forwards through it, another (a second thread's, or one made from inside a callback)
  keeps its callable as a static argument (a compilation of its own) rather than wait. Inside a
  caller's `jit` the callback is the caller's (static in their program, as any callable).

A direct call runs through an `_executables.Program`: its programs compiled ahead of time, one
per shape signature (and kept whole on disk when the compilation cache is on), called through
JAX's compiled fast path. Value checks inside (`bsjax._checks`) become the program's failure
code there (`_checks.collecting`: an int32 beside the result, whose messages the program
carries), raised here as a `ValueError` with the check's message — the same message the caller
sees inside their own `jit`, where the checks are `eqx.error_if`s (as a `JaxRuntimeError`).
JAX logs every failed host callback with its traceback; the records of bsjax's own checks
(message `name: expected …, got …`) are dropped from that log, since the error itself reaches
the caller.

Every compiled function is traced with `jax.default_matmul_precision("highest")` (`precise`):
on GPUs JAX's default lets float32 products run in TF32 (10-bit mantissa), which puts errors of
~1e-3 into evaluated points and normals; geometry keeps full float32 (on CPU nothing changes).
On an asynchronous backend (GPU, TPU) a direct call waits for its result, so that a failed value
check raises its `ValueError` at the call rather than wherever the result is first read.

This is `eqx.filter_jit`'s idea with less work per call (equinox's bound methods alone cost
~30 µs per attribute access on this machine): `compiled` works on free functions and on methods
of `eqx.Module`s alike. `clear_caches()` drops every compiled entry point (not the disk's).
"""

from __future__ import annotations

import functools
import inspect
import logging
import re
import threading
import weakref
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import numpy as np

from bsjax import _checks, _executables, _xla
from bsjax._declared import check_declared, declared_kinds

# equinox's EQX_ON_ERROR other than "raise" (nan, breakpoint, off) asks for its own handling of
# failed checks: then every check stays an `eqx.error_if`.
_FUNCTIONAL = eqx._config.EQX_ON_ERROR == "raise"  # pyright: ignore[reportPrivateImportUsage]
_ERROR = re.compile(r"_EquinoxRuntimeError: (.*?)(?:\n\n-{10}|\Z)", re.S)
_CHECK_MESSAGE = re.compile(r"^[\w\[\]., ()]+: expected .*, got ", re.S)
_registry: weakref.WeakSet = weakref.WeakSet()
_host_caches: list = []


class _Static:
    """A leaf kept static whatever its type (for `static=` arguments); hashed by value."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value

    def __hash__(self):
        return hash((type(self.value), self.value))

    def __eq__(self, other):
        return (
            isinstance(other, _Static) and type(other.value) is type(self.value) and other.value == self.value
        )


class _QuietChecks(logging.Filter):
    """Drops JAX's log record of a host callback that failed on one of bsjax's value checks (an
    `eqx.error_if` whose message is `name: expected …, got …`): the error reaches the caller."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        return not (type(error).__name__ == "_EquinoxRuntimeError" and _CHECK_MESSAGE.match(str(error)))


logging.getLogger("jax._src.callback").addFilter(_QuietChecks())


def _array_like(value) -> bool:
    """A (nested) list of numbers, or a tuple of numbers holding at least one float."""
    if isinstance(value, list):
        return _numbers(value) is not None
    return isinstance(value, tuple) and _numbers(value) is True


_NUMBER = (int, float, np.integer, np.floating)


def _numbers(seq):
    """None when `seq` is not a nested sequence of real numbers; else whether any is a float."""
    any_float = False
    for item in seq:
        if isinstance(item, (list, tuple)):
            inner = _numbers(item) if item else False
            if inner is None:
                return None
            any_float |= inner
        elif isinstance(item, (bool, np.bool_)) or not isinstance(item, _NUMBER):
            return None
        else:
            any_float |= isinstance(item, (float, np.floating))
    return any_float


def as_arrays(args, kwargs):
    """`(args, kwargs)` with every array-like list (or float tuple) as a numpy array."""
    args = tuple(np.asarray(a) if _array_like(a) else a for a in args)
    if any(_array_like(v) for v in kwargs.values()):
        kwargs = {k: np.asarray(v) if _array_like(v) else v for k, v in kwargs.items()}
    return args, kwargs


def _unwrap(leaf):
    return leaf.value if isinstance(leaf, _Static) else leaf


def is_traced(leaf) -> bool:
    """Whether a leaf of a public call's arguments is traced (arrays, floats) or static."""
    if isinstance(leaf, (bool, np.bool_, _Static)):
        return False
    return isinstance(leaf, (jax.Array, np.ndarray, float, np.floating))


def precise(fn: Callable) -> Callable:
    """`fn` traced with full-precision matrix products (`jax.default_matmul_precision("highest")`:
    no TF32 or bf16 passes on GPUs/TPUs; no effect on CPU)."""

    @functools.wraps(fn)
    def traced(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)

    return traced


@functools.cache
def _asynchronous() -> bool:
    """Whether JAX's default backend runs calls asynchronously to the host (anything but CPU,
    where a failed check already raises at the call)."""
    return jax.default_backend() != "cpu"


def check_failure(err: Exception) -> ValueError | None:
    """The one-line `ValueError` of a failed bsjax value check (`eqx.error_if`) that a JAX runtime
    error carries, or None when `err` is something else."""
    found = _ERROR.search(str(err))
    return None if found is None else ValueError(found.group(1).strip())


class _Relay:
    """The stand-in for a direct call's `progress` callback in its program (module docstring):
    calls the callback of the direct call now running."""

    def __init__(self):
        self._lock = threading.Lock()  # one direct call forwards through it at a time
        self._target: Callable | None = None

    def __call__(self, *args):
        if self._target is not None:
            return self._target(*args)
        return None

    def take(self, target: Callable) -> bool:
        """Forward to `target` until `release`; False (nothing taken) while another call
        forwards — that call's callback then stays its own static argument (a compilation
        of its own), so neither waits for the other."""
        if not self._lock.acquire(blocking=False):
            return False
        self._target = target
        return True

    def release(self) -> None:
        self._target = None
        self._lock.release()

    def __repr__(self) -> str:
        return "<the running direct call's progress callback>"


_RELAY = _Relay()


class _Compiled:
    """A function compiled at the public boundary (see the module docstring)."""

    def __init__(self, fn: Callable, static: tuple[str, ...] = ()):
        functools.update_wrapper(self, fn)
        self.__qualname__: str = fn.__qualname__
        self._fn = fn
        self._cache: dict = {}
        self._static = self._static_positions(fn, static)
        names = list(inspect.signature(fn).parameters)
        self._progress_at = names.index("progress") if "progress" in names else None
        self._declared = None  # the checked argument kinds, read from the annotations on first call
        _registry.add(self)

    @staticmethod
    def _static_positions(fn, static):
        if not static:
            return ()
        names = list(inspect.signature(fn).parameters)
        missing = [s for s in static if s not in names]
        if missing:
            raise TypeError(f"static: {missing} are not parameters of {fn.__qualname__}")
        return tuple((names.index(s), s) for s in static)

    def _mark_static(self, args, kwargs):
        args = list(args)
        for pos, name in self._static:
            if pos < len(args):
                args[pos] = _Static(args[pos])
            elif name in kwargs:
                kwargs = {**kwargs, name: _Static(kwargs[name])}
        return tuple(args), kwargs

    def _jitted(self, treedef, mask, static, functional: bool, top_level: bool):
        """The compiled form of a call structure: a direct call's `_executables.Program` (its
        programs with their failure messages, kept on disk where they may be), or inside the
        caller's trace a `jax.jit` (inlined in the caller's program)."""
        key = (treedef, mask, static, functional, top_level)
        jitted = self._cache.get(key)
        if jitted is None:
            make_core = functools.partial(self._core, treedef, mask, static, functional)
            if top_level:  # compiler options for a program of its own (not one inlined in a jit)
                key_parts = (self._fn, treedef, (mask, tuple(map(_unwrap, static)), functional))
                jitted = _executables.Program(make_core, key_parts, _xla.boundary_options())
            else:
                jitted = jax.jit(make_core())
            self._cache[key] = jitted
        return jitted

    def _core(self, treedef, mask, static, functional: bool):
        """A new function of the traced leaves that calls the public function (with the failure
        code of its checks beside the result when `functional`; the messages of the codes in
        its attribute `messages`, set while it is traced)."""
        fn = precise(self._fn)

        def core(dynamic):
            it = iter(dynamic)
            leaves = [
                next(it) if m else (s.value if isinstance(s, _Static) else s) for m, s in zip(mask, static)
            ]
            args, kwargs = jax.tree_util.tree_unflatten(treedef, leaves)
            if not functional:
                return fn(*args, **kwargs)
            with _checks.collecting() as failures:
                out = fn(*args, **kwargs)
                core.messages = failures.messages
                return out, failures.code()

        core.messages = []
        core.__name__ = core.__qualname__ = self.__qualname__  # compile logs name the entry
        return core

    def __call__(self, *args, **kwargs):
        if self._declared is None:
            self._declared = declared_kinds(self._fn)
        check_declared(self._declared, args, kwargs)
        if _checks.collecting_now():  # inside another compiled program's trace: inlined there,
            args, kwargs = as_arrays(args, kwargs)  # its checks become that program's
            return self._fn(*args, **kwargs)
        if self._static:
            args, kwargs = self._mark_static(args, kwargs)
        args, kwargs = as_arrays(args, kwargs)
        leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
        if any(isinstance(leaf, np.ndarray) and leaf.dtype.kind not in "biuf" for leaf in leaves):
            self._refuse_non_numeric(args, kwargs)
        mask = tuple(is_traced(leaf) for leaf in leaves)
        static = tuple(None if m else leaf for m, leaf in zip(mask, leaves))
        dynamic = [leaf for m, leaf in zip(mask, leaves) if m]
        traced = _checks.tracing() or not _checks.is_concrete(dynamic)  # in the caller's jit/vmap/grad
        functional = not traced and _FUNCTIONAL
        progress = None if traced else self._progress(args, kwargs)
        relayed = progress is not None and _RELAY.take(progress)
        try:
            if relayed:  # keyed as "a callback": the program calls the relay
                leaves = [_RELAY if leaf is progress else leaf for leaf in leaves]
                static = tuple(None if m else leaf for m, leaf in zip(mask, leaves))
            try:
                jitted = self._jitted(treedef, mask, static, functional, not traced)
            except TypeError as err:  # an unhashable static argument
                raise TypeError(f"{self.__qualname__}: static arguments must be hashable ({err})") from None
            if traced:
                return jitted(dynamic)
            out, failure = self._run(jitted, dynamic, functional)
            if relayed:
                jax.block_until_ready(out)  # every report made before the relay moves on
        finally:
            if relayed:
                _RELAY.release()
        if failure:
            raise ValueError(failure)
        return out

    def _progress(self, args, kwargs):
        """The `progress` callback of a call (None when the function has none or it is None)."""
        if self._progress_at is None:
            return None
        at = self._progress_at
        progress = args[at] if at < len(args) else kwargs.get("progress")
        return progress if callable(progress) else None

    def _refuse_non_numeric(self, args, kwargs) -> None:
        """`_checks.check_real` on each argument holding a numpy array of strings, objects or
        complex numbers: its `TypeError` names the parameter (no program is traced for it)."""
        try:
            bound = inspect.signature(self._fn).bind(*args, **kwargs).arguments
        except TypeError:  # a wrong call: let the function itself say so
            return
        for name, value in bound.items():
            for leaf in jax.tree_util.tree_leaves(value):
                if isinstance(leaf, np.ndarray) and leaf.dtype.kind not in "biuf":
                    _checks.check_real(leaf, name)

    @staticmethod
    def _run(program, dynamic, functional: bool):
        """`(result, failure message or "")` of a direct call: the message of the program's
        failure code when `functional`, a failed `eqx.error_if` check inside it raised as its
        `ValueError` otherwise."""
        try:
            out, messages = program(dynamic)
            if functional:
                out, code = out
                code = int(code)  # waits for the program
                return out, messages[code - 1] if code else ""
            if _asynchronous():  # a failed check raises here, not where the result is read
                jax.block_until_ready(out)
            return out, ""
        except (jax.errors.JaxRuntimeError, ValueError) as err:  # the C++ fast path: a ValueError
            failure = check_failure(err)
            if failure is None:
                raise
            raise failure from None

    def __repr__(self) -> str:
        return f"<compiled {self.__qualname__}>"

    def __get__(self, instance, owner=None):
        if instance is None:
            return self
        return functools.partial(self, instance)

    def clear_cache(self) -> None:
        self._cache.clear()


def compiled(fn: Callable | None = None, *, static: tuple[str, ...] = ()) -> Any:
    """Decorator: compile `fn` at the public boundary (module docstring); works on free
    functions and on methods of `eqx.Module`s alike. `static`: parameter names kept static."""
    if fn is None:
        return lambda f: _Compiled(f, tuple(static))
    return _Compiled(fn, tuple(static))


def host_cache(maxsize: int = 64):
    """`functools.lru_cache` for host-side planning keyed by static (hashable) values — topology,
    knot rules, layouts — registered so that `clear_caches()` empties it too."""

    def decorate(fn):
        cached = functools.lru_cache(maxsize=maxsize)(fn)
        _host_caches.append(cached)
        return cached

    return decorate


def register(cache) -> None:
    """Register an object with a `clear_cache()` method (e.g. a plan store) for `clear_caches()`."""
    _registry.add(cache)


def clear_caches() -> None:
    """Forget every compiled public entry point and every registered host-side cache (the next
    call of each compiles or plans again)."""
    for entry in list(_registry):
        entry.clear_cache()
    for cached in _host_caches:
        cached.cache_clear()
