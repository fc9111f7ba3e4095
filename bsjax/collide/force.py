"""Contact forces: Gao & Gibson's distributed springs (paper 002 §3.2.2–3.2.3).

Each contact sample i is a spring of stiffness k compressed by its depth d_i. The force on the
tool has magnitude `k Σ d_i` (plus damping `−c ṡ` per spring) and the direction of the
depth-weighted sum of normals: the surface normals (**surface-normal method**, smooth on
smooth surfaces and consistent when the probe passes through a wall) or the reversed outward
normals of the probe at the contacts (**probe-normal method**, no jumps at sharp edges). The
surface receives equal and opposite forces, per sample and then per lattice node.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks
from bsjax._tensor import unit

METHODS = ("surface_normal", "probe_normal")


def _direction(contact, method: str):
    if method not in METHODS:
        _checks.fail("method", f"one of {METHODS}", repr(method))
    w = contact.depth[..., None]
    normals = contact.normals if method == "surface_normal" else -contact.tool_normals
    return unit(jnp.sum(w * normals, axis=(0, 1)))


def _magnitudes(contact, stiffness, damping, velocity, direction):
    """Per-sample spring forces along `direction`: `k d_i + c ṡ_i`, `ṡ_i = −v·ê` in contact."""
    _checks.check_positive(stiffness, "stiffness", strict=False)
    _checks.check_positive(damping, "damping", strict=False)
    dtype = contact.depth.dtype
    k = jnp.asarray(stiffness, dtype)
    c = jnp.asarray(damping, dtype)
    spring = k * contact.depth
    if velocity is None:
        return spring
    v = jnp.asarray(velocity, dtype)
    if v.shape != (3,):
        _checks.fail("velocity", "shape (3,)", v.shape)
    # ṡ_i: the depth grows while the tool moves against ê; the damper resists that motion
    # (the paper's `F = k s − d ṡ` with s measured along the spring from the tool side).
    closing = -jnp.dot(v, direction)
    return spring + jnp.where(contact.mask, c * closing, 0)


def contact_force(
    contact,
    stiffness: float | Array,
    method: str = "surface_normal",
    damping: float | Array = 0.0,
    velocity: Float[Array, "3"] | None = None,
) -> Float[Array, "3"]:
    """Force on the tool from the distributed contact springs (paper 002 §3.2).

    **Arguments:**
    - `contact`: a `Contact` from `contacts`.
    - `stiffness` k ≥ 0 (N/m per contact sample); `damping` c ≥ 0 (N·s/m per contact sample).
    - `method`: `"surface_normal"` (direction `Σ d_i N_i`, surface normals) or `"probe_normal"`
      (direction `−Σ d_i n_i`, the tool's outward normals at the contacts).
    - `velocity (3,)`: the tool's velocity, for damping (`F = k s − c ṡ` per spring).

    **Returns:** `(3,)` force `ê (k Σ d_i + c Σ_contacts ṡ_i)`, `ṡ_i = −v·ê` the rate at which
    the tool closes in (damping resists penetration); zero without contact.
    Differentiable in the tool pose, size and the control points.
    """
    e = _direction(contact, method)
    return e * jnp.sum(_magnitudes(contact, stiffness, damping, velocity, e))


def sample_forces(
    contact,
    stiffness: float | Array,
    method: str = "surface_normal",
    damping: float | Array = 0.0,
    velocity: Float[Array, "3"] | None = None,
) -> Float[Array, "m n 3"]:
    """Per-sample reaction forces on the surface, equal and opposite to `contact_force`.

    Sample i receives `−ê (k d_i + c ṡ_i)`, so `sample_forces(...).sum((0, 1)) ==
    −contact_force(...)` exactly.
    """
    e = _direction(contact, method)
    return -_magnitudes(contact, stiffness, damping, velocity, e)[..., None] * e


def nodal_forces(
    points: Float[Array, "... 3"], forces: Float[Array, "... 3"], nodes: Float[Array, "N 3"], k: int = 1
) -> Float[Array, "N 3"]:
    """Spread point forces onto the nearest lattice nodes (for the mass-spring system, SPEC §3).

    **Arguments:** `points (..., 3)` where the forces act (e.g. `contact.points`), `forces
    (..., 3)` (e.g. `sample_forces`), `nodes (N, 3)` node positions, `k` (static) nearest nodes
    per point, weighted by inverse distance (weights sum to 1, so the total force is kept).

    **Returns:** `(N, 3)` summed nodal forces.
    """
    _checks.check_ndim(nodes, "nodes", 2, last=3)
    if np.shape(points) != np.shape(forces):
        _checks.fail("forces", f"the shape of points {np.shape(points)}", np.shape(forces))
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= nodes.shape[0]:
        _checks.fail("k", f"an int in [1, {nodes.shape[0]}]", k)
    p, f = points.reshape(-1, 3), forces.reshape(-1, 3)
    d2 = jnp.sum((p[:, None, :] - nodes[None, :, :]) ** 2, -1)
    neg, idx = jax.lax.top_k(-jax.lax.stop_gradient(d2), k)
    if k == 1:
        w = jnp.ones(neg.shape, f.dtype)
    else:
        dist = jnp.sqrt(jnp.maximum(-neg, 0))
        exact = dist <= jnp.finfo(dist.dtype).eps
        # inverse-distance weights; a point sitting on a node gives it everything
        inv = jnp.where(exact, 0, 1 / jnp.where(exact, 1, dist))
        inv = jnp.where(jnp.any(exact, 1, keepdims=True), exact.astype(dist.dtype), inv)
        w = (inv / jnp.sum(inv, 1, keepdims=True)).astype(f.dtype)
    contrib = (w[..., None] * f[:, None, :]).reshape(-1, 3)
    return jax.ops.segment_sum(contrib, idx.reshape(-1), num_segments=nodes.shape[0])
