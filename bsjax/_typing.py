"""Annotation aliases: what the public functions accept.

`ArrayLike`: anything that becomes an array — JAX or numpy arrays, scalars, and (nested) lists or
tuples of numbers; jaxtyping's `ArrayLike` without the sequences would refuse plain lists, which
every public function accepts.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeAlias

from jaxtyping import ArrayLike as _ArrayLike

ArrayLike: TypeAlias = _ArrayLike | Sequence[Any]
