"""Tests run in float64 with strict dtype promotion (geometry needs the precision)."""

import sys
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).parent))  # tests import helpers.py

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
