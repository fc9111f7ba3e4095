"""`Lattice` (the model: rest shape, springs, masses, fixed nodes) and `State` (positions, velocities).

A lattice is any set of nodes joined by Voigt springs (thesis §5.3, Fig. 5.7). Builders for the two
lattices of the thesis live here too: the volumetric hexahedral lattice (edges, face and body
diagonals) and the sample-grid lattice of a surface (structural, shear and bending springs).
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled, host_cache
from bsjax._declared import check_fields, declared
from bsjax.mss._materials import Material, _damping, _stiffness

# The 13 half-directions of a 26-neighbour hexahedral lattice: 3 edges, 6 face diagonals,
# 4 body diagonals (each spring counted once).
HEX_DIRECTIONS: tuple[tuple[int, int, int], ...] = (
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (1, 1, 0),
    (1, -1, 0),
    (1, 0, 1),
    (1, 0, -1),
    (0, 1, 1),
    (0, 1, -1),
    (1, 1, 1),
    (1, 1, -1),
    (1, -1, 1),
    (1, -1, -1),
)


class State(eqx.Module):
    """Dynamic state of a lattice: `position (N, 3)` in m and `velocity (N, 3)` in m/s."""

    position: Float[Array, "N 3"]
    velocity: Float[Array, "N 3"]

    def __check_init__(self):
        check_fields(self)  # real arrays (values: checked where a state enters a step)


class Lattice(eqx.Module):
    """A mass-spring-damper lattice (thesis eqs. 5.1–5.13).

    **Arguments:**
    - `rest_positions (N, 3)`: the rest shape (m); rest lengths `L_ij` are measured on it.
    - `edges (E, 2)`: node index pairs of the springs.
    - `stiffness`: `K` in N/m, scalar or `(E,)` (eq. 5.1 `K = E A / L`).
    - `damping`: Voigt damping `D` in N·s/m along each spring, scalar or `(E,)` (eq. 5.2).
    - `mass`: node mass `ρ_i` in kg, scalar or `(N,)`.
    - `fixed`: optional boolean mask `(N,)` of nodes that never move (a clamp, a table).
    - `node_damping`: absolute (ground) damping `D_i` in N·s/m of eq. 5.12, scalar or `(N,)`.
    - `rest_length`: optional `(E,)` rest lengths (default: from `rest_positions`).
    - `grid_shape`: `(a, b, c)` when the nodes are a C-ordered hexahedral grid and the edges are
      in `hex_edges` order; springs are then summed by a stencil kernel of static slices instead
      of a scatter (the same forces, faster on CPU). Set by `hex_lattice`; leave `None` otherwise.
    """

    rest_positions: Float[Array, "N 3"]
    edges: Int[Array, "E 2"]
    rest_length: Float[Array, " E"]
    stiffness: Float[Array, " E"]
    damping: Float[Array, " E"]
    mass: Float[Array, " N"]
    fixed: Bool[Array, " N"]
    node_damping: Float[Array, " N"]
    grid_shape: tuple[int, int, int] | None = eqx.field(static=True, default=None)

    def __init__(
        self,
        rest_positions,
        edges,
        stiffness,
        damping,
        mass,
        fixed=None,
        *,
        node_damping=0.0,
        rest_length=None,
        grid_shape=None,
    ):
        _checks.check_ndim(rest_positions, "rest_positions", 2, last=3)
        _checks.check_real(rest_positions, "rest_positions")
        x = jnp.asarray(rest_positions)
        if not jnp.issubdtype(x.dtype, jnp.floating):
            x = x.astype(jnp.asarray(1.0).dtype)
        x = _checks.finite(x, "rest_positions")
        n = x.shape[0]
        edges = _check_edges(edges, n)
        n_edges = edges.shape[0]
        self.rest_positions = x
        self.edges = edges
        self.stiffness = _per(stiffness, n_edges, "stiffness", "E", x.dtype, strict=False)
        self.damping = _per(damping, n_edges, "damping", "E", x.dtype, strict=False)
        self.mass = _per(mass, n, "mass", "N", x.dtype, strict=True)
        self.node_damping = _per(node_damping, n, "node_damping", "N", x.dtype, strict=False)
        if rest_length is None:
            self.rest_length = _safe.norm(x[edges[:, 0]] - x[edges[:, 1]])
        else:
            self.rest_length = _per(rest_length, n_edges, "rest_length", "E", x.dtype, strict=False)
        if fixed is None:
            self.fixed = jnp.zeros(n, dtype=bool)
        else:
            if np.shape(fixed) != (n,):
                _checks.fail("fixed", f"a boolean mask of shape ({n},)", np.shape(fixed))
            if jnp.asarray(fixed).dtype != jnp.bool_:
                _checks.fail("fixed", "a boolean mask", f"dtype {jnp.asarray(fixed).dtype}")
            self.fixed = jnp.asarray(fixed)
        if grid_shape is not None:
            grid_shape = tuple(int(g) for g in grid_shape)
            if int(np.prod(grid_shape)) != n or n_edges != len(hex_edges(grid_shape)):
                _checks.fail(
                    "grid_shape", f"a grid of {n} nodes whose hex_edges are the {n_edges} edges", grid_shape
                )
        self.grid_shape = grid_shape

    @property
    def n_nodes(self) -> int:
        return self.rest_positions.shape[0]

    @property
    def n_edges(self) -> int:
        return self.edges.shape[0]


@compiled
def init(
    lattice: Lattice,
    position: Float[ArrayLike, "N 3"] | None = None,
    velocity: Float[ArrayLike, "N 3"] | None = None,
) -> State:
    """A `State` at the rest shape (or at `position (N, 3)`, m) with zero (or the given
    `velocity (N, 3)`, m/s) velocity; both checked finite."""
    x = (
        lattice.rest_positions
        if position is None
        else jnp.asarray(position, dtype=lattice.rest_positions.dtype)
    )
    if x.shape != lattice.rest_positions.shape:
        _checks.fail("position", f"shape {lattice.rest_positions.shape}", x.shape)
    v = jnp.zeros_like(x) if velocity is None else jnp.asarray(velocity, dtype=x.dtype)
    if v.shape != x.shape:
        _checks.fail("velocity", f"shape {x.shape}", v.shape)
    return State(_checks.finite(x, "position"), _checks.finite(v, "velocity"))


def _check_edges(edges, n: int) -> Int[Array, "E 2"]:
    _checks.check_ndim(edges, "edges", 2, last=2)
    _checks.check_integer(edges, "edges", "integer node indices")
    e = jnp.asarray(edges)
    e = _checks.check(
        e, (e < 0) | (e >= n), "edges", f"node indices in [0, {n})", "an index outside", _index_range
    )
    loop = e[:, 0] == e[:, 1]
    e = _checks.check(e, loop, "edges", "springs between two different nodes", "a self-loop", _first_loop)
    return e.astype(jnp.int32)


def _index_range(a):
    return f"range [{a.min()}, {a.max()}]"


def _first_loop(a):
    return f"a self-loop at row {int(np.argmax(a[:, 0] == a[:, 1]))}"


def _per(value, count: int, name: str, count_name: str, dtype, strict: bool):
    """A scalar or a `(count,)` array of non-negative (positive when `strict`) values."""
    shape = np.shape(value)
    if shape not in ((), (count,)):
        _checks.fail(name, f"a scalar or shape ({count},) (one per {count_name})", shape)
    _checks.check_real(value, name)
    value = _checks.positive(_checks.array(value, name, dtype=dtype), name, strict=strict)
    return jnp.broadcast_to(value, (count,))


# --- builders --------------------------------------------------------------------------------------


def _slices(offset: int, size: int) -> tuple[slice, slice]:
    """Index ranges of the spring's first node and of its partner along one axis."""
    if offset == 0:
        return slice(0, size), slice(0, size)
    if offset == 1:
        return slice(0, size - 1), slice(1, size)
    return slice(1, size), slice(0, size - 1)


def hex_edges(shape: tuple[int, int, int]) -> np.ndarray:
    """Springs of an `a × b × c` hexahedral grid (C order): edges, face and body diagonals.

    Grouped by direction in `HEX_DIRECTIONS` order, each group in C order of its first node; the
    dense force kernel relies on this order. Returns `(E, 2)` int32 (read-only: the topology is
    built once per `shape` and cached; `_hex_edges.cache_clear()` forgets it).
    """
    if not isinstance(shape, (tuple, list)) or not all(
        isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in shape
    ):
        _checks.fail("shape", "three lattice sizes (ints >= 1)", repr(shape))
    shape = tuple(int(s) for s in shape)  # pyright: ignore[reportAssignmentType]  (length checked next)
    if len(shape) != 3 or min(shape) < 1:
        _checks.fail("shape", "three sizes >= 1", shape)
    return _hex_edges(shape)


@host_cache(maxsize=64)
def _hex_edges(shape: tuple[int, int, int]) -> np.ndarray:
    ids = np.arange(int(np.prod(shape)), dtype=np.int32).reshape(shape)
    blocks = []
    for d in HEX_DIRECTIONS:
        s0, s1 = zip(*(_slices(o, n) for o, n in zip(d, shape)))
        blocks.append(np.stack([ids[s0].ravel(), ids[s1].ravel()], axis=-1))
    edges = np.concatenate(blocks).astype(np.int32)
    edges.flags.writeable = False
    return edges


@compiled
def hex_volume(positions: Float[ArrayLike, "a b c 3"]) -> Float[Array, ""]:
    """Volume enclosed by a hexahedral grid `(a, b, c, 3)`: sum over cells of 6 tetrahedra
    (signed; positive for a right-handed grid)."""
    _checks.check_ndim(positions, "positions", 4, last=3)
    p = jnp.asarray(positions)
    c = [
        p[i : p.shape[0] - 1 + i, j : p.shape[1] - 1 + j, k : p.shape[2] - 1 + k]
        for i, j, k in itertools.product((0, 1), repeat=3)
    ]
    # corners indexed by (i, j, k) bits: 0=000 1=001 2=010 3=011 4=100 5=101 6=110 7=111
    tets = ((0, 4, 6, 7), (0, 6, 2, 7), (0, 2, 3, 7), (0, 3, 1, 7), (0, 1, 5, 7), (0, 5, 4, 7))
    vol = jnp.zeros((), p.dtype)
    for a, b, cc, d in tets:
        u, v, w = c[b] - c[a], c[cc] - c[a], c[d] - c[a]
        vol = vol + jnp.sum(jnp.einsum("...i,...i->...", u, jnp.cross(v, w))) / 6.0
    return vol


@compiled
def hex_lattice(
    positions: Float[ArrayLike, "a b c 3"],
    stiffness=None,
    damping=None,
    mass=None,
    fixed=None,
    *,
    material: Material | None = None,
    node_damping=0.0,
) -> Lattice:
    """A volumetric hexahedral lattice on a node grid (e.g. the output of `bsjax.vsofm.fit`).

    Give either `stiffness`, `damping`, `mass` directly, or a `material` (then `from_material`
    rules apply, with the grid's enclosed volume). `fixed` may be `(a, b, c)` or `(N,)`.
    Compiled at the boundary; the topology (`hex_edges`) is cached per grid shape.
    """
    _checks.check_ndim(positions, "positions", 4, last=3)
    _checks.check_real(positions, "positions")
    p = _checks.finite(_checks.array(positions, "positions"), "positions")
    shape = p.shape[:3]
    edges = hex_edges(shape)
    if fixed is not None:
        fixed = jnp.reshape(jnp.asarray(fixed), (-1,))
    x = p.reshape(-1, 3)
    if material is not None:
        return from_material(
            x, edges, material, _enclosed_volume(p), fixed=fixed, node_damping=node_damping, grid_shape=shape
        )
    if stiffness is None or damping is None or mass is None:
        _checks.fail("stiffness, damping, mass", "all three, or a material", "some missing")
    return Lattice(x, edges, stiffness, damping, mass, fixed, node_damping=node_damping, grid_shape=shape)


@compiled
def _enclosed_volume(p):
    """The grid's volume, checked: a flat, inverted or overflowing grid names `positions`."""
    volume = hex_volume(p)
    bad = ~(jnp.isfinite(volume) & (volume > 0))
    expected = "a grid enclosing a finite volume > 0 (not flat, not overflowing)"
    return _checks.check(volume, bad, "positions", expected, "a zero, negative or non-finite volume")


@declared
def from_material(
    rest_positions, edges, material: Material, volume, fixed=None, *, node_damping=0.0, grid_shape=None
) -> Lattice:
    """A lattice with the parameters of `material` for a body of `volume` m³.

    Node masses share the body's mass equally, `m = ρ V / N`. Each spring gets the same
    cross-section `A = V / Σ L_e` (so the springs together fill the volume once) and
    `K_e = E A / L_e` (eq. 5.1); `D_e = 2 ζ √(K_e m)` (eq. 5.7).

    **Arguments:** `rest_positions (N, 3)`, `edges (E, 2)`, `material`, `volume` (m³, > 0),
    `fixed (N,)`, `node_damping`, `grid_shape` as `Lattice`.
    """
    _checks.check_real(rest_positions, "rest_positions")
    _checks.check_real(edges, "edges")
    _checks.check_ndim(rest_positions, "rest_positions", 2, last=3)
    volume = _checks.positive(_checks.array(volume, "volume"), "volume")
    x = jnp.asarray(rest_positions)
    n = x.shape[0]
    e = _check_edges(edges, n)
    rest = _safe.norm(x[e[:, 0]] - x[e[:, 1]])
    mass = material.density * volume / n
    area = volume / jnp.sum(rest)
    k = _stiffness(material, rest, area)
    d = _damping(material, k, mass)
    dt = x.dtype
    return Lattice(
        x,
        e,
        k.astype(dt),
        d.astype(dt),
        jnp.asarray(mass, dtype=dt),
        fixed,
        node_damping=node_damping,
        rest_length=rest,
        grid_shape=grid_shape,
    )


def grid_edges(
    node_map: np.ndarray,
    periodic_u: bool = False,
    periodic_v: bool = False,
    shear: bool = True,
    bending: bool = True,
) -> np.ndarray:
    """Springs of an `m × n` sample grid: structural (±1), shear (diagonals), bending (±2).

    `node_map (m, n)` gives the node of each sample (coincident samples — a closed seam, a pole —
    share a node); springs that join a node to itself and repeated springs are dropped.
    """
    _checks.check_ndim(node_map, "node_map", 2)
    node_map = np.asarray(node_map)
    if not np.issubdtype(node_map.dtype, np.integer):
        _checks.fail("node_map", "integer node indices", node_map.dtype)
    m, n = node_map.shape
    offsets = [(1, 0), (0, 1)] + ([(1, 1), (1, -1)] if shear else []) + ([(2, 0), (0, 2)] if bending else [])
    i, j = np.meshgrid(np.arange(m), np.arange(n), indexing="ij")
    pairs = []
    for du, dv in offsets:
        i2, j2 = i + du, j + dv
        ok = np.ones_like(i, dtype=bool)
        if periodic_u:
            i2 = i2 % m
        else:
            ok &= i2 < m
        if periodic_v:
            j2 = j2 % n
        else:
            ok &= (j2 >= 0) & (j2 < n)
        a = node_map[i[ok], j[ok]]
        b = node_map[i2[ok], j2[ok]]
        pairs.append(np.stack([a, b], axis=-1))
    e = np.concatenate(pairs)
    e = e[e[:, 0] != e[:, 1]]
    e = np.unique(np.sort(e, axis=1), axis=0)
    return e.astype(np.int32)


def merge_coincident(points: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge grid points closer than `tol` (a closed seam, a pole) into one node.

    **Returns:** `(first, node_map)`: the grid index (flat) of each node's first sample, `(N,)`,
    and the node of every sample, shaped like `points[..., 0]`.
    """
    from scipy.spatial import cKDTree

    flat = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    label = np.arange(len(flat))
    for a, b in sorted(cKDTree(flat).query_pairs(tol)):
        root_a, root_b = _root(label, a), _root(label, b)
        label[max(root_a, root_b)] = min(root_a, root_b)
    roots = np.array([_root(label, k) for k in range(len(flat))])
    first, inverse = np.unique(roots, return_inverse=True)
    return first, inverse.reshape(np.shape(points)[:-1]).astype(np.int32)


def _root(label, k):
    while label[k] != k:
        k = label[k]
    return k
