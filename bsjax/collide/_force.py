"""Contact forces: Gao & Gibson's distributed springs.

Gao & Gibson, *Haptic B-spline surface sculpting with a shaped tool of implicit surface*
(§3.2.2–3.2.3): each contact sample i is a spring of stiffness k compressed by its depth d_i.
The force on the tool has magnitude `k Σ d_i` (plus damping `−c ṡ` per spring) and the
direction of the depth-weighted sum of normals: the surface normals (**surface-normal method**,
smooth on smooth surfaces and consistent when the probe passes through a wall) or the reversed
outward normals of the probe at the contacts (**probe-normal method**, no jumps at sharp
edges). The surface receives equal and opposite forces per sample (`sample_forces`).

`contact_force` and `sample_forces` are compiled at the public boundary
(`bsjax._boundary.compiled`): `method` is static, stiffness, damping and velocity are
traced (a new stiffness never recompiles). Values are checked under `jit` too (stiffness and
damping ≥ 0, finite velocity); a force that overflows the dtype raises instead of giving inf/NaN.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax.collide._contact import Contact
from bsjax.collide._penetration import Penetration

METHODS = ("surface_normal", "probe_normal")


def _checked_contact(contact):
    if not isinstance(contact, Contact):
        raise TypeError(f"contact: expected a bsjax.collide.Contact, got {type(contact).__name__}")
    return contact


def _coefficient(value, name: str, dtype):
    """A scalar `value` ≥ 0 and finite (checked at run time too), in `dtype`."""
    _checks.check_real(value, name)
    if np.ndim(value) != 0:
        _checks.fail(name, "a scalar", f"shape {np.shape(value)}")
    return _checks.positive(_checks.array(value, name, dtype), name, strict=False)


def _direction(contact, method: str):
    if method not in METHODS:
        _checks.fail("method", f"one of {METHODS}", repr(method))
    normals = contact.normals if method == "surface_normal" else -contact.tool_normals
    # Σ d_i N_i as a contraction: XLA:CPU runs it as a product, several times faster than a sum
    return _safe.unit(jnp.einsum("ab,abc->c", contact.depth, normals))


def _magnitudes(contact, stiffness, damping, velocity, direction):
    """Per-sample spring forces along `direction`: `k d_i + c ṡ_i`, `ṡ_i = −v·ê` in contact."""
    dtype = contact.depth.dtype
    k = _coefficient(stiffness, "stiffness", dtype)
    c = _coefficient(damping, "damping", dtype)
    spring = k * contact.depth
    if velocity is None:  # a tool at rest: no damping force (and the damping check stays alive)
        velocity = jnp.zeros(3, dtype)
    _checks.check_real(velocity, "velocity")
    if np.shape(velocity) != (3,):
        _checks.fail("velocity", "shape (3,)", np.shape(velocity))
    v = _checks.finite(_checks.array(velocity, "velocity", dtype), "velocity")
    # ṡ_i: the depth grows while the tool moves against ê; the damper resists that motion
    # (the paper's `F = k s − d ṡ` with s measured along the spring from the tool side).
    closing = -jnp.dot(v, direction)
    return spring + jnp.where(contact.mask, c * closing, 0)


def _representable(force):
    """`force`, checked to be finite: a huge stiffness, damping or velocity must not give inf/NaN."""
    expected = f"a force that fits in {force.dtype} (k Σ d_i + c Σ ṡ_i finite)"
    return _checks.check(force, ~jnp.isfinite(force), "stiffness, damping", expected, "an overflow")


@compiled
def contact_force(
    contact: Contact,
    stiffness: float | Array,
    method: str = "surface_normal",
    damping: float | Array = 0.0,
    velocity: Float[Array, "3"] | None = None,
) -> Float[Array, "3"]:
    """Force on the tool from the distributed contact springs (Gao & Gibson §3.2).

    **Arguments:**
    - `contact`: a `Contact` from `contacts`.
    - `stiffness` k ≥ 0 (N/m per contact sample); `damping` c ≥ 0 (N·s/m per contact sample);
      scalars, traced.
    - `method` (static): `"surface_normal"` (direction `Σ d_i N_i`, surface normals) or
      `"probe_normal"` (direction `−Σ d_i n_i`, the tool's outward normals at the contacts).
    - `velocity (3,)`: the tool's velocity (finite), for damping (`F = k s − c ṡ` per spring).

    **Returns:** `(3,)` force `ê (k Σ d_i + c Σ_contacts ṡ_i)`, `ṡ_i = −v·ê` the rate at which
    the tool closes in (damping resists penetration); zero without contact. Differentiable in
    the tool pose, size and the control points. A force beyond the dtype's range raises
    (`ValueError`, or the `eqx.error_if` runtime error inside a caller's `jit`).
    """
    contact = _checked_contact(contact)
    e = _direction(contact, method)
    return _representable(e * jnp.sum(_magnitudes(contact, stiffness, damping, velocity, e)))


@compiled
def sample_forces(
    contact: Contact,
    stiffness: float | Array,
    method: str = "surface_normal",
    damping: float | Array = 0.0,
    velocity: Float[Array, "3"] | None = None,
) -> Float[Array, "m n 3"]:
    """Per-sample reaction forces on the surface, equal and opposite to `contact_force`.

    **Arguments:** as `contact_force`. **Returns:** `(m, n, 3)`: sample i receives
    `−ê (k d_i + c ṡ_i)`, so `sample_forces(...).sum((0, 1)) == −contact_force(...)`
    (Gao & Gibson §3.2.3, the reaction on the surface).
    """
    contact = _checked_contact(contact)
    e = _direction(contact, method)
    forces = -_magnitudes(contact, stiffness, damping, velocity, e)[..., None] * e[None, None]
    return _representable(forces)


def _positions(x, name: str):
    _checks.check_real(x, name)
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    if x.ndim < 1 or x.shape[-1] != 3:
        _checks.fail(name, "shape (..., 3)", f"shape {x.shape}")
    return _checks.finite(x, name)


class DistributedSprings(eqx.Module):
    """The distributed-spring contact model (Gao & Gibson, *Haptic B-spline surface sculpting
    with a shaped tool of implicit surface*, eq. 3.3 and §3.2.3), as one strategy object.

    Every sample in contact is a spring of stiffness `stiffness` k (N/m per sample) compressed by
    its depth `d_i`, with a damper `damping` c (N·s/m per sample) on the rate `ṡ_i` at which it
    closes; its force pushes along the contact normal `n_i` with magnitude
    `max(k d_i + c ṡ_i, 0)` (a contact pushes, never pulls: the damper does not hold a
    separating sample back). Each force acts in an equal and opposite pair: the reaction goes to
    the other body at the sample's foot point (split over the foot triangle's vertices by its
    barycentric weights, which sum to 1), so the contact forces of a scene sum to zero.

    **Fields:** `stiffness ()`, `damping ()`: ≥ 0 and finite (checked, under `jit` too).
    """

    stiffness: Float[Array, ""]
    damping: Float[Array, ""]

    def __init__(self, stiffness: float | Array, damping: float | Array = 0.0):
        dtype = jnp.result_type(float)
        self.stiffness = _coefficient(stiffness, "stiffness", dtype)
        self.damping = _coefficient(damping, "damping", dtype)

    def magnitudes(self, depth, closing, mask) -> Float[Array, "..."]:
        """`max(k d_i + c ṡ_i, 0)` where `mask`, else 0 (shapes broadcast; `closing` is `ṡ_i`)."""
        k, c = self.stiffness.astype(depth.dtype), self.damping.astype(depth.dtype)
        return jnp.where(mask, jnp.maximum(k * depth + c * closing, 0), 0)

    @compiled
    def surface_forces(
        self,
        penetration_ab,
        penetration_ba,
        velocity_a: Float[Array, "ma na 3"] | None = None,
        velocity_b: Float[Array, "mb nb 3"] | None = None,
    ) -> tuple[Float[Array, "ma na 3"], Float[Array, "mb nb 3"]]:
        """Contact forces on the samples of two surfaces from `surface_penetration`'s pair.

        **Arguments:** `penetration_ab` (A's samples in B) and `penetration_ba` (B's samples in
        A), the two `collide.Penetration`s of `surface_penetration(blending_a, ctrl_a,
        blending_b, ctrl_b, reach=…)`; `velocity_a (m_a, n_a, 3)`, `velocity_b (m_b, n_b, 3)`:
        the samples' velocities for the damper (default: at rest).

        **Returns:** `(forces_a (m_a, n_a, 3), forces_b (m_b, n_b, 3))` in N. A's sample i in B
        gets `f_i = max(k d_i + c ṡ_i, 0) n_i`, `ṡ_i = −(v_i − v_B(c_i))·n_i` with `v_B(c_i)` the
        barycentric blend of B's velocities at the foot triangle; B's samples there get
        `−bary_ik f_i`; the same with A and B exchanged. The springs of both surfaces act in
        parallel (neither surface is the tool), so `forces_a.sum((0, 1)) + forces_b.sum((0, 1))
        = 0` to rounding.
        """
        for name, p in (("penetration_ab", penetration_ab), ("penetration_ba", penetration_ba)):
            if not isinstance(p, Penetration):
                raise TypeError(f"{name}: expected a bsjax.collide.Penetration, got {type(p).__name__}")
        shape_a, shape_b = penetration_ab.depth.shape, penetration_ba.depth.shape
        dtype = penetration_ab.depth.dtype
        va = _velocities(velocity_a, shape_a, "velocity_a", dtype)
        vb = _velocities(velocity_b, shape_b, "velocity_b", dtype)
        on_a, back_b = self._one_side(penetration_ab, va, vb)
        on_b, back_a = self._one_side(penetration_ba, vb, va)
        forces_a = (on_a + back_a.reshape(shape_a + (3,))).astype(dtype)
        forces_b = (on_b + back_b.reshape(shape_b + (3,))).astype(dtype)
        return _representable(forces_a), _representable(forces_b)

    def _one_side(self, pen, v_x, v_y):
        """Forces on X's samples `(m, n, 3)` and their reactions on Y's flat samples `(M, 3)`."""
        m, n = pen.depth.shape
        faces = pen.faces.reshape(-1, 3)
        bary = pen.bary.reshape(-1, 3, 1)
        v_foot = jnp.sum(bary * v_y.reshape(-1, 3)[faces], 1).reshape(m, n, 3)
        closing = -jnp.sum((v_x - v_foot) * pen.normals, -1)
        f = self.magnitudes(pen.depth, closing, pen.mask)[..., None] * pen.normals
        reaction = -(bary * f.reshape(-1, 1, 3)).reshape(-1, 3)
        back = jax.ops.segment_sum(reaction, faces.reshape(-1), num_segments=v_y.reshape(-1, 3).shape[0])
        return f, back


def _velocities(v, shape, name: str, dtype):
    """`v` as finite velocities `shape + (3,)` in `dtype` (zeros when None)."""
    if v is None:
        return jnp.zeros(shape + (3,), dtype)
    if np.shape(v) != shape + (3,):
        _checks.fail(name, f"shape {shape + (3,)} (the sample grid)", f"shape {np.shape(v)}")
    return _positions(v, name).astype(dtype)
