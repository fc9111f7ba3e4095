"""The physics of `bsjax studio`: a built surface dropped on a table or pressed by a sphere, as a
deformable body (`mss.Body.from_surface`) in a `mss.Scene` (the two-body contact model of the
thesis, ch. 5 and §7.3: distributed springs, Gao & Gibson eq. 3.3, against rigid tools).

The body is a jelly (`mss.JELLY`): an open surface a shell of 8 × 8 × 2 nodes, 5 % of the
surface's size thick (against its normal), a closed one a 5³ VSOFM volume lattice. The table is
a `collide.Plane` below the body's lowest node (z up, as the studio's camera); the contact
stiffness is set so that a body resting on a tenth of its samples sinks 1 % of its size
(`k = m g / (0.1 · samples · 0.01 · size)`), critically damped per sample. A press holds the
body from behind by a plane instead (no gravity) and pushes a sphere along the surface normal.
The step is half the scene's stable step (`mss.scene_stable_dt`); the result is the body's
refit surface (`SurfaceCoupling.ctrl`, thesis eq. 3.7) after `seconds`.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from bsjax import collide, mss
from bsjax.basis import BSplineSurface, elevate_degree, insert_knots

GRAVITY = 9.81
MAX_STEPS = 20_000  # a longer rollout is refused (the page waits for the reply)
NET = 8  # the fewest control points per open direction a deformation is shown with
UP = np.asarray([0.0, 0.0, 1.0])


def dropped(surface: BSplineSurface, seconds: float, gap: float = 0.05) -> tuple[BSplineSurface, int]:
    """`(surface after falling for seconds, steps)`: the body released at rest `gap` × the
    surface's size above a table (z up)."""
    surface = _refined(surface)
    size = _size(surface)
    body = _body(surface, size)
    lowest = float(np.min(np.asarray(body.lattice.rest_positions)[:, 2]))
    table = collide.Plane(jnp.asarray(UP * (lowest - gap * size)), jnp.asarray(UP))
    return _simulated(body, (table,), size, seconds, gravity=True)


def pressed(
    surface: BSplineSurface, u: float, v: float, depth: float, seconds: float
) -> tuple[BSplineSurface, int]:
    """`(surface pressed for seconds, steps)`: a sphere of a quarter of the surface's size pushed
    `depth` (a fraction of that size) into S(u, v) along the surface normal there, the body
    held from behind by a plane through its farthest node (no gravity)."""
    surface = _refined(surface)
    size = _size(surface)
    body = _body(surface, size)
    at = np.asarray([u]), np.asarray([v])
    point = np.asarray(surface.evaluate(*at)).reshape(3)
    normal = np.asarray(surface.normal(*at)).reshape(3)
    normal = normal / np.linalg.norm(normal)
    outward = _outward(body, point, normal)
    radius = 0.25 * size  # its cap spans the shell's nodes (8 across) at a few % of depth
    sphere = collide.Sphere(jnp.asarray(point + outward * (radius - depth * size)), radius)
    back = np.asarray(body.lattice.rest_positions) @ outward
    support = collide.Plane(jnp.asarray(outward * back.min()), jnp.asarray(outward))
    return _simulated(body, (support, sphere), size, seconds, gravity=False)


def _size(surface: BSplineSurface) -> float:
    points = np.asarray(surface.blending(16, 16).points(surface.ctrl)).reshape(-1, 3)
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def _outward(body: mss.Body, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The normal at `point` turned away from the body's nodes (a shell lies against the
    normal, a volume inside a closed surface)."""
    centre = np.asarray(body.lattice.rest_positions).mean(0)
    return normal if np.dot(point - centre, normal) >= 0 else -normal


def _refined(surface: BSplineSurface) -> BSplineSurface:
    """`surface`, the same geometry, with a net rich enough to show a dent: each open direction
    raised to degree 3 and given at least `NET` control points (NURBS Book §5.5, §5.2) — a loft
    of two lines has a 2-point net across, on which any deformation refits to a ruled surface."""
    refined = surface
    for direction in ("u", "v"):
        if refined.direction(direction).periodic:
            continue
        degree = refined.direction(direction).degree
        if degree < 3:
            refined = elevate_degree(refined, direction, 3 - degree)
        missing = NET - refined.direction(direction).n_ctrl
        if missing > 0:
            refined = insert_knots(refined, direction, np.linspace(0.0, 1.0, missing + 2)[1:-1])
        assert isinstance(refined, BSplineSurface)  # the refinements keep the spline's type
    return refined


def _body(surface: BSplineSurface, size: float) -> mss.Body:
    """A shell for an open surface, a volume lattice for a closed one (`mss.Body.from_surface`
    decides which a surface is)."""
    try:
        return mss.Body.from_surface(surface, (8, 8, 2), mss.JELLY, thickness=0.05 * size)
    except ValueError:
        pass
    try:
        return mss.Body.from_surface(surface, (5, 5, 5), mss.JELLY)
    except ValueError as err:
        raise ValueError(
            "surface: expected an open surface without a periodic direction (a shell) or a closed "
            f"one (a volume body), got neither ({err})"
        ) from None


def _simulated(
    body: mss.Body, tools, size: float, seconds: float, gravity: bool
) -> tuple[BSplineSurface, int]:
    """The body among `tools` for `seconds`: `(its refit surface, steps)`."""
    mass = float(jnp.sum(body.lattice.mass))
    samples = int(np.prod(body.coupling.node_map.shape[:2]))
    stiffness = GRAVITY * mass / (0.1 * samples * 0.01 * size)
    damping = 2.0 * math.sqrt(stiffness * mass / samples)
    scene = mss.Scene(
        (body,),
        tools=tools,
        gravity=jnp.asarray(-GRAVITY * UP) if gravity else None,
        contact=collide.DistributedSprings(stiffness, damping),
    )
    dt = 0.5 * float(mss.scene_stable_dt(scene))
    steps = max(1, math.ceil(seconds / dt))
    if steps > MAX_STEPS:
        raise ValueError(f"seconds: expected at most {MAX_STEPS * dt:.3g} s for this body, got {seconds}")
    (end,) = mss.simulate_scene(scene, mss.scene_init(scene), dt, steps)
    return body.surface.with_ctrl(body.coupling.ctrl(end.position)), steps
