"""Rollouts: `simulate` (final state), `trajectory` (saved states), `simulate_plastic`
(rest lengths evolve), `relax` (run to rest) — `lax.scan` with optional `jax.checkpoint`."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bsjax import _checks, _tensor
from bsjax.mss._integrators import METHODS, Contact, Plasticity, check_dt, implicit_step, step
from bsjax.mss._lattice import Lattice, State


def yield_rest_lengths(lattice: Lattice, position, plasticity: Plasticity, rest_length=None):
    """New rest lengths after plastic yield (thesis §5.4, strain eq. 5.10), `(E,)`."""
    rest = lattice.rest_length if rest_length is None else rest_length
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    l = _tensor.safe_norm(position[i] - position[j])
    safe_rest = jnp.where(rest > 0, rest, 1.0)
    strain = jnp.where(rest > 0, (l - rest) / safe_rest, 0.0)
    ey = plasticity.yield_strain
    near = jnp.ones_like(l, dtype=bool)
    if plasticity.center is not None:
        mid = 0.5 * (position[i] + position[j])
        near = _tensor.safe_norm(mid - plasticity.center) <= plasticity.radius
    yielded = near & (jnp.abs(strain) > ey)
    return jnp.where(yielded, l / (1.0 + jnp.sign(strain) * ey), rest)


def _check_method(method):
    if method not in METHODS:
        _checks.fail("method", f"one of {METHODS}", repr(method))


def _per_step_force(external_force, n_steps, n_nodes):
    """Split `external_force` into a constant `(N, 3)` part and a per-step `(n_steps, N, 3)` part."""
    if external_force is None:
        return None, None
    shape = np.shape(external_force)
    if shape == (n_nodes, 3):
        return external_force, None
    if shape == (n_steps, n_nodes, 3):
        return None, external_force
    _checks.fail("external_force", f"shape ({n_nodes}, 3) or ({n_steps}, {n_nodes}, 3)", shape)


def _run(
    lattice,
    state,
    dt,
    n_steps,
    external_force,
    gravity,
    tools,
    tool_path,
    contact,
    method,
    cg_iterations,
    checkpoint_every,
    save_every,
    plasticity,
    check_stability,
):
    _check_method(method)
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 0:
        _checks.fail("n_steps", "an int >= 0", n_steps)
    n = lattice.n_nodes
    if state.position.shape != (n, 3) or state.velocity.shape != (n, 3):
        _checks.fail(
            "state", f"position and velocity of shape ({n}, 3)", (state.position.shape, state.velocity.shape)
        )
    _checks.check_finite(state.position, "state.position")
    _checks.check_finite(state.velocity, "state.velocity")
    tools = tuple(tools)
    contact = Contact() if ((tools or tool_path is not None) and contact is None) else contact
    if method == "semi_implicit" and check_stability:
        dt = check_dt(lattice, dt, contact.stiffness if contact is not None else 0.0)
    const_force, path_force = _per_step_force(external_force, n_steps, n)
    path_tools = () if tool_path is None else tuple(tool_path)

    def body(carry, xs):
        s, rest = carry
        f_t, tools_t = xs
        f = const_force if f_t is None else (f_t if const_force is None else f_t + const_force)
        all_tools = tools + tuple(tools_t)
        if method == "semi_implicit":
            s = step(lattice, s, dt, f, gravity, all_tools, contact, rest)
        else:
            s = implicit_step(lattice, s, dt, f, gravity, all_tools, contact, rest, cg_iterations)
        if plasticity is not None:
            rest = yield_rest_lengths(lattice, s.position, plasticity, rest)
        return (s, rest), None

    xs = (path_force, path_tools)
    carry = (state, lattice.rest_length)
    if save_every is None:
        return _scan(body, carry, xs, n_steps, checkpoint_every), None
    return _scan_saving(body, carry, xs, n_steps, save_every)


def _scan(body, carry, xs, n_steps, checkpoint_every):
    """`n_steps` of `body`; with `checkpoint_every = c`, an outer scan over chunks of `c` steps whose
    inner scans are rematerialised in the backward pass (memory O(n/c + c) states)."""
    if checkpoint_every is None or n_steps <= checkpoint_every:
        return jax.lax.scan(body, carry, xs, length=n_steps)[0]
    c = int(checkpoint_every)
    n_outer, rem = divmod(n_steps, c)
    head = jax.tree.map(lambda a: a[: n_outer * c].reshape((n_outer, c) + a.shape[1:]), xs)
    tail = jax.tree.map(lambda a: a[n_outer * c :], xs)

    @jax.checkpoint
    def chunk(carry, xs_chunk):
        return jax.lax.scan(body, carry, xs_chunk, length=c)[0], None

    carry = jax.lax.scan(chunk, carry, head, length=n_outer)[0]
    return jax.lax.scan(body, carry, tail, length=rem)[0] if rem else carry


def _scan_saving(body, carry, xs, n_steps, save_every):
    if n_steps % save_every:
        _checks.fail("save_every", f"a divisor of n_steps = {n_steps}", save_every)
    k = n_steps // save_every
    chunked = jax.tree.map(lambda a: a.reshape((k, save_every) + a.shape[1:]), xs)

    def outer(carry, xs_chunk):
        carry = jax.lax.scan(body, carry, xs_chunk, length=save_every)[0]
        return carry, carry[0]

    return jax.lax.scan(outer, carry, chunked, length=k)


def simulate(
    lattice: Lattice,
    state: State,
    dt,
    n_steps: int,
    external_force=None,
    gravity=None,
    *,
    tools=(),
    tool_path=None,
    contact: Contact | None = None,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
    checkpoint_every: int | None = None,
    check_stability: bool = True,
) -> State:
    """Integrate the lattice for `n_steps` steps of `dt` seconds; returns the final `State`.

    **Arguments:**
    - `lattice`, `state`: the model and the initial state.
    - `dt`: time step in s; `method="semi_implicit"` (eqs. 5.14–5.16, the default) refuses a
      `dt` above `stable_dt(lattice)` (ValueError naming the largest stable step; an
      `eqx.error_if` error when traced). `method="implicit"`: linearised backward Euler with
      `cg_iterations` CG iterations per step, stable for stiff materials (steel at 1 kHz).
    - `external_force`: `(N, 3)` constant, or `(n_steps, N, 3)` one per step (N).
    - `gravity`: `(3,)` acceleration (m/s²), e.g. `(0, 0, -9.81)`.
    - `tools`: rigid tools (objects with `center`/`radius` or `point`/`normal`) in penalty contact;
      `tool_path`: tools whose arrays have a leading `n_steps` axis (a moving tool);
      `contact`: `Contact(stiffness, damping)` of the penalty.
    - `checkpoint_every`: rematerialise chunks of this many steps in reverse mode (`jax.checkpoint`),
      so `jax.grad` through 10 000 steps keeps only `n/c + c` states.
    """
    (final, _), _ = _run(
        lattice,
        state,
        dt,
        n_steps,
        external_force,
        gravity,
        tools,
        tool_path,
        contact,
        method,
        cg_iterations,
        checkpoint_every,
        None,
        None,
        check_stability,
    )
    return final


def trajectory(
    lattice: Lattice,
    state: State,
    dt,
    n_steps: int,
    external_force=None,
    gravity=None,
    *,
    save_every: int = 1,
    tools=(),
    tool_path=None,
    contact=None,
    method="semi_implicit",
    cg_iterations=20,
    check_stability=True,
) -> tuple[State, State]:
    """Like `simulate`, and also the states after every `save_every` steps, stacked `(k, N, 3)`."""
    (final, _), saved = _run(
        lattice,
        state,
        dt,
        n_steps,
        external_force,
        gravity,
        tools,
        tool_path,
        contact,
        method,
        cg_iterations,
        None,
        save_every,
        None,
        check_stability,
    )
    return final, saved


def simulate_plastic(
    lattice: Lattice,
    state: State,
    dt,
    n_steps: int,
    plasticity: Plasticity,
    external_force=None,
    gravity=None,
    *,
    tools=(),
    tool_path=None,
    contact=None,
    method="semi_implicit",
    cg_iterations=20,
    check_stability=True,
) -> tuple[Lattice, State]:
    """`simulate` with plastic yield after each step; returns the lattice with its new rest
    lengths (the permanently deformed shape) and the final state."""
    final, rest = _run(
        lattice,
        state,
        dt,
        n_steps,
        external_force,
        gravity,
        tools,
        tool_path,
        contact,
        method,
        cg_iterations,
        None,
        None,
        plasticity,
        check_stability,
    )[0]
    return eqx.tree_at(lambda l: l.rest_length, lattice, rest), final


def relax(
    lattice: Lattice,
    state: State,
    dt,
    external_force=None,
    gravity=None,
    *,
    tol=1e-9,
    max_steps: int = 100_000,
    check_every: int = 50,
    tools=(),
    contact=None,
    method="semi_implicit",
    cg_iterations=20,
) -> tuple[State, jax.Array, jax.Array]:
    """Global deformation: integrate until the kinetic energy falls below `tol` (J) or
    `max_steps`; returns `(state, steps_taken, converged)`. (A `while_loop`: not reverse-mode
    differentiable — use `simulate` with a fixed step count for gradients.)"""
    _check_method(method)
    tools = tuple(tools)
    contact = Contact() if (tools and contact is None) else contact
    if method == "semi_implicit":
        dt = check_dt(lattice, dt, contact.stiffness if contact is not None else 0.0)

    def advance(s):
        def body(s, _):
            if method == "semi_implicit":
                return step(lattice, s, dt, external_force, gravity, tools, contact), None
            return implicit_step(
                lattice, s, dt, external_force, gravity, tools, contact, None, cg_iterations
            ), None

        return jax.lax.scan(body, s, None, length=check_every)[0]

    def kinetic(s):
        return 0.5 * jnp.sum(lattice.mass * jnp.sum(s.velocity**2, axis=-1))

    def cond(carry):
        s, k = carry
        return (kinetic(s) > tol) & (k < max_steps)

    def body(carry):
        s, k = carry
        return advance(s), k + check_every

    s, k = jax.lax.while_loop(cond, body, (advance(state), jnp.asarray(check_every)))
    return s, k, kinetic(s) <= tol
