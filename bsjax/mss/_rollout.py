"""Rollouts: `simulate` (final state), `trajectory` (saved states), `simulate_plastic` (rest
lengths evolve), `relax` (run to rest) — `lax.scan` with optional `jax.checkpoint`.

Each is compiled at the public boundary (`bsjax._boundary.compiled`: `dt`, forces, lattices and
states traced; counts, `method` and flags static), checks `dt` and the state once before the
loop, and runs the unchecked kernels of `_integrators` inside it.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bsjax import _checks, _safe, batch
from bsjax._boundary import compiled
from bsjax.mss._integrators import (
    Penalty,
    Plasticity,
    _check_method,
    _checked_dt,
    _checked_implicit_dt,
    _checked_inputs,
    _explicit,
    _implicit,
    _linear_implicit,
    _rest_system,
)
from bsjax.mss._lattice import Lattice, State


def _yield(lattice: Lattice, position, plasticity: Plasticity, rest):
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    l = _safe.norm(position[i] - position[j])
    strain = _safe.ratio(l - rest, jnp.where(rest > 0, rest, 0.0))
    ey = plasticity.yield_strain
    near = jnp.ones_like(l, dtype=bool)
    if plasticity.center is not None:
        mid = 0.5 * (position[i] + position[j])
        near = _safe.norm(mid - plasticity.center[None]) <= plasticity.radius
    yielded = near & (jnp.abs(strain) > ey)
    return jnp.where(yielded, l / (1.0 + jnp.sign(strain) * ey), rest)


@compiled
def yield_rest_lengths(
    lattice: Lattice,
    position: Float[ArrayLike, "N 3"],
    plasticity: Plasticity,
    rest_length: Float[ArrayLike, " E"] | None = None,
) -> Float[Array, " E"]:
    """New rest lengths `(E,)` after plastic yield (thesis §5.4, strain eq. 5.10): a spring of
    strain `e = (l − L)/L` beyond `±ε_y` (near `plasticity.center`) takes `L' = l / (1 ± ε_y)`.

    **Arguments:** `lattice`; `position (N, 3)` in m; `plasticity`; `rest_length (E,)` (default
    the lattice's)."""
    if np.shape(position) != (lattice.n_nodes, 3):
        _checks.fail("position", f"shape ({lattice.n_nodes}, 3)", np.shape(position))
    rest = lattice.rest_length if rest_length is None else rest_length
    return _yield(lattice, _checks.finite(_checks.array(position, "position"), "position"), plasticity, rest)


def _per_step_force(external_force, n_steps, n_nodes):
    """Split `external_force` into a constant `(N, 3)` part and a per-step `(n_steps, N, 3)` part."""
    if external_force is None:
        return None, None
    shape = np.shape(external_force)
    if shape in ((n_nodes, 3), (n_steps, n_nodes, 3)):
        external_force = _checks.finite(_checks.array(external_force, "external_force"), "external_force")
    if shape == (n_nodes, 3):
        return external_force, None
    if shape == (n_steps, n_nodes, 3):
        return None, external_force
    _checks.fail("external_force", f"shape ({n_nodes}, 3) or ({n_steps}, {n_nodes}, 3)", shape)


def _prepare(lattice, state, dt, method, cg_iterations, tools, contact, check_stability):
    """Structure and value checks shared by the rollouts: `(state, dt, contact)`."""
    _check_method(method, lattice)
    _checks.check_count(cg_iterations, "cg_iterations")
    state = _checked_inputs(lattice, state)[0]
    contact = Penalty() if (tools and contact is None) else contact
    k_c = contact.stiffness if contact is not None else 0.0
    if method != "semi_implicit":
        return state, _checked_implicit_dt(lattice, dt, k_c), contact
    return state, _checked_dt(lattice, dt, k_c, check_stability), contact


def _kernel(method, cg_iterations, lattice, dt):
    """The step kernel `(lattice, state, dt, force, gravity, tools, contact, rest) -> state` of
    `method` for `lattice` at step `dt` (`"linear_implicit"` factors its system here, once)."""
    if method == "semi_implicit":
        return _explicit
    if method == "linear_implicit":
        system = _rest_system(lattice, jnp.asarray(dt, lattice.rest_positions.dtype), lattice.rest_length)
        return lambda *args: _linear_implicit(*args, system)
    return lambda *args: _implicit(*args, cg_iterations)


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
    progress=None,
):
    n_steps = _checks.check_count(n_steps, "n_steps")
    _checks.check_progress(progress)
    if checkpoint_every is not None:
        _checks.check_count(checkpoint_every, "checkpoint_every")
    if save_every is not None:
        _checks.check_count(save_every, "save_every")
        if n_steps % save_every:
            _checks.fail("save_every", f"a divisor of n_steps = {n_steps}", save_every)
    if gravity is not None:
        if np.shape(gravity) != (3,):
            _checks.fail("gravity", "an acceleration of shape (3,)", np.shape(gravity))
        _checks.check_real(gravity, "gravity")
        gravity = _checks.finite(_checks.array(gravity, "gravity"), "gravity")
    tools = tuple(tools)
    path_tools = () if tool_path is None else tuple(tool_path)
    state, dt, contact = _prepare(
        lattice, state, dt, method, cg_iterations, tools + path_tools, contact, check_stability
    )
    const_force, path_force = _per_step_force(external_force, n_steps, lattice.n_nodes)  # pyright: ignore[reportGeneralTypeIssues]
    advance = _kernel(method, cg_iterations, lattice, dt)

    def body(carry, xs):
        s, rest = carry
        f_t, tools_t = xs
        f = const_force if f_t is None else (f_t if const_force is None else f_t + const_force)
        s = advance(lattice, s, dt, f, gravity, tools + tuple(tools_t), contact, rest)
        if plasticity is not None:
            rest = _yield(lattice, s.position, plasticity, rest)
        return (s, rest), None

    xs = (path_force, path_tools)
    carry = (state, lattice.rest_length)
    if save_every is None:
        return _scan(body, carry, xs, n_steps, checkpoint_every, progress), None
    return _scan_saving(body, carry, xs, n_steps, save_every, progress)


#: A rollout given a `progress` callback reports after each of at most this many chunks of steps.
REPORTS = 100


def _scan(body, carry, xs, n_steps, checkpoint_every, progress=None):
    """`n_steps` of `body`; with `checkpoint_every = c`, an outer scan over chunks of `c` steps whose
    inner scans are rematerialised in the backward pass (memory O(n/c + c) states). With
    `progress`, `progress(done, n_steps)` after each chunk (`c` steps, or `⌈n_steps / REPORTS⌉`):
    the same steps in the same order, so the same result."""
    if progress is None and (checkpoint_every is None or n_steps <= checkpoint_every):
        return jax.lax.scan(body, carry, xs, length=n_steps)[0]
    c = min(checkpoint_every or -(-n_steps // REPORTS), n_steps)
    n_outer, rem = divmod(n_steps, c)
    head = jax.tree.map(lambda a: a[: n_outer * c].reshape((n_outer, c) + a.shape[1:]), xs)
    tail = jax.tree.map(lambda a: a[n_outer * c :], xs)

    def steps(carry, xs_chunk):
        return jax.lax.scan(body, carry, xs_chunk, length=c)[0]

    if checkpoint_every is not None:
        steps = jax.checkpoint(steps)

    def chunk(carry, item):
        k, xs_chunk = item
        carry = steps(carry, xs_chunk)
        batch.report_progress(progress, (k + 1) * c, n_steps, after=carry[0].position)
        return carry, None

    carry = jax.lax.scan(chunk, carry, (jnp.arange(n_outer), head), length=n_outer)[0]
    if not rem:
        return carry
    carry = jax.lax.scan(body, carry, tail, length=rem)[0]
    batch.report_progress(progress, n_steps, n_steps, after=carry[0].position)
    return carry


def _scan_saving(body, carry, xs, n_steps, save_every, progress=None):
    """The states after every `save_every` steps; `progress(done, n_steps)` after each."""
    k = n_steps // save_every
    chunked = jax.tree.map(lambda a: a.reshape((k, save_every) + a.shape[1:]), xs)
    if progress is None:  # the program of a rollout without the feature

        def outer(carry, xs_chunk):
            carry = jax.lax.scan(body, carry, xs_chunk, length=save_every)[0]
            return carry, carry[0]

        return jax.lax.scan(outer, carry, chunked, length=k)

    def reporting(carry, item):
        i, xs_chunk = item
        carry = jax.lax.scan(body, carry, xs_chunk, length=save_every)[0]
        batch.report_progress(progress, (i + 1) * save_every, n_steps, after=carry[0].position)
        return carry, carry[0]

    return jax.lax.scan(reporting, carry, (jnp.arange(k), chunked), length=k)


@compiled
def simulate(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    n_steps: int,
    external_force: Float[ArrayLike, "N 3"] | Float[ArrayLike, "n_steps N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    *,
    tools=(),
    tool_path=None,
    contact: Penalty | None = None,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
    checkpoint_every: int | None = None,
    check_stability: bool = True,
    progress: Callable[[int, int], object] | None = None,
) -> State:
    """Integrate the lattice for `n_steps` steps of `dt` seconds; returns the final `State`.

    **Arguments:**
    - `lattice`, `state`: the model and the initial state (finite).
    - `dt`: time step in s, finite and > 0; `method="semi_implicit"` (eqs. 5.14–5.16, the default)
      refuses a `dt` above `stable_dt(lattice, contact.stiffness)` (unless
      `check_stability=False`). `method="implicit"`: linearised backward Euler with
      `cg_iterations` CG iterations per step, stable for stiff materials (steel at 1 kHz).
      `method="linear_implicit"` (hexahedral grid lattices): backward Euler linearised about
      the rest shape, `(M + hC + h²K₀) Δv = h f − h²K₀ v`, solved exactly by a block Cholesky
      factor built once per call — for a stiff body that stays near its rest shape (steel),
      where a few CG iterations leave most of the step unsolved; the full force `f` (springs at
      the current state, tools) stays explicit.
    - `n_steps`: number of steps, an int ≥ 1.
    - `external_force`: `(N, 3)` constant, or `(n_steps, N, 3)` one per step (N).
    - `gravity`: `(3,)` acceleration (m/s²), e.g. `(0, 0, -9.81)`.
    - `tools`: rigid tools (the solid `bsjax.collide` tools) in penalty
      contact; `tool_path`: tools whose arrays have a leading `n_steps` axis (a moving tool);
      `contact`: `Penalty(stiffness, damping)` of the penalty.
    - `checkpoint_every`: an int ≥ 1: rematerialise chunks of this many steps in reverse mode
      (`jax.checkpoint`), so `jax.grad` through 10 000 steps keeps only `n/c + c` states.
    - `progress`: an optional callback `progress(done, n_steps)` called on the host after each
      chunk of steps (`checkpoint_every`, else `⌈n_steps / 100⌉`) as the rollout runs
      (`bsjax.batch.report_progress`: an ordered `jax.debug.callback`, also inside the caller's
      `jit`/`vmap`/`grad`); the result is the same. A callable is static: the same callback
      reuses the compilation, a new one compiles once more. None (the default) adds nothing.

    Bad values (NaN state, `dt` ≤ 0, NaN or unstable) raise `ValueError` when called directly,
    and an `eqx.error_if` runtime error with the same message inside the caller's `jit`.
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
        progress,
    )
    return final


@compiled
def trajectory(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    n_steps: int,
    external_force: Float[ArrayLike, "N 3"] | Float[ArrayLike, "n_steps N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    *,
    save_every: int = 1,
    tools=(),
    tool_path=None,
    contact: Penalty | None = None,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
    check_stability: bool = True,
    progress: Callable[[int, int], object] | None = None,
) -> tuple[State, State]:
    """Like `simulate`, and also the states after every `save_every` steps (an int ≥ 1 dividing
    `n_steps`), stacked: `(final, saved)` with `saved.position (n_steps // save_every, N, 3)`;
    `progress(done, n_steps)` after each saved state (see `simulate`)."""
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
        progress,
    )
    return final, saved  # pyright: ignore[reportReturnType]


@compiled
def simulate_plastic(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    n_steps: int,
    plasticity: Plasticity,
    external_force: Float[ArrayLike, "N 3"] | Float[ArrayLike, "n_steps N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    *,
    tools=(),
    tool_path=None,
    contact: Penalty | None = None,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
    check_stability: bool = True,
) -> tuple[Lattice, State]:
    """`simulate` with plastic yield (`yield_rest_lengths`, thesis §5.4) after each step; returns
    the lattice with its new rest lengths (the permanently deformed shape) and the final state.
    `method="linear_implicit"` is refused: its factor is built once from the rest lengths as
    they were, which yield changes."""
    if method == "linear_implicit":
        _checks.fail(
            "method", "'semi_implicit' or 'implicit' (plastic yield changes the rest lengths)", repr(method)
        )
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


@compiled
def relax(
    lattice: Lattice,
    state: State,
    dt: Float[ArrayLike, ""],
    external_force: Float[ArrayLike, "N 3"] | None = None,
    gravity: Float[ArrayLike, " 3"] | None = None,
    *,
    tol: Float[ArrayLike, ""] = 1e-9,
    max_steps: int = 100_000,
    check_every: int = 50,
    tools=(),
    contact: Penalty | None = None,
    method: str = "semi_implicit",
    cg_iterations: int = 20,
) -> tuple[State, Int[Array, ""], Bool[Array, ""]]:
    """Global deformation: integrate until the kinetic energy falls below `tol` (J, ≥ 0) or
    `max_steps` (an int ≥ 1), testing every `check_every` steps (an int ≥ 1); returns
    `(state, steps_taken, converged)`. (A `while_loop`: not reverse-mode differentiable — use
    `simulate` with a fixed step count for gradients.) Other arguments as `simulate`."""
    max_steps = _checks.check_count(max_steps, "max_steps")
    check_every = _checks.check_count(check_every, "check_every")
    external_force, gravity = _checked_inputs(lattice, state, external_force, gravity)[1:]
    tol = _checks.positive(_checks.array(tol, "tol", dtype=lattice.mass.dtype), "tol", strict=False)
    tools = tuple(tools)
    state, dt, contact = _prepare(lattice, state, dt, method, cg_iterations, tools, contact, True)
    advance = _kernel(method, cg_iterations, lattice, dt)

    def chunk(s):
        def body(s, _):
            return advance(lattice, s, dt, external_force, gravity, tools, contact, None), None

        return jax.lax.scan(body, s, None, length=check_every)[0]

    def kinetic(s):
        return 0.5 * jnp.sum(lattice.mass * jnp.sum(s.velocity**2, axis=-1))

    def cond(carry):
        s, k = carry
        return (kinetic(s) > tol) & (k < max_steps)

    def body(carry):
        s, k = carry
        return chunk(s), k + check_every

    s, k = jax.lax.while_loop(cond, body, (chunk(state), jnp.asarray(check_every)))
    return s, k, kinetic(s) <= tol
