"""A closed surface's seam counts once in every sum over its samples.

A periodic direction's default grid holds both 0 and 1, the same row of points; `Blending.counted`
marks the second copy, and contacts, penetrations and deviation statistics leave it out. The
checks are symmetries that hold only when the seam counts once (a rotationally symmetric body
pressed by a centred plane has no sideways force; a contact region's area does not change when
it moves onto the seam) and a closed form (scipy's quadrature of the area of a cylinder inside a
sphere)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from bsjax import collide, merge, shapes
from bsjax.basis import BSplineSurface, clamped_knots

K = 16  # control points around the cylinder


def test_counted_marks_the_second_copy_of_a_periodic_seam_only():
    b = shapes.teardrop().blending(5, 9)  # closed in v: v = 0 and v = 1 are one column
    counted = np.asarray(b.counted)
    assert counted[:, :-1].all() and not counted[:, -1].any()
    first = np.asarray(b.first_samples)
    np.testing.assert_array_equal(first[:, -1], first[:, 0])
    np.testing.assert_allclose(
        b.points(shapes.teardrop().ctrl)[:, -1], b.points(shapes.teardrop().ctrl)[:, 0], atol=1e-14
    )
    assert np.asarray(shapes.plate().blending(6, 7).counted).all()  # clamped: every sample
    assert np.asarray(b.window(0.0, 1.0, 0.5, 1.0).counted).all()  # the view holds one copy
    np.testing.assert_array_equal(jax.jit(lambda b: b.counted)(b), counted)  # traced params too


def test_a_centred_plane_pushes_a_symmetric_body_straight_up():
    drop = shapes.teardrop()  # 8 control columns around; 80 distinct columns: the grid is symmetric
    b = drop.blending(41, 81)
    plane = collide.Plane(jnp.array([0.0, 0.0, 0.5]), jnp.array([0.0, 0.0, -1.0]))
    for method in ("window", "dense"):
        c = collide.contacts(b, drop.ctrl, plane, method=method)
        assert not np.asarray(c.mask)[:, -1].any()
        force = np.asarray(collide.contact_force(c, 100.0))
        assert abs(force[2]) > 1e3
        assert np.abs(force[:2]).max() <= 1e-12 * abs(force[2]), force


def _cylinder(radius: float) -> BSplineSurface:
    """A closed-in-v cubic cylinder of `K` control columns about z, z in [-1, 1]."""
    theta = 2 * np.pi * np.arange(K) / K
    rho = radius / (2 / 3 + np.cos(2 * np.pi / K) / 3)  # the ring's radius gain (shapes.py)
    z = np.linspace(-1.0, 1.0, 4)[:, None] * np.ones(K)
    ctrl = np.stack([rho * np.cos(theta) * np.ones((4, 1)), rho * np.sin(theta) * np.ones((4, 1)), z], -1)
    return BSplineSurface(ctrl, clamped_knots(4, 3), None, 3, 3, periodic_v=True)


def test_contact_area_across_the_seam_equals_the_area_beside_it_and_the_closed_form():
    radius, ball = 1.0, 0.3
    cyl = _cylinder(radius)
    m, n = 201, 12 * K + 1  # n - 1 distinct columns, a multiple of K: the grid turns with the net
    b = cyl.blending(m, n)
    t_u, t_v = b.tangents(cyl.ctrl)
    trapezoid = np.r_[0.5, np.ones(m - 2), 0.5][:, None] / (m - 1)
    d_area = np.linalg.norm(np.cross(t_u, t_v), axis=-1) * trapezoid / (n - 1)  # v: [0, 1) once
    seam = np.asarray(b.points(cyl.ctrl))[m // 2, 0]
    phi_seam = np.arctan2(seam[1], seam[0])

    def area(phi):
        centre = jnp.array([radius * np.cos(phi), radius * np.sin(phi), 0.0])
        c = collide.contacts(b, cyl.ctrl, collide.Sphere(centre, ball))
        return float(np.sum(np.where(c.mask, d_area, 0.0)))

    on_seam, beside = area(phi_seam), area(phi_seam + 2 * np.pi / K)
    assert on_seam == pytest.approx(beside, rel=1e-12)
    half = 2 * np.arcsin(ball / (2 * radius))  # where the sphere leaves the circle of the section
    exact, _ = integrate.quad(
        lambda t: 2 * radius * np.sqrt(max(ball**2 - 2 * radius**2 * (1 - np.cos(t)), 0.0)), -half, half
    )
    assert on_seam == pytest.approx(exact, rel=0.01)  # the ring's ripple and the grid: < 1 %


def test_a_point_behind_the_seam_gives_its_depth_to_the_first_copy():
    cyl = _cylinder(1.0)
    n = 4 * K + 1
    b = cyl.blending(21, n)

    def depths(v):  # a point 2 cm behind the surface at (0.5, v)
        u, v = jnp.asarray(0.5), jnp.asarray(v)
        x = cyl.evaluate(u, v) - 0.02 * cyl.normal(u, v)
        c = collide.contacts(b, cyl.ctrl, collide.Point(x))
        assert bool(c.hit)
        return np.asarray(c.depth)

    at_seam = depths(1.0 - 0.3 / (n - 1))  # in the cells beside the seam copy
    assert at_seam[:, -1].max() == 0.0 and at_seam[:, 0].max() > 0
    beside = depths(1.0 - 0.3 / (n - 1) - 1.0 / K)  # the same place one control column round
    assert at_seam.sum() == pytest.approx(beside.sum(), rel=1e-12)
    assert at_seam.sum() == pytest.approx(0.02, rel=0.1)  # the tessellation's chord lies inside


def test_penetrations_leave_the_seam_copy_out():
    drop = shapes.teardrop()
    b = drop.blending(12, 17)
    plate = shapes.plate(6, 6, size=3.0)
    lifted = plate.ctrl + jnp.array([[[-1.5, -1.5, -0.7]]])  # through the teardrop's lower half
    pb = plate.blending(30, 30)
    ab, _ = collide.surface_penetration(b, drop.ctrl, pb, lifted, reach=0.5)
    mask = np.asarray(ab.mask)
    assert mask[:, 0].any() and not mask[:, -1].any() and np.asarray(ab.depth)[:, -1].max() == 0.0


def test_deviation_statistics_do_not_depend_on_where_the_seam_lies():
    drop = shapes.teardrop()
    turned = BSplineSurface(
        np.roll(np.asarray(drop.ctrl), 1, axis=1), drop.knots_u, None, 3, 3, periodic_v=True
    )
    wide = BSplineSurface(
        np.asarray(drop.ctrl) * np.array([1.1, 1.0, 1.0]), drop.knots_u, None, 3, 3, periodic_v=True
    )
    a = merge.deviation(drop, wide, samples=16)
    b = merge.deviation(turned, wide, samples=16)  # the same surface, its seam an eighth round
    assert float(a.mean) > 1e-3
    assert float(a.mean) == pytest.approx(float(b.mean), rel=1e-9)
    assert float(a.std) == pytest.approx(float(b.std), rel=1e-7)
