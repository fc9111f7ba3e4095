"""Tests run in float64 (geometry needs the precision) with strict dtype and rank promotion.

Every process of a run — both xdist workers, and the CLI, demo and notebook-kernel subprocesses
(they inherit the environment) — shares one persistent compilation cache, `.cache/jax-tests` in
the checkout (`BSJAX_CACHE_DIR` moves it; `off` disables it): a program one of them compiled is
loaded, not compiled again, by the others.
"""

import os
from pathlib import Path

_CACHE = os.environ.setdefault("BSJAX_CACHE_DIR", str(Path(__file__).parents[1] / ".cache" / "jax-tests"))
if _CACHE.strip().lower() not in ("off", "0", "false", "no", "none", ""):
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _CACHE)  # notebook kernels: JAX reads it at import
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402

import bsjax  # noqa: E402

bsjax.enable_compilation_cache()  # this process too (JAX may have been imported before the env)
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")
