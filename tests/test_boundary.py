"""The compiled public boundary (`bsjax._boundary`): full-precision matrix products.

On GPUs JAX's default matmul precision lets float32 products run in TF32 (a 10-bit mantissa),
which moved evaluated points by ~1e-3 on an H200. Every compiled public function is traced with
`jax.default_matmul_precision("highest")`; the property is read off the lowered program, so it
holds on any backend (on CPU the flag changes no number).
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import collide
from bsjax.basis import BSplineSurface, clamped_knots


def _dot_precisions(fn, *args) -> list[str]:
    """The `precision` of every `dot_general` in the StableHLO of `jax.jit(fn)(*args)`."""
    text = jax.jit(fn).lower(*args).as_text()
    dots = [line for line in text.splitlines() if "stablehlo.dot_general" in line]
    return [m.group(1) if (m := re.search(r"precision = \[([^\]]*)\]", d)) else "DEFAULT" for d in dots]


@pytest.fixture(scope="module")
def surface():
    ctrl = np.random.default_rng(3).normal(size=(6, 6, 3)).astype(np.float32)
    return BSplineSurface(ctrl, clamped_knots(6, 3), clamped_knots(6, 3), 3, 3)


CALLS = {
    "Blending.points": lambda b, c: b.points(c),
    "Blending.normals": lambda b, c: b.normals(c),
    "Blending.refit": lambda b, c: b.refit(b.points(c)),
    "collide.contacts": lambda b, c: collide.contacts(b, c, collide.Sphere(jnp.zeros(3, c.dtype), 0.5)).depth,
}


@pytest.mark.parametrize("name", list(CALLS))
def test_public_products_run_at_full_precision_inside_a_callers_jit(surface, name):
    blending = surface.blending(12, 12)
    with jax.default_matmul_precision("bfloat16"):  # the caller's own, cheapest setting
        precisions = _dot_precisions(lambda c: CALLS[name](blending, c), jnp.asarray(surface.ctrl))
    assert precisions, f"{name}: no matrix product found"
    assert set(precisions) == {"HIGHEST, HIGHEST"}, f"{name}: {precisions}"


def test_the_check_reads_a_default_product():
    """The reader above sees a product at the caller's precision (the test can fail)."""
    a = jnp.ones((3, 3), jnp.float32)
    with jax.default_matmul_precision("bfloat16"):
        precisions = _dot_precisions(lambda x: x @ x, a)
    assert len(precisions) == 1 and "HIGHEST" not in precisions[0]
