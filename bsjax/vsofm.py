"""Volumetric self-organising feature map (VSOFM): a hexahedral lattice fitted inside a closed
surface from surface samples (thesis §5.3.2, Igwe & Knopf).

An `a × b × c` lattice of weight nodes, initially the samples' bounding box, is trained
Kohonen-style: each sample finds its best-matching boundary node, and every boundary node moves
toward the neighbourhood-weighted mean of the samples won around it (batch SOM: a whole batch per
cycle, the neighbourhood a separable Gaussian over lattice index distance), with a learning rate
and a radius that both decay geometrically over the cycles. Interior nodes are kept at the
discrete-harmonic position of the boundary (Jacobi sweeps during training, conjugate gradients at
the end), so they spread evenly inside. At the end boundary nodes are projected onto local
quadric fits of the samples.
`report` counts inverted hexahedra and measures boundary distance and element quality;
`mss.hex_lattice(nodes, material=...)` turns the result into a lattice.

No inverted hexahedra. A box lattice fitted into a smooth closed surface has cells on
the box's edges (two faces on the surface) and corners (three faces): at their box-edge corner
nodes all three edges are chords of the surface, so the corner Jacobian is second order, of the
sign of the surface's normal curvature across the box edge, and scaled about `κ h` (κ curvature,
h cell size). Two things therefore decide the sign, and both are handled at the root:

- the boundary nodes must carry the curvature: they are projected onto quadric patches, not onto
  tangent planes of the samples (a plane flattens the `κ h²/2` sag that makes these Jacobians
  positive, leaving them at 0 ± noise: 11 and 62 inverted cells at 30³ and 40³ on the teardrop);
- box edges must not run across concave (saddle) regions, where no tangential placement helps
  (the teardrop's pointed tip has concave meridians above z ≈ 0.69). The lattice starts as the
  samples' bounding box, already ordered and aligned with the shape, so the neighbourhood only
  needs to span a few cells (`Settings.radius_start = 2`); a neighbourhood spanning the whole
  lattice with a learning rate of 0.9 collapses it onto the samples' mean in the first cycles,
  and the batch noise then picks a new, tilted orientation (top-face corners of the teardrop
  lattice 1 apart in height, its edges climbing onto the tip).

The scaled Jacobian at those box-edge nodes is bounded by about `κ h`, so the minimum shrinks
with the lattice size (≈ 0.005–0.01 at 40³ on the teardrop and a unit sphere) while staying > 0.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks, _linalg, _safe
from bsjax._boundary import compiled, host_cache
from bsjax._declared import declared
from bsjax.batch import report_progress

__all__ = ["Report", "Settings", "corner_jacobians", "fit", "report"]


class Settings(eqx.Module):
    """Training settings: learning rate and neighbourhood radius (lattice units) decay
    geometrically from `*_start` to `*_end` (a start radius of a few cells keeps the initial
    box's orientation, see the module notes); `batch` samples per cycle (all when fewer);
    `sweeps` Jacobi sweeps of the interior per cycle; `boundary_smoothing` final rounds of
    Laplacian smoothing of the boundary nodes over their boundary neighbours, each followed by
    re-projection onto the samples (evens out the surface quads before the interior solve)."""

    learning_rate_start: float = eqx.field(static=True, default=0.9)
    learning_rate_end: float = eqx.field(static=True, default=0.05)
    radius_start: float = eqx.field(static=True, default=2.0)
    radius_end: float = eqx.field(static=True, default=0.5)
    batch: int = eqx.field(static=True, default=512)
    sweeps: int = eqx.field(static=True, default=2)
    boundary_smoothing: int = eqx.field(static=True, default=3)

    def __check_init__(self):
        for name in ("learning_rate_start", "learning_rate_end", "radius_start", "radius_end"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                _checks.fail(name, "a finite float > 0", value)
        _checks.check_count(self.batch, "batch")
        _checks.check_count(self.sweeps, "sweeps", minimum=0)
        _checks.check_count(self.boundary_smoothing, "boundary_smoothing", minimum=0)


@host_cache(maxsize=64)
def _boundary_mask(shape: tuple[int, int, int]) -> np.ndarray:
    mask = np.zeros(shape, dtype=bool)
    mask[[0, -1]] = True
    mask[:, [0, -1]] = True
    mask[:, :, [0, -1]] = True
    mask.flags.writeable = False
    return mask


@declared
def fit(
    points: Float[ArrayLike, "P 3"],
    shape: tuple[int, int, int],
    cycles: int = 300,
    key=None,
    settings: Settings = Settings(),
    progress: Callable[[int, int], object] | None = None,
) -> Float[Array, "a b c 3"]:
    """Train a VSOFM lattice of `shape = (a, b, c)` on surface samples `points (P, 3)`.

    **Arguments:**
    - `points`: samples of a closed surface (e.g. `blending.points(ctrl).reshape(-1, 3)`);
      repeated points (poles, seams) are dropped.
    - `shape`: lattice size, each ≥ 2.
    - `cycles`: training cycles (thesis: 300).
    - `key`: `jax.random` key for the batch draws (default `PRNGKey(0)`).
    - `settings`: `Settings`.
    - `progress`: an optional callback `progress(done, cycles)` called on the host after each
      training cycle as the training runs (`bsjax.batch.report_progress`, an ordered
      `jax.debug.callback`); the nodes are the same. A callable is static (the same callback
      reuses the compilation); None (the default) adds nothing to the program.

    **Returns:** node positions `shape + (3,)`; boundary nodes on the sampled surface (its local
    quadric fits), interior nodes inside. Check `report(points, nodes).inverted == 0`.

    The training is compiled at the boundary (`bsjax._boundary.compiled`, once per sample count,
    `shape`, `cycles` and `settings`), the samples' 16 nearest distinct neighbours found by a
    k-d tree on the host. Called with concrete samples, repeated samples are dropped and the
    neighbours found before the program runs; inside the caller's `jit` (where the count of
    distinct samples is not known) the search is a `jax.pure_callback` and the copies of a
    sample share one quadric patch and one sample's draw weight.
    """
    pts, shape = _check_fit_input(points, shape)  # pyright: ignore[reportAssignmentType]
    cycles = _checks.check_count(cycles, "cycles")
    if not isinstance(settings, Settings):
        raise TypeError(f"settings: expected a vsofm.Settings, got {type(settings).__name__}")
    _checks.check_progress(progress)
    key = jax.random.PRNGKey(0) if key is None else key
    scale = _power_of_two_scale(pts)  # the training is scale-free: 1e-300 or 1e300 samples work
    unit = pts / scale
    if isinstance(unit, jax.core.Tracer):  # inside the caller's jit: the search as a host callback
        near = None
    else:  # concrete, repeats dropped: the search now (at unit scale), its indices an input
        near = tuple(jnp.asarray(a) for a in _kd_neighbours(np.asarray(unit), min(_NEAR, pts.shape[0]), True))
    return _fit(unit, key, shape, cycles, settings, progress, near) * scale


def _power_of_two_scale(points):
    """The power of two nearest the samples' largest coordinate: dividing by it is exact, so
    samples of ordinary size train bit for bit as before."""
    xp = _checks.xp(points)
    return xp.exp2(xp.round(xp.log2(xp.max(xp.abs(points))))).astype(points.dtype)


def _check_fit_input(points, shape):
    _checks.check_ndim(points, "points", 2, last=3)
    _checks.check_real(points, "points")
    if np.ndim(shape) != 1 or len(shape) != 3:
        _checks.fail("shape", "three lattice sizes >= 2", shape)
    shape = tuple(_checks.check_count(size, "shape", 1) for size in shape)  # ints
    if min(shape) < 2:
        _checks.fail("shape", "three lattice sizes >= 2", shape)
    pts = jnp.asarray(points)
    if not jnp.issubdtype(pts.dtype, jnp.floating):
        pts = pts.astype(jnp.asarray(1.0).dtype)
    pts = _distinct(_checks.finite(pts, "points"))
    if pts.shape[0] < 4:
        _checks.fail("points", "at least 4 distinct samples", pts.shape[0])
    if not isinstance(pts, jax.core.Tracer):
        _check_volume(np.asarray(pts))
    return pts, shape


def _check_volume(points: np.ndarray) -> None:
    """Samples that span three dimensions: a flat or collinear set encloses no volume, and every
    cell of a lattice trained on it comes out inverted (singular values of the centred samples)."""
    spread = np.linalg.svd(points - points.mean(0), compute_uv=False)
    if not spread[2] > 1e-9 * spread[0]:
        _checks.fail(
            "points", "samples of a closed surface (spanning three dimensions)", "a flat or collinear set"
        )


def _distinct(points):
    """Concrete samples without repeats (poles, seams); traced samples as they are."""
    if isinstance(points, jax.core.Tracer):
        return points
    return jnp.asarray(np.unique(np.asarray(points), axis=0), dtype=points.dtype)


@compiled
def _fit(points, key, shape, cycles, settings, progress=None, near=None):
    """The training of `fit` on samples `points (P, 3)`; `near`: `(nbr, copies)` of
    `_kd_neighbours` found on the host already (distinct samples: a program without a host
    callback, which the persistent compilation cache can store), or `None` to search inside."""
    dtype = points.dtype
    nbr, copies = _neighbours(points, _NEAR) if near is None else near
    # draw probability of each sample ∝ the surface area it stands for (squared mean distance to
    # its 6 nearest distinct samples, shared among its copies), so a parameter grid crowded at the
    # poles does not crowd the lattice
    gap = jnp.linalg.norm(points[nbr[:, 1:7]] - points[:, None], axis=-1)
    weights = jnp.mean(gap, axis=1) ** 2 / copies.astype(dtype)
    weights = weights / jnp.sum(weights)
    n = int(np.prod(shape))
    bmask = _boundary_mask(shape)
    bidx = jnp.asarray(np.nonzero(bmask.ravel())[0].astype(np.int32))
    bgrid = jnp.asarray(bmask)[..., None]
    lo, hi = jnp.min(points, axis=0), jnp.max(points, axis=0)
    axes = jnp.meshgrid(*[jnp.linspace(0.0, 1.0, s, dtype=dtype) for s in shape], indexing="ij")
    nodes = lo[None, None, None] + jnp.stack(axes, axis=-1) * (hi - lo)[None, None, None]
    idx = [jnp.arange(s, dtype=dtype) for s in shape]
    r0 = settings.radius_start
    batch = settings.batch
    frac = jnp.arange(cycles, dtype=dtype) / max(cycles - 1, 1)
    sigma = r0 * (settings.radius_end / r0) ** frac
    alpha = settings.learning_rate_start * (settings.learning_rate_end / settings.learning_rate_start) ** frac
    draws = _draws(jax.random.split(key, cycles), weights, batch)
    count = None if progress is None else jnp.arange(1, cycles + 1)

    def cycle(nodes, xs):
        sig, lr, drawn, done = xs
        x = points[drawn]
        win = bidx[_nearest_node(x, nodes.reshape(-1, 3)[bidx])]
        acc = jax.ops.segment_sum(jnp.concatenate([x, jnp.ones((batch, 1), dtype)], axis=-1), win, n)
        acc = _gauss_smooth(acc.reshape(shape + (4,)), idx, sig)
        cnt = acc[..., 3:]
        ok = cnt > 1e-6 * jnp.max(cnt)
        target = acc[..., :3] / jnp.where(ok, cnt, 1.0)
        moved = jnp.where(ok & bgrid, nodes + lr * (target - nodes), nodes)
        nodes = _jacobi(moved, bgrid, settings.sweeps)
        report_progress(progress, done, cycles, after=nodes)
        return nodes, None

    nodes = jax.lax.scan(cycle, nodes, (sigma, alpha, draws, count))[0]
    surface = (points, *_patches(points, nbr))
    nodes = _snap(nodes, bidx, surface)
    smooth = lambda _, nodes: _snap(jnp.where(bgrid, _boundary_mean(nodes, bgrid), nodes), bidx, surface)
    nodes = jax.lax.fori_loop(0, settings.boundary_smoothing, smooth, nodes)  # one body in the program
    return _harmonic_interior(nodes, bgrid, 4 * max(shape))


def _draws(keys, weights, batch):
    """`(cycles, batch)` sample indices, cycle `c` drawn with `keys[c]` ∝ `weights`: the same
    indices as `jax.random.choice(keys[c], P, (batch,), p=weights)` (inverse-CDF sampling), with
    the cumulative sum formed once and every cycle's draw made in one batch before the training
    loop instead of once per cycle inside it."""
    cdf = jnp.cumsum(weights)
    u = jax.vmap(lambda k: jax.random.uniform(k, (batch,), dtype=cdf.dtype))(keys)
    return jnp.searchsorted(cdf, cdf[-1] * (1 - u)).astype(jnp.int32)


def _nearest_node(x, nodes):
    """Index of the nearest of `nodes (N, 3)` to each sample `x (B, 3)`, the best-matching unit
    (the first on ties, as `argmin`). `|w|² − 2 x·w` with its minimum and then the first index
    reaching it: two plain reductions, which XLA's CPU backend vectorises, where the paired
    value-and-index reduction of `argmin` runs element by element (≈ 2× slower at 12³)."""
    d2 = jnp.sum(nodes * nodes, axis=-1)[:, None] - 2.0 * nodes @ x.T  # (N, B)
    low = jnp.min(d2, axis=0, keepdims=True)
    first = jnp.where(d2 == low, jnp.arange(nodes.shape[0], dtype=jnp.int32)[:, None], nodes.shape[0])
    return jnp.min(first, axis=0)


def _gauss_smooth(field, idx, sigma):
    """Separable Gaussian `exp(−Δ²/2σ²)` over lattice index distance along the three axes."""
    for axis, i in enumerate(idx):
        g = jnp.exp(-((i[:, None] - i[None, :]) ** 2) / (2.0 * sigma * sigma))
        field = jnp.moveaxis(jnp.tensordot(g, jnp.moveaxis(field, axis, 0), axes=1), 0, axis)
    return field


def _neighbour_mean(nodes):
    """Mean of the 6 face neighbours (interior entries only are used)."""
    p = jnp.pad(nodes, ((1, 1), (1, 1), (1, 1), (0, 0)), mode="edge")
    s = (
        p[2:, 1:-1, 1:-1]
        + p[:-2, 1:-1, 1:-1]
        + p[1:-1, 2:, 1:-1]
        + p[1:-1, :-2, 1:-1]
        + p[1:-1, 1:-1, 2:]
        + p[1:-1, 1:-1, :-2]
    )
    return s / 6.0


def _boundary_mean(nodes, bgrid):
    """Mean of each node's face neighbours that are boundary nodes (the cube's surface graph)."""
    w = bgrid.astype(nodes.dtype)
    p = jnp.pad(nodes * w, ((1, 1), (1, 1), (1, 1), (0, 0)))
    q = jnp.pad(w, ((1, 1), (1, 1), (1, 1), (0, 0)))
    shifts = [
        (slice(2, None), slice(1, -1), slice(1, -1)),
        (slice(None, -2), slice(1, -1), slice(1, -1)),
        (slice(1, -1), slice(2, None), slice(1, -1)),
        (slice(1, -1), slice(None, -2), slice(1, -1)),
        (slice(1, -1), slice(1, -1), slice(2, None)),
        (slice(1, -1), slice(1, -1), slice(None, -2)),
    ]
    total = sum(p[s] for s in shifts)
    count = sum(q[s] for s in shifts)
    return total / jnp.maximum(count, 1.0)


def _jacobi(nodes, bgrid, sweeps):
    sweep = lambda _, nodes: jnp.where(bgrid, nodes, _neighbour_mean(nodes))
    return jax.lax.fori_loop(0, sweeps, sweep, nodes)


def _laplacian(u, bgrid):
    """`(I − mean of 6 neighbours)` on interior nodes; boundary entries pass through unchanged."""
    return jnp.where(bgrid, u, u - _neighbour_mean(jnp.where(bgrid, 0.0, u)))


def _harmonic_interior(nodes, bgrid, iterations):
    """Interior nodes at the discrete harmonic extension of the boundary: `iterations` of
    conjugate gradients (`bsjax._linalg.cg`) on the 7-point Laplacian with the boundary as
    Dirichlet data, from the current nodes."""
    b = jnp.where(bgrid, nodes, _neighbour_mean(jnp.where(bgrid, nodes, 0.0)))  # boundary contributions
    return _linalg.cg(lambda u: _laplacian(u, bgrid), b, iterations, x0=nodes)


_NEAR = 16  # samples per quadric patch (6 coefficients)


def _neighbours(points, k, distinct=False):
    """`(P, k)` indices of each sample's `k` nearest distinct samples (itself first) and `(P,)` how
    many times each sample occurs, from a k-d tree on the host (`scipy.spatial.cKDTree`,
    O(P log P)); a `jax.pure_callback`, so the same search runs inside the caller's `jit` and
    `vmap` (integer indices: no gradient flows through). Repeated samples (a parameter grid's
    poles and seams) share one entry of the tree, so no quadric patch is built from copies of
    one point; `distinct=True` (static: the caller dropped repeats already) skips that step."""
    k = min(k, points.shape[0])
    shape = (
        jax.ShapeDtypeStruct((points.shape[0], k), jnp.int32),
        jax.ShapeDtypeStruct((points.shape[0],), jnp.int32),
    )
    search = functools.partial(_kd_neighbours, k=k, distinct=distinct)
    return jax.pure_callback(search, shape, jax.lax.stop_gradient(points), vmap_method="sequential")


def _kd_neighbours(points, k, distinct=False):
    p = np.asarray(points, dtype=np.float64)
    if distinct:
        first = inverse = np.arange(len(p))
        counts = np.ones(len(p), dtype=np.int64)
        unique = p
    else:
        unique, first, inverse, counts = np.unique(
            p, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
        inverse = inverse.reshape(-1)
    tree = _kd_tree(unique)
    near = tree.query(unique, k=min(k, len(unique)))[1].reshape(len(unique), -1)
    near = np.pad(near, ((0, 0), (0, k - near.shape[1])), mode="edge")  # fewer distinct than k
    nbr = first[near][inverse]
    nbr[:, 0] = np.arange(len(p))
    return nbr.astype(np.int32), counts[inverse].astype(np.int32)


def _kd_tree(points):
    from scipy.spatial import cKDTree

    # sliding-midpoint splits: the median-split build crashes XLA's callback thread on inputs
    # with many repeated coordinates (scipy 1.17), and is not needed for a one-off query
    return cKDTree(points, balanced_tree=False)


def _nearest_sample(x, points):
    """`(N,)` index of the sample of `points (P, 3)` nearest each `x (N, 3)` (the first on exact
    ties; copies of a sample share one quadric patch, so which copy is found does not matter):
    exact squared distances, `_CHUNK` query points at a time (O(N P) work in O(_CHUNK P)
    memory), inside the program — no host callback, so the program can be stored by the
    persistent compilation cache."""

    def nearest(q):
        d = q[None, :] - points
        return jnp.argmin(jnp.sum(d * d, axis=-1)).astype(jnp.int32)

    return jax.lax.map(nearest, jax.lax.stop_gradient(x), batch_size=_CHUNK)


_CHUNK = 128  # query points per step of `_nearest_sample`


def _patches(points, nbr):
    """Local quadric surface patches, one per sample: frame rows `(t1, t2, n)` from the principal
    directions of its neighbours (`nbr (P, k)`), and the least-squares height
    `w = c0 + c1 u + c2 v + c3 u² + c4 uv + c5 v²` over them in that frame. A quadric follows the
    surface to second order, so projected boundary nodes carry the surface's curvature (a tangent
    plane flattens it, which leaves cells at lattice edges and corners with Jacobians ~ 0)."""
    near = points[nbr]  # (P, k, 3)
    d = near - jnp.mean(near, axis=1, keepdims=True)
    frame = jnp.swapaxes(jnp.linalg.eigh(jnp.swapaxes(d, 1, 2) @ d)[1][..., ::-1], 1, 2)  # t1, t2, n
    local = jnp.einsum("pij,pkj->pki", frame, near - points[:, None])
    s = jnp.sqrt(jnp.mean(local[..., 0] ** 2 + local[..., 1] ** 2, axis=1))[:, None]  # patch size
    u, v, w = local[..., 0] / s, local[..., 1] / s, local[..., 2]
    a = jnp.stack([jnp.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)  # (P, k, 6), O(1) columns
    ridge = (
        1e-6 * nbr.shape[1] * jnp.eye(6, dtype=points.dtype)[None]
    )  # few or coplanar samples stay solvable
    coef = jnp.linalg.solve(jnp.swapaxes(a, 1, 2) @ a + ridge, jnp.einsum("pki,pk->pi", a, w)[..., None])[
        ..., 0
    ]
    return frame, coef / jnp.concatenate([jnp.ones_like(s), s, s, s * s, s * s, s * s], axis=-1)


def _project(x, points, frame, coef):
    """Points `x (N, 3)` onto the quadric patch of their nearest sample (along its normal)."""
    i = _nearest_sample(x, points)
    f, c, p = frame[i], coef[i], points[i]
    u, v = (jnp.sum(f[:, j] * (x - p), axis=-1) for j in (0, 1))
    w = c[:, 0] + c[:, 1] * u + c[:, 2] * v + c[:, 3] * u * u + c[:, 4] * u * v + c[:, 5] * v * v
    return p + u[:, None] * f[:, 0] + v[:, None] * f[:, 1] + w[:, None] * f[:, 2]


def _snap(nodes, bidx, surface):
    """Boundary nodes onto the sampled surface (`surface = (points, frame, coef)`)."""
    flat = nodes.reshape(-1, 3)
    return flat.at[bidx].set(_project(flat[bidx], *surface)).reshape(nodes.shape)


# --- quality -------------------------------------------------------------------------------------------

# corner (bit i, j, k) → its three edge neighbours in right-handed order (+i, +j, +k reversed
# where the corner sits at the far end), so a positively oriented hexahedron has all 8 > 0.
_CORNERS = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]


@compiled
def corner_jacobians(
    nodes: Float[ArrayLike, "a b c 3"], scaled: bool = True
) -> Float[Array, "a-1 b-1 c-1 8"]:
    """Jacobian determinants of every hexahedron of the node grid `(a, b, c, 3)` at its 8 corners,
    `det(e1, e2, e3)` of the corner's three edges (scaled: divided by the three edge lengths, so
    1 for a cube, ≤ 0 for an inverted/degenerate corner; Knupp, *Achieving finite element mesh
    quality via optimization of the Jacobian matrix norm and associated quantities*, 2000)."""
    _checks.check_ndim(nodes, "nodes", 4, last=3)
    p = _checks.finite(_checks.array(nodes, "nodes"), "nodes")
    a, b, c = (s - 1 for s in p.shape[:3])
    # the 8 corners of every cell as one leading axis, so the program computes one determinant
    # expression over (8, a, b, c), not eight copies of it
    o = jnp.stack([p[i : i + a, j : j + b, k : k + c] for i, j, k in _CORNERS])
    index = {corner: n for n, corner in enumerate(_CORNERS)}
    sign = np.array([[1 - 2 * bit for bit in corner] for corner in _CORNERS], p.dtype)  # (8, 3)

    def edge(axis):
        other = [index[tuple(1 - x if d == axis else x for d, x in enumerate(corner))] for corner in _CORNERS]
        return (o[np.asarray(other)] - o) * sign[:, axis].reshape(8, 1, 1, 1, 1)

    e1, e2, e3 = edge(0), edge(1), edge(2)
    det = jnp.sum(e1 * jnp.cross(e2, e3), axis=-1)
    if scaled:
        det = _safe.ratio(det, _safe.norm(e1) * _safe.norm(e2) * _safe.norm(e3))
    return jnp.moveaxis(det, 0, -1)


class Report(eqx.Module):
    """Quality of a fitted lattice: `inverted` hexahedra (any corner Jacobian ≤ 0);
    `min_scaled_jacobian`, `mean_scaled_jacobian` over all corners; boundary-to-surface
    distance `boundary_max`, `boundary_mean` (to the local quadric fit of the 16 samples nearest
    the node's nearest sample, an estimate of the distance to the sampled surface that, unlike a
    tangent plane, does not count the surface's own sag), `sample_max` (to the nearest sample);
    `n_elements`."""

    inverted: int
    n_elements: int
    min_scaled_jacobian: float
    mean_scaled_jacobian: float
    boundary_max: float
    boundary_mean: float
    sample_max: float


def report(points: Float[ArrayLike, "P 3"], nodes: Float[ArrayLike, "a b c 3"]) -> Report:
    """Element quality and boundary distance of a VSOFM result.

    **Arguments:** the samples `points (P, 3)` (repeats dropped) and the fitted `nodes (a, b, c, 3)`.

    **Returns:** a `Report` of Python numbers. The measures are compiled at the boundary (once per
    sample count and lattice shape); the host drops repeated samples and finds the samples'
    neighbours and each boundary node's nearest sample with a k-d tree first (concrete values
    only: the report is a host-side summary).
    """
    from scipy.spatial import cKDTree

    _checks.check_real(points, "points")
    _checks.check_real(nodes, "nodes")
    _checks.check_ndim(nodes, "nodes", 4, last=3)
    _checks.check_ndim(points, "points", 2, last=3)
    nodes = np.asarray(nodes, dtype=np.float64)
    pts = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    _checks.finite(pts, "points")
    _checks.finite(nodes, "nodes")
    b = nodes[_boundary_mask(nodes.shape[:3])]
    near = cKDTree(pts).query(b)[0]
    p = jnp.asarray(pts)
    near_samples = _kd_neighbours(pts, min(_NEAR, len(pts)), distinct=True)[0]  # on the host, as above
    measures = _quality(jnp.asarray(nodes), p, jnp.asarray(near_samples))
    inverted, n_elements, jmin, jmean, dmax, dmean = (np.asarray(m) for m in measures)
    return Report(
        int(inverted),
        int(n_elements),
        float(jmin),
        float(jmean),
        float(dmax),
        float(dmean),
        float(near.max()),
    )


@compiled
def _quality(nodes, points, near):
    """`(inverted, n_elements, min and mean scaled Jacobian, max and mean boundary distance to the
    quadric patches)` of `report`, as arrays; `near (P, k)`: each sample's nearest samples (the
    host's k-d tree, so the program holds no host callback and is stored on disk)."""
    jac = corner_jacobians(nodes)
    bad = jnp.any(jac <= 0, axis=-1)
    b = nodes[_boundary_mask(nodes.shape[:3])]  # a static mask: a fixed gather
    dist = _safe.norm(b - _project(b, points, *_patches(points, near)))
    return jnp.sum(bad), jnp.asarray(bad.size), jnp.min(jac), jnp.mean(jac), jnp.max(dist), jnp.mean(dist)
