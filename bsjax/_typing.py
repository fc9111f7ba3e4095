"""Annotation aliases: what the public functions accept.

`ArrayLike`: anything that becomes an array — JAX or numpy arrays, scalars, and (nested) lists or
tuples of numbers; jaxtyping's `ArrayLike` without the sequences would refuse plain lists, which
every public function accepts. `HostArray`: a JAX or a numpy array — what a kernel written for
both array modules takes and returns (`bsjax._checks.xp`: numpy on the host when every input is
concrete).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeAlias

import numpy as np
from jax import Array
from jaxtyping import ArrayLike as _ArrayLike

ArrayLike: TypeAlias = _ArrayLike | Sequence[Any]
HostArray: TypeAlias = Array | np.ndarray
