"""Collision tools: point, sphere, ellipsoid, plane (half-space), implicit solid, triangle mesh.

Every tool is an `eqx.Module` whose arrays (pose, size) are differentiable leaves. Each solid
tool knows its implicit function (`value(x) < 0` inside), the penetration depth of a surface
sample along the sample's normal (Gao & Gibson 2005/2006, paper 002 §3.2.2), the outward
normal of the tool at the depth point (for the probe-normal force), a bounding sphere for the
control-hull broad phase, and a conservative overlap test against boxes of control points
(thesis §3.3.3.2, the parametric window).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

from bsjax import _checks
from bsjax._tensor import safe_norm, unit
from bsjax.collide.broad import hulls_apart


def _vector(x, name: str, size: int = 3):
    arr = jnp.asarray(x)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    if arr.shape != (size,):
        _checks.fail(name, f"shape ({size},)", arr.shape)
    _checks.check_finite(arr, name)
    return arr


def _scalar(x, name: str):
    arr = jnp.asarray(x)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    if arr.shape != ():
        _checks.fail(name, "a scalar", arr.shape)
    _checks.check_positive(arr, name)
    return arr


def _sqrt(x):
    """`sqrt(max(x, 0))` with a finite gradient at and below 0 (double where)."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def _closer_root(a, b, c):
    """|t| of the root of `a t² + 2 b t + c = 0` closest to 0 (a > 0, c < 0 inside → real roots)."""
    disc = _sqrt(b * b - a * c)
    safe_a = jnp.where(a > 0, a, 1)
    t_plus, t_minus = (-b + disc) / safe_a, (-b - disc) / safe_a
    return jnp.where(jnp.abs(t_plus) <= jnp.abs(t_minus), t_plus, t_minus)


class AbstractTool(eqx.Module):
    """A rigid tool. Subclasses define the implicit value, depth and bounds (see module doc)."""

    def value(self, x: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """Implicit function: negative inside the tool."""
        raise NotImplementedError

    def penetration(self, x, n) -> tuple[Array, Array]:
        """`(depth (...), tool_normal (..., 3))` of samples `x` with unit surface normals `n`."""
        raise NotImplementedError

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
    nearest = jnp.clip(center, lo, hi)
    return jnp.sum((nearest - center) ** 2, -1) <= radius * radius


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
        reach = jnp.asarray(reach, self.position.dtype)
        if reach.shape != () or (_checks.is_concrete(reach) and not bool(reach >= 0)):
            _checks.fail("reach", "a scalar >= 0", reach)
        self.reach = reach

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
        self.radius = _scalar(radius, "radius").astype(self.center.dtype)

    def value(self, x):
        return jnp.sum((x - self.center) ** 2, -1) - self.radius**2

    def penetration(self, x, n):
        y = x - self.center
        t = _closer_root(jnp.sum(n * n, -1), jnp.sum(y * n, -1), jnp.sum(y * y, -1) - self.radius**2)
        hit = x + t[..., None] * n
        return jnp.abs(t), unit(hit - self.center)

    def bound(self):
        return self.center, self.radius


class Ellipsoid(AbstractTool):
    """A solid ellipsoid `|D⁻¹ Rᵀ (x − center)| < 1`, `D = diag(radii)`.

    **Fields:** `center (3,)`, `radii (3,)` > 0 (semi-axes), `rotation (3, 3)` orthonormal, its
    columns the axes in world coordinates (identity by default). Depth: exact, along the sample
    normal (the quadratic of paper 002 §3.2.2 solved in the ellipsoid's unit-sphere frame).
    """

    center: Float[Array, "3"]
    radii: Float[Array, "3"]
    rotation: Float[Array, "3 3"]

    def __init__(self, center, radii, rotation=None):
        self.center = _vector(center, "center")
        self.radii = _vector(radii, "radii").astype(self.center.dtype)
        _checks.check_positive(self.radii, "radii")
        if rotation is None:
            rotation = jnp.eye(3, dtype=self.center.dtype)
        rotation = jnp.asarray(rotation, self.center.dtype)
        if rotation.shape != (3, 3):
            _checks.fail("rotation", "shape (3, 3)", rotation.shape)
        _checks.check_finite(rotation, "rotation")
        if _checks.is_concrete(rotation):
            err = float(np.max(np.abs(np.asarray(rotation).T @ np.asarray(rotation) - np.eye(3))))
            if err > 1e-6 or np.linalg.det(np.asarray(rotation)) < 0:
                _checks.fail(
                    "rotation", "a proper rotation matrix (R^T R = I, det 1)", f"|R^T R - I| = {err:.2g}"
                )
        self.rotation = rotation

    def _local(self, x):
        return ((x - self.center) @ self.rotation) / self.radii

    def value(self, x):
        y = self._local(x)
        return jnp.sum(y * y, -1) - 1

    def penetration(self, x, n):
        y, m = self._local(x), (n @ self.rotation) / self.radii
        t = _closer_root(jnp.sum(m * m, -1), jnp.sum(y * m, -1), jnp.sum(y * y, -1) - 1)
        hit_local = y + t[..., None] * m
        grad = (hit_local / self.radii) @ self.rotation.T
        return jnp.abs(t), unit(grad)

    def bound(self):
        return self.center, jnp.max(self.radii)

    def hull_apart(self, points):
        # an affine map keeps convex hulls: test against the unit ball in the ellipsoid frame
        return hulls_apart(self._local(points), jnp.zeros((1, 3), points.dtype), jnp.ones((), points.dtype))

    def box_overlap(self, lo, hi):
        # the 8 box corners in the unit-sphere frame bound the box's image (a parallelepiped)
        corners = jnp.stack(
            [
                jnp.stack([jnp.where(bit, hi[..., k], lo[..., k]) for k, bit in enumerate(bits)], -1)
                for bits in np.ndindex(2, 2, 2)
            ],
            -2,
        )
        local = self._local(corners)
        return _sphere_box(jnp.zeros(3, lo.dtype), jnp.ones((), lo.dtype), local.min(-2), local.max(-2))


class Plane(AbstractTool):
    """A half-space tool: the solid is the side the normal points away from, `n·(x − p) < 0`.

    **Fields:** `point (3,)`, `normal (3,)` (normalised here; a zero normal is rejected).
    Depth: the signed distance `−n·(x − p)`.
    """

    point: Float[Array, "3"]
    normal: Float[Array, "3"]

    def __init__(self, point, normal):
        self.point = _vector(point, "point")
        normal = _vector(normal, "normal").astype(self.point.dtype)
        if _checks.is_concrete(normal) and not float(np.linalg.norm(np.asarray(normal))) > 0:
            _checks.fail("normal", "a non-zero vector", np.asarray(normal).tolist())
        self.normal = unit(normal)

    def value(self, x):
        return jnp.sum((x - self.point) * self.normal, -1)

    def penetration(self, x, n):
        depth = -self.value(x)
        return depth, jnp.broadcast_to(self.normal, x.shape)

    def hull_apart(self, points):
        return jax.lax.stop_gradient(jnp.min(self.value(points)) >= 0)

    def box_overlap(self, lo, hi):
        low_corner = jnp.where(self.normal > 0, lo, hi)  # the box corner deepest into the solid
        return self.value(low_corner) < 0


class ProjectionSolver(eqx.Module):
    """Settings of the closest-point projection onto an implicit surface (optimistix Newton)."""

    rtol: float = eqx.field(static=True, default=1e-8)
    atol: float = eqx.field(static=True, default=1e-10)
    max_steps: int = eqx.field(static=True, default=32)


class Implicit(AbstractTool):
    """Any implicit solid `fn(x) < 0` (a torus, a blend of primitives, a learned SDF…).

    **Fields:** `fn` (static): `fn(x (3,)) -> scalar`, or `fn(x, params)` when `params` is given
    (then the tool is differentiable in `params`); optional bounding sphere `center`, `radius`
    for the broad phase; `solver` settings.
    Depth: distance to the closest point of `fn = 0`: a start point on the surface along the
    gradient ray (doubling and bisection), refined by an optimistix Newton solve of the Lagrange
    conditions `y − x + λ∇f(y) = 0, f(y) = 0` (differentiated implicitly); the start point is
    kept where Newton fails or lands on a farther stationary point.
    """

    fn: Callable = eqx.field(static=True)
    params: Any = None
    center: Float[Array, "3"] | None = None
    radius: Float[Array, ""] | None = None
    solver: ProjectionSolver = eqx.field(static=True, default=ProjectionSolver())

    def __init__(self, fn, params=None, center=None, radius=None, solver=ProjectionSolver()):
        if not callable(fn):
            raise TypeError(f"fn: expected a callable f(x) -> scalar, got {type(fn).__name__}")
        if (center is None) != (radius is None):
            _checks.fail("center, radius", "both or neither", (center, radius))
        self.fn, self.params, self.solver = fn, params, solver
        self.center = None if center is None else _vector(center, "center")
        self.radius = None if radius is None else _scalar(radius, "radius")

    def _f(self, x):
        return self.fn(x) if self.params is None else self.fn(x, self.params)

    def value(self, x):
        flat = x.reshape(-1, 3)
        return jax.vmap(self._f)(flat).reshape(x.shape[:-1])

    def penetration(self, x, n):
        flat = x.reshape(-1, 3)
        depth, normal = jax.vmap(self._project_one)(flat)
        return depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    def _project_one(self, x):
        f, grad = jax.value_and_grad(self._f)(x)
        g2 = jnp.sum(grad * grad)
        safe = jnp.where(g2 > 0, g2, 1)
        y0 = jax.lax.stop_gradient(self._march(x, f, grad, g2))

        def residual(z, args):
            y, lam = z[:3], z[3]
            fy, gy = jax.value_and_grad(self._f)(y)
            return jnp.concatenate([y - x + lam * gy, fy[None]])

        eps = jnp.finfo(x.dtype).eps
        rtol, atol = max(self.solver.rtol, float(10 * eps)), max(self.solver.atol, float(100 * eps))
        lam0 = jax.lax.stop_gradient(-jnp.dot(y0 - x, grad) / safe)
        sol = optx.root_find(
            residual,
            optx.Newton(rtol=rtol, atol=atol),
            jnp.concatenate([y0, lam0[None]]),
            max_steps=self.solver.max_steps,
            throw=False,
        )
        y = sol.value[:3]
        # accept the Newton point unless it failed or wandered off to a farther stationary point
        ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
        ok = ok & (safe_norm(y - x) <= safe_norm(y0 - x) * (1 + 1e-6) + atol)
        y = jnp.where(ok, y, y0)
        depth = safe_norm(y - x)
        normal = unit(jax.grad(self._f)(y))
        return depth, normal

    def _march(self, x, f, grad, g2):
        """Start point: the first zero of `f` along the gradient ray from `x`.

        Geometric march (×1.25 per step from 1e-4 of the first-order distance `|f|/|∇f|`, which
        overshoots the first crossing by at most 25 %, so thin far parts are not jumped to),
        then bisection of the last bracket.
        """
        g = unit(grad)
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
    """A closed triangle mesh as a solid tool (inside by the generalised winding number).

    **Fields:** `vertices (V, 3)` (differentiable), `faces (F, 3)` int, counter-clockwise seen
    from outside. Depth: unsigned distance to the nearest face. Build from trimesh with
    `TriangleMesh.from_trimesh(mesh)` or from a file with `TriangleMesh.load(path)`.
    """

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]

    def __init__(self, vertices, faces):
        vertices = jnp.asarray(vertices)
        if not jnp.issubdtype(vertices.dtype, jnp.floating):
            vertices = vertices.astype(jnp.result_type(float))
        _checks.check_ndim(vertices, "vertices", 2, last=3)
        _checks.check_finite(vertices, "vertices")
        faces_np = np.asarray(faces)
        if faces_np.ndim != 2 or faces_np.shape[1] != 3 or faces_np.shape[0] == 0:
            _checks.fail("faces", "an (F, 3) integer array with F >= 1", faces_np.shape)
        if not np.issubdtype(faces_np.dtype, np.integer):
            _checks.fail("faces", "integer vertex indices", faces_np.dtype)
        if faces_np.min() < 0 or faces_np.max() >= vertices.shape[0]:
            _checks.fail(
                "faces", f"indices in [0, {vertices.shape[0]})", (int(faces_np.min()), int(faces_np.max()))
            )
        self.vertices = vertices
        self.faces = jnp.asarray(faces_np.astype(np.int32))

    @classmethod
    def from_trimesh(cls, mesh, dtype=None) -> "TriangleMesh":
        """From a `trimesh.Trimesh`."""
        return cls(np.asarray(mesh.vertices, dtype=dtype or np.float64), np.asarray(mesh.faces))

    @classmethod
    def load(cls, path, dtype=None) -> "TriangleMesh":
        """From any mesh file trimesh reads (OBJ, STL, PLY, GLB…)."""
        import trimesh

        try:
            mesh = trimesh.load(path, force="mesh")
        except Exception as err:  # trimesh raises many types
            raise ValueError(f"{path}: cannot read a triangle mesh ({err})") from err
        return cls.from_trimesh(mesh, dtype)

    @property
    def triangles(self) -> Float[Array, "F 3 3"]:
        return self.vertices[self.faces]

    def value(self, x):
        return 0.5 - _winding_number(x.reshape(-1, 3), self.triangles).reshape(x.shape[:-1])

    def penetration(self, x, n):
        from bsjax.collide.triangles import closest_point_on_triangle

        tris = self.triangles
        flat = x.reshape(-1, 3)

        def one(p):
            closest, _ = closest_point_on_triangle(p[None], tris)
            d2 = jnp.sum((closest - p) ** 2, -1)
            k = jnp.argmin(d2)
            t = tris[k]
            return _sqrt(d2[k]), unit(jnp.cross(t[1] - t[0], t[2] - t[0]))

        depth, normal = jax.lax.map(one, flat, batch_size=256)
        return depth.reshape(x.shape[:-1]), normal.reshape(x.shape)

    def bound(self):
        center = 0.5 * (self.vertices.min(0) + self.vertices.max(0))
        return center, jnp.max(safe_norm(self.vertices - center))

    def hull_apart(self, points):
        return hulls_apart(points, self.vertices, jnp.zeros((), points.dtype))

    def box_overlap(self, lo, hi):
        vlo, vhi = self.vertices.min(0), self.vertices.max(0)
        return jnp.all((lo <= vhi) & (vlo <= hi), -1)


def _winding_number(points, tris):
    """Generalised winding number (Jacobson et al. 2013): Σ solid angles / 4π, Van Oosterom–Strackee."""

    def one(p):
        a, b, c = tris[:, 0] - p, tris[:, 1] - p, tris[:, 2] - p
        la, lb, lc = safe_norm(a), safe_norm(b), safe_norm(c)
        num = jnp.sum(a * jnp.cross(b, c), -1)
        den = la * lb * lc + jnp.sum(a * b, -1) * lc + jnp.sum(b * c, -1) * la + jnp.sum(c * a, -1) * lb
        return jnp.sum(2 * jnp.arctan2(num, den)) / (4 * jnp.pi)

    return jax.lax.map(one, points, batch_size=256)
