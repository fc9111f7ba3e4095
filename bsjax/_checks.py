"""Input validation shared by every public constructor and function.

Two kinds of checks (STYLE "Checks and numerics"):

* **structure** (ndim, lengths, counts, degrees, types): known from shapes, also under `jit`;
  raise `ValueError`/`TypeError` at once (`fail`, `check_ndim`, `check_degree`, `check_count`).
* **values** (finite, positive, monotone, in a range): `finite`, `positive`, `in_range`,
  `monotone`, `clamped_knots`, `check` — each returns its (checked) input, which the caller
  must use in place of the original. On concrete values they raise `ValueError` at once; on
  traced values (inside `jit`, `vmap`, `grad`, or the compiled public boundary) they attach an
  `eqx.error_if` with the *same* message, so the check never switches itself off. Inside the
  compiled boundary's own program they become its failure code instead (`collecting`), and in
  the loop bodies and branches of a program that re-call public methods on values its entry
  checked they are not built at all (`trusted`).
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator
from typing import Any, NoReturn

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

_Tracer = jax.core.Tracer  # pyright: ignore[reportAttributeAccessIssue]  (public, not in the stubs)

try:  # the trace being built now (JAX has no public name for it; without it: always error_if)
    from jax._src.core import trace_ctx as _trace_ctx
except ImportError:  # pragma: no cover
    _trace_ctx = None


def tracing() -> bool:
    """Whether a transformation (`jit`, `vmap`, `grad`, …) is being traced now: then even a call
    on concrete arrays gives traced results."""
    return _trace_ctx is not None and not _trace_ctx.is_top_level()


def is_concrete(x: Any) -> bool:
    """True when no leaf of `x` is a tracer (its values are known now)."""
    return not any(isinstance(leaf, _Tracer) for leaf in jax.tree_util.tree_leaves(x))


def message(name: str, expected: str, got: Any) -> str:
    """The project's standard message: argument name, what was expected, what came."""
    return f"{name}: expected {expected}, got {got}"


def fail(name: str, expected: str, got: Any) -> NoReturn:
    """Raise the project's standard `ValueError`."""
    raise ValueError(message(name, expected, got))


def check(x, bad, name: str, expected: str, got: str, detail=None):
    """`x`, after checking that `bad` (a boolean array) is all False.

    Concrete `bad` → `ValueError` now (its "got" part from `detail(x)` when given: the offending
    values); traced → `report` of the message "name: expected …, got <got>".
    """
    if is_concrete(bad):
        if bool(np.any(np.asarray(bad))):
            fail(name, expected, got if detail is None or not is_concrete(x) else detail(np.asarray(x)))
        return x
    return report(x, jnp.any(bad), message(name, expected, got))


def xp(*arrays):
    """`numpy` when every leaf of `arrays` is concrete, else `jax.numpy`: a check of concrete
    values computes in numpy (no JAX program compiled and dispatched per elementwise test)."""
    return np if is_concrete(arrays) else jnp


def values(x):
    """`x` as a numpy array when concrete (its checks then compute in numpy, as `xp` chooses),
    else `x` itself (a tracer: the checks are traced)."""
    return np.asarray(x) if is_concrete(x) else x


def on_device(tree):
    """The numpy leaves of `tree` (host-side results of an `xp` computation) as JAX arrays, by
    `jax.device_put`, which compiles nothing (`jnp.asarray` compiles a small program per shape
    and dtype); JAX arrays and tracers unchanged, `None` kept."""
    return jax.tree.map(lambda x: x if isinstance(x, jax.Array) else jax.device_put(x), tree)


# --- failures as part of a compiled program's result ---------------------------------------------
class _Collector:
    """The failure codes of one program being traced at the compiled boundary: code k ≥ 1 is
    `messages[k − 1]`, numbered in the program's own order (so a program compiled in another
    process and loaded from disk carries its messages with it: `bsjax._executables`)."""

    def __init__(self):
        self.trace = _trace_ctx.trace if _trace_ctx is not None else None
        self.codes: list = []
        self.messages: list[str] = []

    def here(self) -> bool:
        """Whether the trace being built now is the program's own (not a `vmap`/`scan`/`cond`
        body or a derivative inside it, whose values cannot become the program's result)."""
        return _trace_ctx is not None and _trace_ctx.trace is self.trace

    def add(self, failed, text: str) -> None:
        """Report the traced scalar `failed` as the failure `text`."""
        if text not in self.messages:
            self.messages.append(text)
        self.codes.append(jnp.where(failed, self.messages.index(text) + 1, 0).astype(jnp.int32))

    def code(self):
        """int32 scalar: the first non-zero code in program order, 0 when none."""
        code = jnp.zeros((), jnp.int32)
        for c in reversed(self.codes):
            code = jnp.where(c != 0, c, code)
        return code


_collector: contextvars.ContextVar[_Collector | None] = contextvars.ContextVar("bsjax_checks", default=None)


@contextlib.contextmanager
def collecting() -> Iterator[_Collector]:
    """Inside, traced checks of the program being built add their failure to the collector's
    `code()` instead of an `eqx.error_if` (the compiled boundary returns it beside the result)."""
    collector = _Collector()
    token = _collector.set(collector)
    try:
        yield collector
    finally:
        _collector.reset(token)


def collecting_now() -> bool:
    """Whether a compiled-boundary program is being traced (`collecting`)."""
    return _collector.get() is not None


_trusted: contextvars.ContextVar[bool] = contextvars.ContextVar("bsjax_trusted", default=False)


@contextlib.contextmanager
def trusted() -> Iterator[None]:
    """Inside, traced value checks are not built: for the body of a loop or branch of a compiled
    program (`lax.scan`/`while_loop`/`cond`) that calls public methods on values the program's
    entry already checked (or computed from checked values). There a check could only become an
    `eqx.error_if` — a host callback, so the program could never be stored on disk — for a
    failure the entry rules out. Structure checks (shapes, types) still raise while tracing."""
    token = _trusted.set(True)
    try:
        yield
    finally:
        _trusted.reset(token)


def report(x, failed, text: str):
    """`x`, with the traced scalar `failed` reported as the failure `text`: added to the program's
    failure code when collecting in the program's own trace, else an `eqx.error_if` (nothing
    inside `trusted`)."""
    if _trusted.get():
        return x
    collector = _collector.get()
    if collector is not None and collector.here():
        collector.add(failed, text)
        return x
    if collector is not None and collector.codes:  # in a body of the program: an earlier failed
        failed = failed & (collector.code() == 0)  # check of the program is the one reported
    return eqx.error_if(x, failed, text)


# --- structure --------------------------------------------------------------------------------
def check_ndim(x: Any, name: str, ndim: int, last: int | None = None) -> None:
    """`x` must have `ndim` dimensions (and a trailing size `last` when given)."""
    shape = np.shape(x)
    if len(shape) != ndim:
        fail(name, f"an array with {ndim} dimension(s)", f"shape {shape}")
    if last is not None and shape[-1] != last:
        fail(name, f"trailing dimension {last}", f"shape {shape}")


def check_degree(degree: Any, name: str, n_ctrl: int | None = None, n_name: str = "") -> None:
    """`degree` must be an int ≥ 1 and smaller than the number of control points."""
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
        raise TypeError(f"{name}: expected an int, got {type(degree).__name__}")
    if degree < 1:
        fail(name, "a degree >= 1", degree)
    if n_ctrl is not None and degree >= n_ctrl:
        fail(name, f"a degree smaller than the {n_ctrl} control points along {n_name}", degree)


def check_count(value: Any, name: str, minimum: int = 1) -> int:
    """An int (not a bool) ≥ `minimum` — counts, sizes, steps, derivative orders."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: expected an int >= {minimum}, got {type(value).__name__} {value!r}")
    if value < minimum:
        fail(name, f"an int >= {minimum}", value)
    return int(value)


def check_progress(progress: Any) -> None:
    """A long function's optional `progress(done, total)` callback: a callable or None."""
    if progress is not None and not callable(progress):
        raise TypeError(f"progress: expected a callable progress(done, total) or None, got {progress!r}")


def check_real(x: Any, name: str) -> None:
    """Refuse complex input (it would be truncated to its real part), booleans (not numbers) and
    anything that is not numbers at all (strings, objects, `None`)."""
    if isinstance(x, (str, bytes)):  # numpy would read "0.5" as a string dtype, not a number
        raise TypeError(f"{name}: expected real numbers, got {type(x).__name__} {_short(x)}")
    dtype = getattr(x, "dtype", None)  # tracers too (their dtype is known; their values are not)
    if dtype is None:
        try:
            dtype = np.asarray(x).dtype
        except (TypeError, ValueError):  # ragged nesting
            raise TypeError(f"{name}: expected real numbers, got {type(x).__name__} {_short(x)}") from None
    if not (jnp.issubdtype(dtype, jnp.number) or dtype == np.bool_):  # strings, objects, PRNG keys
        raise TypeError(f"{name}: expected real numbers, got {type(x).__name__} {_short(x)} (dtype {dtype})")
    if np.issubdtype(dtype, np.complexfloating):
        raise TypeError(f"{name}: expected real numbers, got complex dtype {dtype}")
    if dtype == np.bool_:
        raise TypeError(f"{name}: expected real numbers, got booleans")


def check_integer(x: Any, name: str, what: str) -> None:
    """Refuse an array-like `x` that is not of an integer dtype (indices: `what` names them),
    before JAX sees it (a string or an object array has no JAX dtype)."""
    dtype = np.dtype(x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype)
    if dtype.kind not in "iu":
        fail(name, what, f"dtype {dtype}")


def _short(x) -> str:
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


# --- values -----------------------------------------------------------------------------------
def vector3(x: Any, name: str, dtype) -> jax.Array:
    """`x` as a real `(3,)` vector of `dtype` (a point, a direction, a force): its type and shape
    checked (values are the caller's: `finite`, `coordinates`, …)."""
    check_real(x, name)
    x = jnp.asarray(x, dtype)
    check_ndim(x, name, 1, last=3)
    return x


def array(x: Any, name: str, dtype=None) -> jax.Array:
    """`x` as a JAX array (of `dtype`), after `check_real`: a string, an object, a complex or a
    boolean value is refused naming `name` instead of failing inside JAX."""
    check_real(x, name)
    return jnp.asarray(x, dtype)


def finite(x, name: str):
    """`x` with every entry finite."""
    check_real(x, name)
    return check(x, ~xp(x).isfinite(x), name, "finite values", "NaN or inf")


def coordinate_limit(dtype) -> float:
    """The largest coordinate or length bsjax accepts in `dtype`: `√(max float) / 4` (float64
    ≈ 3.4e153, float32 ≈ 4.6e18), so squared distances and sums of them stay finite."""
    return float(np.sqrt(np.finfo(dtype).max) / 4)


def coordinates(x, name: str):
    """`x` with every entry finite and `|x| ≤ coordinate_limit(dtype)` (positions, lengths)."""
    limit = coordinate_limit(x.dtype)
    bad = ~(xp(x).abs(x) <= limit)
    return check(x, bad, name, f"finite values of magnitude <= {limit:.3g}", "NaN, inf or larger", _span)


def positive(x, name: str, strict: bool = True):
    """`x` with every entry finite and > 0 (≥ 0 when `strict=False`)."""
    sign = "> 0" if strict else ">= 0"
    check_real(x, name)
    v = values(x)
    bad = (v <= 0) if strict else (v < 0)
    got = f"a value not {sign} (or NaN/inf)"
    return check(x, bad | ~xp(x).isfinite(v), name, f"finite values {sign}", got, _extreme)


def in_range(x, name: str, lo: float, hi: float):
    """`x` with every entry in `[lo, hi]` (NaN fails)."""
    check_real(x, name)
    v = values(x)
    bad = ~((v >= lo) & (v <= hi))
    return check(x, bad, name, f"values in [{lo}, {hi}]", "a value outside (or NaN)", _span)


def monotone(x, name: str):
    """A 1-D `x`, finite and non-decreasing."""
    x = finite(x, name)
    return check(x, xp(x).diff(x) < 0, name, "a non-decreasing knot vector", "a decrease")


def clamped_knots(knots, degree: int, n_ctrl: int, name: str):
    """A clamped, non-decreasing knot vector of length `n_ctrl + degree + 1` on [0, 1] with
    interior multiplicities ≤ degree."""
    check_ndim(knots, name, 1)
    if knots.shape[0] != n_ctrl + degree + 1:
        fail(name, f"length n_ctrl + degree + 1 = {n_ctrl + degree + 1}", knots.shape[0])
    knots = monotone(knots, name)
    t = values(knots)
    ends = (t[: degree + 1] != 0) | (t[-degree - 1 :] != 1)
    expected = f"a clamped knot vector on [0, 1] ({degree + 1} knots 0 and 1)"
    knots = check(knots, ends, name, expected, "other ends", lambda t: f"[{t[0]}, {t[-1]}]")
    interior = t[degree + 1 : n_ctrl]
    if interior.shape[0] > degree:  # degree + 1 equal consecutive interior knots
        windows = xp(t).stack([interior[i : interior.shape[0] - degree + i] for i in range(degree + 1)])
        too_many = xp(t).all(windows == windows[:1], axis=0)
        knots = check(knots, too_many, name, f"interior knot multiplicity <= degree {degree}", "more")
    return knots


def _extreme(a):
    bad = a[~np.isfinite(a) | (a <= 0)] if a.size else a
    return f"{bad.min() if bad.size else a.min()}"


def _span(a):
    return f"[{np.nanmin(a)}, {np.nanmax(a)}]" if a.size else "[]"


def float_dtype(*xs, names: tuple[str, ...] = ()):
    """The floating dtype to work in: that of the inputs, else JAX's default float.

    Non-numeric and complex inputs are refused (complex would be truncated to its real part),
    naming `names[i]` for input i (`argument i` where none is given)."""
    for i, x in enumerate(xs):
        if x is not None:
            check_real(x, names[i] if i < len(names) else f"argument {i}")
    given = [np.asarray(x) if isinstance(x, (list, tuple)) else x for x in xs if x is not None]
    dtype = jnp.result_type(*given) if given else None
    if dtype is None or not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    return dtype
