"""Time integration: semi-implicit Euler (thesis eqs. 5.14–5.16), linearised backward Euler,
`lax.scan` rollouts with optional `jax.checkpoint`, stability limit, relaxation to rest.

Pure functions over pytrees (jax-md / brax style): `step(model, state, dt, …) -> state`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, _tensor
from bsjax.mss._forces import _dot3, _inv_length, edge_sum, spring_forces, tool_forces
from bsjax.mss._lattice import Lattice, State

METHODS = ("semi_implicit", "implicit")


class Contact(eqx.Module):
    """Penalty contact settings: `stiffness` in N/m per unit depth, `damping` in N·s/m."""

    stiffness: Float[Array, ""]
    damping: Float[Array, ""]

    def __init__(self, stiffness: ArrayLike = 1e3, damping: ArrayLike = 0.0):
        _checks.check_positive(stiffness, "stiffness", strict=False)
        _checks.check_positive(damping, "damping", strict=False)
        self.stiffness = jnp.asarray(stiffness)
        self.damping = jnp.asarray(damping)


class Plasticity(eqx.Module):
    """Rest-length update (thesis §5.4): a spring whose strain `e = (l − L)/L` (eq. 5.10)
    exceeds `yield_strain` in magnitude takes a new rest length so that its strain is
    `±yield_strain` — but only springs whose midpoint lies within `radius` of `center`
    (the neighbourhood of the tool; `center=None` means everywhere)."""

    yield_strain: Float[Array, ""]
    radius: Float[Array, ""]
    center: Float[Array, " 3"] | None

    def __init__(self, yield_strain: ArrayLike, radius: ArrayLike = jnp.inf, center: ArrayLike | None = None):
        _checks.check_positive(yield_strain, "yield_strain")
        self.yield_strain = jnp.asarray(yield_strain)
        self.radius = jnp.asarray(radius)
        self.center = None if center is None else jnp.asarray(center)


# --- forces and energy -----------------------------------------------------------------------------


def forces(
    lattice: Lattice,
    state: State,
    external_force=None,
    gravity=None,
    tools=(),
    contact=None,
    rest_length=None,
) -> Float[Array, "N 3"]:
    """Net force on every node: `f − D_i ẋ − g` of eq. 5.12, plus `ρ_i g` and tool contact."""
    x, v = state.position, state.velocity
    f = spring_forces(lattice, x, v, rest_length) - lattice.node_damping[:, None] * v
    if external_force is not None:
        f = f + external_force
    if gravity is not None:
        f = f + lattice.mass[:, None] * jnp.asarray(gravity, dtype=x.dtype)
    if tools:
        c = Contact() if contact is None else contact
        f = f + tool_forces(tools, x, v, c.stiffness, c.damping)
    return f


def energy(lattice: Lattice, state: State, gravity=None) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """`(kinetic, potential)` in J: `½ Σ m v²` and `½ Σ K (l − L)² − Σ m g·x`."""
    x, v = state.position, state.velocity
    kinetic = 0.5 * jnp.sum(lattice.mass * jnp.sum(v * v, axis=-1))
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    stretch = _tensor.safe_norm(x[i] - x[j]) - lattice.rest_length
    potential = 0.5 * jnp.sum(lattice.stiffness * stretch**2)
    if gravity is not None:
        potential = potential - jnp.sum(lattice.mass[:, None] * x * jnp.asarray(gravity, dtype=x.dtype))
    return kinetic, potential


# --- stability ----------------------------------------------------------------------------------------


def stable_dt(lattice: Lattice, contact_stiffness: ArrayLike = 0.0) -> Float[Array, ""]:
    """Largest time step for which semi-implicit Euler is stable on this lattice.

    Bounds the largest eigenvalue `ω²` of `M⁻¹K` and `c` of `M⁻¹C` by block Gershgorin discs
    (`ω² ≤ max_i Σ_j K_ij (1/m_i + 1/√(m_i m_j))`, exact for one free spring), adds the contact
    stiffness `k_c/m_i`, and returns the largest `h` with `h²ω² + 2hc ≤ 4`, the stability
    condition of symplectic Euler on `ẍ = −ω²x − cẋ`: `h = (√(c² + 4ω²) − c) / ω²`.
    """
    m = lattice.mass
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    cross = 1.0 / jnp.sqrt(m[i] * m[j])
    n = m.shape[0]

    def bound(per_edge, per_node):
        b = (
            jax.ops.segment_sum(per_edge * (1.0 / m[i] + cross), i, n)
            + jax.ops.segment_sum(per_edge * (1.0 / m[j] + cross), j, n)
            + per_node / m
        )
        return jnp.max(jnp.where(lattice.fixed, 0.0, b))

    w2 = bound(lattice.stiffness, jnp.asarray(contact_stiffness, dtype=m.dtype))
    c = bound(lattice.damping, lattice.node_damping)
    ok = w2 > 0
    w2s = jnp.where(ok, w2, 1.0)
    h = (jnp.sqrt(c * c + 4.0 * w2s) - c) / w2s
    return jnp.where(ok, h, jnp.where(c > 0, 2.0 / jnp.where(c > 0, c, 1.0), jnp.inf))


def check_dt(lattice: Lattice, dt, contact_stiffness=0.0):
    """Raise `ValueError` (concrete values) or an `eqx.error_if` runtime error (traced) when `dt`
    exceeds `stable_dt`; returns `dt` (threaded through the error check when traced)."""
    limit = stable_dt(lattice, contact_stiffness)
    if _checks.is_concrete(limit) and _checks.is_concrete(dt):
        if not float(dt) > 0:
            _checks.fail("dt", "a time step > 0", dt)
        if float(dt) > float(limit):
            _checks.fail(
                "dt",
                f"a time step <= {float(limit):.6g} s, the largest stable step of the "
                "semi-implicit Euler scheme for this lattice (stiffest spring, lightest node); "
                "use a smaller dt or method='implicit'",
                f"{float(dt):.6g} s",
            )
        return dt
    dt = jnp.asarray(dt, dtype=lattice.mass.dtype)
    return eqx.error_if(
        dt,
        (dt > limit) | (dt <= 0),
        "dt: expected a time step <= the semi-implicit Euler stability limit (mss.stable_dt)",
    )


# --- steps --------------------------------------------------------------------------------------------


def step(
    lattice: Lattice,
    state: State,
    dt,
    external_force=None,
    gravity=None,
    tools=(),
    contact=None,
    rest_length=None,
) -> State:
    """One semi-implicit (symplectic) Euler step, thesis eqs. 5.14–5.16:
    `a = (f − D ẋ − g)/ρ;  v ← v + Δt a;  x ← x + Δt v`. Fixed nodes keep their position and
    have zero velocity. No stability check here (the haptic loop calls this at a fixed rate);
    `simulate` and `check_dt` check."""
    f = forces(lattice, state, external_force, gravity, tools, contact, rest_length)
    a = f / lattice.mass[:, None]
    free = ~lattice.fixed[:, None]
    v = jnp.where(free, state.velocity + dt * a, 0.0)
    x = jnp.where(free, state.position + dt * v, state.position)
    return State(x, v)


def _tangent_pair(h, damped=True):
    """Spring block of `(hC + h²K_t) w` at node i for `dw = w_i − w_j` (component-first).

    `K_t = k [ê êᵀ + max(0, 1 − L/l)(I − ê êᵀ)]` is the spring's stiffness matrix with the
    compressive (negative) geometric term dropped, so the system stays positive definite.
    """

    def pair(dx, dw, rest, k, c):
        inv, _ = _inv_length(dx)
        lam = _transverse(rest, inv)
        along = _dot3(dx, dw) * inv * inv  # (ê·dw)/l, so along·dx = (ê·dw) ê
        axial = (h * c + h * h * k) if damped else h * h * k
        return (axial - h * h * k * lam) * along * dx + h * h * k * lam * dw

    return pair


def _transverse(rest, inv):
    """`max(0, 1 − L/l)`; 1 for a zero-length spring (a linear spring `−K d`), 0 for l = 0 < L."""
    return jnp.where(inv > 0, jnp.maximum(1.0 - rest * inv, 0.0), (rest == 0).astype(inv.dtype))


def _contact_diag(tools, x, contact):
    """`k_c n nᵀ` of every node inside a tool (the penalty force's normal stiffness)."""
    out = jnp.zeros(x.shape + (3,), x.dtype)
    for tool in tools:
        if hasattr(tool, "radius"):
            d = x - tool.center
            inside = _tensor.safe_norm(d) < tool.radius
            n = _tensor.unit(d)
        else:
            n = jnp.broadcast_to(_tensor.unit(jnp.asarray(tool.normal, dtype=x.dtype)), x.shape)
            inside = jnp.sum((x - tool.point) * n, axis=-1) < 0
        out = out + jnp.where(inside[:, None, None], contact.stiffness * n[:, :, None] * n[:, None, :], 0.0)
    return out


def implicit_step(
    lattice: Lattice,
    state: State,
    dt,
    external_force=None,
    gravity=None,
    tools=(),
    contact=None,
    rest_length=None,
    cg_iterations: int = 20,
) -> State:
    """One linearised backward-Euler step (Baraff & Witkin 1998), stable for stiff springs.

    Solves `(M + hC + h²K_t) Δv = h f(x, v) − h²K_t v` with `cg_iterations` of Jacobi-
    preconditioned conjugate gradients (a fixed budget, so the cost per step is bounded — the
    haptic case), then `v ← v + Δv`, `x ← x + h v`. Fixed nodes are held.
    """
    h = jnp.asarray(dt, dtype=state.position.dtype)
    x, v = state.position, state.velocity
    rest = lattice.rest_length if rest_length is None else rest_length
    contact = Contact() if (tools and contact is None) else contact
    free = ~lattice.fixed[:, None]
    pair = _tangent_pair(h)
    cdiag = _contact_diag(tools, x, contact) if tools else None
    mass = lattice.mass[:, None] + h * lattice.node_damping[:, None]

    def stiffness_only(w):  # h²K_t w (plus h C w from the spring dampers)
        out = edge_sum(lattice, pair, (x, w), (rest, lattice.stiffness, lattice.damping))
        if cdiag is not None:
            out = out + h * h * jnp.einsum("nij,nj->ni", cdiag, w)
        return out

    def matvec(w):
        w = jnp.where(free, w, 0.0)
        return jnp.where(free, mass * w + stiffness_only(w), w)

    f = forces(lattice, state, external_force, gravity, tools, contact, rest)
    # the damping part of K_t·v must not enter: h²K v only, so evaluate with c = 0 separately
    kv = edge_sum(lattice, _tangent_pair(h, damped=False), (x, v), (rest, lattice.stiffness, lattice.damping))
    if cdiag is not None:
        kv = kv + h * h * jnp.einsum("nij,nj->ni", cdiag, v)
    rhs = jnp.where(free, h * f - kv, 0.0)
    diag = (
        mass
        + _diag(lattice, x, rest, h)
        + (h * h * jnp.diagonal(cdiag, axis1=1, axis2=2) if cdiag is not None else 0.0)
    )
    dv = _pcg(matvec, rhs, 1.0 / diag, cg_iterations)
    v1 = jnp.where(free, v + dv, 0.0)
    return State(jnp.where(free, x + h * v1, x), v1)


def _diag(lattice, x, rest, h):
    """Diagonal of `hC + h²K_t` per node and axis (the Jacobi preconditioner), `(N, 3)`."""
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    d = (x[i] - x[j]).T
    inv, _ = _inv_length(d)
    lam = _transverse(rest, inv)
    e2 = d * d * inv * inv
    k, c = lattice.stiffness, lattice.damping
    diag = ((h * c + h * h * k) * e2 + h * h * k * lam * (1.0 - e2)).T
    n = x.shape[0]
    return jax.ops.segment_sum(diag, i, n) + jax.ops.segment_sum(diag, j, n)


def _pcg(matvec, b, inv_diag, iterations: int):
    """Fixed-iteration preconditioned conjugate gradients from zero (safe divisions)."""

    def body(_, carry):
        xk, r, z, p, rz = carry
        ap = matvec(p)
        pap = jnp.sum(p * ap)
        alpha = jnp.where(pap > 0, rz / jnp.where(pap > 0, pap, 1.0), 0.0)
        xk = xk + alpha * p
        r = r - alpha * ap
        z = inv_diag * r
        rz_new = jnp.sum(r * z)
        beta = jnp.where(rz > 0, rz_new / jnp.where(rz > 0, rz, 1.0), 0.0)
        return xk, r, z, z + beta * p, rz_new

    z = inv_diag * b
    init = (jnp.zeros_like(b), b, z, z, jnp.sum(b * z))
    return jax.lax.fori_loop(0, iterations, body, init)[0]
