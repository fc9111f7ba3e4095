"""Forces on the lattice nodes: Voigt springs (eqs. 5.8–5.13), node damping, penalty contact
with the `bsjax.collide` tools (through their `push`).

Every kernel returns the net force *on* each node, `(N, 3)`, in newtons.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe, collide
from bsjax._boundary import compiled, host_cache
from bsjax.mss._lattice import HEX_DIRECTIONS, Lattice, _slices


def _dot3(a, b):
    """`a·b` over the leading (xyz) axis of component-first arrays: `_safe.dot` along axis 0
    (written out, so XLA on CPU fuses it into one elementwise loop)."""
    return _safe.dot(a, b, axis=0)


def _inv_length(d):
    """`(1/l, l)` of component-first differences `d (3, ...)`; `1/l = 0` at `l = 0` (double where)."""
    l2 = _dot3(d, d)
    ok = l2 > 0
    inv = jnp.where(ok, jax.lax.rsqrt(jnp.where(ok, l2, 1.0)), 0.0)
    return inv, l2 * inv


def _pair_force(d, dv, rest, k, c):
    """Coefficients of a spring's force on node i, for `d = x_i − x_j`, `dv = v_i − v_j`
    (component-first, `(3, ...)`): `(a, None)` with the force `a d` (`edge_sum`'s form).

    Hooke `−K (l − L) ê` (eq. 5.11 with `K` in N/m) plus Voigt damping `−D ((v_i − v_j)·ê) ê`
    (eq. 5.2 along the spring), written `−[K (1 − L/l) + D (dv·d)/l²] d` so a zero-length spring
    (L = 0, l = 0, e.g. at a pole) is a finite linear spring with finite gradients.
    """
    inv, _ = _inv_length(d)
    return -(k * (1.0 - rest * inv) + c * _dot3(dv, d) * inv * inv), None


@compiled
def spring_forces(
    lattice: Lattice,
    x: Float[Array, "N 3"],
    v: Float[Array, "N 3"],
    rest_length: Float[Array, " E"] | None = None,
) -> Float[Array, "N 3"]:
    """`−g_i` (eq. 5.13) plus the Voigt damping of every spring at node i.

    Uses the stencil kernel when the lattice is a hexahedral grid (`lattice.grid_shape`), else
    `segment_sum` over the edge list; both give the same forces.
    """
    rest = lattice.rest_length if rest_length is None else rest_length
    return edge_sum(lattice, _pair_force, (x, v), (rest, lattice.stiffness, lattice.damping))


def edge_sum(lattice: Lattice, pair, node_arrays, edge_arrays) -> Float[Array, "N 3"]:
    """`Σ_j f_ij` at every node i (and `−f_ij` at j): the net spring force of a pairwise law.

    `pair` gets the component-first differences `(3, ...)` across each spring of every `(N, 3)`
    array in `node_arrays` and the spring's entries of every `(E,)` array in `edge_arrays`, and
    returns one coefficient array `(...)` (or `None`, meaning zero) per node array: the force on
    the spring's first node is `f = Σ_a coef_a d_a`. (Every pairwise law of a spring lattice is of
    this form — forces and tangent products are combinations of the springs' difference vectors;
    the form lets the kernel compute each spring's scalars once and the vectors at the nodes.)
    Dense stencil kernel on a hexahedral grid (`_grid_sum`, no scatter), `segment_sum` over the
    edge list otherwise.
    """
    if lattice.grid_shape is not None:
        return _grid_sum(lattice.grid_shape, pair, node_arrays, edge_arrays)
    i, j = lattice.edges[:, 0], lattice.edges[:, 1]
    diffs = [(a[i] - a[j]).T for a in node_arrays]
    coefs = pair(*diffs, *edge_arrays)
    f = sum(c[None] * d for c, d in zip(coefs, diffs) if c is not None).T
    n = node_arrays[0].shape[0]
    return jax.ops.segment_sum(f, i, n) - jax.ops.segment_sum(f, j, n)


@compiled
def edge_lengths(lattice: Lattice, x: Float[Array, "N 3"]) -> Float[Array, " E"]:
    """Current length `l_ij = |x_i − x_j|` of every spring (thesis eq. 5.10's `l`), in m.

    **Arguments:** `lattice` (its edges); `x (N, 3)`: node positions, finite.

    **Returns:** `(E,)` in the lattice's edge order — e.g. the new rest lengths of a plastic set.
    On a hexahedral grid (`lattice.grid_shape`) they come from dense slices per direction (no
    gather, the order of `hex_edges`), else from the edge list; both give the same values
    (`bsjax._safe.norm`: exact 0 and a finite gradient for a zero-length spring).
    """
    if np.shape(x) != (lattice.n_nodes, 3):
        _checks.fail("x", f"node positions of shape ({lattice.n_nodes}, 3)", f"shape {np.shape(x)}")
    x = _checks.finite(_checks.array(x, "x"), "x")
    if lattice.grid_shape is None:
        return _safe.norm(x[lattice.edges[:, 0]] - x[lattice.edges[:, 1]])
    shape = lattice.grid_shape
    grid = x.reshape(shape + (3,))
    parts = []
    for direction in HEX_DIRECTIONS:
        s0, s1 = zip(*(_slices(o, n) for o, n in zip(direction, shape)))
        parts.append(_safe.norm(grid[s0] - grid[s1]).reshape(-1))
    return jnp.concatenate(parts)


class _Stencil(NamedTuple):
    """Static plan of the grid kernel: springs as flat-index offsets of a C-ordered grid.

    Direction `d` of `HEX_DIRECTIONS` joins node `s` to `s + offsets[d]` (flat index). On the
    node arrays padded by `pad` zero rows at both ends (node `i` at row `pad + i`), row `d` of
    `partner (D, N + pad)` holds the padded row of the partner of a spring starting at padded row
    `s` and `edge (D, N + pad)` that spring's index in `hex_edges` order, or `E` (a zero
    parameter, so no force) where no spring of direction `d` starts.
    """

    offsets: tuple[int, ...]
    pad: int
    partner: np.ndarray
    edge: np.ndarray


@host_cache(maxsize=64)
def _stencil(shape: tuple[int, int, int]) -> _Stencil:
    n = int(np.prod(shape))
    ids = np.arange(n).reshape(shape)
    strides = (shape[1] * shape[2], shape[2], 1)
    rows, start = [], 0
    for direction in HEX_DIRECTIONS:
        s0, _ = zip(*(_slices(o, m) for o, m in zip(direction, shape)))
        first = ids[s0].ravel()
        rows.append((int(np.dot(direction, strides)), first, start))
        start += first.size
    rows = [r for r in rows if r[1].size]  # a direction with no spring in this grid
    pad = max(r[0] for r in rows)
    partner = np.stack([np.arange(n + pad, dtype=np.int32) + o for o, _, _ in rows])
    edge = np.full((len(rows), n + pad), start, np.int32)
    for d, (_, first, begin) in enumerate(rows):
        edge[d, first + pad] = np.arange(begin, begin + first.size)
    return _Stencil(tuple(r[0] for r in rows), pad, partner, edge)


def _grid_sum(shape, pair, node_arrays, edge_arrays):
    """`edge_sum` on a C-ordered grid with edges in `hex_edges` order, without a scatter.

    Every direction's springs start at every padded node (`_Stencil`): the coefficients of all
    springs come from one gathered `(D, N + pad)` evaluation of `pair` (each spring once); the
    force at node i is then `Σ_d coef_d[i] d_d[i] − coef_d[i − o_d] d_d[i − o_d]`
    (`_spring_sum`).
    """
    plan = _stencil(shape)
    pad = plan.pad
    padded = [jnp.pad(a.T, ((0, 0), (pad, pad))) for a in node_arrays]  # (3, N + 2 pad)
    diffs = [_spring_differences(plan, p) for p in padded]
    params = [jnp.append(e, jnp.zeros((1,), e.dtype))[plan.edge] for e in edge_arrays]
    used = [(coef, p) for coef, p in zip(pair(*diffs, *params), padded) if coef is not None]
    coefs, arrays = tuple(c for c, _ in used), tuple(p for _, p in used)
    return _spring_sum(shape, coefs, arrays).T


def _spring_differences(plan: _Stencil, p) -> Float[Array, "3 D Np"]:
    """`p[s] − p[partner]` of every spring direction at every padded start row `s`: `(3, D, N +
    pad)` from a padded node array `p (3, N + 2 pad)`."""
    return p[:, None, : p.shape[1] - plan.pad] - p[:, plan.partner]


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _spring_sum(shape: tuple[int, int, int], coefs, padded) -> Float[Array, "3 N"]:
    """`Σ_k Σ_d coefs[k]_d[i] (p_k[i] − p_k[i + o_d]) − coefs[k]_d[i − o_d] (p_k[i − o_d] − p_k[i])`
    over the padded node arrays `padded[k] (3, N + 2 pad)` with coefficients `coefs[k] (D, N +
    pad)` of the grid `shape` (`_stencil`): static slices, one elementwise loop (XLA on CPU runs
    this ~3× faster than per-direction slices with scattered updates, and faster than
    `_spring_sum_linear`). Its derivative is `_spring_sum_linear` (bilinear in coefficients and
    nodes), whose transpose is a few array operations where this loop's would be ~25 per
    direction."""
    plan = _stencil(shape)
    pad, n = plan.pad, int(np.prod(shape))
    out = jnp.zeros((3, n), padded[0].dtype)
    for p, coef in zip(padded, coefs):
        here = p[:, pad : pad + n]
        for d, o in enumerate(plan.offsets):
            first = coef[None, d, pad : pad + n] * (here - p[:, pad + o : pad + o + n])
            second = coef[None, d, pad - o : pad - o + n] * (p[:, pad - o : pad - o + n] - here)
            out = out + first - second
    return out


@_spring_sum.defjvp
def _spring_sum_jvp(shape, primals, tangents):
    coefs, padded = primals
    d_coefs, d_padded = tangents
    tangent = _spring_sum_linear(shape, d_coefs, padded) + _spring_sum_linear(shape, coefs, d_padded)
    return _spring_sum(shape, coefs, padded), tangent


def _spring_sum_linear(shape, coefs, padded) -> Float[Array, "3 N"]:
    """`_spring_sum` as whole-array operations: with `g_d = coef_d (p − p[· + o_d])`, the sum
    `Σ_d g_d[i] − g_d[i − o_d]` — one sum over the directions and one over `D` shifted slices."""
    plan = _stencil(shape)
    pad, n = plan.pad, int(np.prod(shape))
    g = sum(c[None] * _spring_differences(plan, p) for c, p in zip(coefs, padded))
    behind = jnp.stack([g[:, d, pad - o : pad - o + n] for d, o in enumerate(plan.offsets)], 1)
    return jnp.sum(g[:, :, pad : pad + n], 1) - jnp.sum(behind, 1)


# --- penalty contact with rigid tools --------------------------------------------------------------


def _solid(tool):
    """`tool` if it is a solid `bsjax.collide` tool, else a clear `TypeError`."""
    if isinstance(tool, collide.Point):
        raise TypeError(
            "tools: a collide.Point has no volume, so it cannot push lattice nodes; "
            "use a solid tool (Sphere, Ellipsoid, Plane, Implicit, TriangleMesh)"
        )
    if not isinstance(tool, collide.AbstractTool):
        raise TypeError(
            "tools: expected bsjax.collide tools (Sphere, Ellipsoid, Plane, Implicit, TriangleMesh), "
            f"got {type(tool).__name__}"
        )
    return tool


@compiled
def tool_contacts(tools, x: Float[Array, "N 3"]) -> list[tuple[Array, Array]]:
    """`[(depth (N,), normal (N, 3)), …]`: each tool's `push` of the nodes `x` (in their dtype).

    A node is in contact with a tool exactly where the tool's implicit value is negative; it is
    pushed out by `depth` along the tool's outward normal at the closest surface point
    (`bsjax.collide.AbstractTool.push`).
    """
    return [_solid(tool).cast(x.dtype).push(x) for tool in tools]


@compiled
def tool_forces(tools, x, v, stiffness, damping=0.0) -> Float[Array, "N 3"]:
    """Sum of the penalty forces of rigid `bsjax.collide` tools on the nodes, `(N, 3)`: positions
    `x (N, 3)` and velocities `v (N, 3)` finite, `stiffness` k and `damping` c finite and ≥ 0
    (checked; `_tool_forces` is the unchecked kernel the integrators call).

    Each tool's `push` gives the depth `δ_i` and outward normal `n_i` of every node inside it;
    `f_i = k δ_i n_i − c min(v_i·n_i, 0) n_i` (damping only while a node moves into the tool),
    the penalty contact of Gao & Gibson, *Haptic B-spline surface sculpting with a
    shaped tool of implicit surface*, §4.2. Accepts `Sphere`, `Ellipsoid`, `Plane`, `Implicit`,
    `TriangleMesh`; a `Point` (no volume) raises `TypeError`.
    """
    if not isinstance(tools, (list, tuple)):
        _checks.fail("tools", "a sequence of bsjax.collide tools", type(tools).__name__)
    x = _checks.finite(_checks.array(x, "x"), "x")
    _checks.check_ndim(x, "x", 2, last=3)
    v = _checks.finite(_checks.array(v, "v", x.dtype), "v")
    if v.shape != x.shape:
        _checks.fail("v", f"the shape of x {x.shape}", v.shape)
    stiffness = _checks.positive(_checks.array(stiffness, "stiffness", x.dtype), "stiffness", strict=False)
    damping = _checks.positive(_checks.array(damping, "damping", x.dtype), "damping", strict=False)
    return _tool_forces(tools, x, v, stiffness, damping)


def _tool_forces(tools, x, v, stiffness, damping=0.0) -> Float[Array, "N 3"]:
    """`tool_forces` without its checks (the integrators' kernel)."""
    f = jnp.zeros_like(x)
    for depth, normal in tool_contacts(tools, x):
        f = f + _penalty(depth, normal, v, stiffness, damping)
    return f


@compiled
def contact_tangent(tools, x, stiffness) -> Float[Array, "N 3 3"]:
    """`Σ_tools k n nᵀ` at every node inside a tool: the penalty force's normal stiffness (the
    contact part of the tangent stiffness for an implicit step), `(N, 3, 3)`."""
    out = jnp.zeros(x.shape + (3,), x.dtype)
    for depth, n in tool_contacts(tools, x):
        out = out + jnp.where((depth > 0)[:, None, None], stiffness * n[:, :, None] * n[:, None, :], 0.0)
    return out


@compiled
def sphere_penalty(x, v, center, radius, stiffness, damping=0.0):
    """Penalty force pushing nodes out of a rigid sphere, `(N, 3)`: `tool_forces` with a
    `collide.Sphere(center, radius)` (depth `max(r − |x − c|, 0)` along `(x − c)/|x − c|`)."""
    return _tool_forces((collide.Sphere(center, radius),), x, v, stiffness, damping)


@compiled
def plane_penalty(x, v, point, normal, stiffness, damping=0.0):
    """Penalty force pushing nodes to the `normal` side of a rigid plane (a table), `(N, 3)`:
    `tool_forces` with a `collide.Plane(point, normal)`."""
    return _tool_forces((collide.Plane(point, normal),), x, v, stiffness, damping)


def _penalty(depth, n, v, stiffness, damping):
    inside = depth > 0
    vn = _safe.dot(v, n)
    mag = stiffness * depth - jnp.where(inside, damping * jnp.minimum(vn, 0.0), 0.0)
    return mag[..., None] * n


@compiled
def behind_plane(positions: Float[Array, "... 3"], point, normal) -> Array:
    """Boolean mask of nodes on the solid side of a plane (`(x − p)·n ≤ 0`) — e.g. the nodes a
    clamp holds, for `Lattice(fixed=...)`."""
    plane = collide.Plane(point, normal)  # a plane tool's checks: (3,) finite, a non-zero normal
    _checks.check_real(positions, "positions")
    positions = jnp.asarray(positions)
    if positions.ndim < 1 or positions.shape[-1] != 3:
        _checks.fail("positions", "points (..., 3)", f"shape {positions.shape}")
    positions = _checks.finite(positions, "positions")
    lead = (1,) * (positions.ndim - 1)
    point, normal = jnp.reshape(plane.point, (*lead, 3)), jnp.reshape(plane.normal, (*lead, 3))
    return jnp.sum((positions - point) * normal, axis=-1) <= 0
