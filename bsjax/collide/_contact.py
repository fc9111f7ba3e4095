"""Contact queries: a deformable B-spline surface against a tool or against another surface.

Pipeline (thesis ch. 3; Pungotra, Knopf & Canas, *An alternative methodology to represent
B-spline surface for applications in virtual reality environment*, §3.1), with static shapes:
control-hull broad phase with an early exit (`lax.cond`); for solid tools the parametric window
of the support spans and a direct evaluation of the tool's implicit function on the window's
samples (thesis §3.4); for a point tool the two triangles of the nearest cell (thesis §3.4);
for two surfaces the level-of-detail sphere hierarchy with a fixed pair capacity, tessellation
of the candidate cells and vmapped triangle–triangle tests. Each query also has a dense
reference method.

`contacts` and `surface_contacts` are compiled at the public boundary
(`bsjax._boundary.compiled`): the blending's and tools' arrays, the control nets and Python
floats are traced; `method`, `capacity`, `flat_angle` and the static fields of the blending and
the tool (degrees, periodicity, an `Implicit`'s function) select a compilation. A direct call is
as fast as the same call inside the caller's `jax.jit` from its second call on; it also works
inside the caller's `jit`, `vmap` and `grad`. The fixed capacity of `surface_contacts` is
decided on the host: when `overflow` comes back True, call again with a larger `capacity` (one
more compilation per capacity, then cached), as `bsjax.merge` does.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax.basis import Blending
from bsjax.collide import _soa
from bsjax.collide._broad import _blocks, _hulls_apart, _parametric_window, support_start, unless_apart
from bsjax.collide._flat import block_planes, flat_pairs, flat_slots, resolve_flat_pairs
from bsjax.collide._hierarchy import (
    _cell_triangles,
    _sphere_hierarchies,
    block_order,
    candidate_triangles,
    levels_for,
    traverse,
)
from bsjax.collide._tools import AbstractTool, Point
from bsjax.collide._triangles import (
    _closest_point_on_triangle,
    _face_table,
    _nearest_face,
    _triangles_intersect,
    candidate_pairs_intersect,
)


class Contact(eqx.Module):
    """Result of `contacts(blending, ctrl, tool)` on the blending's `(m, n)` sample grid.

    **Fields:**
    - `hit ()`: any sample in contact.
    - `mask (m, n)`: samples in contact; `depth (m, n)` ≥ 0 penetration depth (0 elsewhere).
    - `points (m, n, 3)`, `normals (m, n, 3)`: samples and unit surface normals (zeros when the
      broad phase exited early); `tool_normals (m, n, 3)`: the tool's outward unit normal at
      each sample's depth point (for the probe-normal force).
    - `params_u (m,)`, `params_v (n,)`: the (u, v) of the grid.
    - `window (4,)`: `[u_min, u_max, v_min, v_max]` of the parametric window.
    - `apart ()`: the broad phase certified that surface and tool are apart.
    """

    hit: Bool[Array, ""]
    mask: Bool[Array, "m n"]
    depth: Float[Array, "m n"]
    points: Float[Array, "m n 3"]
    normals: Float[Array, "m n 3"]
    tool_normals: Float[Array, "m n 3"]
    params_u: Float[Array, " m"]
    params_v: Float[Array, " n"]
    window: Float[Array, "4"]
    apart: Bool[Array, ""]


class SurfaceContact(eqx.Module):
    """Result of `surface_contacts`: contact regions on both surfaces.

    **Fields:** `hit ()`; `mask_a (m_a, n_a)`, `mask_b (m_b, n_b)`: vertices of intersecting
    triangles (and of the contact cells of flat pairs); `cells_a (K, 2)`, `cells_b (K, 2)`:
    candidate cell pairs (row, column) after the sphere hierarchy, `pair_hit (K,)`: whether
    that pair's triangles intersect (the contact pairs); `candidates ()`: number of
    intersecting sphere pairs at the last level; `overflow ()`: more candidates than
    `capacity` (results incomplete — call again with a larger capacity);
    `flat_pairs ()`: flat block pairs in contact, resolved by planes (`collide.flat`);
    `apart ()`: the control hulls are certified apart.
    """

    hit: Bool[Array, ""]
    mask_a: Bool[Array, "ma na"]
    mask_b: Bool[Array, "mb nb"]
    cells_a: Int[Array, "K 2"]
    cells_b: Int[Array, "K 2"]
    pair_hit: Bool[Array, " K"]
    candidates: Int[Array, ""]
    overflow: Bool[Array, ""]
    flat_pairs: Int[Array, ""]
    apart: Bool[Array, ""]


def _unless_apart(apart, query, *args):
    """`query(*args)` unless the broad phase certified separation (`broad.unless_apart`), with
    `apart` recorded in the result."""
    with _checks.trusted():  # the entry checked `args`: no check (host callback) in a branch
        out = unless_apart(apart, query, *args)
    return eqx.tree_at(lambda c: c.apart, out, apart)


def _checked_net(blending, ctrl, name: str = "ctrl", blending_name: str = "blending"):
    """`ctrl` as a floating array of the blending's control-net shape `(r, s, 3)`, finite.

    Structure (the blending's type, the net's shape, real numbers) raises now; finiteness is
    checked at run time too (`_checks.finite`), so a NaN net raises inside `jit` as well.
    """
    if not isinstance(blending, Blending):
        raise TypeError(f"{blending_name}: expected a bsjax.basis.Blending, got {type(blending).__name__}")
    _checks.check_real(ctrl, name)
    expected = tuple(blending.ctrl_shape) + (3,)
    if np.shape(ctrl) != expected:
        _checks.fail(name, f"shape {expected} (the blending's control net)", f"shape {np.shape(ctrl)}")
    ctrl = jnp.asarray(ctrl)
    if not jnp.issubdtype(ctrl.dtype, jnp.floating):
        ctrl = ctrl.astype(jnp.result_type(float))
    return _checks.finite(ctrl, name)


def _checked_tool(tool) -> AbstractTool:
    """`tool`, after checking that it is a `bsjax.collide` tool."""
    if not isinstance(tool, AbstractTool):
        raise TypeError(f"tool: expected a bsjax.collide tool (Point, Sphere, …), got {type(tool).__name__}")
    return tool


@compiled
def sample_window(
    blending, ctrl: Float[Array, "r s 3"], tool
) -> tuple[Bool[Array, "m n"], Float[Array, "4"]]:
    """Samples whose local control hull may meet `tool`, and the parametric window they span.

    **Arguments:** the surface's `blending` (an `(m, n)` grid), its control net `ctrl (r, s, 3)`
    (finite) and a `bsjax.collide` tool.

    **Returns:** `(mask (m, n), window [u_min, u_max, v_min, v_max])`; an empty window is
    `[1, 0, 1, 0]` (min > max). Sample (i, j) is kept when the box of the `(k+1)(l+1)` control
    points of its support meets the tool (`tool.box_overlap`, thesis §3.3.3.2).
    """
    ctrl = _checked_net(blending, ctrl, "ctrl")
    return _sample_window(blending, ctrl, _checked_tool(tool).cast(ctrl.dtype))


def _sample_window(blending, ctrl, tool):
    """The kernel of `sample_window` (no checks)."""
    su = support_start(blending.a_u[0], blending.degree_u, blending.periodic_u)
    sv = support_start(blending.a_v[0], blending.degree_v, blending.periodic_v)
    lo, hi = _blocks(ctrl, blending.degree_u, blending.degree_v, blending.periodic_u, blending.periodic_v)
    block_hit = tool.box_overlap(lo, hi)
    # mask[i, j] = block_hit[su_i, sv_j] as 0/1 products with one-hot rows: each block is tested
    # once (a gather would repeat the block's test for every sample it covers)
    dtype = lo.dtype
    rows = (su[:, None] == jnp.arange(block_hit.shape[0])[None, :]).astype(dtype)
    cols = (sv[:, None] == jnp.arange(block_hit.shape[1])[None, :]).astype(dtype)
    mask = (rows @ block_hit.astype(dtype) @ cols.T) > 0.5
    return mask, _parametric_window(mask, blending.params_u, blending.params_v)


@compiled
def contacts(
    blending: Blending,
    ctrl: Float[Array, "r s 3"],
    tool: AbstractTool,
    *,
    method: str = "window",
    sample_mask: Bool[Array, "m n"] | None = None,
) -> Contact:
    """Contact of the surface `(blending, ctrl)` with a rigid `tool`.

    **Arguments:**
    - `blending`: the surface's `Blending` (any grid, window or LOD view).
    - `ctrl (r, s, 3)`: control net (finite; differentiable).
    - `tool`: `Point`, `Sphere`, `Ellipsoid`, `Plane`, `Implicit` or `TriangleMesh`.
    - `method` (static): `"window"` (broad phase + parametric window, thesis ch. 3) or
      `"dense"` (every sample; the reference). Both give the same result.
    - `sample_mask (m, n)`: optional booleans on the blending's sample grid (e.g. a trimmed
      face's `bsjax.io.CadObject.sample_mask(blending)`); a sample where it is `False` is never
      in contact (`mask` False, `depth` 0), whatever the tool. Traced: a new mask of the same
      shape does not recompile. `None` (default): every sample. `window` stays the broad phase's.

    **Returns:** a `Contact`. A sample is in contact when it lies inside the solid tool
    (`value < 0`); its depth is the tool's penetration depth along the sample's normal
    (quadrics; Gao & Gibson, *Haptic B-spline surface sculpting with a shaped
    tool of implicit surface*, §3.2.2), the signed distance (plane, mesh) or the closest-point distance
    (implicit). For a `Point`, the three vertices of the nearest triangle carry the point's
    penetration split by barycentric weights, so `Σ depth` is the point's depth behind the
    surface. Every sum over the samples counts a surface point once: the second copy of a seam
    sampled twice (a closed direction's default grid holds both 0 and 1) is never in contact
    (`Blending.counted`); its share of a point's depth goes to the first copy.
    """
    tool = _checked_tool(tool)  # first: the clearest error for a wrong argument order
    if method not in ("window", "dense"):
        _checks.fail("method", "'window' or 'dense'", repr(method))
    ctrl = _checked_net(blending, ctrl, "ctrl")
    sample_mask = None if sample_mask is None else _checked_mask(blending, sample_mask)
    tool = tool.cast(ctrl.dtype)
    query = _point_contact if isinstance(tool, Point) else _solid_contact
    query = functools.partial(query, use_window=method == "window")
    if method == "dense":
        contact = query(blending, ctrl, tool)
    else:
        apart = tool.hull_apart(jax.lax.stop_gradient(ctrl).reshape(-1, 3))  # a decision: no gradient
        contact = _unless_apart(apart, query, blending, ctrl, tool)
    counted = blending.counted  # a seam sampled twice counts once
    return _masked(contact, counted if sample_mask is None else counted & sample_mask)


def _checked_mask(blending, sample_mask):
    """`sample_mask` as a boolean array of the blending's grid shape `(m, n)` (structure only)."""
    dtype = sample_mask.dtype if hasattr(sample_mask, "dtype") else np.asarray(sample_mask).dtype
    if dtype != np.bool_:
        raise TypeError(f"sample_mask: expected booleans of shape (m, n), got dtype {dtype}")
    if np.shape(sample_mask) != tuple(blending.grid_shape):
        _checks.fail(
            "sample_mask",
            f"shape {tuple(blending.grid_shape)} (the blending's sample grid)",
            f"shape {np.shape(sample_mask)}",
        )
    return jnp.asarray(sample_mask)


def _masked(contact: Contact, sample_mask) -> Contact:
    """`contact` with the samples outside `sample_mask` out of contact (mask False, depth 0)."""
    mask = contact.mask & sample_mask
    depth = jnp.where(sample_mask, contact.depth, 0)
    return eqx.tree_at(lambda c: (c.hit, c.mask, c.depth), contact, (jnp.any(mask), mask, depth))


def points_normals(blending, ctrl) -> tuple[Float[Array, "m n 3"], Float[Array, "m n 3"]]:
    """Samples `A_u P A_v^T` and unit normals `T_u × T_v / |·|` (limit normal at poles) of the grid.

    The same values as `blending.points(ctrl)` and `blending.normals(ctrl)` (to rounding), in
    fewer passes for polynomial surfaces: the three products `A_u P A_v^T`, `A'_u P A_v^T`,
    `A_u P A'_v^T` (thesis eq. 3.6) are written component-major `(3, m, n)`, the normal is formed
    per component (`collide._soa`), and the mixed derivative `A'_u P A'_v^T` that only the limit
    normal at a pole needs is computed only when some sample is degenerate (`lax.cond`).
    Rational surfaces take the blending's own methods.
    """
    if blending.weights is not None:
        return blending.points(ctrl), blending.normals(ctrl)
    a_u, a_v = blending.a_u, blending.a_v

    def product(k: int, l: int):
        return jnp.einsum("ai,ijc,bj->cab", a_u[k], ctrl, a_v[l])

    points, t_u, t_v = product(0, 0), product(1, 0), product(0, 1)
    normal = _unit_normal(t_u, t_v, lambda: product(1, 1), blending.params_u, blending.params_v)
    return _soa.stack(points), _soa.stack(normal)


def _unit_normal(t_u, t_v, mixed, params_u, params_v):
    """`bsjax.basis` unit normal (`_tensor.unit_normal`) of component-major tangents `(3, m, n)`.

    Where `|T_u × T_v| ≤ √ε (|T_u|² + |T_v|²)` (a pole) the limit `±T_u × T_uv` (or `±T_uv × T_v`)
    replaces the cross product; `mixed()` gives `T_uv` and runs only when such a sample exists.
    """
    n = _soa.cross(t_u, t_v)
    eps = jnp.finfo(n[0].dtype).eps
    # whether the branch runs: a cheap test without divisions that holds wherever the exact
    # one does (a factor 4 over rounding; overflow and underflow also make it hold)
    maybe = _soa.dot(n, n) <= 4 * eps * (_soa.dot(t_u, t_u) + _soa.dot(t_v, t_v)) ** 2

    def with_limit(n):
        uu, vv = _soa.dot(t_u, t_u), _soa.dot(t_v, t_v)
        degenerate = _soa.norm(n) <= jnp.sqrt(eps) * (uu + vv)
        t_uv = mixed()
        pole_in_v = vv <= uu
        sign_u = jnp.where(params_u < 0.5, 1.0, -1.0).astype(uu.dtype)[:, None]
        sign_v = jnp.where(params_v < 0.5, 1.0, -1.0).astype(uu.dtype)[None, :]
        along_u, along_v = _soa.cross(t_u, t_uv), _soa.cross(t_uv, t_v)
        return tuple(
            jnp.where(degenerate, jnp.where(pole_in_v, sign_u * lu, sign_v * lv), c)
            for c, lu, lv in zip(n, along_u, along_v)
        )

    n = jax.lax.cond(jnp.any(maybe), with_limit, lambda n: n, n)
    return _soa.unit(n)


def _solid_contact(blending, ctrl, tool, use_window: bool) -> Contact:
    points, normals = points_normals(blending, ctrl)
    value, depth, tool_normals = tool.contact_query(points, normals)
    inside = value < 0
    if use_window:
        window_mask, window = _sample_window(
            blending, jax.lax.stop_gradient(ctrl), jax.lax.stop_gradient(tool)
        )
        inside = inside & window_mask
    else:
        window = _parametric_window(jnp.ones(inside.shape, bool), blending.params_u, blending.params_v)
    depth = jnp.where(inside, depth, 0)
    return Contact(
        hit=jnp.any(inside),
        mask=inside,
        depth=depth,
        points=points,
        normals=normals,
        tool_normals=tool_normals,
        params_u=blending.params_u,
        params_v=blending.params_v,
        window=window,
        apart=jnp.zeros((), bool),
    )


_BLOCK = 6  # samples per side of the neighbourhood searched first by the point tool


def _nearest_on_grid(x, points):
    """Nearest triangle of the grid's tessellation: `(vertex indices (3,), closest, bary)`.

    The 5 × 5 cells around the nearest sample are searched first; the result is certified when
    no other cell's corner ball (centre: corner mean, radius: farthest corner) comes closer, and
    otherwise every triangle is searched (`lax.cond`, rarely taken). Which triangle is a decision
    (no gradient: `_triangles._nearest_face` by squared distance; the nearest sample and the
    corner balls over the whole grid one component at a time, `collide._soa`, so that XLA fuses
    them into one loop over the cells); the closest point and its barycentric weights on the
    chosen triangle are differentiable (`_closest_point_on_triangle`, computed once).
    """
    m, n = points.shape[:2]
    p, y = jax.lax.stop_gradient(points), jax.lax.stop_gradient(x)

    def search(block):
        """The vertex indices `(3,)` (in `block`'s grid) of its nearest triangle and its squared distance."""
        tris, faces = _cell_triangles(block)
        k, d2 = _nearest_face(y, _face_table(tris.reshape(-1, 3, 3)))
        return faces.reshape(-1, 3)[k].astype(jnp.int32), d2

    if m <= _BLOCK and n <= _BLOCK:
        face, _ = search(p)
    else:
        face = _certified_block_search(y, p, search)
    closest, bary = _closest_point_on_triangle(x, points.reshape(-1, 3)[face])
    return face, closest, bary


def _certified_block_search(y, p, search):
    """`search` over the `_BLOCK × _BLOCK` samples around the sample nearest to `y`, certified by
    the corner balls of the other cells, else over the whole grid `p (m, n, 3)` (`_nearest_on_grid`)."""
    m, n = p.shape[:2]
    bu, bv = min(_BLOCK, m), min(_BLOCK, n)
    q = _soa.split(p)
    near = jnp.argmin(_soa.dot(_soa.sub(q, y), _soa.sub(q, y)).reshape(-1))
    i0 = jnp.clip(near // n - bu // 2, 0, m - bu).astype(jnp.int32)
    j0 = jnp.clip(near % n - bv // 2, 0, n - bv).astype(jnp.int32)
    block = jax.lax.dynamic_slice(p, (i0, j0, jnp.zeros((), jnp.int32)), (bu, bv, 3))
    face, d2 = search(block)
    rows, cols = face // bv + i0, face % bv + j0
    face = rows * n + cols
    corners = [tuple(c[a, b] for c in q) for a, b in _CORNERS]
    centre = tuple(0.25 * (c0 + c1 + c2 + c3) for c0, c1, c2, c3 in zip(*corners))
    spread = [_soa.sub(c, centre) for c in corners]
    radius2 = functools.reduce(jnp.maximum, [_soa.dot(d, d) for d in spread])
    to_centre = _soa.sub(centre, y)
    bound = jnp.sqrt(_soa.dot(to_centre, to_centre)) - jnp.sqrt(radius2)
    r, c = jnp.arange(m - 1, dtype=jnp.int32)[:, None], jnp.arange(n - 1, dtype=jnp.int32)[None, :]
    inside = (r >= i0) & (r < i0 + bu - 1) & (c >= j0) & (c < j0 + bv - 1)
    certain = jnp.sqrt(d2) <= jnp.min(jnp.where(inside, jnp.inf, bound))
    return jax.lax.cond(certain, lambda: face, lambda: search(p)[0])


_HEAD, _TAIL = slice(None, -1), slice(1, None)
_CORNERS = ((_HEAD, _HEAD), (_TAIL, _HEAD), (_HEAD, _TAIL), (_TAIL, _TAIL))  # p00, p10, p01, p11


def _point_contact(blending, ctrl, tool: Point, use_window: bool) -> Contact:
    points, normals = points_normals(blending, ctrl)
    m, n = points.shape[:2]
    x = tool.position
    face, closest, bary = _nearest_on_grid(x, points)
    tri = points.reshape(-1, 3)[face]
    face = blending.first_samples.reshape(-1)[face]  # a seam copy's share goes to its first sample
    face_normal = _safe.unit(jnp.cross(tri[1] - tri[0], tri[2] - tri[0]))
    offset = x - closest
    dist = _safe.norm(offset)
    inside = (jnp.dot(offset, face_normal) < 0) & (dist <= tool.reach)
    depth = jnp.zeros(m * n, x.dtype).at[face].add(jnp.where(inside, bary * dist, 0)).reshape(m, n)
    mask = jnp.zeros(m * n, bool).at[face].set(inside).reshape(m, n)
    probe = jnp.where(dist > 0, _safe.unit(offset), -face_normal)
    tool_normals = jnp.zeros((m * n, 3), x.dtype).at[face].set(probe).reshape(m, n, 3)
    return Contact(
        hit=inside,
        mask=mask,
        depth=depth,
        points=points,
        normals=normals,
        tool_normals=tool_normals,
        params_u=blending.params_u,
        params_v=blending.params_v,
        window=_parametric_window(mask, blending.params_u, blending.params_v),
        apart=jnp.zeros((), bool),
    )


@declared
def surface_contacts(
    blending_a: Blending,
    ctrl_a: Float[Array, "ra sa 3"],
    blending_b: Blending,
    ctrl_b: Float[Array, "rb sb 3"],
    *,
    capacity: int | None = None,
    method: str = "hierarchy",
    flat_angle: float | None = 0.05,
) -> SurfaceContact:
    """Contact regions of two deformable B-spline surfaces (thesis §3.3).

    **Arguments:** each surface as `(blending, ctrl)` (finite control nets `(r, s, 3)`);
    `capacity` (static int ≥ 1): the most candidate cell pairs kept per refinement step
    (`overflow` reports when more intersect: call again with a larger capacity); `None`: 64 per
    sample of the longest side of either grid, which a crossing along a curve fits (about 47
    per sample: 12×12 plates crossing at 17°, 82² and 244² samples); `method`:
    `"hierarchy"` (control-hull broad phase → alternating LOD sphere refinement → triangle
    tests of the candidate cells) or `"dense"` (every triangle pair; the reference, small grids
    only); `flat_angle` δ (radians, static): blocks of ≥ 3 × 3 cells whose triangle normals
    stay within δ of each other and of the other block's are a flat contact, resolved by
    planes instead of refined (`collide.flat`; thesis §3.3.3.5) — `None` refines everything.

    **Returns:** a `SurfaceContact`; `mask_a`/`mask_b` mark the vertices of the triangles of
    each tessellation (`hierarchy.grid_mesh`) that intersect the other surface's triangles.

    The flat pass runs only when the exact refinement overflows. Called directly (concrete
    arrays), the two passes are two compiled programs and the host reads `overflow` in between,
    so the common case compiles and runs only the exact one (a program that also holds the
    unused flat branch ran about twice as long on CPU); the exact program does not depend on
    `flat_angle` (one compilation per capacity). Inside the caller's `jit`/`vmap` one program
    decides: a `lax.while_loop` of at most two runs of one refinement body, the flat pairs
    enabled in the second (one copy of the refinement in the program instead of two). Both give
    the same result.
    """
    args = (blending_a, ctrl_a, blending_b, ctrl_b)
    if capacity is None:
        capacity = _default_capacity(blending_a, blending_b)
    _check_options(capacity, method, flat_angle)
    if method != "hierarchy":  # the dense reference: capacity and flat angle play no part
        return _surface_contacts(*args, capacity=1, method=method, flat_angle=None, passes="exact")
    options = dict(capacity=capacity, method=method)
    if flat_angle is None:
        return _surface_contacts(*args, **options, flat_angle=None, passes="exact")
    if _traced(args):
        return _surface_contacts(*args, **options, flat_angle=flat_angle, passes="cond")
    exact = _surface_contacts(*args, **options, flat_angle=None, passes="exact")
    if not bool(exact.overflow):  # the host decides: one small read-back
        return exact
    return _surface_contacts(*args, **options, flat_angle=flat_angle, passes="flat")


def _check_options(capacity, method, flat_angle) -> None:
    """The static options of `surface_contacts` (raised before any compilation)."""
    if method not in ("hierarchy", "dense"):
        _checks.fail("method", "'hierarchy' or 'dense'", repr(method))
    _checks.check_count(capacity, "capacity")
    if flat_angle is not None and not (
        isinstance(flat_angle, (int, float, np.integer, np.floating))
        and not isinstance(flat_angle, bool)
        and 0 <= flat_angle < np.pi / 2
    ):
        _checks.fail("flat_angle", "None or an angle in radians in [0, π/2)", flat_angle)


def _default_capacity(blending_a, blending_b) -> int:
    """The candidate capacity `surface_contacts` uses by default: 64 cell pairs per sample of the
    longest side of either grid. Two surfaces crossing along a curve keep about 47 candidate
    pairs per sample of that side (12×12 plates crossing at 17°, at 82² and 244² samples), so
    one pass suffices there; a flatter crossing or a flat contact may still overflow it."""
    sides = (n for b in (blending_a, blending_b) for n in (b.params_u.shape[0], b.params_v.shape[0]))
    return 64 * max(sides)


def _traced(tree) -> bool:
    """Whether any leaf of `tree` is a tracer (the call runs inside a `jit`, `vmap` or `grad`)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


@compiled(static=("capacity", "flat_angle"))
def _surface_contacts(
    blending_a, ctrl_a, blending_b, ctrl_b, *, capacity, method, flat_angle, passes: str
) -> SurfaceContact:
    """`surface_contacts` compiled: `passes` (static) is `"cond"` (the exact refinement, then the
    flat pass when it overflows, in one loop), `"exact"` (the first only) or `"flat"` (the
    second only)."""
    _check_options(capacity, method, flat_angle)
    ctrl_a = _checked_net(blending_a, ctrl_a, "ctrl_a", "blending_a")
    ctrl_b = _checked_net(blending_b, ctrl_b, "ctrl_b", "blending_b")
    if method == "dense":
        return _dense_surfaces(blending_a, ctrl_a, blending_b, ctrl_b)
    # masks only: no tangent enters the `lax.cond` (JAX would linearise its branches under `grad`)
    ctrl_a, ctrl_b = jax.lax.stop_gradient((ctrl_a, ctrl_b))
    a, b = ctrl_a.reshape(-1, 3), ctrl_b.reshape(-1, 3).astype(ctrl_a.dtype)
    apart = _hulls_apart(a, b, jnp.zeros((), a.dtype))
    query = functools.partial(
        _hierarchy_surfaces,
        capacity=int(capacity),
        flat_angle=None if flat_angle is None else float(flat_angle),
        passes=passes,
    )
    return _unless_apart(apart, query, blending_a, ctrl_a, blending_b, ctrl_b)


def _vertex_mask(faces, hit, shape) -> Array:
    """The grid vertices `(m, n)` of the faces or cells that hit: vertex indices `faces (..., k)`
    into the flattened grid, `hit (...)`."""
    flags = jnp.broadcast_to(hit[..., None], faces.shape).reshape(-1)
    return jnp.zeros(shape[0] * shape[1], bool).at[faces.reshape(-1)].max(flags).reshape(shape)


def _hierarchy_surfaces(blending_a, ctrl_a, blending_b, ctrl_b, capacity, flat_angle, passes="cond"):
    """Refine every candidate pair down to triangles; only when that overflows the capacity
    (flat contact: every sphere intersects) run again with flat pairs resolved by planes, so
    the common case pays nothing for the flat test (`passes`: see `_surface_contacts`; `"cond"`
    is a `lax.while_loop` over one body whose flat pairs are enabled by a traced flag in its
    second run, which runs only after an overflow)."""
    pa, pb = blending_a.points(ctrl_a), blending_b.points(ctrl_b)
    lev_a = levels_for(max(pa.shape[0], pa.shape[1]) - 1)
    lev_b = levels_for(max(pb.shape[0], pb.shape[1]) - 1)
    spheres = _sphere_hierarchies(((pa, lev_a), (pb, lev_b)))  # built once for both passes
    refine = functools.partial(_refine_pairs, pa, lev_a, pb, lev_b, spheres, capacity)
    if flat_angle is None or passes == "exact":
        return refine(None)
    if passes == "flat":
        return refine(flat_angle)
    run = lambda use_flat: refine(flat_angle, use_flat)
    empty = jax.tree_util.tree_map(
        lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(run, jnp.zeros((), bool))
    )

    def again(state):  # the first run, and the flat one after an overflow
        k, result = state
        return (k == 0) | ((k == 1) & result.overflow)

    return jax.lax.while_loop(again, lambda state: (state[0] + 1, run(state[0] == 1)), (0, empty))[1]


def _refine_pairs(pa, lev_a, pb, lev_b, spheres, capacity, flat_angle, use_flat=None):
    """One refinement: without flat pairs (`flat_angle` None), with them, or with them when the
    traced flag `use_flat` holds (the planes and the flat resolution then run under `lax.cond`;
    without the flag the result is the exact refinement's)."""
    planes = flat = None
    if flat_angle is not None:
        planes_of = lambda: (block_planes(pa, lev_a), block_planes(pb, lev_b))
        if use_flat is None:
            planes = planes_of()
            flat = functools.partial(flat_pairs, *planes, flat_angle)
        else:
            planes = _when(use_flat, planes_of)
            flat = lambda *a: flat_pairs(*planes, flat_angle, *a) & use_flat
    leaf_a, leaf_b, valid, overflow, count, pairs = traverse(*spheres, capacity, flat)
    cell_a = _cells(leaf_a, lev_a, pa.shape)
    cell_b = _cells(leaf_b, lev_b, pb.shape)
    tri_a, face_a = candidate_triangles(pa, cell_a)  # (K, 2, 3, 3): only the candidate cells
    tri_b, face_b = candidate_triangles(pb, cell_b)
    hits = candidate_pairs_intersect(tri_a[:, :, None], tri_b[:, None, :], valid[:, None, None])
    mask_a = _vertex_mask(face_a, jnp.any(hits, 2), pa.shape[:2])
    mask_b = _vertex_mask(face_b, jnp.any(hits, 1), pb.shape[:2])
    pair_hit = jnp.any(hits, (1, 2))
    flat_hit = jnp.zeros((), jnp.int32)
    if pairs is not None and planes is not None:
        size = valid.shape[0]
        resolve = lambda: resolve_flat_pairs(
            pa, planes[0], pb, planes[1], pairs, flat_slots(size, lev_a), flat_slots(size, lev_b)
        )
        flat_a, flat_b, flat_hit, flat_overflow = resolve() if use_flat is None else _when(use_flat, resolve)
        mask_a, mask_b, overflow = mask_a | flat_a, mask_b | flat_b, overflow | flat_overflow
    return SurfaceContact(
        hit=jnp.any(pair_hit) | (flat_hit > 0),
        mask_a=mask_a,
        mask_b=mask_b,
        cells_a=cell_a,
        cells_b=cell_b,
        pair_hit=pair_hit,
        candidates=count.astype(jnp.int32),
        overflow=overflow,
        flat_pairs=flat_hit,
        apart=jnp.zeros((), bool),
    )


def _when(flag, fn):
    """`fn()` when the traced `flag` holds, else zeros of its shapes: the broad phase's
    `unless_apart` (one trace of `fn`, `lax.cond` at run time)."""
    return unless_apart(jnp.logical_not(flag), fn)


def _cells(leaf, levels, shape):
    """Block-major leaf index → (row, column) cell index, clipped into the grid."""
    rows, cols = block_order(levels)
    cells = np.stack([np.minimum(rows, shape[0] - 2), np.minimum(cols, shape[1] - 2)], -1).astype(np.int32)
    return jnp.asarray(cells)[leaf]


def _dense_surfaces(blending_a, ctrl_a, blending_b, ctrl_b):
    pa, pb = blending_a.points(ctrl_a), blending_b.points(ctrl_b)
    ta, fa = _cell_triangles(pa)
    tb, fb = _cell_triangles(pb)
    ta, fa, tb, fb = ta.reshape(-1, 3, 3), fa.reshape(-1, 3), tb.reshape(-1, 3, 3), fb.reshape(-1, 3)
    hits = _triangles_intersect(ta[:, None], tb[None, :])
    mask_a = _vertex_mask(fa, jnp.any(hits, 1), pa.shape[:2])
    mask_b = _vertex_mask(fb, jnp.any(hits, 0), pb.shape[:2])
    empty = jnp.zeros((0, 2), jnp.int32)
    return SurfaceContact(
        hit=jnp.any(hits),
        mask_a=mask_a,
        mask_b=mask_b,
        cells_a=empty,
        cells_b=empty,
        pair_hit=jnp.zeros((0,), bool),
        candidates=jnp.sum(hits).astype(jnp.int32),
        overflow=jnp.zeros((), bool),
        flat_pairs=jnp.zeros((), jnp.int32),
        apart=jnp.zeros((), bool),
    )
