"""Independent references for the tests and benchmarks: scipy, geomdl and closed forms.

Nothing here calls bsjax's kernels; every function rebuilds the quantity from another
library or from a textbook formula, so a disagreement points at bsjax.
"""

from __future__ import annotations

from math import comb, factorial

import numpy as np
from geomdl import NURBS as GNURBS
from geomdl import BSpline as GBSpline
from scipy.interpolate import BSpline, NdBSpline


def knots_with_repeats(rng, n_ctrl: int, degree: int) -> np.ndarray:
    """Random clamped knots on [0, 1] whose interior knots repeat (multiplicity up to `degree`)."""
    n_interior = n_ctrl - degree - 1
    out, left = [], n_interior
    while left > 0:
        mult = int(rng.integers(1, min(degree, left) + 1))
        out += [rng.uniform(0.05, 0.95)] * mult
        left -= mult
    interior = np.sort(np.asarray(out, dtype=np.float64))
    # distinct values at least 1e-2 apart so the basis stays well conditioned
    values = np.unique(interior)
    spaced = np.linspace(0.1, 0.9, len(values)) if len(values) else values
    interior = spaced[np.searchsorted(values, interior)] if len(values) else interior
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def scipy_matrix(knots, degree: int, x, nu: int = 0) -> np.ndarray:
    """`A[a, i] = B^{(nu)}_{i,k}(x_a)` from scipy (`design_matrix` for nu = 0)."""
    t = np.asarray(knots, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    n = len(t) - degree - 1
    if nu == 0:
        return BSpline.design_matrix(x, t, degree).toarray()
    return BSpline(t, np.eye(n), degree)(x, nu=nu)


def cardinal_bspline(x, degree: int, nu: int = 0) -> np.ndarray:
    """The uniform cardinal B-spline of `degree` on [0, k+1] (knots 0, 1, …, k+1), closed form.

    `N_k(x) = 1/k! Σ_j (−1)^j C(k+1, j) (x − j)_+^k`, and its nu-th derivative.
    """
    x = np.asarray(x, dtype=np.float64)
    k = degree
    if nu > k:
        return np.zeros_like(x)
    power = k - nu
    scale = factorial(k) // factorial(power)
    out = np.zeros_like(x)
    for j in range(k + 2):
        d = x - j
        term = np.where(d > 0, d, 0.0) ** power if power > 0 else (d >= 0).astype(float)
        out += (-1) ** j * comb(k + 1, j) * scale * term
    return np.where((x >= 0) & (x < k + 1), out / factorial(k), 0.0)


def periodic_reference(n_ctrl: int, degree: int, params, nu: int = 0) -> np.ndarray:
    """Closed-form periodic blending matrix (thesis eq. 3.3), knots spaced `1/n` on [0, 1).

    `B_i(u) = N_k((n u − i + k) mod n) n^nu` with the cardinal B-spline `N_k`: function `i`
    starts at `(i − k)/n`, so it peaks over `[(i − k)/n, (i + 1)/n]` and wraps around.
    """
    u = np.asarray(params, dtype=np.float64) % 1.0
    i = np.arange(n_ctrl)
    x = (n_ctrl * u[:, None] - i[None, :] + degree) % n_ctrl
    return cardinal_bspline(x, degree, nu) * float(n_ctrl) ** nu


def _direction_spline(knots, degree, periodic, n_ctrl):
    """(knot vector, index map) for scipy: periodic → unwrapped knots and wrapped coefficients."""
    if not periodic:
        return np.asarray(knots, dtype=np.float64), np.arange(n_ctrl)
    j = np.arange(n_ctrl + 2 * degree + 1)
    return (j - degree) / n_ctrl, np.arange(n_ctrl + degree) % n_ctrl


def _nd_eval(surface, net, u, v, nu, nv):
    tu, iu = _direction_spline(surface.knots_u, surface.degree_u, surface.periodic_u, surface.shape[0])
    tv, iv = _direction_spline(surface.knots_v, surface.degree_v, surface.periodic_v, surface.shape[1])
    c = net[iu][:, iv]
    spline = NdBSpline((tu, tv), c, (surface.degree_u, surface.degree_v))
    u = np.asarray(u, np.float64) % 1.0 if surface.periodic_u else np.asarray(u, np.float64)
    v = np.asarray(v, np.float64) % 1.0 if surface.periodic_v else np.asarray(v, np.float64)
    return spline(np.stack([u.ravel(), v.ravel()], -1), nu=(nu, nv)).reshape(u.shape + (net.shape[-1],))


def ndbspline_surface(surface, u, v, nu: int = 0, nv: int = 0) -> np.ndarray:
    """The (nu, nv) partial derivative of `surface` at `u`, `v` (nu, nv ≤ 2) from scipy NdBSpline.

    NURBS: scipy evaluates the homogeneous map `[wP, w]` and the quotient rule gives `S`
    (derivatives written out by hand, independent of the Leibniz recursion in bsjax).
    """
    ctrl = np.asarray(surface.ctrl, dtype=np.float64)
    if surface.weights is None:
        return _nd_eval(surface, ctrl, u, v, nu, nv)
    w = np.asarray(surface.weights, dtype=np.float64)[..., None]
    net = np.concatenate([ctrl * w, w], -1)
    h = {
        (a, b): _nd_eval(surface, net, u, v, a, b) for a in range(3) for b in range(3) if a <= nu and b <= nv
    }
    W = {kl: x[..., 3:] for kl, x in h.items()}
    A = {kl: x[..., :3] for kl, x in h.items()}
    s = A[0, 0] / W[0, 0]
    if (nu, nv) == (0, 0):
        return s
    su = (A[1, 0] - W[1, 0] * s) / W[0, 0] if nu >= 1 else None
    sv = (A[0, 1] - W[0, 1] * s) / W[0, 0] if nv >= 1 else None
    if (nu, nv) == (1, 0):
        return su
    if (nu, nv) == (0, 1):
        return sv
    if (nu, nv) == (2, 0):
        return (A[2, 0] - 2 * W[1, 0] * su - W[2, 0] * s) / W[0, 0]
    if (nu, nv) == (0, 2):
        return (A[0, 2] - 2 * W[0, 1] * sv - W[0, 2] * s) / W[0, 0]
    if (nu, nv) == (1, 1):
        return (A[1, 1] - W[1, 0] * sv - W[0, 1] * su - W[1, 1] * s) / W[0, 0]
    raise NotImplementedError((nu, nv))


def geomdl_surface(surface):
    """The same (clamped) surface as a geomdl `BSpline.Surface` / `NURBS.Surface`."""
    r, s = surface.shape
    ctrl = np.asarray(surface.ctrl, dtype=np.float64).reshape(r * s, 3)
    if surface.weights is None:
        g = GBSpline.Surface()
        g.degree_u, g.degree_v = surface.degree_u, surface.degree_v
        g.ctrlpts_size_u, g.ctrlpts_size_v = r, s
        g.ctrlpts = ctrl.tolist()
    else:
        g = GNURBS.Surface()
        g.degree_u, g.degree_v = surface.degree_u, surface.degree_v
        g.ctrlpts_size_u, g.ctrlpts_size_v = r, s
        w = np.asarray(surface.weights, dtype=np.float64).reshape(r * s, 1)
        g.ctrlptsw = np.concatenate([ctrl * w, w], -1).tolist()
    g.knotvector_u = np.asarray(surface.knots_u, dtype=np.float64).tolist()
    g.knotvector_v = np.asarray(surface.knots_v, dtype=np.float64).tolist()
    return g


def tolerance(ref, scale: float = 1e-12) -> float:
    """Absolute tolerance `scale · max(1, max|ref|)` (derivatives grow like 1/Δt^nu)."""
    return scale * max(1.0, float(np.max(np.abs(ref))))


def lattice_stiffness(lattice, per_spring=None):
    """The sparse `(3N, 3N)` matrix `Σ_springs k e eᵀ` (the linearised springs at rest, `e` a
    spring's unit direction), `k` the lattice's stiffness or `per_spring (E,)` (its dampers:
    the damping matrix). Reads the lattice's arrays only (`rest_positions`, `edges`)."""
    import scipy.sparse as sp

    x, e = np.asarray(lattice.rest_positions), np.asarray(lattice.edges)
    k = np.asarray(lattice.stiffness if per_spring is None else per_spring)
    n = len(x)
    d = x[e[:, 1]] - x[e[:, 0]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rows, cols, vals = [], [], []
    for a in range(3):
        for b in range(3):
            kab = k * d[:, a] * d[:, b]
            for i, j, sign in ((0, 0, 1), (1, 1, 1), (0, 1, -1), (1, 0, -1)):
                rows.append(3 * e[:, i] + a)
                cols.append(3 * e[:, j] + b)
                vals.append(sign * kab)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), (3 * n, 3 * n))


def lattice_linear_deflection(lattice, force) -> np.ndarray:
    """Displacements `(N, 3)` of a mass-spring lattice's linearised springs (`lattice_stiffness`)
    under node forces `(N, 3)`, the fixed nodes held: scipy's sparse solve of `K u = f` (the
    static answer for vanishing loads)."""
    import scipy.sparse.linalg as spla

    stiffness = lattice_stiffness(lattice)
    n = lattice.rest_positions.shape[0]
    free = np.repeat(~np.asarray(lattice.fixed), 3)
    u = np.zeros(3 * n)
    u[free] = spla.spsolve(stiffness[free][:, free].tocsc(), np.asarray(force).reshape(-1)[free])
    return u.reshape(n, 3)
