"""Target-curve sculpting (thesis *Interactive shape modeling and dynamic deformation based on
spline sculpting*, §5.2.3 and §6.2.3–6.4): key points on a target curve pull their foot points on
a surface with the force `f = λ (k − p)` (eq. 6-20), distributed over the free control points by
the minimum-norm solve; a bound region blocks the control points outside it (eq. 6-22); the
dragger's frame change gives a rotation axis and angle (eqs. 6-29…6-31).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax.basis import BSplineCurve, BSplineSurface, SplineDirection, closest_points
from bsjax.sculpt._constraints import flat_ctrl, point_rows
from bsjax.sculpt._min_norm import _tensor_solve


class SculptResult(eqx.Module):
    """Result of `target_sculpt`.

    **Fields:**
    - `surface`: the sculpted surface.
    - `keys (m, 3)`: key points on the target curve (m = the capacity; see `active`).
    - `feet (m, 3)`, `foot_params (m, 2)`: their foot points on the surface before the edit.
    - `forces (m, 3)`: `λ (k − p)` (eq. 6-20), 0 for inactive keys.
    - `mask (r, s)`: the free control points (eq. 6-22).
    - `active (m,)`: the keys in use (the adaptive count of eq. 6-24 fills a fixed capacity).
    - `status ()`: 0 when every active key's foot moved by its force, 1 otherwise (blocked
      control points or too many keys: the least-squares edit).
    """

    surface: BSplineSurface
    keys: Float[Array, "m 3"]
    feet: Float[Array, "m 3"]
    foot_params: Float[Array, "m 2"]
    forces: Float[Array, "m 3"]
    mask: Bool[Array, "r s"]
    active: Bool[Array, " m"]
    status: Int[Array, ""]


# --- bound region -----------------------------------------------------------------------------
def _centres(direction: SplineDirection, dtype) -> Float[Array, " n"]:
    """Parameter of each control point: Greville abscissae (The NURBS Book eq. 9.8) for a
    clamped direction; the peak of each basis function for a periodic one."""
    n, p = direction.n_ctrl, direction.degree
    if direction.knots is not None:
        t = direction.knots.astype(dtype)
        return jnp.stack([jnp.mean(t[i + 1 : i + p + 1]) for i in range(n)])
    grid = jnp.linspace(0.0, 1.0, 16 * n, endpoint=False, dtype=dtype)
    return grid[jnp.argmax(direction.matrix(grid), axis=0)]


def _inside(points, polygon) -> Bool[Array, " P"]:
    """Crossing-number point-in-polygon test of `points (P, 2)` against a closed `polygon (K, 2)`."""
    a, b = polygon, jnp.roll(polygon, -1, axis=0)
    x, y = points[:, None, 0], points[:, None, 1]
    straddles = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    cross_x = a[None, :, 0] + _safe.ratio(
        (b[None, :, 0] - a[None, :, 0]) * (y - a[None, :, 1]), b[None, :, 1] - a[None, :, 1]
    )
    return jnp.sum(straddles & (x < cross_x), axis=1) % 2 == 1


@compiled
def bound_mask(surface: BSplineSurface, bound_uv) -> Bool[Array, "r s"]:
    """The free control points of a bound region (eq. 6-22): `E(Q_ij) = 1` when the control point's
    parameter point `(u_i, v_j)` (Greville abscissae) lies inside the closed bound curve, else 0.

    **Arguments:**
    - `surface`: the `BSplineSurface`.
    - `bound_uv`: the closed bound curve in parameter space: a polygon `(K, 2)` of (u, v) in
      [0, 1]² (closed implicitly), or a planar `BSplineCurve` in (u, v) (sampled at 8 points per
      control point).

    **Returns:** `(r, s)` booleans, True = free.
    """
    if not isinstance(surface, BSplineSurface):
        raise TypeError(f"surface: expected a BSplineSurface, got {type(surface).__name__}")
    polygon = _polygon(bound_uv, surface.ctrl.dtype)
    cu = _centres(surface.direction_u, polygon.dtype)
    cv = _centres(surface.direction_v, polygon.dtype)
    uu, vv = jnp.meshgrid(cu, cv, indexing="ij")
    return _inside(jnp.stack([uu.reshape(-1), vv.reshape(-1)], -1), polygon).reshape(uu.shape)


def _polygon(bound_uv, dtype):
    if isinstance(bound_uv, BSplineCurve):
        if bound_uv.dim != 2:
            _checks.fail("bound_uv", "a planar curve in (u, v)", f"dimension {bound_uv.dim}")
        t = jnp.linspace(0.0, 1.0, 8 * bound_uv.n_ctrl, dtype=bound_uv.ctrl.dtype)
        return bound_uv.evaluate(t).astype(dtype)
    if isinstance(bound_uv, (list, tuple)):
        bound_uv = jnp.asarray(bound_uv)
    _checks.check_real(bound_uv, "bound_uv")
    polygon = jnp.asarray(bound_uv, dtype)
    _checks.check_ndim(polygon, "bound_uv", 2, last=2)
    if polygon.shape[0] < 3:
        _checks.fail("bound_uv", "a closed polygon of at least 3 (u, v) points", f"shape {polygon.shape}")
    return _checks.in_range(polygon, "bound_uv", 0.0, 1.0)


# --- target sculpting -------------------------------------------------------------------------
def _key_params(surface, target, capacity: int, n_keys: int | None, dtype):
    """Target parameters `(m,)` and the active mask: `n_keys` uniform keys, or (eq. 6-24) one per
    iso-curve crossed between the end keys' feet along the dominant parameter direction, at least
    2, at most the capacity."""
    if n_keys is not None:
        t = jnp.linspace(0.0, 1.0, n_keys, dtype=dtype) if n_keys > 1 else jnp.full((1,), 0.5, dtype)
        return t, jnp.ones(n_keys, bool)
    ends = target.evaluate(jnp.array([0.0, 1.0], dtype))
    uv = closest_points(surface, ends).params
    span = jnp.abs(uv[1] - uv[0])
    lo, hi = jnp.minimum(uv[0], uv[1]), jnp.maximum(uv[0], uv[1])

    def crossed(k, centres):
        return jnp.sum((centres >= lo[k]) & (centres <= hi[k]))

    count_u = crossed(0, _centres(surface.direction_u, dtype))
    count_v = crossed(1, _centres(surface.direction_v, dtype))
    count = jnp.clip(jnp.where(span[0] >= span[1], count_u, count_v), 2, capacity)
    k = jnp.arange(capacity)
    t = jnp.where(k < count, k.astype(dtype) / jnp.maximum(count - 1, 1).astype(dtype), 0.0)
    return t, k < count


@compiled
def target_sculpt(
    surface: BSplineSurface,
    target_curve: BSplineCurve,
    lam: ArrayLike = 1.0,
    *,
    bound=None,
    n_keys: int | None = None,
    relax: int = 0,
) -> SculptResult:
    """Sculpt a surface towards a target curve (thesis *Interactive shape modeling and dynamic
    deformation based on spline sculpting*, §6.2.3–6.3, eqs. 6-19…6-24).

    Key points `k_t` on the target (6-19); foot points `p` = their closest points on the surface;
    forces `f = λ (k − p)` (6-20); the surface then moves by the minimum-norm displacement of the
    free control points with `ΔS(u_t, v_t) = f_t` at every foot (the tensor solve of `min_norm`,
    6-21), so λ = 1 interpolates the key points and a single key's foot moves by exactly λ·D.

    **Arguments:**
    - `surface`: a `BSplineSurface`; `target_curve`: a 3-D `BSplineCurve`.
    - `lam`: stiffness λ in [0, 1].
    - `bound`: `None` (all control points free: a global deformation), an `(r, s)` boolean mask,
      or a bound curve in parameter space (`bound_mask`, eq. 6-22).
    - `n_keys`: the key count; `None`: one per iso-curve crossed between the ends' feet along the
      dominant direction (eq. 6-24, iso-curves at the Greville abscissae), in a fixed capacity
      of `max(r, s)` keys (see `SculptResult.active`).
    - `relax`: relaxation at the ends of the target ([R] for the lost eqs. 6-25/6-26): `relax`
      extra points per end, spaced evenly along the dominant direction from the end's foot to
      the bound's extent (the free control points' span; the domain edge without a bound), whose
      displacement ramps linearly from the end force down to 0.

    **Returns:** a `SculptResult`.
    """
    if not isinstance(surface, BSplineSurface):
        raise TypeError(f"surface: expected a BSplineSurface, got {type(surface).__name__}")
    if not isinstance(target_curve, BSplineCurve) or target_curve.dim != 3:
        _checks.fail("target_curve", "a 3-D BSplineCurve", type(target_curve).__name__)
    relax = _checks.check_count(relax, "relax", 0)
    dtype = surface.ctrl.dtype
    lam = _checks.in_range(_checks.array(lam, "lam", dtype), "lam", 0.0, 1.0)
    _checks.check_ndim(lam, "lam", 0)
    r, s = surface.shape
    mask = _bound(surface, bound)
    capacity = max(r, s) if n_keys is None else _checks.check_count(n_keys, "n_keys")
    t, active = _key_params(surface, target_curve, capacity, n_keys, dtype)
    keys = target_curve.evaluate(t).astype(dtype)
    uv = closest_points(surface, keys).params
    feet = surface.evaluate(uv[:, 0], uv[:, 1])
    forces = jnp.where(active[:, None], lam * (keys - feet), 0.0)

    u, v, b, on = uv[:, 0], uv[:, 1], forces, active
    if relax:
        ru, rv, rb = _relaxation(surface, mask, uv, forces, active, relax)
        u, v, b = jnp.concatenate([u, ru]), jnp.concatenate([v, rv]), jnp.concatenate([b, rb])
        on = jnp.concatenate([active, jnp.ones(ru.shape[0], bool)])
    rows = jnp.where(on[:, None], point_rows(surface, u, v, 0, "u"), 0.0)
    scale = jnp.where(mask, 1.0, 0.0).astype(dtype).reshape(-1)
    d = _tensor_solve(rows, scale) @ b
    ctrl = flat_ctrl(surface) + d
    met = _safe.norm((rows @ d - b).reshape(-1)) <= np.sqrt(float(jnp.finfo(dtype).eps)) * (
        1.0 + _safe.norm(b.reshape(-1))
    )
    return SculptResult(
        surface=surface.with_ctrl(ctrl.reshape(surface.ctrl.shape)),
        keys=keys,
        feet=feet,
        foot_params=uv,
        forces=forces,
        mask=mask,
        active=active,
        status=jnp.where(met, 0, 1).astype(jnp.int32),
    )


def _bound(surface, bound) -> Bool[Array, "r s"]:
    grid = surface.shape
    if bound is None:
        return jnp.ones(grid, bool)
    if not isinstance(bound, BSplineCurve) and jnp.asarray(bound).dtype == jnp.bool_:
        bound = jnp.asarray(bound)
        if bound.shape != grid:
            _checks.fail("bound", f"a boolean mask of shape {grid} or a bound curve", f"shape {bound.shape}")
        return bound
    return bound_mask(surface, bound)


def _relaxation(surface, mask, uv, forces, active, relax: int):
    """Ramp points beyond each end of the target (see `target_sculpt`): `(2·relax,)` u, v and
    `(2·relax, 3)` displacements."""
    dtype = uv.dtype
    last = jnp.maximum(jnp.sum(active) - 1, 0)
    start, end = uv[0], uv[last]
    axis = jnp.where(jnp.abs(end[0] - start[0]) >= jnp.abs(end[1] - start[1]), 0, 1)
    cu, cv = _centres(surface.direction_u, dtype), _centres(surface.direction_v, dtype)
    free_u, free_v = jnp.any(mask, axis=1), jnp.any(mask, axis=0)
    lo = jnp.stack([jnp.min(jnp.where(free_u, cu, 1.0)), jnp.min(jnp.where(free_v, cv, 1.0))])
    hi = jnp.stack([jnp.max(jnp.where(free_u, cu, 0.0)), jnp.max(jnp.where(free_v, cv, 0.0))])
    ahead = end[axis] >= start[axis]  # the target runs towards increasing parameters
    frac = jnp.arange(1, relax + 1, dtype=dtype) / (relax + 1)
    pts, disp = [], []
    for foot, force, outward_low in ((start, forces[0], ahead), (end, forces[last], ~ahead)):
        limit = jnp.where(outward_low, lo[axis], hi[axis])
        along = foot[axis] + (limit - foot[axis]) * frac
        p = jnp.broadcast_to(foot, (relax, 2))
        pts.append(jnp.where(jnp.arange(2)[None, :] == axis, along[:, None], p))
        disp.append((1.0 - frac)[:, None] * force[None, :])
    pts, disp = jnp.concatenate(pts), jnp.concatenate(disp)
    return pts[:, 0], pts[:, 1], disp


# --- the dragger ------------------------------------------------------------------------------
@compiled
def frame_rotation(frame0: Float[Array, "3 3"], frame1: Float[Array, "3 3"]) -> tuple[Array, Array]:
    """Axis and angle of the rotation taking the dragger's frame `(U, V, W)` to `(U', V', W')`
    (thesis §6.4, eqs. 6-29…6-31).

    `D = ΔU × ΔV + ΔV × ΔW + ΔW × ΔU` (6-29), axis `D / |D|`, angle
    `Δα = 2 asin(|ΔX| / (2 |axis × X|))` (6-31) with X the frame vector farthest from the axis
    (the thesis uses U; any X not on the axis gives the same angle). `D = 0` (a pure
    translation, or a half turn, where the formula is blind): axis 0 and angle 0.

    **Arguments:** `frame0`, `frame1`: `(3, 3)`, rows U, V, W (orthonormal, finite).
    **Returns:** `(axis (3,), angle ())`, angle in [0, π].
    """
    f0, f1 = (_frame(f, n) for f, n in ((frame0, "frame0"), (frame1, "frame1")))
    du, dv, dw = f1 - f0
    axis, ok = _safe.unit_or_zero(jnp.cross(du, dv) + jnp.cross(dv, dw) + jnp.cross(dw, du))
    off = _safe.norm(jnp.cross(axis[None, :], f0))  # (3,) distance of each X from the axis
    k = jnp.argmax(off)
    ratio = _safe.ratio(_safe.norm(f1[k] - f0[k]), 2.0 * off[k])
    angle = jnp.where(ok, 2.0 * jnp.arcsin(jnp.clip(ratio, 0.0, 1.0)), 0.0)
    return axis, angle


def _frame(frame, name):
    if isinstance(frame, (list, tuple)):
        frame = jnp.asarray(frame)
    _checks.check_real(frame, name)
    frame = jnp.asarray(frame)
    if frame.shape != (3, 3):
        _checks.fail(name, "shape (3, 3) (rows U, V, W)", f"shape {frame.shape}")
    return _checks.finite(frame, name)
