"""The XLA:CPU compiler options of bsjax's programs.

XLA:CPU compiles each fusion either with its MLIR fusion emitters (the default since 2025) or
with its classic LLVM IR emitters (`xla_cpu_use_fusion_emitters=false`). bsjax's programs —
many small fusions inside while loops — compile 20–40 % faster with the classic ones (first
calls in a new process: `collide.contacts` with a triangle mesh 2.40 → 1.61 s,
`surface_contacts` 3.08 → 2.58 s, `vsofm.fit` 1.81 → 1.41 s). Their run time differs either way
(`benchmarks/api.py`, the same calls in one process): `BSplineSurface.evaluate` 0.41 → 0.20 ms,
`mss.simulate` 6.8 → 4.6 ms and `mss.relax` 68 → 45 ms run faster, `merge.refit` 17 → 13 ms;
`merge.deviation` 56 → 91 ms, the triangle-mesh contact 4.0 → 4.7 ms and `vsofm.fit` 321 →
335 ms slower; the rest within noise.

Two places ask for them, neither touching the user's global configuration:

* `boundary_options()`: the compiler options of every program compiled at bsjax's public
  boundary (`bsjax._boundary`), passed per program to `jax.jit(..., compiler_options=)` on CPU.
  A user's own `jit` around bsjax calls compiles with the user's options (the bsjax call is
  inlined there).
* `prefer_quick_compilation()`: the same flag in `XLA_FLAGS` for the processes bsjax starts
  itself (the CLI, the test suite and their subprocesses), so that their other programs (a
  test's own `jit`) compile the same way; it must run before JAX starts its CPU backend.

A flag the user's `XLA_FLAGS` sets is never overridden (`…=true` keeps XLA's default emitters,
in bsjax's programs too).
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

QUICK_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def boundary_options() -> dict[str, bool] | None:
    """The compiler options of a program compiled at bsjax's boundary: `QUICK_FLAGS` on the CPU
    backend, less any flag the process's `XLA_FLAGS` sets; `None` elsewhere (GPU/TPU)."""
    import jax

    if jax.default_backend() != "cpu":
        return None
    names = {flag.split("=")[0] for flag in os.environ.get("XLA_FLAGS", "").split()}
    options = {
        flag.split("=")[0].lstrip("-"): flag.split("=")[1] != "false"
        for flag in QUICK_FLAGS
        if flag.split("=")[0] not in names
    }
    return options or None


def prefer_quick_compilation(
    environ: MutableMapping[str, str] = os.environ, flags: tuple[str, ...] = QUICK_FLAGS
) -> str:
    """Add `flags` (default `QUICK_FLAGS`) to `environ["XLA_FLAGS"]`, each unless a flag of the
    same name is there.

    Takes effect only if called before JAX's first computation in this process (XLA reads its
    flags once, when the backend starts); subprocesses inherit `environ`.

    **Returns:** the resulting `XLA_FLAGS`.
    """
    present = environ.get("XLA_FLAGS", "").split()
    names = {flag.split("=")[0] for flag in present}
    environ["XLA_FLAGS"] = " ".join(present + [flag for flag in flags if flag.split("=")[0] not in names])
    return environ["XLA_FLAGS"]
