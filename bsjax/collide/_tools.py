"""Collision tools: point, sphere, ellipsoid, plane (half-space), implicit solid, triangle mesh.

These are the only rigid tools of bsjax: collision (`collide.contacts`), the mass-spring
penalty contact (`mss.simulate(..., tools=...)`), the haptic sculpting model and the examples
all take them. Every tool is an `eqx.Module` whose arrays (pose, size) are differentiable
leaves. Each solid tool knows its implicit function (`value(x) < 0` inside), the penetration
depth of a surface sample along the sample's normal (Gao & Gibson, *Haptic B-spline surface
sculpting with a shaped tool of implicit surface*, §3.2.2), the push-out of points inside
it (`push`: closest-point depth and outward normal, the penalty contact of the mass-spring
lattice), a bounding sphere for the control-hull broad phase, and a conservative overlap test
against boxes of control points (thesis §3.3.3.2, the parametric window).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from bsjax import _checks, _safe
from bsjax._boundary import compiled
from bsjax.basis import ProjectionSolver
from bsjax.collide import _soa
from bsjax.collide._broad import hulls_apart


def _float(x, name: str):
    """`x` as a real floating array (ints promoted to the default float; complex refused)."""
    _checks.check_real(x, name)
    arr = jnp.asarray(x)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


def _cast(arr, dtype):
    """`arr` in `dtype` (None or its own dtype: unchanged, no conversion dispatched)."""
    return arr if dtype is None or arr.dtype == dtype else arr.astype(dtype)


def _vector(x, name: str, size: int = 3, dtype=None):
    """A finite `(size,)` vector within the coordinate limit, checked after the cast to `dtype`
    (so a float32 tool refuses 1e39, which the cast makes inf)."""
    arr = _float(x, name)
    arr = _cast(arr, dtype)
    if arr.shape != (size,):
        _checks.fail(name, f"shape ({size},)", arr.shape)
    return _checks.coordinates(arr, name)


def _scalar(x, name: str, dtype=None):
    arr = _float(x, name)
    arr = _cast(arr, dtype)
    if arr.shape != ():
        _checks.fail(name, "a scalar", arr.shape)
    return _checks.coordinates(_checks.positive(arr, name), name)


def _points(x, dtype):
    """Query points `(..., 3)`: real, integers promoted to the tool's `dtype` (structure checked
    at trace time)."""
    _checks.check_real(x, "x")
    x = jnp.asarray(x)
    if x.ndim < 1 or x.shape[-1] != 3:
        _checks.fail("x", "points of shape (..., 3)", x.shape)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(dtype)


_sqrt = _safe.sqrt


def _bc(v, x):
    """`v` with leading unit axes to the rank of `x` (explicit broadcasting: rank promotion off)."""
    v = jnp.asarray(v)
    return v.reshape((1,) * (jnp.ndim(x) - v.ndim) + v.shape)


def _closer_root(a, b, c):
    """|t| of the root of `a t² + 2 b t + c = 0` closest to 0 (a > 0, c < 0 inside → real roots)."""
    disc = _sqrt(b * b - a * c)
    safe_a = jnp.where(a > 0, a, 1)
    t_plus, t_minus = (-b + disc) / safe_a, (-b - disc) / safe_a
    return jnp.where(jnp.abs(t_plus) <= jnp.abs(t_minus), t_plus, t_minus)


class AbstractTool(eqx.Module):
    """A rigid tool. Subclasses define the implicit value, depth, push and bounds (module doc).

    | method | meaning |
    |---|---|
    | `value(x)` | implicit function, `< 0` inside the solid |
    | `penetration(x, n)` | Gao & Gibson depth of surface samples along their normals `n` |
    | `push(x)` | `(depth, normal)`: closest-point penetration of points and the outward normal |

    `push` is the one interface through which the mass-spring penalty contact (`mss`), the
    haptic sculpting model and the examples use a tool: a point `x` inside the solid moves out
    to the surface at `x + depth · normal`.
    """

    def value(self, x: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """Implicit function: negative inside the tool."""
        raise NotImplementedError

    def penetration(self, x, n) -> tuple[Array, Array]:
        """`(depth (...), tool_normal (..., 3))` of samples `x` with unit surface normals `n`."""
        raise NotImplementedError

    def push(self, x: Float[Array, "... 3"]) -> tuple[Float[Array, "..."], Float[Array, "... 3"]]:
        """Penetration of points into the solid and the direction that pushes them out.

        **Arguments:** `x (..., 3)` points.

        **Returns:** `(depth (...), normal (..., 3))`: `depth ≥ 0` is the distance from `x` to
        the tool's surface where `value(x) < 0` (inside) and exactly 0 elsewhere; `normal` is the
        tool's outward unit normal at the surface point closest to `x`, so that
        `x + depth · normal` lies on the surface. Differentiable in `x` and the tool's arrays.
        A `Point` has no volume: its `push` raises `TypeError`.
        """
        raise TypeError(f"{type(self).__name__}: push needs a solid tool with a volume")

    def contact_query(self, x, n) -> tuple[Array, Array, Array]:
        """`(value (...), depth (...), tool_normal (..., 3))` of surface samples `x` with unit
        normals `n`: `value(x)` and `penetration(x, n)` together, as `collide.contacts` needs
        them (a tool whose two answers share work, such as a mesh's nearest-face search,
        answers both from one pass)."""
        return (self.value(x), *self.penetration(x, n))

    def bound(self) -> tuple[Array, Array] | None:
        """Bounding sphere `(center, radius)` of the tool, or `None` if unbounded/unknown."""
        return None

    def hull_apart(self, points: Float[Array, "p 3"]) -> Array:
        """Certified: the convex hull of `points` (the control net) cannot meet the tool."""
        b = self.bound()
        if b is None:
            return jnp.zeros((), bool)
        return hulls_apart(points, b[0][None], b[1])

    def box_overlap(self, lo, hi) -> Array:
        """Conservative test: may the tool meet the axis-aligned boxes `[lo, hi]` `(..., 3)`?"""
        b = self.bound()
        if b is None:
            return jnp.ones(lo.shape[:-1], bool)
        return _sphere_box(b[0], b[1], lo, hi)

    def cast(self, dtype) -> "AbstractTool":
        """The same tool with its floating arrays in `dtype`."""
        return jax.tree_util.tree_map(
            lambda a: (
                a.astype(dtype) if isinstance(a, jax.Array) and jnp.issubdtype(a.dtype, jnp.floating) else a
            ),
            self,
        )


def _sphere_box(center, radius, lo, hi):
    nearest = jnp.clip(_bc(center, lo), lo, hi)
    return jnp.sum((nearest - _bc(center, lo)) ** 2, -1) <= radius * radius


class Point(AbstractTool):
    """A point tool (a stylus tip). It is in contact when it lies behind the tessellated surface.

    **Fields:** `position (3,)`; `reach` (≥ 0, default ∞): the deepest penetration that still
    counts as contact (use a finite reach for open surfaces, whose back side is unbounded).
    Contact is decided against the nearest triangle of the tessellated grid (thesis §3.4 tests
    the point against the two triangles of the final cell); the depth is the distance to it.
    """

    position: Float[Array, "3"]
    reach: Float[Array, ""]

    def __init__(self, position, reach=float("inf")):
        self.position = _vector(position, "position")
        reach = _float(reach, "reach").astype(self.position.dtype)
        if reach.shape != ():
            _checks.fail("reach", "a scalar >= 0", f"shape {reach.shape}")
        self.reach = _checks.check(reach, ~(reach >= 0), "reach", "a scalar >= 0", "a negative value or NaN")

    def push(self, x):
        """A point tool has no volume: refused (use a `Sphere` of small radius for a stylus tip)."""
        raise TypeError(
            "Point: a point tool has no volume, so it cannot push points out of it; "
            "use a solid tool (Sphere, Ellipsoid, Plane, Implicit, TriangleMesh)"
        )

    def hull_apart(self, points):
        # a contact lies within `reach` of the surface, hence of its control hull
        return hulls_apart(points, self.position[None], self.reach)

    def box_overlap(self, lo, hi):
        r = jnp.where(jnp.isfinite(self.reach), self.reach, 0)
        near = _sphere_box(self.position, r, lo, hi)
        return jnp.where(jnp.isfinite(self.reach), near, True)


class Sphere(AbstractTool):
    """A solid ball `|x − center| < radius`.

    **Fields:** `center (3,)`, `radius` > 0. Depth: exact distance along the sample's normal to
    the sphere (ray–sphere intersection, the closer root), Gao & Gibson's depth.
    """

    center: Float[Array, "3"]
    radius: Float[Array, ""]

    def __init__(self, center, radius):
        self.center = _vector(center, "center")
        self.radius = _scalar(radius, "radius", self.center.dtype)

    @compiled
    def value(self, x):
        y = _soa.sub(_soa.split(x), self.center)  # per component: one fused loop on CPU
        return _soa.dot(y, y) - self.radius**2

    @compiled
    def penetration(self, x, n):
        x, n = _soa.split(x), _soa.split(n)
        y = _soa.sub(x, self.center)
        t = _closer_root(_soa.dot(n, n), _soa.dot(y, n), _soa.dot(y, y) - self.radius**2)
        hit = tuple(x[i] + t * n[i] for i in range(3))
        return jnp.abs(t), _soa.stack(_soa.unit(_soa.sub(hit, self.center)))

    @compiled
    def push(self, x):
        """`depth = max(r − |x − c|, 0)`, `normal = (x − c)/|x − c|` (+z at the centre)."""
        x = _points(x, self.center.dtype)
        d = x - _bc(self.center, x)
        normal, ok = _safe.unit_or_zero(d)
        up = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], normal.dtype), normal.shape)
        normal = jnp.where(ok[..., None], normal, up)
        return jnp.maximum(self.radius - _safe.norm(d), 0), normal

    def bound(self):
        return self.center, self.radius


_MAX_ASPECT = 1e12  # the largest ratio of an ellipsoid's semi-axes (its quadratics stay finite)


class Ellipsoid(AbstractTool):
    """A solid ellipsoid `|D⁻¹ Rᵀ (x − center)| < 1`, `D = diag(radii)`.

    **Fields:** `center (3,)`, `radii (3,)` > 0 (semi-axes), `rotation (3, 3)` orthonormal, its
    columns the axes in world coordinates (identity by default). Depth: exact, along the sample
    normal (the quadratic of Gao & Gibson §3.2.2 solved in the ellipsoid's unit-sphere frame).
    """

    center: Float[Array, "3"]
    radii: Float[Array, "3"]
    rotation: Float[Array, "3 3"]

    def __init__(self, center, radii, rotation=None):
        self.center = _vector(center, "center")
        radii = _checks.positive(_vector(radii, "radii", dtype=self.center.dtype), "radii")
        r = _checks.values(radii)  # numpy when concrete: no program compiled per check
        self.radii = _checks.check(
            radii,
            r.max() > _MAX_ASPECT * r.min(),
            "radii",
            f"semi-axes within a ratio of {_MAX_ASPECT:.0e} of each other",
            "a larger ratio",
            lambda r: f"{r.max() / r.min():.3g}",
        )
        rotation = _cast(_float(np.eye(3) if rotation is None else rotation, "rotation"), self.center.dtype)
        if rotation.shape != (3, 3):
            _checks.fail("rotation", "shape (3, 3)", rotation.shape)
        rotation = _checks.finite(rotation, "rotation")
        # float32 rotations from quaternions are orthonormal to ~1e-7 only
        tol = max(1e-6, 100 * float(jnp.finfo(rotation.dtype).eps))
        xp, q = _checks.xp(rotation), _checks.values(rotation)
        err = xp.max(xp.abs(q.T @ q - xp.eye(3, dtype=q.dtype)))
        self.rotation = _checks.check(
            rotation,
            (err > tol) | (xp.linalg.det(q) < 0),
            "rotation",
            "a proper rotation matrix (R^T R = I, det 1)",
            "a matrix that is not",
            lambda r: f"|R^T R - I| = {np.max(np.abs(r.T @ r - np.eye(3))):.2g}, det {np.linalg.det(r):.3g}",
        )

    def _local(self, x):
        return ((x - _bc(self.center, x)) @ self.rotation) / _bc(self.radii, x)

    def _quadric(self):
        """`Q = R D⁻² Rᵀ` (symmetric 3 × 3): `value(x) = (x − c)ᵀ Q (x − c) − 1`."""
        r = self.rotation / self.radii[None, :]
        return r @ r.T

    def _query(self, x, n):
        """`(value, |t|, tool normal)` of component arrays `x`, `n`: with `d = x − c` and
        `e = Q n` the ray `x + t n` meets the surface where `(nᵀe) t² + 2 (dᵀe) t + dᵀQd − 1 = 0`
        (the closer root, Gao & Gibson §3.2.2) and the outward normal there is `unit(Qd + t e)`,
        the gradient `Q (d + t n)` — no division per component, one matrix for all three."""
        q = self._quadric()
        d = _soa.sub(x, self.center)
        qd = tuple(q[i, 0] * d[0] + q[i, 1] * d[1] + q[i, 2] * d[2] for i in range(3))
        value = _soa.dot(d, qd) - 1
        if n is None:
            return value
        e = tuple(q[i, 0] * n[0] + q[i, 1] * n[1] + q[i, 2] * n[2] for i in range(3))
        t = _closer_root(_soa.dot(n, e), _soa.dot(d, e), value)
        grad = tuple(qd[i] + t * e[i] for i in range(3))
        return value, jnp.abs(t), _soa.unit(grad)

    @compiled
    def value(self, x):
        return self._query(_soa.split(x), None)

    @compiled
    def push(self, x):
        """Exact closest point of the ellipsoid surface (`_ellipsoid_closest`), in its frame."""
        x = _points(x, self.center.dtype)
        r = self.rotation
        d = [x[..., j] - self.center[j] for j in range(3)]
        y = [sum(d[j] * r[j, i] for j in range(3)) for i in range(3)]  # per component: fused on CPU
        z, inside = _ellipsoid_closest(y, self.radii)
        depth = jnp.where(inside, _safe.sqrt(sum((y[i] - z[i]) ** 2 for i in range(3))), 0)
        # the gradient z_i / r_i², scaled by r_min² so no term overflows for thin ellipsoids
        small = jnp.min(self.radii)
        g = [(z[i] / self.radii[i]) * (small / self.radii[i]) for i in range(3)]
        n = [sum(r[j, i] * g[i] for i in range(3)) for j in range(3)]
        return depth, _safe.unit(jnp.stack(n, -1))

    @compiled
    def penetration(self, x, n):
        _, depth, normal = self._query(_soa.split(x), _soa.split(n))
        return depth, _soa.stack(normal)

    def contact_query(self, x, n):
        value, depth, normal = self._query(_soa.split(x), _soa.split(n))
        return value, depth, _soa.stack(normal)

    def bound(self):
        return self.center, jnp.max(self.radii)

    def hull_apart(self, points):
        # an affine map keeps convex hulls: test against the unit ball in the ellipsoid frame
        return hulls_apart(self._local(points), jnp.zeros((1, 3), points.dtype), jnp.ones((), points.dtype))

    def box_overlap(self, lo, hi):
        # The box's image in the unit-sphere frame `y = D⁻¹ Rᵀ (x − c)` is a parallelepiped; its
        # bounding box (that of the 8 corners' images) is `M (mid − c) ± |M| half` with
        # `M = D⁻¹ Rᵀ`. Written per component, it fuses into one loop over the boxes.
        m = self.rotation.T / self.radii[:, None]
        mid = [(lo[..., k] + hi[..., k]) * 0.5 - self.center[k] for k in range(3)]
        half = [(hi[..., k] - lo[..., k]) * 0.5 for k in range(3)]
        gap = []
        for i in range(3):
            centre = m[i, 0] * mid[0] + m[i, 1] * mid[1] + m[i, 2] * mid[2]
            extent = jnp.abs(m[i, 0]) * half[0] + jnp.abs(m[i, 1]) * half[1] + jnp.abs(m[i, 2]) * half[2]
            gap.append(jnp.maximum(jnp.abs(centre) - extent, 0))  # the box's distance to 0 along i
        return _soa.dot(gap, gap) <= 1


def _ellipsoid_closest(y, a, iterations: int = 16):
    """Closest point `z` of the ellipsoid `Σ (z_i / a_i)² = 1` to `y` (its own frame, semi-axes
    `a (3,)`), and whether `y` is inside; points as three component arrays `[y_0, y_1, y_2]`.

    Lagrange condition (Eberly, *Distance from a point to an ellipse, an ellipsoid, or a
    hyperellipsoid*): `z_i = a_i² y_i / (a_i² + t)` with `t` the root in `(−a_min², ∞)` of
    `Σ (a_i y_i / (a_i² + t))² = 1`. Written in `s = t + a_min² > 0` the root is bracketed by
    `[max_i (a_i |y_i| − a_i² + a_min²), |a ∘ y|]` (one term alone; every shift dropped), and
    `ψ(s) = q(s)^{−1/2}` with `q(s) = Σ (a_i y_i / (a_i² − a_min² + s))²` is increasing and
    nearly linear (exactly linear for a sphere), so a safeguarded Newton iteration on `ψ(s) = 1`
    (bisection whenever Newton leaves the bracket), started from the radial point's estimate,
    reaches round-off in 8 steps for axis ratios up to 10 and in 16 for ratios up to 10⁶
    (16 are run). A last Newton step from the stopped-gradient root carries the implicit-function
    derivative. Where `y` lies on the medial plane of the smallest axis (`y_k = 0`, e.g. the
    centre) and no root lies above `s = 0`, the closest point is completed on that axis.
    The arithmetic is written per component (structure of arrays): XLA on CPU fuses it into one
    loop over the points, where reductions over a trailing axis of 3 are several times slower.
    """
    dtype = y[0].dtype
    a2 = a * a
    k = jnp.argmin(a)
    comps = list(y)
    shift = [a2[i] - a2[k] for i in range(3)]  # a_i² − a_min² ≥ 0
    ay2 = [(a[i] * comps[i]) ** 2 for i in range(3)]
    frozen = jax.lax.stop_gradient((ay2, shift))
    # bracket: each term alone bounds the root below, and `q(s) ≤ Σ a_i² y_i² / s²` above
    lo = jnp.maximum(functools.reduce(jnp.maximum, [_safe.sqrt(c) - sh for c, sh in zip(*frozen)]), 0)
    hi = jnp.maximum(_safe.sqrt(sum(frozen[0])), lo)

    def body(carry):
        s, lo, hi = carry
        p, dp = _ellipsoid_psi(s, *frozen)
        lo, hi = jnp.where(p < 1, s, lo), jnp.where(p < 1, hi, s)
        newton = s - _safe.ratio(p - 1, dp)
        ok = (newton >= lo) & (newton <= hi) & (dp > 0)
        return jnp.where(ok, newton, 0.5 * (lo + hi)), lo, hi

    carry = (jnp.clip(_ellipsoid_start(comps, a, a2[k]), lo, hi), lo, hi)
    for _ in range(iterations):  # unrolled: XLA fuses the whole solve into one loop over points
        carry = body(carry)
    s = carry[0]
    p, dp = _ellipsoid_psi(s, ay2, shift)
    root = jnp.abs(p - 1) < jnp.sqrt(jnp.finfo(dtype).eps)
    s = jnp.where(root, s - _safe.ratio(p - 1, dp), s)  # one Newton step: the implicit derivative
    z = [_safe.ratio(a2[i] * comps[i], shift[i] + s) for i in range(3)]
    # medial case (y_k = 0, no root above s = 0): complete z on the smallest axis onto the surface
    yk = sum(jnp.where(k == i, comps[i], 0) for i in range(3))
    rest = 1 - sum(jnp.where(k == i, 0, (z[i] / a[i]) ** 2) for i in range(3))
    zk = jnp.where(yk < 0, -1, 1).astype(dtype) * a[k] * _safe.sqrt(rest)
    medial = (yk == 0) & ~root
    z = [jnp.where(medial & (k == i), zk, z[i]) for i in range(3)]
    inside = sum((comps[i] / a[i]) ** 2 for i in range(3)) < 1
    return z, inside


def _ellipsoid_start(comps, a, a2_min):
    """A start for `s` from the radial point `z_r = y / |y / a|`: the least-squares `t` of the
    Lagrange condition `y − z_r = t z_r / a²` (exact for a sphere), as `s = t + a_min²` ≥ 0."""
    comps, a = jax.lax.stop_gradient((comps, a))
    rho = _safe.sqrt(sum((comps[i] / a[i]) ** 2 for i in range(3)))
    zr = [_safe.ratio(comps[i], rho) for i in range(3)]
    g = [zr[i] / a[i] ** 2 for i in range(3)]
    t = _safe.ratio(sum((comps[i] - zr[i]) * g[i] for i in range(3)), sum(g[i] * g[i] for i in range(3)))
    return jnp.maximum(t + jax.lax.stop_gradient(a2_min), 0)


def _ellipsoid_psi(s, ay2, shift):
    """`(ψ, dψ/ds)` of `_ellipsoid_closest`: `ψ = q^{−1/2}`, `q = Σ a_i² y_i² / (shift_i + s)²`
    (per-component lists); `ψ = ∞` where `q = 0` (the centre), 0 where a term is singular."""
    q, dq, singular = 0, 0, False
    for c, sh in zip(ay2, shift):
        den = sh + s
        pos = den > 0
        inv = 1 / jnp.where(pos, den, 1)
        term = c * inv * inv
        q = q + jnp.where(pos, term, 0)
        dq = dq - 2 * jnp.where(pos, term * inv, 0)
        singular = singular | (~pos & (c > 0))
    ok = (q > 0) & ~singular
    qs = jnp.where(ok, q, 1)
    inv = jax.lax.rsqrt(qs)
    psi = jnp.where(ok, inv, jnp.where(singular, 0, jnp.inf))
    return psi, jnp.where(ok, -0.5 * dq * inv / qs, 0)


class Plane(AbstractTool):
    """A half-space tool: the solid is the side the normal points away from, `n·(x − p) < 0`.

    **Fields:** `point (3,)`, `normal (3,)` (normalised here; a zero normal is rejected).
    Depth: the signed distance `−n·(x − p)`.
    """

    point: Float[Array, "3"]
    normal: Float[Array, "3"]

    def __init__(self, point, normal):
        self.point = _vector(point, "point")
        normal = _vector(normal, "normal", dtype=self.point.dtype)
        normal = _checks.check(
            normal, jnp.all(normal == 0), "normal", "a non-zero vector", "a zero vector", lambda n: n.tolist()
        )
        self.normal = _safe.unit(normal)

    @compiled
    def value(self, x):
        return _soa.dot(_soa.sub(_soa.split(x), self.point), self.normal)

    @compiled
    def penetration(self, x, n):
        depth = -self.value(x)
        return depth, jnp.broadcast_to(self.normal, x.shape)

    @compiled
    def push(self, x):
        """`depth = max(−n·(x − p), 0)`, `normal = n` (exact: the signed distance)."""
        x = _points(x, self.point.dtype)
        return jnp.maximum(-self.value(x), 0), jnp.broadcast_to(self.normal, x.shape)

    def hull_apart(self, points):
        return jax.lax.stop_gradient(jnp.min(self.value(points)) >= 0)

    def box_overlap(self, lo, hi):
        low_corner = jnp.where(_bc(self.normal > 0, lo), lo, hi)  # the box corner deepest into the solid
        return self.value(low_corner) < 0


# the projection onto fn = 0 is a root-find of the Lagrange conditions: a few more Newton steps
# than a surface's Gauss–Newton projection, and its own default tolerances
_IMPLICIT_SOLVER = ProjectionSolver(rtol=1e-8, atol=1e-10, max_steps=32)


def _newton(residual, z0, rtol: float, atol: float, max_steps: int):
    """`(z, converged)`: Newton's method on `residual(z) = 0 (n,)` from `z0 (n,)`, until a
    step is within `atol + rtol·|z|` (max norms) or after `max_steps` steps.

    Differentiated implicitly (`jax.lax.custom_root`: `dz/dθ = −J⁻¹ ∂r/∂θ` for whatever the
    residual closes over), not through the iterations. Written out rather than
    `optimistix.root_find`: the same Newton steps trace in a tenth of the time, which is most of
    a direct call's first call once its program is cached on disk (an `Implicit`'s user function
    keeps it from being stored whole).
    """

    def solve(f, z):
        def step(carry):
            z, _, k = carry
            jac, r = jax.jacfwd(lambda z: (f(z),) * 2, has_aux=True)(z)  # one trace of f
            dz = jnp.linalg.solve(jac, r)
            z = z - dz
            return z, jnp.max(jnp.abs(dz)) <= atol + rtol * jnp.max(jnp.abs(z)), k + 1

        def going(carry):
            z, done, k = carry
            return ~done & (k < max_steps) & jnp.all(jnp.isfinite(z))

        z, done, _ = jax.lax.while_loop(going, step, (z, jnp.asarray(False), jnp.asarray(0)))
        return z, done.astype(z.dtype)  # a float: `custom_root`'s JVP gives aux a zero tangent

    def tangent_solve(g, y):  # the linearised residual's inverse
        return jnp.linalg.solve(jax.jacfwd(g)(y), y)

    z, converged = jax.lax.custom_root(residual, z0, solve, tangent_solve, has_aux=True)
    return z, converged > 0


class Implicit(AbstractTool):
    """Any implicit solid `fn(x) < 0` (a torus, a blend of primitives, a learned SDF…).

    **Fields:** `fn` (static): `fn(x (3,)) -> scalar`, or `fn(x, params)` when `params` is given
    (then the tool is differentiable in `params`); optional bounding sphere `center`, `radius`
    for the broad phase; `solver`, a `basis.ProjectionSolver` (default: rtol 1e-8, atol 1e-10,
    32 Newton steps).
    Depth: distance to the closest point of `fn = 0`: a start point on the surface along the
    gradient ray (doubling and bisection), refined by a Newton solve (`_newton`) of the Lagrange
    conditions `y − x + λ∇f(y) = 0, f(y) = 0` (differentiated implicitly); the start point is
    kept where Newton fails or lands on a farther stationary point.
    """

    fn: Callable = eqx.field(static=True)
    params: Any = None
    center: Float[Array, "3"] | None = None
    radius: Float[Array, ""] | None = None
    solver: ProjectionSolver = eqx.field(static=True, default=_IMPLICIT_SOLVER)

    def __init__(self, fn, params=None, center=None, radius=None, solver=_IMPLICIT_SOLVER):
        if not callable(fn):
            raise TypeError(f"fn: expected a callable f(x) -> scalar, got {type(fn).__name__}")
        if (center is None) != (radius is None):
            _checks.fail("center, radius", "both or neither", (center, radius))
        self.fn, self.params, self.solver = fn, params, solver
        self.center = None if center is None else _vector(center, "center")
        self.radius = None if radius is None else _scalar(radius, "radius")
        leaves = [leaf for leaf in jax.tree_util.tree_leaves(params) if hasattr(leaf, "dtype")]
        for leaf in leaves:
            _checks.check_real(leaf, "params")

    def _f(self, x):
        value = self.fn(x) if self.params is None else self.fn(x, self.params)
        if np.shape(value) != ():  # traced: the shape is known while tracing
            _checks.fail("fn", "a scalar per point, fn(x (3,)) -> ()", f"shape {np.shape(value)}")
        return value

    @compiled
    def value(self, x):
        flat = x.reshape(-1, 3)
        return jax.vmap(self._f)(flat).reshape(x.shape[:-1])

    @compiled
    def penetration(self, x, n):
        flat = x.reshape(-1, 3)
        depth, normal = jax.vmap(self._project_one)(flat)
        return depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    @compiled
    def push(self, x):
        """Closest point of `fn = 0` (the projection of `penetration`); depth where `fn(x) < 0`."""
        x = _points(x, _dtype_of(self))
        flat = x.reshape(-1, 3)
        depth, normal = jax.vmap(self._project_one)(flat)
        inside = jax.vmap(self._f)(flat) < 0
        return jnp.where(inside, depth, 0).reshape(x.shape[:-1]), normal.reshape(x.shape)

    def _project_one(self, x):
        f, grad = jax.value_and_grad(self._f)(x)
        g2 = jnp.sum(grad * grad)
        safe = jnp.where(g2 > 0, g2, 1)
        y0 = jax.lax.stop_gradient(self._march(x, f, grad, g2))

        def residual(z):
            y, lam = z[:3], z[3]
            fy, gy = jax.value_and_grad(self._f)(y)
            return jnp.concatenate([y - x + lam * gy, fy[None]])

        rtol, atol = self.solver.tolerances(x.dtype)
        lam0 = jax.lax.stop_gradient(-jnp.dot(y0 - x, grad) / safe)
        z, converged = _newton(residual, jnp.concatenate([y0, lam0[None]]), rtol, atol, self.solver.max_steps)
        y = z[:3]
        # accept the Newton point unless it failed or wandered off to a farther stationary point
        ok = converged & jnp.all(jnp.isfinite(z))
        ok = ok & (_safe.norm(y - x) <= _safe.norm(y0 - x) * (1 + 1e-6) + atol)
        y = jnp.where(ok, y, y0)
        depth = _safe.norm(y - x)
        normal = _safe.unit(jax.grad(self._f)(y))
        return depth, normal

    def _march(self, x, f, grad, g2):
        """Start point: the first zero of `f` along the gradient ray from `x`.

        Geometric march (×1.25 per step from 1e-4 of the first-order distance `|f|/|∇f|`, which
        overshoots the first crossing by at most 25 %, so thin far parts are not jumped to),
        then bisection of the last bracket.
        """
        g = _safe.unit(grad)
        sign = jnp.where(f < 0, 1.0, -1.0).astype(x.dtype)
        first = jnp.abs(f) / jnp.sqrt(jnp.where(g2 > 0, g2, 1))
        start = jnp.maximum(1e-4 * first, jnp.finfo(x.dtype).eps)
        side = lambda t: sign * self._f(x + sign * t * g) < 0  # still on x's side of the surface

        def grow(_, hi):
            return jnp.where(side(hi), 1.25 * hi, hi)

        hi = jax.lax.fori_loop(0, 80, grow, start)
        lo = jnp.where(hi > start, hi / 1.25, 0)

        def bisect(_, bracket):
            lo, hi = bracket
            mid = 0.5 * (lo + hi)
            inside = side(mid)
            return jnp.where(inside, mid, lo), jnp.where(inside, hi, mid)

        lo, hi = jax.lax.fori_loop(0, 50, bisect, (lo, hi))
        return x + sign * 0.5 * (lo + hi) * g

    def bound(self):
        return None if self.center is None else (self.center, self.radius)


class TriangleMesh(AbstractTool):
    """A closed triangle mesh as a solid tool.

    **Fields:** `vertices (V, 3)` (differentiable), `faces (F, 3)` int, counter-clockwise seen
    from outside; `tree`: the face hierarchy (`collide.mesh_bvh.FaceTree`), built on the host
    when the mesh is constructed from concrete arrays (`None` when built from traced arrays
    inside a `jit`: then every query tests every face). Depth: unsigned distance to the nearest
    face. Build from trimesh with `TriangleMesh.from_trimesh(mesh)` or from a file with
    `TriangleMesh.load(path)`.

    Inside: for a closed, consistently oriented mesh (every edge in two faces, opposite
    directions, positive volume — checked at construction) by the angle-weighted pseudo-normal
    at the nearest face's closest feature (Bærentzen & Aanæs, *Signed distance computation
    using the angle weighted pseudonormal*), which equals the winding number's answer there and
    reuses the hierarchical nearest-face search; otherwise by the generalised winding number
    over every face (Jacobson et al., *Robust inside-outside segmentation using generalized
    winding numbers*). The tree stores topology only (boxes come from the current vertices on
    every query), so `eqx.tree_at` on `vertices` keeps results exact; the pseudo-normal test
    assumes the moved mesh still does not intersect itself.
    """

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]
    tree: Any

    def __init__(self, vertices, faces):
        from bsjax.collide._mesh_bvh import build_tree

        vertices = _float(vertices, "vertices")
        _checks.check_ndim(vertices, "vertices", 2, last=3)
        self.vertices = _checks.finite(vertices, "vertices")
        _checks.check_integer(faces, "faces", "integer vertex indices")
        faces = jnp.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
            _checks.fail("faces", "an (F, 3) integer array with F >= 1", faces.shape)
        n = vertices.shape[0]
        self.faces = _checks.check(
            faces.astype(jnp.int32),
            (faces < 0) | (faces >= n),
            "faces",
            f"indices in [0, {n})",
            "an index outside",
            lambda f: (int(f.min()), int(f.max())),
        )
        concrete = not any(isinstance(a, jax.core.Tracer) for a in (self.vertices, self.faces))
        self.tree = build_tree(np.asarray(self.vertices), np.asarray(self.faces)) if concrete else None

    @classmethod
    def from_trimesh(cls, mesh, dtype=None) -> "TriangleMesh":
        """From a `trimesh.Trimesh`."""
        return cls(np.asarray(mesh.vertices, dtype=dtype or np.float64), np.asarray(mesh.faces))

    @classmethod
    def load(cls, path, dtype=None) -> "TriangleMesh":
        """From any mesh file trimesh reads (OBJ, STL, PLY, GLB…); needs the `mesh` extra."""
        from bsjax._optional import require

        trimesh = require("trimesh", "mesh", "bsjax.collide.TriangleMesh.load")

        try:  # unprocessed first: trimesh's processing drops non-finite vertices with their faces
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as err:  # trimesh raises many types
            raise ValueError(f"{path}: cannot read a triangle mesh ({err})") from err
        bad = ~np.isfinite(np.asarray(mesh.vertices)).all(axis=1)
        if bad.any():
            raise ValueError(f"{path}: vertices: expected finite values, got NaN or inf in {int(bad.sum())}")
        mesh.process()  # merge duplicate vertices (an STL stores three per face)
        return cls.from_trimesh(mesh, dtype)

    @property
    def triangles(self) -> Float[Array, "F 3 3"]:
        return self.vertices[self.faces]

    def _nearest(self, flat, active=None):
        """Nearest face of each point `(N,)`, its closest point `(N, 3)` and barycentrics; the
        search is not differentiated, the closest point on the chosen face is. `active (N,)`:
        only these points are searched (tree only; the others get some face)."""
        from bsjax.collide._mesh_bvh import nearest_faces, nearest_faces_dense
        from bsjax.collide._triangles import _closest_point_on_triangle

        tris = self.triangles
        if self.tree is not None:
            face = nearest_faces(self.tree, self.vertices, self.faces, flat, active)
        else:
            face = nearest_faces_dense(tris, flat)
        closest, bary = _closest_point_on_triangle(flat, tris[face])
        return face, closest, bary

    def _inside(self, flat, nearest=None):
        """`(inside (N,), winding (N,))` of points `(N, 3)`: by the pseudo-normal where the mesh
        is closed (winding 1, 0, or ½ on a face), else by the winding number."""
        from bsjax.collide._mesh_bvh import pseudo_normal_inside

        if self.tree is None or not self.tree.closed:
            winding = _winding_number(flat, self.triangles)
            return 0.5 - winding < 0, winding
        face, closest, bary = self._nearest(flat) if nearest is None else nearest
        v = jax.lax.stop_gradient(self.vertices)
        c = jax.lax.stop_gradient(closest)
        inside = pseudo_normal_inside(self.tree, v, self.faces, jax.lax.stop_gradient(flat), face, c, bary)
        on_face = jnp.all(jax.lax.stop_gradient(flat) == c, -1)
        winding = jnp.where(on_face, 0.5, jnp.where(inside, 1.0, 0.0)).astype(flat.dtype)
        return inside & ~on_face, winding

    @compiled
    def value(self, x):
        """`½ − w`: `w` the winding number (1 inside, 0 outside, ½ on a face of a closed mesh)."""
        x = _points(x, self.vertices.dtype)
        flat = x.reshape(-1, 3)
        winding = self._culled_search(flat)[2] if self._culls else self._inside(flat)[1]
        return (0.5 - winding).reshape(x.shape[:-1])

    @property
    def _culls(self) -> bool:
        """Whether a point outside the mesh's box may skip the search: the mesh is closed (its
        winding number is exactly 0 there; not so for an open mesh) and has a tree."""
        return self.tree is not None and self.tree.closed

    def _culled_search(self, flat):
        """`(in_box (N,), nearest, winding (N,))` of a culling mesh: the nearest-face search only
        for the points inside the box, winding number 0 outside it."""
        in_box = self._in_box(flat)
        nearest = self._nearest(flat, in_box)
        return in_box, nearest, jnp.where(in_box, self._inside(flat, nearest)[1], 0)

    def _in_box(self, flat):
        """Points `(N, 3)` in the closed axis-aligned box of the vertices `(N,)`; the others
        are outside a closed mesh (a decision: no gradient)."""
        v = jax.lax.stop_gradient(self.vertices)
        x = jax.lax.stop_gradient(flat)
        return jnp.all((x >= v.min(0)[None]) & (x <= v.max(0)[None]), -1)

    @compiled
    def push(self, x):
        """Inside by the winding number; depth the distance to the nearest face, pushed along
        `closest − x` (the face normal where `x` lies on the mesh)."""
        x = _points(x, self.vertices.dtype)
        flat = x.reshape(-1, 3)
        nearest = self._nearest(flat)
        face, closest, _ = nearest
        inside, _ = self._inside(flat, nearest)
        t = self.triangles[face]
        face_normal = _safe.unit(jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))
        toward, ok = _safe.unit_or_zero(closest - flat)
        normal = jnp.where(ok[:, None], jnp.where(inside[:, None], toward, -toward), face_normal)
        depth = jnp.where(inside, _safe.norm(closest - flat), 0)
        return depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    @compiled
    def penetration(self, x, n):
        flat = x.reshape(-1, 3)
        depth, normal = self._depth(flat, self._nearest(flat))
        return depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    def _depth(self, flat, nearest):
        """Distance to the nearest face and that face's unit normal, `(N,)`, `(N, 3)`."""
        face, closest, _ = nearest
        t = self.triangles[face]
        depth = _sqrt(jnp.sum((closest - flat) ** 2, -1))
        return depth, _safe.unit(jnp.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))

    def contact_query(self, x, n):
        """`value` and `penetration` from one nearest-face search (see `AbstractTool`).

        For a closed mesh only the samples inside the axis-aligned box of its vertices are
        searched: a sample outside the box is outside the solid (`value` ½, winding number 0),
        and gets `depth` 0 and a zero tool normal (as a sample of a broad-phase early exit in
        `collide.contacts`); inside the box the answers are those of `value` and `penetration`.
        """
        flat = x.reshape(-1, 3)
        if self._culls:
            in_box, nearest, winding = self._culled_search(flat)
            depth, normal = self._depth(flat, nearest)
            depth, normal = jnp.where(in_box, depth, 0), jnp.where(in_box[:, None], normal, 0)
        else:
            nearest = self._nearest(flat)
            winding = self._inside(flat, nearest)[1]
            depth, normal = self._depth(flat, nearest)
        return (0.5 - winding).reshape(x.shape[:-1]), depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    def bound(self):
        center = 0.5 * (self.vertices.min(0) + self.vertices.max(0))
        return center, jnp.max(_safe.norm(self.vertices - center[None]))

    def hull_apart(self, points):
        return hulls_apart(points, self.vertices, jnp.zeros((), points.dtype))

    def box_overlap(self, lo, hi):
        vlo, vhi = self.vertices.min(0), self.vertices.max(0)
        return jnp.all((lo <= _bc(vhi, lo)) & (_bc(vlo, hi) <= hi), -1)


def _dtype_of(tool):
    """The floating dtype of a tool's arrays (the default float when it has none)."""
    for leaf in jax.tree_util.tree_leaves(tool):
        if hasattr(leaf, "dtype") and jnp.issubdtype(leaf.dtype, jnp.floating):
            return leaf.dtype
    return jnp.result_type(float)


def _winding_number(points, tris):
    """Generalised winding number (Jacobson et al. 2013): Σ solid angles / 4π, Van Oosterom–Strackee."""

    def one(p):
        a, b, c = tris[:, 0] - p[None], tris[:, 1] - p[None], tris[:, 2] - p[None]
        la, lb, lc = _safe.norm(a), _safe.norm(b), _safe.norm(c)
        num = jnp.sum(a * jnp.cross(b, c), -1)
        den = la * lb * lc + jnp.sum(a * b, -1) * lc + jnp.sum(b * c, -1) * la + jnp.sum(c * a, -1) * lb
        return jnp.sum(2 * jnp.arctan2(num, den)) / (4 * jnp.pi)

    return jax.lax.map(one, points, batch_size=256)
