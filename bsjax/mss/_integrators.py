"""Time integration: semi-implicit Euler (thesis eqs. 5.14–5.16), linearised backward Euler (about
the current state, by conjugate gradients; or about the rest shape, by a block Cholesky factor),
the stability limit and the time-step checks.

Pure functions over pytrees (jax-md / brax style): `step(model, state, dt, …) -> state`. The
public functions are compiled at the boundary (`bsjax._boundary.compiled`); the rollouts of
`_rollout` run the private kernels `_explicit`/`_implicit` inside their own scan and check `dt`
once, before the loop.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, _linalg, _safe
from bsjax._boundary import compiled
from bsjax.mss._forces import _dot3, _inv_length, _tool_forces, contact_tangent, edge_sum, spring_forces
from bsjax.mss._lattice import Lattice, State

METHODS = ("semi_implicit", "implicit", "linear_implicit")


def _check_method(method, lattice: Lattice | None = None) -> None:
    """`method`: one of `METHODS` (`"linear_implicit"` on a hexahedral grid lattice only)."""
    if method not in METHODS:
        _checks.fail("method", f"one of {METHODS}", repr(method))
    if method == "linear_implicit" and lattice is not None and lattice.grid_shape is None:
        _checks.fail(
            "method", "'linear_implicit' on a hexahedral grid lattice (grid_shape set)", "an edge list"
        )


class Penalty(eqx.Module):
    """Penalty contact settings: `stiffness` in N/m per unit depth, `damping` in N·s/m (both ≥ 0)."""

    stiffness: Float[Array, ""]
    damping: Float[Array, ""]

    def __init__(self, stiffness: ArrayLike = 1e3, damping: ArrayLike = 0.0):
        self.stiffness = _checks.positive(_checks.array(stiffness, "stiffness"), "stiffness", strict=False)
        self.damping = _checks.positive(_checks.array(damping, "damping"), "damping", strict=False)


class Plasticity(eqx.Module):
    """Rest-length update (thesis §5.4): a spring whose strain `e = (l − L)/L` (eq. 5.10)
    exceeds `yield_strain` (> 0) in magnitude takes a new rest length so that its strain is
    `±yield_strain` — but only springs whose midpoint lies within `radius` (≥ 0, may be inf) of
    `center` (the neighbourhood of the tool; `center=None` means everywhere)."""

    yield_strain: Float[Array, ""]
    radius: Float[Array, ""]
    center: Float[Array, " 3"] | None

    def __init__(self, yield_strain: ArrayLike, radius: ArrayLike = jnp.inf, center: ArrayLike | None = None):
        self.yield_strain = _checks.positive(_checks.array(yield_strain, "yield_strain"), "yield_strain")
        radius = _checks.array(radius, "radius")
        self.radius = _checks.check(
            radius, ~(radius >= 0), "radius", "a radius >= 0 (inf allowed)", "< 0 or NaN"
        )
        if center is not None:
            _checks.check_ndim(center, "center", 1, last=3)
            center = _checks.finite(_checks.array(center, "center"), "center")
        self.center = center


# --- forces and energy -----------------------------------------------------------------------------


def _checked_inputs(lattice: Lattice, state: State, external_force=None, gravity=None):
    """`(state, external_force, gravity)` after checking their shapes against the lattice (at
    trace time) and that every entry is finite (an `eqx.error_if` when traced)."""
    n = lattice.n_nodes
    if np.shape(state.position) != (n, 3) or np.shape(state.velocity) != (n, 3):
        _checks.fail(
            "state",
            f"position and velocity of shape ({n}, 3)",
            (np.shape(state.position), np.shape(state.velocity)),
        )
    if external_force is not None:
        if np.shape(external_force) != (n, 3):
            _checks.fail("external_force", f"shape ({n}, 3)", np.shape(external_force))
        external_force = _checks.finite(_checks.array(external_force, "external_force"), "external_force")
    if gravity is not None:
        if np.shape(gravity) != (3,):
            _checks.fail("gravity", "an acceleration of shape (3,)", np.shape(gravity))
        gravity = _checks.finite(_checks.array(gravity, "gravity"), "gravity")
    return _checked_state(state), external_force, gravity


def _checked_state(state: State) -> State:
    """`state` with finite positions and velocities (an `eqx.error_if` when traced)."""
    return State(
        _checks.finite(state.position, "state.position"), _checks.finite(state.velocity, "state.velocity")
    )


def _net_force(lattice, state, external_force=None, gravity=None, tools=(), contact=None, rest_length=None):
    x, v = state.position, state.velocity
    f = spring_forces(lattice, x, v, rest_length) - lattice.node_damping[:, None] * v
    if external_force is not None:
        f = f + external_force
    if gravity is not None:
        f = f + lattice.mass[:, None] * jnp.asarray(gravity, dtype=x.dtype)[None]
    if tools:
        c = Penalty() if contact is None else contact
        f = f + _tool_forces(tools, x, v, c.stiffness.astype(x.dtype), c.damping.astype(x.dtype))
    return f


@compiled
def forces(
    lattice: Lattice,
    state: State,
    external_force: Float[ArrayLike, "N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    tools=(),
    contact: Penalty | None = None,
    rest_length: Float[ArrayLike, " E"] | None = None,
) -> Float[Array, "N 3"]:
    """Net force on every node in N, `(N, 3)`: `f − D_i ẋ − g` of thesis eq. 5.12 (springs,
    Voigt dampers, ground damping), plus the weight `ρ_i g`, `external_force (N, 3)` and the
    penalty contact of `tools` (`contact`: `Penalty`, default `Penalty()`)."""
    state, external_force, gravity = _checked_inputs(lattice, state, external_force, gravity)
    tools = tuple(tools)
    return _net_force(lattice, state, external_force, gravity, tools, contact, rest_length)


@compiled
def energy(
    lattice: Lattice, state: State, gravity: Float[ArrayLike, " 3"] | None = None
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """`(kinetic, potential)` in J: `½ Σ m v²` and `½ Σ K (l − L)² − Σ m g·x` (thesis §5.3)."""
    state, _, gravity = _checked_inputs(lattice, state, None, gravity)
    x, v = state.position, state.velocity
    kinetic = 0.5 * jnp.sum(lattice.mass * jnp.sum(v * v, axis=-1))
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    stretch = _safe.norm(x[i] - x[j]) - lattice.rest_length
    potential = 0.5 * jnp.sum(lattice.stiffness * stretch**2)
    if gravity is not None:
        potential = potential - jnp.sum(lattice.mass[:, None] * x * jnp.asarray(gravity, dtype=x.dtype)[None])
    return kinetic, potential


# --- stability ----------------------------------------------------------------------------------------


def _bounds(lattice: Lattice, contact_stiffness, contact_damping=0.0, springs=True) -> tuple[Array, Array]:
    """Block-Gershgorin bounds `(ω², c)` of the largest eigenvalues of `M⁻¹K` and `M⁻¹C` over the
    free nodes: `max_i Σ_j K_ij (1/m_i + 1/√(m_i m_j)) + k_c/m_i`, the same with the damping
    (node damping plus the contact damper `c_c` of a node in contact). `springs=False`: the
    contact terms alone (a lattice integrated implicitly, its contact forces explicitly).

    Terms with a zero coefficient contribute 0 (never `0·inf`), and `1/√(m_i m_j)` is formed as
    `(1/√m_i)(1/√m_j)`, so extreme but finite masses give `inf`, never NaN.
    """
    m = lattice.mass
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    inv_m, inv_sqrt = 1.0 / m, jax.lax.rsqrt(m)
    cross = inv_sqrt[i] * inv_sqrt[j]

    def term(coef, weight):
        return jnp.where(coef > 0, coef * weight, 0.0)

    k_c = jnp.broadcast_to(jnp.asarray(contact_stiffness, dtype=m.dtype), m.shape)
    c_c = jnp.broadcast_to(jnp.asarray(contact_damping, dtype=m.dtype), m.shape)
    per_edge = jnp.stack([lattice.stiffness, lattice.damping], -1)  # (E, 2): the ω² and c columns
    if not springs:
        per_edge = jnp.zeros_like(per_edge)
    per_node = jnp.stack([k_c, lattice.node_damping + c_c if springs else c_c], -1)
    # both ends of every edge in one segment sum (each is a loop kernel of its own on XLA:CPU)
    ends = jnp.concatenate(
        [term(per_edge, (inv_m[i] + cross)[:, None]), term(per_edge, (inv_m[j] + cross)[:, None])]
    )
    b = jax.ops.segment_sum(ends, jnp.concatenate([i, j]), m.shape[0]) + term(per_node, inv_m[:, None])
    w2, c = jnp.max(jnp.where(lattice.fixed[:, None], 0.0, b), 0, initial=0.0)
    return w2, c


def _stable_dt(lattice: Lattice, contact_stiffness, contact_damping=0.0, springs=True) -> Array:
    w2, c = _bounds(lattice, contact_stiffness, contact_damping, springs)
    # h = (√(c² + 4ω²) − c)/ω² written as 4/(√(c² + 4ω²) + c): no 0/0 at ω² = 0 (→ 2/c, or inf
    # when also c = 0), no inf/inf at ω² = inf (→ 0); the root is a scaled norm (no overflow of c²)
    ok = jnp.isfinite(w2) & jnp.isfinite(c)
    pair = jnp.where(ok, jnp.stack([c, 2.0 * jnp.sqrt(jnp.where(ok, w2, 0.0))]), 0.0)
    root = jnp.where(ok, _safe.norm(pair), jnp.inf)
    return 4.0 / (root + c)


@compiled
def stable_dt(
    lattice: Lattice,
    contact_stiffness: Float[ArrayLike, ""] = 0.0,
    contact_damping: Float[ArrayLike, ""] = 0.0,
) -> Float[Array, ""]:
    """Largest time step in s for which semi-implicit Euler is stable on this lattice.

    **Arguments:**
    - `lattice`: the model.
    - `contact_stiffness`: penalty stiffness `k_c` (N/m, ≥ 0) of the tools in contact.
    - `contact_damping`: the contact damper `c_c` (N·s/m, ≥ 0) on a node in contact (e.g. a
      `collide.DistributedSprings`' damping), added to the node damping.

    **Returns:** `h > 0` (inf for a lattice without springs or dampers). A lattice whose bound
    overflows the dtype (stiffness 1e308 on a gram) raises: no step is representable.

    Bounds the largest eigenvalue `ω²` of `M⁻¹K` and `c` of `M⁻¹C` by block Gershgorin discs
    (`ω² ≤ max_i Σ_j K_ij (1/m_i + 1/√(m_i m_j))`, exact for one free spring), adds the contact
    stiffness `k_c/m_i`, and returns the largest `h` with `h²ω² + 2hc ≤ 4`, the stability
    condition of symplectic Euler on `ẍ = −ω²x − cẋ`: `h = (√(c² + 4ω²) − c) / ω²`.
    """
    contact_stiffness = _checks.positive(
        _checks.array(contact_stiffness, "contact_stiffness"), "contact_stiffness", strict=False
    )
    contact_damping = _checks.positive(
        _checks.array(contact_damping, "contact_damping"), "contact_damping", strict=False
    )
    h = _stable_dt(lattice, contact_stiffness, contact_damping)
    return _checks.check(
        h,
        ~(h > 0),
        "lattice",
        "stiffness / mass ratios with a representable stable step",
        "an overflowing bound",
    )


_UNSTABLE = (
    "a time step <= mss.stable_dt(lattice, contact_stiffness), the largest stable step of the "
    "semi-implicit Euler scheme for this lattice (stiffest spring, lightest node); use a smaller dt "
    "or method='implicit'"
)


def _checked_dt(
    lattice: Lattice, dt, contact_stiffness=0.0, stability: bool = True, contact_damping=0.0, springs=True
) -> Array:
    """`dt` as an array of the lattice's dtype, checked finite and > 0, and (`stability`) not above
    the semi-implicit Euler limit `_stable_dt` (of the contact terms alone, `springs=False`) —
    raised at once when concrete, `eqx.error_if` when traced."""
    dt = _checks.positive(_checks.array(dt, "dt", dtype=lattice.mass.dtype), "dt")
    if np.ndim(dt) != 0:
        _checks.fail("dt", "a scalar time step", f"shape {np.shape(dt)}")
    if stability:
        limit = _stable_dt(lattice, contact_stiffness, contact_damping, springs)
        dt = _checks.check(dt, dt > limit, "dt", _UNSTABLE, "a larger one")
    return dt


def _checked_implicit_dt(lattice: Lattice, dt, contact_stiffness=0.0) -> Array:
    """`dt` finite, > 0 and small enough that the implicit system `M + hC + h²K` stays finite."""
    dt = _checked_dt(lattice, dt, stability=False)
    w2, c = _bounds(lattice, contact_stiffness)
    scale = dt * dt * w2 + dt * c
    expected = "a time step whose implicit system h²ω² + hc (mss.stable_dt's bounds) is finite"
    return _checks.check(dt, ~jnp.isfinite(scale), "dt", expected, "one that overflows")


@compiled
def check_dt(lattice: Lattice, dt: Float[ArrayLike, ""], contact_stiffness: Float[ArrayLike, ""] = 0.0):
    """`dt` (an array), after checking that it is finite, > 0 and at most `stable_dt(lattice,
    contact_stiffness)`: a `ValueError` when called directly, an `eqx.error_if` runtime error with
    the same message inside the caller's `jit`."""
    contact_stiffness = _checks.positive(
        _checks.array(contact_stiffness, "contact_stiffness"), "contact_stiffness", strict=False
    )
    return _checked_dt(lattice, dt, contact_stiffness)


def _contact_stiffness(tools, contact) -> Array | float:
    return (Penalty() if contact is None else contact).stiffness if tools else 0.0


# --- steps --------------------------------------------------------------------------------------------


def _explicit(
    lattice, state, dt, external_force=None, gravity=None, tools=(), contact=None, rest_length=None
):
    """The semi-implicit Euler kernel (no checks)."""
    v = _velocity_step(lattice, state, dt, external_force, gravity, tools, contact, rest_length)
    return State(_position_step(lattice, state.position, v, dt), v)


def _velocity_step(
    lattice, state, dt, external_force=None, gravity=None, tools=(), contact=None, rest_length=None
):
    """`v ← v + Δt a` (eqs. 5.14–5.15), zero at fixed nodes: the first half of `_explicit`.

    A loop of steps that carries the position one step behind (`_position_step` at the start of
    the next step) computes the spring sum once per step; XLA on CPU fuses it into both the
    velocity and the position update of `_explicit` (computed twice).
    """
    f = _net_force(lattice, state, external_force, gravity, tools, contact, rest_length)
    a = f / lattice.mass[:, None]
    return jnp.where(~lattice.fixed[:, None], state.velocity + dt * a, 0.0)


def _position_step(lattice, x, v, dt):
    """`x ← x + Δt v` (eq. 5.16) at the free nodes: the second half of `_explicit`."""
    return jnp.where(~lattice.fixed[:, None], x + dt * v, x)


@compiled
def step(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    external_force: Float[ArrayLike, "N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    tools=(),
    contact: Penalty | None = None,
    rest_length: Float[ArrayLike, " E"] | None = None,
    *,
    check_stability: bool = True,
) -> State:
    """One semi-implicit (symplectic) Euler step, thesis eqs. 5.14–5.16:
    `a = (f − D ẋ − g)/ρ;  v ← v + Δt a;  x ← x + Δt v`. Fixed nodes keep their position and
    have zero velocity.

    **Arguments:** as `forces`, and `dt` in s (finite, > 0 and — unless `check_stability=False`,
    for a loop that checked it once already — at most `stable_dt(lattice, contact.stiffness)`).

    **Returns:** the new `State`.
    """
    state, external_force, gravity = _checked_inputs(lattice, state, external_force, gravity)
    tools = tuple(tools)
    dt = _checked_dt(lattice, dt, _contact_stiffness(tools, contact), check_stability)
    return _explicit(lattice, state, dt, external_force, gravity, tools, contact, rest_length)


def _tangent_pair(h, damped=True):
    """Spring block of `(hC + h²K_t) w` at node i for `dw = w_i − w_j` (component-first), as
    `edge_sum` coefficients of `(dx, dw)`.

    `K_t = k [ê êᵀ + max(0, 1 − L/l)(I − ê êᵀ)]` is the spring's stiffness matrix with the
    compressive (negative) geometric term dropped, so the system stays positive definite.
    """

    def pair(dx, dw, rest, k, c):
        inv, _ = _inv_length(dx)
        lam = _transverse(rest, inv)
        along = _dot3(dx, dw) * inv * inv  # (ê·dw)/l, so along·dx = (ê·dw) ê
        axial = (h * c + h * h * k) if damped else h * h * k
        return (axial - h * h * k * lam) * along, h * h * k * lam

    return pair


def _transverse(rest, inv):
    """`max(0, 1 − L/l)`; 1 for a zero-length spring (a linear spring `−K d`), 0 for l = 0 < L."""
    return jnp.where(inv > 0, jnp.maximum(1.0 - rest * inv, 0.0), (rest == 0).astype(inv.dtype))


def _implicit(
    lattice,
    state,
    dt,
    external_force=None,
    gravity=None,
    tools=(),
    contact=None,
    rest_length=None,
    cg_iterations=20,
):
    """The linearised backward-Euler kernel (no checks)."""
    h = jnp.asarray(dt, dtype=state.position.dtype)
    x, v = state.position, state.velocity
    rest = lattice.rest_length if rest_length is None else rest_length
    contact = Penalty() if (tools and contact is None) else contact
    free = ~lattice.fixed[:, None]
    pair = _tangent_pair(h)
    cdiag = contact_tangent(tools, x, contact.stiffness.astype(x.dtype)) if tools else None
    mass = lattice.mass[:, None] + h * lattice.node_damping[:, None]

    def stiffness_only(w):  # h²K_t w (plus h C w from the spring dampers)
        out = edge_sum(lattice, pair, (x, w), (rest, lattice.stiffness, lattice.damping))
        if cdiag is not None:
            out = out + h * h * jnp.einsum("nij,nj->ni", cdiag, w)
        return out

    def matvec(w):
        w = jnp.where(free, w, 0.0)
        return jnp.where(free, mass * w + stiffness_only(w), w)

    f = _net_force(lattice, state, external_force, gravity, tools, contact, rest)
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
    dv = _linalg.cg(matvec, rhs, cg_iterations, inv_diag=1.0 / diag)
    v1 = jnp.where(free, v + dv, 0.0)
    return State(jnp.where(free, x + h * v1, x), v1)


@compiled
def implicit_step(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    external_force: Float[ArrayLike, "N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    tools=(),
    contact: Penalty | None = None,
    rest_length: Float[ArrayLike, " E"] | None = None,
    cg_iterations: int = 20,
) -> State:
    """One linearised backward-Euler step (Baraff & Witkin, *Large steps in cloth simulation*,
    1998, §4–5), stable for stiff springs.

    Solves `(M + hC + h²K_t) Δv = h f(x, v) − h²K_t v` with `cg_iterations` (an int ≥ 1) of
    Jacobi-preconditioned conjugate gradients (`bsjax._linalg.cg`; a fixed budget, so the cost
    per step is bounded — the haptic case), then `v ← v + Δv`, `x ← x + h v`. Fixed nodes are
    held. `dt` must be finite, > 0 and small enough that `h²K` does not overflow. Other
    arguments as `step`; returns the new `State`.
    """
    state, external_force, gravity = _checked_inputs(lattice, state, external_force, gravity)
    cg_iterations = _checks.check_count(cg_iterations, "cg_iterations")
    tools = tuple(tools)
    dt = _checked_implicit_dt(lattice, dt, _contact_stiffness(tools, contact))
    return _implicit(lattice, state, dt, external_force, gravity, tools, contact, rest_length, cg_iterations)


def _diag(lattice, x, rest, h):
    """Diagonal of `hC + h²K_t` per node and axis (the Jacobi preconditioner), `(N, 3)`."""
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    d = (x[i] - x[j]).T
    inv, _ = _inv_length(d)
    lam = _transverse(rest, inv)
    e2 = d * d * (inv * inv)[None]
    k, c = lattice.stiffness, lattice.damping
    diag = ((h * c + h * h * k)[None] * e2 + (h * h * k * lam)[None] * (1.0 - e2)).T
    n = x.shape[0]
    return jax.ops.segment_sum(diag, i, n) + jax.ops.segment_sum(diag, j, n)


def _rest_system(lattice: Lattice, h, rest):
    """Block Cholesky factor `(L (a, B, B), W (a, B, B))` of `A = M + hC + h²K₀` on a hexahedral
    grid lattice of `grid_shape = (a, b, c)` (`B = 3bc`: one block per slab of the first index).

    `K₀` is the springs' tangent stiffness at the rest positions (`_tangent_pair`), rows and
    columns of fixed nodes the identity. The grid's springs join neighbouring slabs only, so `A`
    is block tridiagonal; its 2a blocks are read from `3B` products `A w` (every third slab
    perturbed at once) and factored slab by slab: `L_0 L_0ᵀ = A_00`, `W_i = A_{i,i−1} L_{i−1}⁻ᵀ`,
    `L_i L_iᵀ = A_ii − W_i W_iᵀ` (`W_0 = 0`)."""
    assert lattice.grid_shape is not None
    a = lattice.grid_shape[0]
    x0 = lattice.rest_positions
    n, dtype = x0.shape[0], x0.dtype
    width = 3 * n // a
    free = ~lattice.fixed[:, None]
    mass = lattice.mass[:, None] + h * lattice.node_damping[:, None]
    pair = _tangent_pair(h)

    def matvec(w):  # (a, B) -> (a, B)
        w = w.reshape(n, 3)
        held = jnp.where(free, w, 0.0)
        out = mass * held + edge_sum(lattice, pair, (x0, held), (rest, lattice.stiffness, lattice.damping))
        return jnp.where(free, out, w).reshape(a, width)

    eye = jnp.eye(width, dtype=dtype)
    slab = jnp.arange(a) % 3

    def column(colour, d):
        return matvec(jnp.where((slab == colour)[:, None], eye[d][None], 0.0))

    y = jax.vmap(jax.vmap(column, (None, 0)), (0, None))(jnp.arange(3), jnp.arange(width))  # (3, B, a, B)
    i = jnp.arange(a)
    diag = jnp.swapaxes(y[i % 3, :, i, :], 1, 2)  # A_ii[row, col]
    sub = jnp.swapaxes(y[(i - 1) % 3, :, i, :], 1, 2)  # A_{i,i-1}[row, col]

    def factor(prev, blocks):
        d, c = blocks
        w = jax.scipy.linalg.solve_triangular(prev, c.T, lower=True).T
        chol = jnp.linalg.cholesky(d - w @ w.T)
        return chol, (chol, w)

    first = jnp.linalg.cholesky(diag[0])
    _, (chols, ws) = jax.lax.scan(factor, first, (diag[1:], sub[1:]))
    return jnp.concatenate([first[None], chols]), jnp.concatenate([jnp.zeros_like(first)[None], ws])


def _rest_solve(system, r):
    """`A⁻¹ r` for `r (a, B)` by the block factor of `_rest_system` (two sweeps over the slabs)."""
    chol, w = system
    solve = jax.scipy.linalg.solve_triangular

    def down(y_prev, blocks):
        l, wi, ri = blocks
        y = solve(l, ri - wi @ y_prev, lower=True)
        return y, y

    _, y = jax.lax.scan(down, jnp.zeros_like(r[0]), (chol, w, r))
    w_next = jnp.concatenate([w[1:], jnp.zeros_like(w[:1])])

    def up(x_next, blocks):
        l, wn, yi = blocks
        x = solve(l, yi - wn.T @ x_next, lower=True, trans="T")
        return x, x

    return jax.lax.scan(up, jnp.zeros_like(r[0]), (chol, w_next, y), reverse=True)[1]


def _linear_implicit(lattice, state, dt, external_force, gravity, tools, contact, rest_length, system):
    """Backward Euler linearised about the rest shape: `(M + hC + h²K₀) Δv = h f(x, v) − h²K₀ v`,
    solved exactly by the factor `system = _rest_system(lattice, h, rest)` (built once per
    rollout); `f` in full (springs at the current state, forces, gravity, tools explicitly).
    Stable and accurate while the body stays close to its rest shape (a stiff one: steel), at a
    cost per step of two sweeps of `a` block solves. Fixed nodes are held."""
    h = jnp.asarray(dt, dtype=state.position.dtype)
    x, v = state.position, state.velocity
    rest = lattice.rest_length if rest_length is None else rest_length
    free = ~lattice.fixed[:, None]
    f = _net_force(lattice, state, external_force, gravity, tools, contact, rest)
    pair = _tangent_pair(h, damped=False)
    kv = edge_sum(lattice, pair, (lattice.rest_positions, v), (rest, lattice.stiffness, lattice.damping))
    rhs = jnp.where(free, h * f - kv, 0.0)
    a = system[0].shape[0]
    dv = _rest_solve(system, rhs.reshape(a, -1)).reshape(x.shape)
    v1 = jnp.where(free, v + dv, 0.0)
    return State(jnp.where(free, x + h * v1, x), v1)
