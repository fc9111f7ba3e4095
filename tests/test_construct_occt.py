"""`bsjax.construct` against OCCT (its Python binding `OCP`, the `cad` extra) as an independent
peer: the surfaces bsjax builds lie on OCCT's own constructions of the same shapes, measured by
OCCT's point inversion (`GeomAPI_ProjectPointOnSurf`)."""

from __future__ import annotations

import numpy as np
import pytest

from bsjax import BSplineCurve, clamped_knots, construct

OCP = pytest.importorskip("OCP", reason="OCCT's binding (cadquery-ocp-novtk) is part of `make test`")


def _occ_curve(curve: BSplineCurve):
    from OCP.Geom import Geom_BSplineCurve
    from OCP.gp import gp_Pnt
    from OCP.OCP.collections import Array1_double, Array1_gp_Pnt, Array1_int

    knots, mults = np.unique(np.asarray(curve.knots), return_counts=True)
    ctrl = np.asarray(curve.ctrl, float)
    poles = Array1_gp_Pnt(1, ctrl.shape[0])
    for i, (x, y, z) in enumerate(ctrl.tolist(), 1):
        poles.SetValue(i, gp_Pnt(x, y, z))
    k, m = Array1_double(1, len(knots)), Array1_int(1, len(knots))
    for i, (a, b) in enumerate(zip(knots.tolist(), mults.tolist()), 1):
        k.SetValue(i, a)
        m.SetValue(i, int(b))
    return Geom_BSplineCurve(poles, k, m, curve.degree)


def _distances_to(occ_surface, points) -> np.ndarray:
    """Distance from each point to OCCT's surface (its own projection, global minimum)."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    out = []
    for x, y, z in np.asarray(points, float).reshape(-1, 3).tolist():
        projection = GeomAPI_ProjectPointOnSurf(gp_Pnt(x, y, z), occ_surface)
        out.append(projection.LowerDistance() if projection.NbPoints() else np.inf)
    return np.asarray(out)


def _profile():
    z = np.linspace(0.0, 1.0, 7)
    r = 0.4 + 0.2 * np.sin(3.0 * z)
    return BSplineCurve(np.stack([r, 0.0 * z, z], -1), clamped_knots(7, 3), 3)


def test_revolve_lies_on_occt_surface_of_revolution():
    from OCP.Geom import Geom_SurfaceOfRevolution
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    profile = _profile()
    surface = construct.revolve(profile, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    occ = Geom_SurfaceOfRevolution(_occ_curve(profile), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)))
    points = surface.blending(9, 13).points(surface.ctrl)
    assert _distances_to(occ, points).max() < 1e-9


def test_ruled_lies_on_occt_ruled_surface():
    from OCP.GeomFill import GeomFill

    t = np.linspace(0.0, 1.0, 6)
    c0 = BSplineCurve(np.stack([t, 0 * t, 0.3 * np.sin(3 * t)], -1), clamped_knots(6, 3), 3)
    c1 = BSplineCurve(np.stack([t, 1 + 0 * t, 0.2 * np.cos(2 * t)], -1), clamped_knots(6, 2), 2)
    surface = construct.ruled(c0, c1)
    occ = GeomFill.Surface_s(_occ_curve(c0), _occ_curve(c1))
    points = surface.blending(11, 7).points(surface.ctrl)
    assert _distances_to(occ, points).max() < 1e-9
