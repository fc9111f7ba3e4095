"""The haptic device drives constraint sculpting: the surface point under the stylus follows it.

A second model for the servo loop beside the lattice `SculptModel`, built on `bsjax.sculpt`
(thesis *Interactive shape modeling and dynamic deformation based on spline sculpting*, §6.1 and
the dragger of §6.3–6.4; Fowler & Bartels, *Constraint-based curve manipulation*):

* **Grab.** While the stylus button is held and the tool touches the surface (its centre within
  `tool_radius` of the tangent plane at the nearest sample of a `proxy_grid²` grid, on the side
  it came from), the surface point under the tool — the closest point `S(u₀, v₀)` to the tool
  centre `c₀`, refined by `basis.project` from that sample — is grabbed, and the interaction
  is factored once: `factor = sculpt.prefactor(S, [Position(u₀, ·, v₀)], free)`, i.e. the
  solve matrix `C = S (F S)⁺` of the single point row `F` with the blocked control points' columns
  zeroed (eqs. 6-8/6-9). By default the control points of the net's border rows (`border` rows
  along every clamped direction) are blocked, so the edit stays local and the boundary holds.
* **Drag.** Every physics tick while the button stays down, the point follows the tool:
  `target = S(u₀, v₀) + (c − c₀)` and the new net is `factor.drag([target])`, `P + C b` — one
  matrix product per event, compiled once (the thesis's per-event `d = C b`, §6.1). The single
  point constraint with free columns is always met, so `S'(u₀, v₀) = target` exactly.
* **Release** keeps the dragged surface; the next grab factors the new one.
* **Force.** During a drag the user feels a spring back to the un-dragged point,
  `F = k_drag (S(u₀, v₀) − target) = −k_drag (c − c₀)`, clamped to `|F| ≤ max_force`; it is
  handed to the servo as a plane proxy along `F` placed so that the servo renders exactly `F`
  at the tool centre and extrapolates it with `k_drag` until the next tick (Gao & Gibson,
  *Haptic B-spline surface sculpting with a shaped tool of implicit surface*, §3.2: a penalty
  spring with damping). Out of a drag the surface is felt as the plane of the nearest sample,
  its normal facing the side the tool came from (latched while in contact), as in `SculptModel`.

Safety (the same contract as `SculptModel`): a pose `accepts` refuses (a non-finite position or
orientation, or a centre farther than `reach` from the body) is dropped and counted
(`dropped_poses`) and never reaches the solve; a tick whose result is not finite (or whose solve
raised) is rolled back — the last good surface and proxy are kept, counted in `rollbacks` — and
after `max_rollbacks` bad ticks in a row `update` raises `FloatingPointError`, which stops the
servo's physics thread (its watchdog then ramps the force to zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from bsjax import _checks, _safe, basis, sculpt, shapes
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax.basis import Blending, BSplineSurface
from bsjax.device._model import AbstractHapticModel
from bsjax.device._protocol import DeviceSample, positive_number
from bsjax.device._proxy import Proxy


# --- compiled kernels -------------------------------------------------------------------------
@compiled
def _probe(dense: Blending, ctrl: Float[Array, "r s 3"], centre: Float[Array, " 3"]):
    """`(point, unit normal, flat index)` of the grid sample nearest `centre`."""
    pts = dense.points(ctrl).reshape(-1, 3)
    nrm = dense.normals(ctrl).reshape(-1, 3)
    k = jnp.argmin(jnp.sum((pts - centre[None]) ** 2, axis=-1))
    return pts[k], _safe.unit(nrm[k]), k


@compiled
def _grab(surface: BSplineSurface, free, uv0: Float[Array, " 2"], centre: Float[Array, " 3"], steps: int):
    """Factor the drag of the surface point closest to `centre` (Gauss–Newton from `uv0`).

    **Returns:** `(factor, uv (2,), point (3,))`: the `sculpt.Factor` of the single point
    constraint at `uv` with the `free` mask, the parameters and the point `S(uv)`.
    """
    uv = basis.project(surface, centre[None], uv0[None], steps)[0]
    point = surface.evaluate(uv[0], uv[1])
    factor = sculpt.prefactor(surface, [sculpt.Position(uv[0], point, uv[1])], free)
    return factor, uv, point


@declared
def border_free(surface: BSplineSurface, border: int = 1) -> np.ndarray:
    """`(r, s)` mask: every control point free except `border` rows at each end of a clamped
    direction (a periodic direction has no border)."""
    r, s = surface.shape
    free = np.ones((r, s), bool)
    if border > 0 and not surface.periodic_u:
        free[:border], free[r - border :] = False, False
    if border > 0 and not surface.periodic_v:
        free[:, :border], free[:, s - border :] = False, False
    return free


@dataclass(frozen=True)
class Grab:
    """One interaction: the factor, the grabbed parameters `uv`, the point `S(uv)` before the
    drag, and the tool centre when it was grabbed."""

    factor: sculpt.Factor
    uv: np.ndarray
    point: np.ndarray
    centre: np.ndarray
    normal: np.ndarray  # the surface normal at the grab, facing the tool


class ConstraintSculptModel(AbstractHapticModel):
    """A B-spline surface sculpted by dragging the point under the stylus (minimum-norm edits).

    **Arguments:**
    - `surface`: a `BSplineSurface` (default `shapes.teardrop()`); its dtype is the model's dtype.
    - `free`: `(r, s)` boolean mask of the control points that may move (default: all but
      `border` rows at each end of a clamped direction, `border_free`).
    - `border`: int ≥ 0, border rows blocked when `free` is not given.
    - `tool_radius`: model units, the spherical tool (grab distance and the felt surface).
    - `drag_stiffness`: N per model unit, the spring back to the un-dragged point.
    - `max_force`: N, the largest drag force handed to the servo (`|F| ≤ max_force`).
    - `proxy_stiffness`, `proxy_damping`: the felt surface out of a drag (N, N·s per model unit);
      the damping also applies to the drag spring.
    - `proxy_grid`: samples per direction of the grid the nearest point is taken from (≥ 2).
    - `project_steps`: Gauss–Newton steps refining the grabbed point (`basis.project`).
    - `reach`: model units; a tool centre farther than this from the centre of the control net's
      bounding box is dropped (default 10 × the box's diagonal; `math.inf`: no limit).
    - `max_rollbacks`: bad ticks in a row (rolled back) before `update` raises.

    Counters: `ticks` (good physics ticks), `grabs` (interactions started), `dropped_poses`,
    `rollbacks`. State: `ctrl` (the current net), `grab` (the current `Grab` or None).
    """

    def __init__(
        self,
        surface: BSplineSurface | None = None,
        free=None,
        border: int = 1,
        tool_radius: float = 0.25,
        drag_stiffness: float = 30.0,
        max_force: float = 3.0,
        proxy_stiffness: float = 30.0,
        proxy_damping: float = 0.3,
        proxy_grid: int = 40,
        project_steps: int = 8,
        reach: float | None = None,
        max_rollbacks: int = 10,
    ):
        surface = shapes.teardrop() if surface is None else surface
        if not isinstance(surface, BSplineSurface):
            raise TypeError(f"surface: expected a BSplineSurface, got {type(surface).__name__}")
        border = _checks.check_count(border, "border", minimum=0)
        proxy_grid = _checks.check_count(proxy_grid, "proxy_grid", minimum=2)
        self.project_steps = _checks.check_count(project_steps, "project_steps")
        self.max_rollbacks = _checks.check_count(max_rollbacks, "max_rollbacks")
        self.tool_radius = positive_number(tool_radius, "tool_radius")
        self.drag_stiffness = positive_number(drag_stiffness, "drag_stiffness")
        self.max_force = positive_number(max_force, "max_force")
        self.proxy_stiffness = positive_number(proxy_stiffness, "proxy_stiffness")
        self.proxy_damping = positive_number(proxy_damping, "proxy_damping", allow_zero=True)
        self.free = self._free_mask(surface, free, border)
        self._init_protocol(surface, reach, self.max_rollbacks)
        self.dtype = surface.ctrl.dtype
        self.surface0 = surface
        self.dense = surface.blending(proxy_grid, proxy_grid)
        params = np.linspace(0.0, 1.0, proxy_grid)
        self._uv = np.stack(np.meshgrid(params, params, indexing="ij"), -1).reshape(-1, 2)
        self._free = jnp.asarray(self.free)
        self.reset()
        self.grabs = 0

    @staticmethod
    def _free_mask(surface, free, border) -> np.ndarray:
        if free is None:
            return border_free(surface, border)
        mask = np.asarray(free)
        if mask.shape != surface.shape or mask.dtype != np.bool_:
            _checks.fail("free", f"a boolean mask of shape {surface.shape}", f"{mask.dtype} {mask.shape}")
        if not mask.any():
            _checks.fail("free", "at least one free control point", "all blocked")
        return mask.copy()

    # --- model interface ----------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the initial surface, no grab, no proxy."""
        with self._lock:
            self.ctrl = self.surface0.ctrl
            self.grab: Grab | None = None
            self._side: float | None = None  # +1: the tool on the normal's side; latched in contact
            self._last_proxy = Proxy()
            self._bad_ticks = 0

    def surface(self) -> BSplineSurface:
        """The current surface."""
        return self.surface0.with_ctrl(self.ctrl)

    @property
    def dragging(self) -> bool:
        return self.grab is not None

    def warmup(self) -> None:
        """Compile the probe, the grab (projection + `prefactor`) and `drag` once, before the
        servo starts (all shapes are fixed: nothing compiles in the physics thread)."""
        centre = jnp.asarray(self.centre, self.dtype)
        _, _, k = _probe(self.dense, self.ctrl, centre)
        factor, _, point = _grab(self.surface(), self._free, self._uv0(k), centre, self.project_steps)
        jax.block_until_ready(factor.drag([point]))

    def _advance(self, sample: DeviceSample) -> Proxy | None:
        """One tick (`AbstractHapticModel.update` gates the pose and rolls a bad tick back):
        button held and touching: grab (first tick) and drag; button released: the dragged
        surface is kept."""
        return self._tick(np.asarray(sample.position, dtype=np.float64), sample.pressed)

    # --- one tick -----------------------------------------------------------------------------
    def _tick(self, centre: np.ndarray, pressed: bool) -> Proxy | None:
        """The new proxy (state committed), or None when the tick's result is not finite."""
        if self.grab is not None and not pressed:
            self.grab = None  # released: the dragged surface stays
        if self.grab is None:
            c = jnp.asarray(centre, self.dtype)
            q, n, k = (np.asarray(a) for a in _probe(self.dense, self.ctrl, c))
            q, n = q.astype(np.float64), n.astype(np.float64)
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(n))):
                return None
            gap = float(np.dot(centre - q, n))
            if self._side is None or abs(gap) >= self.tool_radius:  # out of contact: may change side
                self._side = 1.0 if gap >= 0 else -1.0
            if not (pressed and self._side * gap <= self.tool_radius):
                return self._surface_proxy(q, self._side * n)
            grab = self._start(c, centre, k, self._side * n)
            if grab is None:
                return None
            dragged = self._drag(grab, centre)
            if dragged is not None:  # committed only when the whole tick is good
                self.grab, self.grabs = grab, self.grabs + 1
            return dragged
        return self._drag(self.grab, centre)

    def _uv0(self, k) -> Array:
        return jnp.asarray(self._uv[int(k)], self.dtype)

    def _start(self, c, centre, k, normal) -> Grab | None:
        factor, uv, point = _grab(self.surface(), self._free, self._uv0(k), c, self.project_steps)
        uv, point = np.asarray(uv, np.float64), np.asarray(point, np.float64)
        if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(point))):
            return None
        return Grab(factor=factor, uv=uv, point=point, centre=centre.copy(), normal=normal)

    def _drag(self, grab: Grab, centre: np.ndarray) -> Proxy | None:
        """Move the grabbed point with the tool (`P + C b`, committed) and return the spring proxy."""
        delta = centre - grab.centre
        target = jnp.asarray(grab.point + delta, self.dtype)
        ctrl = grab.factor.drag([target]).ctrl
        if not np.all(np.isfinite(np.asarray(ctrl))):
            return None
        force = self.drag_force(delta)
        self.ctrl = ctrl
        return self._spring_proxy(centre, force, grab.normal)

    def drag_force(self, delta) -> np.ndarray:
        """`(3,)` N: the spring back to the un-dragged point for a drag `delta` (model units),
        `−k_drag · delta` clamped to `|F| ≤ max_force` (direction kept)."""
        d = np.asarray(delta, dtype=np.float64)
        big = float(np.max(np.abs(d)))
        if not (big > 0 and math.isfinite(big)):  # no drag (a non-finite one never gets here)
            return np.zeros(3)
        direction = d / big
        length = math.hypot(*direction)  # scaled: a 1e300 drag neither overflows nor loses its direction
        if self.drag_stiffness * big * length > self.max_force:
            return -self.max_force * direction / length
        return -self.drag_stiffness * d

    # --- proxies ------------------------------------------------------------------------------
    def _surface_proxy(self, q, normal) -> Proxy:
        """The felt surface: the plane at the nearest sample, its normal facing the tool."""
        return self._plane(q, normal, self.proxy_stiffness, self.proxy_damping, self.tool_radius)

    def _spring_proxy(self, centre, force, normal) -> Proxy:
        """A plane along `force` placed so that the servo renders exactly `force` at `centre` (and
        extrapolates it with `drag_stiffness`); along the grab normal while the force is zero."""
        size = float(np.linalg.norm(force))
        n = force / size if size > 0 else normal
        return self._plane(
            centre + n * (size / self.drag_stiffness), n, self.drag_stiffness, self.proxy_damping, 0.0
        )
