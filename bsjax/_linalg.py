"""Linear solvers shared by the physics (`mss.implicit_step`) and the VSOFM (`vsofm.fit`).

One conjugate-gradient loop: a fixed iteration budget (the cost per call is bounded and known in
advance — the haptic loop's requirement — and reverse-mode differentiation goes through the
unrolled iterations), an optional Jacobi (diagonal) preconditioner and divisions that stay finite
when the residual vanishes (`bsjax._safe.ratio`).

lineax's `CG` solves the same systems, but stops on a tolerance inside a `while_loop` (norms
and a convergence test every iteration); a fixed budget written out here is cheaper per
iteration. Derivatives of a solve from zero are those of the solution (`jax.lax.custom_linear_solve`:
the same fixed-budget CG applied to the tangent's right-hand side), not of the iterations: the
iterations' own derivative divides vanishing quantities once the residual is small (`α = rᵀz /
pᵀAp` with both → 0) and grows without bound over a rollout of steps (a lightly loaded steel
spoon: 1e12 after 80 steps).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from bsjax import _safe


def cg(
    matvec: Callable[[Array], Array],
    b: Float[Array, "..."],
    iterations: int,
    x0: Float[Array, "..."] | None = None,
    inv_diag: Float[Array, "..."] | None = None,
) -> Float[Array, "..."]:
    """`iterations` steps of (preconditioned) conjugate gradients for `A x = b`, `A` symmetric
    positive (semi-)definite; without `x0`, differentiated as the solution `x = A⁻¹ b` (module
    docstring), with `x0` through the iterations.

    **Arguments:**
    - `matvec`: `w ↦ A w` on arrays shaped like `b` (any shape; inner products run over all
      entries).
    - `b`: right-hand side.
    - `iterations`: fixed number of iterations (a static int ≥ 0); no early exit.
    - `x0`: initial guess (default 0).
    - `inv_diag`: `1 / diag(A)` shaped like `b`, the Jacobi preconditioner `M⁻¹` (default none).

    **Returns:** the iterate `x_k`, shaped like `b`.

    Hestenes & Stiefel, *Methods of conjugate gradients for solving linear systems* (1952), in
    the preconditioned form of Shewchuk, *An introduction to the conjugate gradient method
    without the agonizing pain*, §B3: `α = rᵀz / pᵀAp`, `x += α p`, `r −= α Ap`, `z = M⁻¹ r`,
    `β = r'ᵀz' / rᵀz`, `p = z + β p`. A step whose `pᵀAp ≤ 0` (the solution reached, or a
    semi-definite direction) or whose `rᵀz = 0` moves by 0 instead of dividing by zero.
    """
    if x0 is None:
        solve = lambda mv, rhs: _iterate(mv, rhs, iterations, None, inv_diag)
        return jax.lax.custom_linear_solve(matvec, b, solve, symmetric=True)
    return _iterate(matvec, b, iterations, x0, inv_diag)


def _iterate(matvec, b, iterations: int, x0, inv_diag):
    """The iterations of `cg`."""
    precondition = (lambda r: r) if inv_diag is None else (lambda r: inv_diag * r)
    x = jnp.zeros_like(b) if x0 is None else x0
    r = b if x0 is None else b - matvec(x0)
    z = precondition(r)

    def body(_, carry):
        x, r, p, rz = carry
        ap = matvec(p)
        alpha = _safe.ratio(rz, jnp.maximum(jnp.sum(p * ap), 0.0))
        x = x + alpha * p
        r = r - alpha * ap
        z = precondition(r)
        rz_new = jnp.sum(r * z)
        beta = _safe.ratio(rz_new, jnp.maximum(rz, 0.0))
        return x, r, z + beta * p, rz_new

    return jax.lax.fori_loop(0, iterations, body, (x, r, z, jnp.sum(r * z)))[0]
