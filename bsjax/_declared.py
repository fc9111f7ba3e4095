"""The arguments' declared kinds, checked before a public function runs (or is traced).

A parameter annotated with a bsjax type (`Lattice`, `Blending`, `BSplineCurve`, …), a plain
`float`, `int`, `bool` or `str`, or a union of those with `None`, gets that kind checked at the
call: a `TypeError` naming the parameter, with what was expected and what came
(`lattice: expected a Lattice, got str`). Arrays, callables, sequences and every other annotation
are the function's own checks (`bsjax._checks`). `float` admits ints and 0-d real arrays (tracers
too); no kind admits a bool but `bool`. `bsjax._boundary.compiled` checks every compiled public
function so; `declared` decorates the public functions that are not compiled. Imports no JAX.
"""

from __future__ import annotations

import collections.abc
import functools
import inspect
import os
import pathlib
import types
import typing
from collections.abc import Callable

import numpy as np

_SCALARS = {
    float: ("a real number", lambda v: _real_scalar(v, floats=True)),
    int: ("an int", lambda v: _real_scalar(v, floats=False)),
    bool: ("True or False", lambda v: isinstance(v, (bool, np.bool_))),
    str: ("a string", lambda v: isinstance(v, str)),
}


def _real_scalar(value, floats: bool) -> bool:
    """An integer (a Python or numpy int, or an array of an integer dtype — a tracer too), or
    with `floats` also a real float; never a bool, never complex."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    if isinstance(value, (float, np.floating)):
        return floats
    dtype = getattr(value, "dtype", None)
    return dtype is not None and np.dtype(dtype).kind in ("iuf" if floats else "iu")


def _bsjax_class(hint) -> bool:
    return isinstance(hint, type) and hint.__module__.startswith("bsjax")


class _Kind(typing.NamedTuple):
    """What an argument must be: `what` in words, `test(value)`, and for a sequence the kind of
    its elements (`items`), so that a bad element is named by its index."""

    what: str
    test: Callable[[object], bool]
    items: _Kind | None = None
    options: tuple = ()  # a `Literal`'s values: another value of their type is a ValueError

    def check(self, value, name: str) -> None:
        if self.test(value):
            return
        if self.items is not None and isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                self.items.check(item, f"{name}[{i}]")
        wrong_value = any(type(value) is type(option) for option in self.options)
        raise (ValueError if wrong_value else TypeError)(f"{name}: expected {self.what}, got {_shown(value)}")


def _shown(value) -> str:
    return repr(value) if isinstance(value, (str, int, float, complex)) else type(value).__name__


def _member(hint) -> _Kind | None:
    """The kind of one member of an annotation, or None when not checked here."""
    if hint is type(None):
        return _Kind("None", lambda v: v is None)
    if hint in _SCALARS:
        return _Kind(*_SCALARS[hint])
    if typing.get_origin(hint) is typing.Literal:
        options = typing.get_args(hint)
        what = "one of " + ", ".join(map(repr, options))
        return _Kind(what, lambda v: any(type(v) is type(o) and v == o for o in options), options=options)
    if hint in (os.PathLike, pathlib.Path):
        return _Kind("a path", lambda v: isinstance(v, os.PathLike))
    if hint is collections.abc.Callable or typing.get_origin(hint) is collections.abc.Callable:
        return _Kind("a callable", callable)
    if _bsjax_class(hint):
        article = "an" if hint.__name__[0] in "AEIOU" else "a"
        return _Kind(f"{article} {hint.__name__}", lambda v: isinstance(v, hint))
    items = typing.get_args(hint)
    if typing.get_origin(hint) is tuple and len(items) == 2 and items[1] is Ellipsis:
        items = items[:1]  # `tuple[X, ...]`: a sequence of X
    if typing.get_origin(hint) in (collections.abc.Sequence, list, tuple) and len(items) == 1:
        inner = _declared_kind(items[0])
        if inner is not None:
            test = inner.test
            return _Kind(
                f"a sequence of {inner.what.removeprefix('a ').removeprefix('an ')}",
                lambda v: isinstance(v, (list, tuple)) and all(map(test, v)),
                inner,
            )
    return None


def _declared_kind(hint) -> _Kind | None:
    """The kind of an annotation the boundary checks — a bsjax type, a plain
    `float`/`int`/`bool`/`str`, a path, a callable, a sequence of those, or a union of those
    (with `None`) — else None (arrays and every other annotation are the function's own)."""
    union = typing.get_origin(hint) in (typing.Union, types.UnionType)
    found = [_member(m) for m in (typing.get_args(hint) if union else (hint,))]
    members = [m for m in found if m is not None]
    if not members or len(members) < len(found):
        return None
    if len(members) == 1:
        return members[0]
    tests = [m.test for m in members]
    options = tuple(o for m in members for o in m.options)
    sequences = [m.items for m in members if m.items is not None]
    items = sequences[0] if len(sequences) == 1 else None
    return _Kind(
        " or ".join(m.what for m in members), lambda v: any(test(v) for test in tests), items, options
    )


def declared_kinds(fn) -> tuple[tuple[int, str, _Kind], ...]:
    """`(position, name, kind)` of each parameter of `fn` with a checked kind."""
    found = []
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    for position, (name, parameter) in enumerate(inspect.signature(fn).parameters.items()):
        hint = _resolved(fn, name)
        kind = None if hint is None or name == "self" else _declared_kind(hint)
        if kind is not None and parameter.kind in (*positional, inspect.Parameter.KEYWORD_ONLY):
            # a keyword-only parameter (after `*args` too) is found by name only
            found.append((position if parameter.kind in positional else -1, name, kind))
    return tuple(found)


def _resolved(fn, name: str):
    """The annotation of parameter `name` of `fn`, evaluated in `fn`'s module."""
    return _evaluated(getattr(fn, "__annotations__", {}).get(name), getattr(fn, "__globals__", {}))


def _evaluated(hint, namespace: dict):
    """An annotation, evaluated in `namespace` when it is a string (None when it is missing or
    does not evaluate there, e.g. a name imported only for type checkers)."""
    if not isinstance(hint, str):
        return hint
    try:
        return eval(hint, namespace)  # the library's own annotations
    except Exception:
        return None


def check_declared(declared, args, kwargs) -> None:
    """Raise a `TypeError` naming the first argument (or element of a sequence argument) that is
    not of its declared kind."""
    for position, name, kind in declared:
        if 0 <= position < len(args):
            kind.check(args[position], name)
        elif name in kwargs:
            kind.check(kwargs[name], name)


def check_fields(module) -> None:
    """`__check_init__` of a public `eqx.Module` built by users: each field annotated with a
    checked kind is checked as an argument would be (`name: expected …`), and each field
    annotated as an array holds real numbers (`_checks.check_real`: no string, object, complex or
    boolean array); None passes where the annotation allows it. Values (NaN, ranges) are the
    class's own checks."""
    from bsjax import _checks

    for name, kind in _field_kinds(type(module)):
        value = getattr(module, name)
        if kind is not None:
            kind.check(value, name)
        elif value is not None and not _bsjax_class(type(value)):
            _checks.check_real(value, name)


@functools.cache
def _field_kinds(cls: type) -> tuple[tuple[str, _Kind | None], ...]:
    """`(name, kind)` of each checked field of `cls`, read once per class: the field's declared
    kind, or None for a field annotated as an array (checked for real numbers)."""
    import dataclasses

    namespace = vars(inspect.getmodule(cls))
    found = []
    for field in dataclasses.fields(cls):
        hint = _evaluated(field.type, namespace)
        kind = None if hint is None else _declared_kind(hint)
        if kind is not None or "Array" in str(hint):
            found.append((field.name, kind))
    return tuple(found)


def declared(fn: Callable) -> Callable:
    """Decorator for a public function that is not compiled: its arguments' declared kinds
    (a bsjax type, `float`, `int`, `bool`, `str`, optionally `None`) are checked before it runs,
    as `compiled` checks them — a `TypeError` naming the argument."""
    kinds = None

    @functools.wraps(fn)
    def checked(*args, **kwargs):
        nonlocal kinds
        if kinds is None:
            kinds = declared_kinds(fn)
        check_declared(kinds, args, kwargs)
        return fn(*args, **kwargs)

    return checked
