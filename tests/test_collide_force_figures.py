"""The distributed springs of a rigid probe against its closed forms and the figures of
Gao & Gibson, *Haptic B-spline surface sculpting with a shaped tool of implicit surface*
(CAD & Applications, 2005): Fig. 4 (force magnitude against intrusion depth for a spherical
probe through a plane) and Fig. 5 (force direction by surface normals or probe normals, at a
sharp edge and through a surface).

The surfaces are bilinear plates sampled on uniform grids, so every interior sample stands for
the same area `s²` and the spring sum `k Σ d_i` has a closed form. One compiled sweep per
force method (`jax.vmap` over probe centres) serves every test.
"""

import functools

import jax
import numpy as np
import pytest

from bsjax import shapes
from bsjax.basis import BSplineSurface, clamped_knots
from bsjax.collide import Sphere, contact_force, contacts

M = 101  # samples per side of each unit plate
SPACING = 1.0 / (M - 1)
R = 0.25  # the probe's radius (the paper's 800-unit diameter, scaled)
K = 100.0  # N/m per sample in contact
TOP = shapes.plate(2, 2, degree=1)  # z = 0, normal +z, [0, 1]²
# the block's side face x = 1 below the top: u runs down (z 0 → −1), v along y, normal +x
SIDE = BSplineSurface(
    np.array([[[1.0, 0, 0], [1, 1, 0]], [[1, 0, -1], [1, 1, -1]]]),
    clamped_knots(2, 1),
    clamped_knots(2, 1),
    1,
    1,
)


@functools.cache
def _sweep(method: str):
    """Forces `(P, 3)` on the probe at `centres (P, 3)` from one surface, one program."""

    def force(ctrl, blending, centre):
        return contact_force(contacts(blending, ctrl, Sphere(centre, R)), K, method)

    return jax.jit(jax.vmap(force, in_axes=(None, None, 0)))


def _forces(method: str, centres, surfaces=(TOP,)) -> np.ndarray:
    return sum(np.asarray(_sweep(method)(s.ctrl, s.blending(M, M), centres)) for s in surfaces)


def _above_the_middle(heights) -> np.ndarray:
    heights = np.asarray(heights, float)
    return np.stack([np.full_like(heights, 0.5), np.full_like(heights, 0.5), heights], -1)


def _plane_force(c):
    """`k Σ d_i` of a sphere of radius R centred at height `c` over a plane sampled at density
    `1/s²`: the depth along the plane's normal of a sample at distance r from the axis is
    `√(R² − r²) − |c|` (the closer ray root, Gao & Gibson §3.2.2), so
    `F = (k/s²) ∫₀^a 2πr (√(R² − r²) − |c|) dr = (k/s²) (2π/3 (R³ − |c|³) − π (R² − c²) |c|)`."""
    c = np.abs(c)
    return K / SPACING**2 * (2 * np.pi / 3 * (R**3 - c**3) - np.pi * (R**2 - c**2) * c)


def test_fig4_force_against_intrusion_follows_the_closed_form_and_peaks_at_the_radius():
    """Fig. 4: a spherical probe passing through a plane feels a continuous force that grows
    until its centre reaches the plane (intrusion = radius: the largest contact disc), then
    falls; the spring sum equals the closed-form integral to the sampling's error."""
    intrusion = np.linspace(0.0, 2 * R, 41)  # probe centre from R above the plane to R below
    f = _forces("surface_normal", _above_the_middle(R - intrusion))
    reference = _plane_force(R - intrusion)
    peak = reference.max()
    np.testing.assert_allclose(f[:, :2], 0, atol=1e-9 * peak)  # straight up: along the normal
    np.testing.assert_allclose(f[:, 2], reference, atol=2e-3 * peak)
    assert np.argmax(f[:, 2]) == 20 and intrusion[20] == pytest.approx(R)  # the peak at the radius
    rising, falling = np.diff(f[:21, 2]), np.diff(f[20:, 2])
    assert (rising > 0).all() and (falling < 0).all()
    # continuous: no step larger than the closed form's steepest one, plus the sampling's error
    assert np.abs(np.diff(f[:, 2])).max() <= np.abs(np.diff(reference)).max() + 4e-3 * peak


def test_fig5b_d_through_a_surface_probe_normals_reverse_and_surface_normals_do_not():
    """Fig. 5 (b) and (d): as the probe's centre passes through the surface, the surface-normal
    force keeps the surface's normal; the probe-normal force reverses with the centre's side."""
    heights = np.array([0.2, 0.1, 0.05, 0.01, -0.01, -0.05, -0.1, -0.2])
    by_surface = _forces("surface_normal", _above_the_middle(heights))
    by_probe = _forces("probe_normal", _above_the_middle(heights))
    unit = lambda f: f / np.linalg.norm(f, axis=1, keepdims=True)
    np.testing.assert_allclose(unit(by_surface), np.tile([0.0, 0.0, 1.0], (8, 1)), atol=1e-12)
    np.testing.assert_allclose(unit(by_probe), np.sign(heights)[:, None] * [0.0, 0.0, 1.0], atol=1e-9)
    # the same springs either way: only the direction differs
    np.testing.assert_allclose(np.linalg.norm(by_probe, axis=1), by_surface[:, 2], rtol=1e-12)


def _block_normal(centres) -> np.ndarray:
    """The frictionless contact normal of a ball against the solid quarter block x ≤ 1, z ≤ 0:
    from the block's nearest point to the ball's centre (straight up over the top face; from
    the edge x = 1, z = 0 beyond it)."""
    x, z = centres[:, 0], centres[:, 2]
    d = np.stack([np.maximum(x - 1, 0), np.zeros_like(x), z], -1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_fig5a_c_at_a_sharp_edge_probe_normals_follow_the_contact_and_surface_normals_jump():
    """Fig. 5 (a) and (c): a probe sliding over the block's edge (top face and side face, two
    surfaces). With surface normals the force tilts towards the side face's normal as soon as
    the edge is inside the probe, while the centre is still over the top face (the paper's
    sudden impulse); with probe normals it follows the geometric contact normal of the block,
    beyond the edge within 6°."""
    x = np.linspace(0.6, 1.2, 31)
    centres = np.stack([x, np.full_like(x, 0.5), np.full_like(x, 0.1)], -1)
    truth = _block_normal(centres)

    def error_deg(method):
        f = _forces(method, centres, (TOP, SIDE))
        cos = np.sum(f / np.linalg.norm(f, axis=1, keepdims=True) * truth, 1)
        return np.degrees(np.arccos(np.clip(cos, -1, 1)))

    by_surface, by_probe = error_deg("surface_normal"), error_deg("probe_normal")
    # (where the centre crosses the side face's plane, x = 1, its samples' probe normals reverse
    # as in Fig. 5 (d); the error that leaves decays within a few hundredths beyond)
    over_top, beyond = x <= 1.0, x >= 1.08
    assert by_surface[over_top].max() > 30  # the jump before the centre has left the top face
    assert by_probe[over_top].max() < 15
    assert by_probe[beyond].max() < 6 < by_surface[beyond].max()
    assert by_probe.mean() < 0.5 * by_surface.mean()
    np.testing.assert_allclose(by_surface[x <= 0.7], 0, atol=1e-9)  # far from the edge: the same
    np.testing.assert_allclose(by_probe[x <= 0.7], 0, atol=1e-9)
