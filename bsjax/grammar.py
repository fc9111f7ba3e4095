"""Curve semantics of planar B-spline curves: curvature extrema, the symbol string, Leyton's
process grammar, quantitative parameters, aesthetic measures and operators (thesis ch. 7).

A planar curve's *characteristic points* are its curvature extrema — `M` (local maximum) or `m`
(local minimum) followed by the sign of κ — and its inflections `0` (κ = 0). Read along a closed
curve oriented counter-clockwise they form its *symbol string*, e.g. `"M+m+M+m+"` for an
ellipse; Leyton's vocabulary (thesis eq. 7-1): M+ protrusion, m− indentation, m+ squashing,
M− internal resistance. Strings are written in ASCII (`"M+"`, `"m+"`, `"M-"`, `"m-"`, `"0"`).

The process grammar (Leyton, *A process-grammar for shape*; thesis eq. 7-2) rewrites one symbol
of a valid string: two continuations `Cm+: m+ → 0m-0`, `CM-: M- → 0M+0` and four bifurcations
`BM+: M+ → M+m+M+`, `Bm-: m- → m-M-m-`, `Bm+: m+ → m+M+m+`, `BM-: M- → M-m-M-`.

Numerical functions (`characteristic_points`, `point_parameters`, `measures`) are compiled at
the boundary; string functions (`is_valid`, `canonical`, `apply_rule`, `enumerate_shapes`) are
plain Python on strings.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from bsjax import _checks, _safe, sculpt
from bsjax._boundary import compiled
from bsjax._declared import declared
from bsjax.basis import BSplineCurve

__all__ = [
    "RULES",
    "SYMBOLS",
    "CharacteristicPoints",
    "Measures",
    "OperatorResult",
    "PointParameters",
    "accelerate",
    "apply_inverse",
    "apply_rule",
    "bifurcation",
    "canonical",
    "characteristic_points",
    "continuation",
    "convexify",
    "enumerate_shapes",
    "is_closed",
    "is_valid",
    "measures",
    "point_parameters",
    "sharpen",
    "simplify",
    "soften",
    "straighten",
    "symbols",
    "tension",
    "tokens",
]

# --- the vocabulary ---------------------------------------------------------------------------
SYMBOLS: tuple[str, ...] = ("0", "M+", "m+", "M-", "m-")
"""Kind codes of `CharacteristicPoints.kind`: index into this tuple (−1 marks an empty slot)."""

_FLIP = {"0": "0", "M+": "m-", "m-": "M+", "m+": "M-", "M-": "m+"}  # κ → −κ
_RANK = {"M+": 0, "m+": 1, "0": 2, "m-": 3, "M-": 4}  # canonical order: M+ first
_TOKEN = re.compile(r"[Mm][+-]|0")

RULES: dict[str, tuple[str, tuple[str, ...]]] = {
    "Cm+": ("m+", ("0", "m-", "0")),
    "CM-": ("M-", ("0", "M+", "0")),
    "BM+": ("M+", ("M+", "m+", "M+")),
    "Bm-": ("m-", ("m-", "M-", "m-")),
    "Bm+": ("m+", ("m+", "M+", "m+")),
    "BM-": ("M-", ("M-", "m-", "M-")),
}
"""The six processes of Leyton's grammar (thesis eq. 7-2): name → (symbol, its replacement).
CM+ and Cm− are no processes (they change no extremum) and are absent."""

SAMPLES_PER_CTRL = 32
"""Default κ sampling density: `max(256, 32 · n_ctrl)` samples on [0, 1] (at least ~32 per knot
span), then bracketed bisection of each sign change of κ (inflections) or of its differences
(extrema) to machine precision in the parameter."""

MERGE_REL = 1e-2
"""Default relative κ threshold of `simplify`: adjacent extrema with
`|Δκ| < 1e-2 · (κ_max − κ_min)` are interpolation ripple and are merged (an inverse
bifurcation; thesis §7.3.2 "redundant extrema")."""

_FLAT = 1e-9  # κ differences below 1e-9 · max|κ| are rounding noise (a circle has no extrema)
_BISECT = 60
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(5)


# --- symbol strings ---------------------------------------------------------------------------
@declared
def tokens(name: str) -> list[str]:
    """The symbols of a string, e.g. `tokens("M+0m-0") == ["M+", "0", "m-", "0"]`.

    Accepts ASCII or the typographic minus `−`; raises ValueError on anything else.
    """
    if not isinstance(name, str):
        raise TypeError(f"name: expected a symbol string such as 'M+m+M+m+', got {type(name).__name__}")
    text = name.replace("−", "-").replace(" ", "")
    found = _TOKEN.findall(text)
    if "".join(found) != text:
        _checks.fail("name", "a string of the symbols M+, m+, M-, m-, 0", repr(name))
    return found


def _signs_ok(seq: list[str], closed: bool) -> bool:
    """Alternation of maxima and minima, the one 0 between opposite signs, none between equal."""
    extrema = [(i, s) for i, s in enumerate(seq) if s != "0"]
    pairs = list(itertools.pairwise(extrema))
    if closed and extrema:
        pairs.append((extrema[-1], (extrema[0][0] + len(seq), extrema[0][1])))
    for (i, a), (j, b) in pairs:
        zeros = j - i - 1
        if a[0] == b[0] or zeros != (a[1] != b[1]) or {a, b} == {"M-", "m+"}:
            return False
    if closed:
        return bool(extrema) or not seq
    return _open_ends_ok(seq, extrema)


def _open_ends_ok(seq, extrema) -> bool:
    if not extrema:
        return seq.count("0") <= 1
    (first, a), (last, b) = extrema[0], extrema[-1]
    lead, trail = first, len(seq) - 1 - last
    # through 0 into the first extremum: κ rises to an M+ or falls to an m-
    return lead <= 1 and trail <= 1 and (lead == 0 or a in ("M+", "m-")) and (trail == 0 or b in ("M+", "m-"))


@declared
def is_valid(name: str, closed: bool = True) -> bool:
    """Whether a symbol string can be the curvature string of a smooth planar curve.

    Rules (thesis §7.1, reconstructed): maxima `M` and minima `m` alternate; `M-` stands only
    next to `m-` and `m+` only next to `M+` (a maximum exceeds its neighbouring minima); exactly
    one `0` between neighbours of opposite sign, none between neighbours of equal sign; a closed
    curve has at least two `M+` (the four-vertex theorem) and is read cyclically. An open curve
    (end points excluded, Fig. 7-9) may start or end with one `0` next to an `M+` or `m-`.
    The empty string is valid (constant curvature: a circle, a line).
    """
    seq = tokens(name)
    if not seq:
        return True
    if not _signs_ok(seq, closed):
        return False
    return not closed or seq.count("M+") >= 2


@declared
def canonical(name: str, closed: bool = True) -> str:
    """The canonical spelling of a shape name.

    Closed: the least of every rotation and of the reversal's rotations (two strings name the
    same closed shape when one is a rotation or the reversal of the other; thesis §7.1), in the
    order M+ < m+ < 0 < m- < M- — so it starts with M+ (`"m+M+m+M+"` → `"M+m+M+m+"`).
    Open: the string or the same curve traversed backwards (reversed, κ negated), whichever is
    less.
    """
    seq = tokens(name)
    if closed:
        variants = [s[r:] + s[:r] for s in (seq, seq[::-1]) for r in range(max(len(s), 1))]
    else:
        variants = [seq, [_FLIP[s] for s in reversed(seq)]]
    return "".join(min(variants, key=lambda s: [_RANK[x] for x in s]))


def _rule(rule: str) -> tuple[str, tuple[str, ...]]:
    if rule not in RULES:
        _checks.fail("rule", f"one of {sorted(RULES)}", repr(rule))
    return RULES[rule]


def _index(seq, index, name):
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise TypeError(f"index: expected an int, got {type(index).__name__}")
    if not 0 <= index < len(seq):
        _checks.fail("index", f"a symbol index in 0..{len(seq) - 1} of {name!r}", index)
    return int(index)


@declared
def apply_rule(name: str, rule: str, index: int) -> str:
    """Apply one process of `RULES` at symbol `index` of `name` (counting every symbol, 0s too).

    `apply_rule("M+m+M+m+", "Cm+", 1) == "M+0m-0M+m+"`. The result keeps the input's rotation
    (call `canonical` to compare shapes). Raises ValueError when the symbol at `index` is not the
    rule's left-hand side. Thesis eq. 7-2.
    """
    seq = tokens(name)
    lhs, rhs = _rule(rule)
    i = _index(seq, index, name)
    if seq[i] != lhs:
        _checks.fail("index", f"a {lhs} symbol for rule {rule}", f"{seq[i]} at {i} of {name!r}")
    return "".join(seq[:i] + list(rhs) + seq[i + 1 :])


@declared
def apply_inverse(name: str, rule: str, index: int, closed: bool = True) -> str:
    """Undo `rule` on the three symbols starting at `index` (cyclically when `closed`):
    `apply_inverse(apply_rule(s, r, i), r, i) == s`. The inverse processes are the aesthetic
    operators' building blocks (thesis §7.4: inverse Cm+ removes an indentation "0m-0").
    Raises ValueError when those symbols are not the rule's right-hand side."""
    seq = tokens(name)
    lhs, rhs = _rule(rule)
    i = _index(seq, index, name)
    n = len(seq)
    window = [seq[(i + k) % n] for k in range(3)] if closed and n >= 3 else seq[i : i + 3]
    if tuple(window) != rhs:
        _checks.fail("index", f"the symbols {''.join(rhs)} of rule {rule}", f"{''.join(window)} at {i}")
    if i + 3 <= n:
        return "".join(seq[:i] + [lhs] + seq[i + 3 :])
    wrap = i + 3 - n  # the pattern runs over the end: the replaced symbol goes first
    return "".join([lhs] + seq[wrap:i])


def _closed_shapes(pairs: int) -> Iterator[tuple[str, ...]]:
    for signs in itertools.product("+-", repeat=2 * pairs):
        extrema = [("M" if k % 2 == 0 else "m") + s for k, s in enumerate(signs)]
        seq: list[str] = []
        for k, a in enumerate(extrema):
            seq.append(a)
            if a[1] != extrema[(k + 1) % len(extrema)][1]:
                seq.append("0")
        yield tuple(seq)


@declared
def enumerate_shapes(max_extrema: int, closed: bool = True) -> list[str]:
    """Every closed shape the grammar allows with at most `max_extrema` curvature extrema, in
    canonical spelling, sorted by length then name.

    Counts: 3 shapes up to 4 extrema, 9 up to 6, **21 up to 8 — the twenty-one shapes of the
    thesis §7.1** (after Leyton), 43 up to 10. Only closed curves are enumerated.
    """
    _checks.check_count(max_extrema, "max_extrema", 1)
    if not closed:
        raise ValueError("closed: expected True (only closed shapes are enumerated), got False")
    found = {
        canonical("".join(s))
        for pairs in range(1, max_extrema // 2 + 1)
        for s in _closed_shapes(pairs)
        if is_valid("".join(s))
    }
    return sorted(found, key=lambda s: (len(tokens(s)), [_RANK[x] for x in tokens(s)]))


# --- characteristic points --------------------------------------------------------------------
class CharacteristicPoints(eqx.Module):
    """Curvature extrema and inflections of a planar curve, in parameter order, fixed capacity.

    **Fields:** `params (c,)` parameters in [0, 1]; `kind (c,)` codes into `SYMBOLS`
    (0 inflection, 1 M+, 2 m+, 3 M-, 4 m-; −1 empty slot); `curvature (c,)` κ at each point;
    `count ()` filled slots (the first `count`); `overflow ()` True when more points existed
    than the capacity (the rest were dropped: call again with a larger `capacity`);
    `closed` (static) whether the curve was read as closed.
    """

    params: Float[Array, " c"]
    kind: Int[Array, " c"]
    curvature: Float[Array, " c"]
    count: Int[Array, ""]
    overflow: Bool[Array, ""]
    closed: bool = eqx.field(static=True)

    @property
    def valid(self) -> Bool[Array, " c"]:
        """Which slots hold a point."""
        return jnp.arange(self.params.shape[0]) < self.count

    def symbols(self) -> list[str]:
        """The filled slots as symbols (host side)."""
        return [SYMBOLS[k] for k in np.asarray(self.kind)[: int(self.count)]]


def _planar(curve, name="curve") -> BSplineCurve:
    """Structure: a 2-D `BSplineCurve` (its values are checked inside the kernels, `_finite`)."""
    if not isinstance(curve, BSplineCurve):
        _checks.fail(name, "a bsjax.basis.BSplineCurve", type(curve).__name__)
    if curve.dim != 2:
        _checks.fail(name, "a planar curve (control points of dimension 2)", f"dimension {curve.dim}")
    return curve


def _finite(curve, name="curve") -> BSplineCurve:
    """The curve with its control points checked finite (an `eqx.error_if` when traced)."""
    return eqx.tree_at(lambda c: c.ctrl, curve, _checks.finite(curve.ctrl, f"{name}.ctrl"))


@declared
def is_closed(curve: BSplineCurve, tol: float = 1e-9) -> bool:
    """The `closed=None` rule: a periodic curve, or a clamped one whose end points coincide and
    whose unit end tangents agree (within `tol` relative to the control polygon's size).

    Needs concrete control points (host side); inside `jit`/`vmap` pass `closed` explicitly.
    """
    if curve.periodic:
        return True
    if not _checks.is_concrete(curve.ctrl):
        raise TypeError(
            "closed: expected True or False when the curve's control points are traced (jit, vmap, grad), "
            "got None"
        )
    p = np.asarray(curve.ctrl, dtype=np.float64)
    size = float(np.ptp(p, axis=0).max()) or 1.0
    if np.linalg.norm(p[0] - p[-1]) > tol * size:
        return False
    start = next((q - p[0] for q in p[1:] if np.linalg.norm(q - p[0]) > tol * size), None)
    end = next((p[-1] - q for q in p[-2::-1] if np.linalg.norm(q - p[-1]) > tol * size), None)
    if start is None or end is None:
        return False
    cos = start @ end / (np.linalg.norm(start) * np.linalg.norm(end))
    return bool(cos > 1 - tol)


def _closed(curve, closed) -> bool:
    if closed is None:
        return is_closed(curve)
    if not isinstance(closed, (bool, np.bool_)):
        raise TypeError(f"closed: expected True, False or None, got {type(closed).__name__}")
    return bool(closed)


def _samples(curve, samples) -> int:
    if samples is None:
        return max(256, SAMPLES_PER_CTRL * curve.n_ctrl)
    return _checks.check_count(samples, "samples", 8)


def _derivatives(curve: BSplineCurve, t, top: int = 2) -> list:
    """`[C^(1), …, C^(top)]` at parameters `t (m,)` from the blending matrices (thesis eq. 3.6);
    rational curves by the quotient rule on the homogeneous form (The NURBS Book eq. 4.8):
    `C^(k) = (H^(k) − Σ_{i=1..k} binom(k, i) w^(i) C^(k−i)) / w`."""
    a = curve.direction.matrices(t, tuple(range(top + 1)))
    if curve.weights is None:
        return [a[k] @ curve.ctrl for k in range(1, top + 1)]
    w = curve.weights
    h = [ak @ (curve.ctrl * w[:, None]) for ak in a]
    wd = [(ak @ w)[:, None] for ak in a]
    c = [h[0] / wd[0]]
    binom = ((1,), (1, 1), (1, 2, 1), (1, 3, 3, 1))
    for k in range(1, top + 1):
        rest = sum(binom[k][i] * wd[i] * c[k - i] for i in range(1, k + 1))
        c.append((h[k] - rest) / wd[0])
    return c[1:]


def _cross(a, b):
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _kappa(curve, t):
    """Signed curvature κ(t) = (x'y'' − y'x'') / |C'|³ (0 where the speed vanishes)."""
    d1, d2 = _derivatives(curve, t)
    return _safe.ratio(_cross(d1, d2), _safe.norm(d1) ** 3)


def _kappa_and_slope(curve, t):
    """κ(t) and dκ/dt = [(C1×C3)|C1|² − 3 (C1×C2)(C1·C2)] / |C1|⁵ with Ck = C^(k)
    (0 where the speed vanishes)."""
    d1, d2, d3 = _derivatives(curve, t, 3)
    speed2 = jnp.sum(d1 * d1, axis=-1)
    turn = _cross(d1, d2)
    kappa = _safe.ratio(turn, _safe.norm(d1) ** 3)
    slope = _safe.ratio(_cross(d1, d3) * speed2 - 3 * turn * jnp.sum(d1 * d2, axis=-1), _safe.norm(d1) ** 5)
    return kappa, slope


def _bisect(f, lo, hi, rising):
    """The point of [lo, hi] where `f` changes sign (from − to + when `rising`), per element,
    and the auxiliary value `f` returned there: `f(s) -> (g, aux)`, bisection on the sign of g."""

    def step(_, state):
        lo, hi, _, _ = state
        mid = 0.5 * (lo + hi)
        value, aux = f(mid)
        up = (value < 0) == rising
        return jnp.where(up, mid, lo), jnp.where(up, hi, mid), mid, aux

    init = (lo, hi, lo, jnp.zeros_like(lo))
    _, _, mid, aux = jax.lax.fori_loop(0, _BISECT, step, init)
    return mid, aux


def _last_nonzero(sign):
    """For each index j, the last index < j where `sign` ≠ 0 (−1 when none)."""
    idx = jnp.where(sign != 0, jnp.arange(sign.shape[0]), -1)
    before = jax.lax.cummax(idx)
    return jnp.concatenate([jnp.array([-1]), before[:-1]])


def _grid(n, closed, dtype):
    if closed:  # n samples on the circle [0, 1), read twice so every bracket may cross the seam
        t = jnp.arange(n, dtype=dtype) / n
        return jnp.concatenate([t, t + 1]), n
    return jnp.linspace(0.0, 1.0, n, dtype=dtype), 0


@declared
def characteristic_points(
    curve: BSplineCurve, closed: bool | None = None, samples: int | None = None, capacity: int = 64
) -> CharacteristicPoints:
    """Curvature extrema (M±, m±) and inflections (0) of a planar curve, sorted by parameter.

    κ is sampled at `samples` points (default `max(256, 32 · n_ctrl)`, see `SAMPLES_PER_CTRL`);
    an inflection is a sign change of κ, an extremum a sign change of its differences (changes
    within `1e-9 · max|κ|` are rounding noise and skipped, so a circle has none); each is then
    refined by 60 bisections of κ (inflections) or dκ/dt (extrema, by forward differentiation).
    Open curves exclude their end points (thesis Fig. 7-9); closed curves are read cyclically.

    **Arguments:**
    - `curve`: a planar `BSplineCurve` (d = 2), polynomial or rational.
    - `closed`: True, False, or None — then `is_closed(curve)` decides (a periodic curve, or a
      clamped one whose ends and unit end tangents coincide; needs concrete control points).
    - `samples`: κ samples (int ≥ 8); `capacity`: slots of the result (int ≥ 1).

    **Returns:** `CharacteristicPoints` (fixed capacity, `overflow` flag).

    κ = (x'y'' − y'x'') / (x'² + y'²)^{3/2} (thesis eq. 7-4), positive where the curve turns left.
    The `closed=None` decision is taken on the host before the compiled kernel runs.
    """
    curve = _planar(curve)
    return _points(
        curve, _closed(curve, closed), _samples(curve, samples), _checks.check_count(capacity, "capacity")
    )


@compiled
def _points(curve: BSplineCurve, closed: bool, n: int, capacity: int) -> CharacteristicPoints:
    curve = _finite(curve)
    t, offset = _grid(n, closed, curve.ctrl.dtype)
    wrap = (lambda s: jnp.mod(s, 1.0)) if closed else (lambda s: s)
    kappa = _kappa(curve, wrap(t))
    flat = _FLAT * jnp.max(jnp.abs(kappa))

    # inflections: sign changes of κ between sample j and the last non-flat sample before it
    sign = jnp.where(jnp.abs(kappa) > flat, jnp.sign(kappa), 0.0)
    prev = _last_nonzero(sign)
    at = jnp.arange(t.shape[0])
    is_zero = (sign != 0) & (prev >= 0) & (sign[prev] != sign) & (at >= offset)
    zi, z_count = _compact(is_zero, capacity)

    # extrema: sign changes of the differences Δ_j = κ_{j+1} − κ_j (interval j)
    delta = kappa[1:] - kappa[:-1]
    dsign = jnp.where(jnp.abs(delta) > flat, jnp.sign(delta), 0.0)
    dprev = _last_nonzero(dsign)
    at = jnp.arange(delta.shape[0])
    in_turn = (at >= offset - 1) & (at < offset - 1 + n)  # each interval of a closed curve once
    is_ext = (dsign != 0) & (dprev >= 0) & (dsign[dprev] != dsign) & in_turn
    ei, e_count = _compact(is_ext, capacity)
    is_max = dsign[ei] < 0

    # one bisection for both: of κ in the inflection brackets, of dκ/dt in the extremum brackets
    lo = jnp.concatenate([t[prev[zi]], t[dprev[ei]]])
    hi = jnp.concatenate([t[zi], t[ei + 1]])
    rising = jnp.concatenate([sign[zi] > 0, ~is_max])
    of_slope = jnp.arange(2 * capacity) >= capacity

    def f(s):
        value, slope = _kappa_and_slope(curve, wrap(s))
        return jnp.where(of_slope, slope, value), value

    found, found_kappa = _bisect(f, lo, hi, rising)
    return _merge(wrap(found), found_kappa, (z_count, e_count, is_max), capacity, closed)


def _compact(mask, capacity):
    (idx,) = jnp.nonzero(mask, size=capacity, fill_value=0)
    return idx, jnp.sum(mask)


def _merge(found, found_kappa, counts, capacity, closed) -> CharacteristicPoints:
    z_count, e_count, is_max = counts
    e_kappa = found_kappa[capacity:]
    e_kind = jnp.where(is_max, jnp.where(e_kappa > 0, 1, 3), jnp.where(e_kappa > 0, 2, 4))
    slot = jnp.arange(capacity)
    used = jnp.concatenate([slot < z_count, slot < e_count])
    params = jnp.where(used, found, jnp.inf)
    kind = jnp.concatenate([jnp.zeros(capacity, dtype=jnp.int32), e_kind.astype(jnp.int32)])
    kappa = jnp.concatenate([jnp.zeros_like(e_kappa), e_kappa])
    order = jnp.argsort(params)[:capacity]
    total = z_count + e_count
    count = jnp.minimum(total, capacity)
    filled = slot < count
    return CharacteristicPoints(
        params=jnp.where(filled, params[order], 0.0),
        kind=jnp.where(filled, kind[order], -1),
        curvature=jnp.where(filled, kappa[order], 0.0),
        count=count,
        overflow=total > capacity,
        closed=closed,
    )


# --- merging spurious extrema and the symbol string -------------------------------------------
@declared
def simplify(points: CharacteristicPoints, rel: float = MERGE_REL) -> CharacteristicPoints:
    """Merge the spurious extrema of an approximating spline (host side, concrete input).

    Repeatedly drops the adjacent pair of extrema (cyclically when closed) with the smallest
    `|Δκ|` while it is below `max(rel · (κ_max − κ_min), 1e-8 · max|κ|)` — an inverse
    bifurcation (thesis §7.3.2 "redundant extrema"; a 64-sample interpolant of an ellipse shows
    8 extrema, its shape 4). Then keeps one inflection between extrema of opposite sign (the
    middle one) and none between extrema of equal sign; at the open ends one when their count is
    odd. Default `rel = MERGE_REL = 1e-2`.

    **Returns:** `CharacteristicPoints` of the same capacity.
    """
    if not isinstance(points, CharacteristicPoints):
        _checks.fail("points", "CharacteristicPoints", type(points).__name__)
    if not isinstance(rel, (int, float)) or not 0 <= rel < 1:
        _checks.fail("rel", "a number in [0, 1)", rel)
    n = int(points.count)
    entries = list(
        zip(
            np.asarray(points.params)[:n].tolist(),
            np.asarray(points.kind)[:n].tolist(),
            np.asarray(points.curvature)[:n].tolist(),
        )
    )
    extrema = [e for e in entries if e[1] != 0]
    extrema = _drop_ripple(extrema, rel, points.closed)
    kept = _with_inflections(entries, extrema, points.closed)
    return _pack(kept, points)


def _drop_ripple(extrema, rel, closed):
    if not extrema:
        return extrema
    values = [e[2] for e in extrema]
    threshold = max(rel * (max(values) - min(values)), 1e-8 * max(abs(v) for v in values))
    while len(extrema) >= 2:
        m = len(extrema)
        pairs = range(m if closed and m > 2 else m - 1)
        gaps = [(abs(extrema[i][2] - extrema[(i + 1) % m][2]), i) for i in pairs]
        gap, i = min(gaps)
        if gap >= threshold:
            break
        drop = {i, (i + 1) % m}
        extrema = [e for k, e in enumerate(extrema) if k not in drop]
    return extrema


def _with_inflections(entries, extrema, closed):
    """The kept extrema with the inflections their signs call for, in parameter order."""
    zeros = [e for e in entries if e[1] == 0]
    if not extrema:
        return [] if closed or len(zeros) % 2 == 0 else [zeros[len(zeros) // 2]]
    out = []
    m = len(extrema)
    for k, e in enumerate(extrema):
        out.append(e)
        if k == m - 1 and not closed:
            break
        nxt = extrema[(k + 1) % m]
        if (e[2] > 0) != (nxt[2] > 0):
            between = [z for z in zeros if _between(z[0], e[0], nxt[0])]
            if between:
                out.append(between[len(between) // 2])
    if not closed:
        head = [z for z in zeros if z[0] < extrema[0][0]]
        tail = [z for z in zeros if z[0] > extrema[-1][0]]
        out = head[-1:] * (len(head) % 2) + out + tail[:1] * (len(tail) % 2)
    return sorted(out, key=lambda e: e[0])


def _between(t, a, b):
    return a < t < b if a < b else (t > a or t < b)  # (b < a: the arc runs over the seam)


def _pack(entries, like: CharacteristicPoints) -> CharacteristicPoints:
    c = like.params.shape[0]
    params = np.zeros(c, like.params.dtype)
    kind = np.full(c, -1, np.int32)
    kappa = np.zeros(c, like.curvature.dtype)
    for i, (t, k, v) in enumerate(entries):
        params[i], kind[i], kappa[i] = t, k, v
    return CharacteristicPoints(
        params=jnp.asarray(params),
        kind=jnp.asarray(kind),
        curvature=jnp.asarray(kappa),
        count=jnp.asarray(len(entries), dtype=like.count.dtype),
        overflow=like.overflow,
        closed=like.closed,
    )


@declared
def symbols(
    curve: BSplineCurve,
    closed: bool | None = None,
    rel: float = MERGE_REL,
    samples: int | None = None,
    capacity: int = 64,
) -> str:
    """The symbol string of a planar curve (thesis §7.1), e.g. `"M+m+M+m+"` for an ellipse.

    `characteristic_points`, then `simplify(points, rel)`. A closed curve is read
    counter-clockwise (a clockwise one is reversed: κ changes sign, M+ ↔ m-, m+ ↔ M-) and
    returned in `canonical` spelling; an open curve is read along its parameter, end points
    excluded. A circle (constant curvature) has no characteristic points: `""`.

    **Arguments:** as `characteristic_points`; `rel`: merging threshold of `simplify`.
    **Returns:** `str`. Raises ValueError when the points overflow `capacity`.
    """
    curve = _planar(curve)
    closed = _closed(curve, closed)
    points = characteristic_points(curve, closed, samples, capacity)
    if bool(points.overflow):
        _checks.fail("capacity", f"room for every characteristic point (more than {capacity})", "an overflow")
    seq = simplify(points, rel).symbols()
    if not closed:
        return "".join(seq)
    if float(_signed_area(curve, 64)) < 0:
        seq = [_FLIP[s] for s in reversed(seq)]
    return canonical("".join(seq))


# --- arc length, area ---------------------------------------------------------------------------
def _gauss(lo, hi):
    """Gauss–Legendre nodes `(m, 5)` and weights on each interval [lo, hi]."""
    x = jnp.asarray(_GAUSS_X, dtype=lo.dtype)
    w = jnp.asarray(_GAUSS_W, dtype=lo.dtype)
    half = (0.5 * (hi - lo))[:, None]
    return (0.5 * (hi + lo))[:, None] + half * x[None, :], half * w[None, :]


def _integrate(curve, lo, hi, integrand):
    """`∫_lo^hi integrand(C', C'') dt` per interval, 5-point Gauss–Legendre."""
    nodes, weights = _gauss(lo, hi)
    d1, d2 = _derivatives(curve, nodes.reshape(-1))
    return jnp.sum(integrand(d1, d2).reshape(nodes.shape) * weights, axis=1)


def _speed(d1, d2):
    return _safe.norm(d1)


class _ArcLength(eqx.Module):
    """Cumulative arc length at `knots (N+1,)` = linspace(0, 1); `at(t)` adds the partial span."""

    grid: Float[Array, " N1"]
    cumulative: Float[Array, " N1"]

    def at(self, curve, t):
        n = self.grid.shape[0] - 1
        j = jnp.clip(jnp.floor(t * n).astype(jnp.int32), 0, n - 1)
        return self.cumulative[j] + _integrate(curve, self.grid[j], t, _speed)

    @property
    def total(self):
        return self.cumulative[-1]


def _arc_length(curve, n: int) -> _ArcLength:
    grid = jnp.linspace(0.0, 1.0, n + 1, dtype=curve.ctrl.dtype)
    pieces = _integrate(curve, grid[:-1], grid[1:], _speed)
    return _ArcLength(grid, jnp.concatenate([jnp.zeros(1, pieces.dtype), jnp.cumsum(pieces)]))


@compiled
def _signed_area(curve: BSplineCurve, n: int):
    """Signed area enclosed by the curve and its end chord, `½ ∮ (x dy − y dx)` (Green)."""
    return _area(curve, n)


def _area(curve, n):
    grid = jnp.linspace(0.0, 1.0, n + 1, dtype=curve.ctrl.dtype)
    nodes, weights = _gauss(grid[:-1], grid[1:])
    flat = nodes.reshape(-1)
    a = curve.direction.matrices(flat, (0,))[0]
    point = a @ curve.ctrl if curve.weights is None else _rational_points(curve, a)
    (d1,) = _derivatives(curve, flat, 1)
    sweep = jnp.sum((_cross(point, d1)).reshape(nodes.shape) * weights)
    ends = _rational_points(curve, curve.direction.matrices(grid[jnp.array([0, -1])], (0,))[0])
    chord = ends[1, 0] * ends[0, 1] - ends[1, 1] * ends[0, 0]
    return 0.5 * (sweep + chord)


def _rational_points(curve, a):
    if curve.weights is None:
        return a @ curve.ctrl
    w = curve.weights
    return (a @ (curve.ctrl * w[:, None])) / (a @ w)[:, None]


def _wrapper(closed):
    return (lambda s: jnp.mod(s, 1.0)) if closed else (lambda s: jnp.clip(s, 0.0, 1.0))


# --- aesthetic measures -------------------------------------------------------------------------
class Measures(eqx.Module):
    """Aesthetic measures of a planar curve (thesis §7.3.3, FIORES-II terms); scalars.

    **Fields:** `acceleration` = (κ_max − κ_min) / (arc length between their locations; the
    shorter way round a closed curve); `softness` = 1 / κ_max (the smallest radius of curvature;
    inf when κ_max ≤ 0); `flatness` = 1 − d_min / d_max of the minimum-area enclosing rectangle
    (0 for a square's worth of extent, 1 for a segment); `convexity` = signed area between the
    curve and its end chord / (d_max · d_min) (∈ [−1, 1], + when the curve turns left);
    `tension` = (κ_max − κ_min) / κ_avg with κ_avg = ∫κ ds / L (arc-length average);
    also `kappa_max`, `kappa_min`, `length` (L), `d_max`, `d_min`.
    """

    acceleration: Float[Array, ""]
    softness: Float[Array, ""]
    flatness: Float[Array, ""]
    convexity: Float[Array, ""]
    tension: Float[Array, ""]
    kappa_max: Float[Array, ""]
    kappa_min: Float[Array, ""]
    length: Float[Array, ""]
    d_max: Float[Array, ""]
    d_min: Float[Array, ""]


@declared
def measures(curve: BSplineCurve, closed: bool | None = None, samples: int | None = None) -> Measures:
    """The aesthetic measures of a planar curve (thesis §7.3.3): acceleration, softness,
    flatness, convexity and tension, as defined in `Measures`.

    κ_max and κ_min: the largest and smallest of `samples` κ samples (default as in
    `characteristic_points`), refined by bisection of dκ/dt (end points count on open curves);
    arc length and ∫κ ds by 5-point Gauss–Legendre on every sample interval; the enclosing
    rectangle of the sampled curve (its Gauss nodes) over 90 orientations in [0, π/2), refined by
    golden-section search. Compiled; `closed` as in `characteristic_points`.

    **Returns:** `Measures` of scalars.
    """
    curve = _planar(curve)
    return _measures(curve, _closed(curve, closed), _samples(curve, samples))


@compiled
def _measures(curve: BSplineCurve, closed: bool, n: int) -> Measures:
    curve = _finite(curve)
    wrap = _wrapper(closed)
    dtype = curve.ctrl.dtype
    grid = jnp.linspace(0.0, 1.0, n + 1, dtype=dtype)
    kappa = _kappa(curve, grid)
    (t_max, k_max), (t_min, k_min) = _extreme_kappa(curve, grid, kappa, wrap)
    arc = _arc_length(curve, n)
    total = arc.total
    between = jnp.abs(arc.at(curve, t_max[None])[0] - arc.at(curve, t_min[None])[0])
    between = jnp.minimum(between, total - between) if closed else between
    turning = jnp.sum(_integrate(curve, grid[:-1], grid[1:], _turning))
    spread = k_max - k_min
    d_max, d_min = _rectangle(_sample_points(curve, grid))
    area = _area(curve, n)
    return Measures(
        acceleration=_safe.ratio(spread, between),
        softness=jnp.where(k_max > 0, 1 / jnp.where(k_max > 0, k_max, 1), jnp.inf),
        flatness=1 - _safe.ratio(d_min, d_max),
        convexity=_safe.ratio(area, d_max * d_min),
        tension=_safe.ratio(spread * total, turning),
        kappa_max=k_max,
        kappa_min=k_min,
        length=total,
        d_max=d_max,
        d_min=d_min,
    )


def _turning(d1, d2):
    return _safe.ratio(_cross(d1, d2), jnp.sum(d1 * d1, axis=-1))  # κ |C'|


def _extreme_kappa(curve, grid, kappa, wrap):
    """(t, κ) of the largest and smallest κ: best sample, then bisection of dκ/dt around it."""
    h = grid[1] - grid[0]
    centre = grid[jnp.stack([jnp.argmax(kappa), jnp.argmin(kappa)])]
    lo, hi = centre - h, centre + h
    rising = jnp.array([False, True])

    def f(s):
        value, slope = _kappa_and_slope(curve, wrap(s))
        return slope, value

    t, k = _bisect(f, lo, hi, rising)
    best = jnp.stack([jnp.max(kappa), jnp.min(kappa)])
    better = jnp.array([k[0] >= best[0], k[1] <= best[1]])  # an end maximum stays at its end
    t = jnp.where(better, wrap(t), centre)
    k = jnp.where(better, k, best)
    return (t[0], k[0]), (t[1], k[1])


def _sample_points(curve, grid):
    nodes, _ = _gauss(grid[:-1], grid[1:])
    a = curve.direction.matrices(jnp.concatenate([nodes.reshape(-1), grid]), (0,))[0]
    return _rational_points(curve, a)


_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


def _rectangle(points):
    """(d_max, d_min) of the minimum-area enclosing rectangle of `points (m, 2)`: 90 coarse
    orientations, then 60 golden-section steps around the best (the area is continuous in the
    angle and its minimum lies at a hull-edge direction, a kink the search converges to)."""
    dtype = points.dtype

    def extent(theta):
        u = jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)
        v = jnp.stack([-jnp.sin(theta), jnp.cos(theta)], axis=-1)
        pu, pv = points @ u.T, points @ v.T
        return jnp.ptp(pu, axis=0), jnp.ptp(pv, axis=0)

    coarse = jnp.arange(90, dtype=dtype) * (0.5 * np.pi / 90)
    wu, wv = extent(coarse)
    best = coarse[jnp.argmin(wu * wv)]
    step = 0.5 * np.pi / 90

    def area(theta):
        a, b = extent(jnp.reshape(theta, (1,)))
        return (a * b)[0]

    def golden(_, bounds):
        lo, hi = bounds
        x1 = hi - _GOLDEN * (hi - lo)
        x2 = lo + _GOLDEN * (hi - lo)
        left = area(x1) < area(x2)
        return jnp.where(left, lo, x1), jnp.where(left, x2, hi)

    lo, hi = jax.lax.fori_loop(0, 60, golden, (best - step, best + step))
    a, b = extent(jnp.reshape(0.5 * (lo + hi), (1,)))
    a, b = a[0], b[0]
    return jnp.maximum(a, b), jnp.minimum(a, b)


# --- quantitative parameters ----------------------------------------------------------------------
class PointParameters(eqx.Module):
    """Quantitative parameters of each characteristic point (thesis §7.3.2), slots as in the
    `CharacteristicPoints` they were computed from.

    **Fields:** `dk_left`, `dk_right` — |κ(CP) − κ(neighbour)| to the left / right characteristic
    point; `d_left`, `d_right` — arc length to it; `range_left`, `range_right` — arc length from
    the CP to the point where κ = κ(CP) ∓ Δκ/2 (half way in κ to the neighbour, so the ranges
    of neighbours tile the curve); `left`, `right` — slot of the neighbour (−1: the curve's end
    on an open curve, whose ends act as neighbours); `kind` (codes into `SYMBOLS`), `valid`.
    """

    dk_left: Float[Array, " c"]
    dk_right: Float[Array, " c"]
    d_left: Float[Array, " c"]
    d_right: Float[Array, " c"]
    range_left: Float[Array, " c"]
    range_right: Float[Array, " c"]
    left: Int[Array, " c"]
    right: Int[Array, " c"]
    kind: Int[Array, " c"]
    valid: Bool[Array, " c"]

    @property
    def visibility(self) -> tuple[Float[Array, " c"], Float[Array, " c"]]:
        """`(D_L · Δκ_L, D_R · Δκ_R)` — how visible a characteristic point is from each side."""
        return self.d_left * self.dk_left, self.d_right * self.dk_right

    @compiled
    def small_visibility(self, gamma: float, beta: float) -> Bool[Array, " c"]:
        """`(D_L < γ ∨ D_R < γ) ∧ (Δκ_L < β ∨ Δκ_R < β)` (thesis §7.3.2; γ, β user thresholds)."""
        near = (self.d_left < gamma) | (self.d_right < gamma)
        return self.valid & near & ((self.dk_left < beta) | (self.dk_right < beta))

    @compiled
    def sharp_corner(self, gamma: float, mu: float) -> Bool[Array, " c"]:
        """`D_L + D_R < γ ∧ Δκ_L > μ ∧ Δκ_R > μ` (thesis §7.3.2)."""
        short = self.d_left + self.d_right < gamma
        return self.valid & short & (self.dk_left > mu) & (self.dk_right > mu)

    @compiled
    def symmetric(self, rtol: float = 1e-6) -> Bool[Array, " c"]:
        """`Δκ_L = Δκ_R ∧ D_L = D_R ∧ R_L = R_R` within `rtol` relative (thesis §7.3.2)."""

        def same(a, b):
            return jnp.abs(a - b) <= rtol * jnp.maximum(jnp.abs(a), jnp.abs(b))

        pairs = ((self.dk_left, self.dk_right), (self.d_left, self.d_right))
        ok = same(*pairs[0]) & same(*pairs[1]) & same(self.range_left, self.range_right)
        return self.valid & ok

    @compiled
    def redundant_extrema(self, distance: float) -> Bool[Array, " c"]:
        """The middle extremum of "M+m+M+", "m+M+m+", "m-M-m-" or "M-m-M-" whose neighbours lie
        within arc length `distance` on both sides: the triple collapses to its outer symbol
        (an inverse bifurcation; thesis §7.3.2)."""
        outer = jnp.array([-1, 2, 1, 4, 3], dtype=jnp.int32)  # middle kind → its neighbours' kind
        kind_l = jnp.where(self.left >= 0, self.kind[self.left], -2)
        kind_r = jnp.where(self.right >= 0, self.kind[self.right], -2)
        want = outer[jnp.clip(self.kind, 0, 4)]
        pattern = (self.kind > 0) & (kind_l == want) & (kind_r == want)
        return self.valid & pattern & (self.d_left < distance) & (self.d_right < distance)


@compiled
def point_parameters(
    curve: BSplineCurve, points: CharacteristicPoints, samples: int = 256
) -> PointParameters:
    """Quantitative parameters ΔκL, ΔκR, DL, DR and the ranges of every characteristic point
    (thesis §7.3.2), see `PointParameters`.

    **Arguments:** the planar `curve` and its `points` (usually `simplify(characteristic_points
    (curve))`; read closed or open as they were); `samples`: intervals of the arc-length table
    (5-point Gauss–Legendre each). **Returns:** `PointParameters`.
    """
    curve = _finite(_planar(curve))
    if not isinstance(points, CharacteristicPoints):
        _checks.fail("points", "CharacteristicPoints", type(points).__name__)
    n = _checks.check_count(samples, "samples", 8)
    closed = points.closed
    wrap = _wrapper(closed)
    c = points.params.shape[0]
    slot = jnp.arange(c)
    count = jnp.maximum(points.count, 1)
    t, k = points.params, points.curvature
    if closed:
        left, right = jnp.mod(slot - 1, count), jnp.mod(slot + 1, count)
        t_l, t_r = t[left], t[right]
        t_l = jnp.where(t_l >= t, t_l - 1, t_l)
        t_r = jnp.where(t_r <= t, t_r + 1, t_r)
    else:
        left = jnp.where(slot == 0, -1, slot - 1)
        right = jnp.where(slot == points.count - 1, -1, slot + 1)
        t_l = jnp.where(left >= 0, t[left], 0.0)
        t_r = jnp.where(right >= 0, t[jnp.maximum(right, 0)], 1.0)
    ends = _kappa(curve, jnp.stack([t[0] * 0, t[0] * 0 + 1]))
    k_l = jnp.where(left >= 0, k[left], ends[0])
    k_r = jnp.where(right >= 0, k[jnp.maximum(right, 0)], ends[1])
    arc = _arc_length(curve, n)

    def length(a, b):  # arc length from a to b ≥ a (unwrapped parameters)
        s = arc.at(curve, wrap(b)) - arc.at(curve, wrap(a))
        return jnp.where(s < 0, s + arc.total, s) if closed else s

    full = (points.count == 1) & closed
    d_l = jnp.where(full, arc.total, length(t_l, t))
    d_r = jnp.where(full, arc.total, length(t, t_r))
    mid = jnp.concatenate([0.5 * (k + k_l), 0.5 * (k + k_r)])

    def f(s):
        value = _kappa(curve, wrap(s)) - mid
        return value, value

    lo = jnp.concatenate([t_l, t])
    hi = jnp.concatenate([t, t_r])
    rising = jnp.concatenate([k > k_l, k_r > k])
    half, _ = _bisect(f, lo, hi, rising)
    valid = points.valid
    zero = jnp.zeros_like(t)
    return PointParameters(
        dk_left=jnp.where(valid, jnp.abs(k - k_l), zero),
        dk_right=jnp.where(valid, jnp.abs(k - k_r), zero),
        d_left=jnp.where(valid, d_l, zero),
        d_right=jnp.where(valid, d_r, zero),
        range_left=jnp.where(valid, length(half[:c], t), zero),
        range_right=jnp.where(valid, length(t, half[c:]), zero),
        left=jnp.where(valid, left, -1),
        right=jnp.where(valid, right, -1),
        kind=points.kind,
        valid=valid,
    )


# --- operators as constraint sets (thesis §7.2, §7.4, §7.5) ----------------------------------------
class OperatorResult(eqx.Module):
    """Result of a shape operator.

    **Fields:** `curve` (the edited curve); `before`, `after` — the symbol strings of the input
    and of the curve actually produced (`symbols`, never the intended name); `status` — the
    `sculpt.min_norm` status (0 every constraint met, 1 over-constrained / least squares);
    `dof_needed` — the scalar equations of the constraint set, i.e. the degrees of freedom it
    needs (a planar curve has 2 per free control point; thesis §7.5: the softness example needs
    14, infeasible on 5 control points, fine on 9).
    """

    curve: BSplineCurve
    before: str = eqx.field(static=True)
    after: str = eqx.field(static=True)
    status: int = eqx.field(static=True)
    dof_needed: int = eqx.field(static=True)


def _amount(amount) -> float:
    return float(_checks.positive(np.asarray(amount, dtype=np.float64), "amount"))


def _reading(curve, closed):
    """The simplified characteristic points as host lists (t, kind symbol, κ) and `closed`."""
    curve = _planar(curve)
    closed = _closed(curve, closed)
    pts = simplify(characteristic_points(curve, closed))
    n = int(pts.count)
    t = np.asarray(pts.params)[:n].tolist()
    return curve, closed, t, pts.symbols()


def _neighbour_extrema(t, kinds, index, closed):
    """Parameters of the nearest extrema before and after characteristic point `index` (open
    curves: the end parameter when there is none)."""
    n = len(t)
    before, after = [], []
    for step, out in ((-1, before), (1, after)):
        k = index + step
        while (0 <= k < n or closed) and len(out) < 1 and abs(k - index) < n:
            if kinds[k % n] != "0":
                out.append(t[k % n])
            k += step
    return (before or [0.0])[0], (after or [1.0])[0]


def _at(curve, closed, index, want):
    shape_t = _reading(curve, closed)
    curve, closed, t, kinds = shape_t
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise TypeError(f"index: expected an int, got {type(index).__name__}")
    if not 0 <= index < len(t):
        _checks.fail("index", f"a characteristic point index in 0..{len(t) - 1} of {''.join(kinds)!r}", index)
    if want is not None and kinds[index] not in want:
        _checks.fail("index", f"a point of kind {' or '.join(want)}", f"{kinds[index]} at {index}")
    return curve, closed, t, kinds


def _run(curve, closed, constraints, before_kinds) -> OperatorResult:
    edit = sculpt.min_norm(curve, constraints)
    before = "".join(before_kinds)
    if closed:
        before = symbols(curve, closed)
    dof = sum(int(np.size(np.asarray(c.u))) for c in constraints) * curve.dim
    return OperatorResult(
        curve=edit.shape,
        before=before,
        after=symbols(edit.shape, closed),
        status=int(edit.status),
        dof_needed=dof,
    )


def _ends(closed):
    return [] if closed else [sculpt.Fixed(0.0), sculpt.Fixed(1.0)]


def _tangents(curve, ts):
    values = curve.evaluate(jnp.asarray(ts), 1)
    return [sculpt.Derivative(u, values[i]) for i, u in enumerate(ts)]


def _normal_push(curve, closed, index, amount, sign, want, keep_tangents=False) -> OperatorResult:
    curve, closed, t, kinds = _at(curve, closed, index, want)
    left, right = _neighbour_extrema(t, kinds, index, closed)
    constraints = [
        sculpt.AlongNormal(t[index], sign * _amount(amount)),
        sculpt.Fixed(left),
        sculpt.Fixed(right),
    ]
    if keep_tangents:
        constraints += _tangents(curve, [left, right])
    return _run(curve, closed, constraints + _ends(closed), kinds)


@declared
def continuation(
    curve: BSplineCurve, index: int, amount: float, closed: bool | None = None
) -> OperatorResult:
    """Leyton's continuation at characteristic point `index` (thesis eq. 7-2, §7.2): `Cm+`
    (m+ → 0m-0) at an m+, `CM-` (M- → 0M+0) at an M-.

    Constraint set (§7.2): `ΔP(u1) = ±amount · n(u1)` along the left unit normal (inwards for a
    counter-clockwise curve: κ at u1 decreases for Cm+, increases for CM-), the neighbouring
    extrema blocked `ΔP(u_L) = ΔP(u_R) = 0` (open curves: their ends too), solved by
    `sculpt.min_norm`. `amount` ≥ 0 is the drag length; the symbol change needs it past a
    threshold, and too large an amount self-intersects (thesis §7.2) — read `after`.
    """
    curve, closed, _t, kinds = _at(curve, closed, index, ("m+", "M-"))
    sign = 1.0 if kinds[index] == "m+" else -1.0
    return _normal_push(curve, closed, index, amount, sign, None)


@declared
def bifurcation(curve: BSplineCurve, index: int, amount: float, closed: bool | None = None) -> OperatorResult:
    """Leyton's bifurcation at characteristic point `index` (thesis eq. 7-2, §7.2): `BM+`
    (M+ → M+m+M+), `BM-` (M- → M-m-M-) lower κ at the point (`ΔP(u1) = +amount · n`),
    `Bm+` (m+ → m+M+m+), `Bm-` (m- → m-M-m-) raise it (`−amount · n`); the neighbouring
    extrema blocked (the thesis's fixed `ΔP(u_O2) = ΔP(u_O3) = 0`)."""
    curve, closed, _t, kinds = _at(curve, closed, index, None)
    if kinds[index] == "0":
        _checks.fail("index", "a curvature extremum (M+, m+, M-, m-)", f"an inflection at {index}")
    sign = 1.0 if kinds[index][0] == "M" else -1.0
    return _normal_push(curve, closed, index, amount, sign, None)


@declared
def sharpen(curve: BSplineCurve, index: int, amount: float, closed: bool | None = None) -> OperatorResult:
    """Sharpness C*M+ (thesis §7.4): raise κ at extremum `index` by dragging it outwards,
    `ΔP(u) = −amount · n(u)`, with positions and tangents of the neighbouring extrema fixed (and
    the ends of an open curve): no new characteristic points. The §7.5 example — 2 end
    positions, positions and tangents of the two neighbours, the drag — is 14 scalar equations."""
    return _normal_push(curve, closed, index, amount, -1.0, ("M+", "m+", "M-", "m-"), keep_tangents=True)


@declared
def soften(curve: BSplineCurve, index: int, amount: float, closed: bool | None = None) -> OperatorResult:
    """Softness (thesis §7.4): lower κ at extremum `index`, `ΔP(u) = +amount · n(u)`, with the
    same fixed positions and tangents as `sharpen`."""
    return _normal_push(curve, closed, index, amount, 1.0, ("M+", "m+", "M-", "m-"), keep_tangents=True)


@declared
def straighten(
    curve: BSplineCurve, index: int, amount: float = 1.0, closed: bool | None = None
) -> OperatorResult:
    """Straightness (thesis §7.4): pull characteristic point `index` towards the chord of its
    neighbouring extrema by the fraction `amount` ∈ [0, 1] (1: onto the chord), the neighbours
    blocked — the inverse continuation that removes a small-visibility codon "0m-0"."""
    curve, closed, t, kinds = _at(curve, closed, index, None)
    fraction = float(_checks.in_range(np.asarray(amount, dtype=np.float64), "amount", 0.0, 1.0))
    left, right = _neighbour_extrema(t, kinds, index, closed)
    p, a, b = np.asarray(curve.evaluate(jnp.asarray([t[index], left, right])))
    chord = b - a
    foot = a + chord * (np.dot(p - a, chord) / max(float(np.dot(chord, chord)), 1e-300))
    constraints = [
        sculpt.Displacement(t[index], fraction * (foot - p)),
        sculpt.Fixed(left),
        sculpt.Fixed(right),
    ]
    return _run(curve, closed, constraints + _ends(closed), kinds)


@declared
def convexify(curve: BSplineCurve, amount: float) -> OperatorResult:
    """Convexity (thesis §7.4) of an open curve: move its lowest-κ extremum by `amount` across
    the end chord, `ΔP(u_m) = amount · ν` with ν the chord's right unit normal (the side a
    left-turning, convex curve bulges to), the ends blocked, each inflection displaced along ν
    by `amount · (1 − D / D_end)` (D its arc distance to u_m, D_end that of the end on its side;
    the thesis's `λ_L = D_L` weights, normalised)."""
    curve, _, t, kinds = _reading(curve, False)
    step = _amount(amount)
    values = np.asarray(curve.curvature(jnp.asarray(t))) if t else np.zeros(0)
    extrema = [i for i, k in enumerate(kinds) if k != "0"]
    if not extrema:
        _checks.fail("curve", "an open curve with a curvature extremum", f"symbols {''.join(kinds)!r}")
    middle = min(extrema, key=lambda i: values[i])
    a, b = np.asarray(curve.evaluate(jnp.asarray([0.0, 1.0])))
    length = float(np.linalg.norm(b - a))
    if not length > 0:
        _checks.fail(
            "curve", "an open curve whose ends differ (ν is the end chord's normal)", "coincident ends"
        )
    chord = (b - a) / length
    nu = np.array([chord[1], -chord[0]])
    s = np.asarray(_arc_table(curve, jnp.asarray([0.0, t[middle], 1.0] + t)))
    constraints = [sculpt.Displacement(t[middle], step * nu)]
    for i, k in enumerate(kinds):
        if k == "0":
            end = s[0] if t[i] < t[middle] else s[2]
            weight = 1 - abs(s[3 + i] - s[1]) / max(abs(end - s[1]), 1e-300)
            constraints.append(sculpt.Displacement(t[i], step * weight * nu))
    return _run(curve, False, constraints + _ends(False), kinds)


@compiled
def _arc_table(curve: BSplineCurve, t):
    return _arc_length(curve, 256).at(curve, t)


@declared
def tension(
    curve: BSplineCurve, index: int, amount: float = 1.0, closed: bool | None = None
) -> OperatorResult:
    """Tension (thesis §7.4): C*m+ (or C*M-) driving κ at extremum `index` towards 0 —
    to `(1 − amount) · κ` (`amount` ∈ [0, 1]; 1: a flat point) — by a normal drag with the
    neighbouring extrema blocked; the drag length is found by Newton's method on κ (linear
    edit, nonlinear κ: 12 steps)."""
    curve, closed, t, kinds = _at(curve, closed, index, ("m+", "M-", "M+", "m-"))
    fraction = float(_checks.in_range(np.asarray(amount, dtype=np.float64), "amount", 0.0, 1.0))
    left, right = _neighbour_extrema(t, kinds, index, closed)
    unit = [sculpt.AlongNormal(t[index], 1.0), sculpt.Fixed(left), sculpt.Fixed(right)] + _ends(closed)
    shift = sculpt.min_norm(curve, unit).displacement
    goal = (1 - fraction) * float(curve.curvature(t[index]))
    step = float(_newton_drag(curve, shift, jnp.asarray(t[index]), jnp.asarray(goal)))
    constraints = [sculpt.AlongNormal(t[index], step)] + unit[1:]
    return _run(curve, closed, constraints, kinds)


@compiled
def _newton_drag(curve: BSplineCurve, shift, u, goal):
    def kappa(step):
        moved = eqx.tree_at(lambda c: c.ctrl, curve, curve.ctrl + step * shift)
        return _kappa(moved, u[None])[0] - goal

    def newton(_, step):
        value, slope = jax.jvp(kappa, (step,), (jnp.ones_like(step),))
        return step - _safe.ratio(value, slope)

    return jax.lax.fori_loop(0, 12, newton, jnp.zeros_like(goal))


@declared
def accelerate(curve: BSplineCurve, amount: float) -> OperatorResult:
    """Acceleration (thesis §7.4, Fig. 7-21) of an open curve: the end tangent at u = 1 grows by
    the factor `1 + amount` (`∂P/∂u(1) = β`), the tangent at u = 0 is frozen
    (`Δ∂P/∂u(0) = 0`), both end points blocked: curvature moves towards the start."""
    curve, _, _t, kinds = _reading(curve, False)
    step = _amount(amount)
    d0, d1 = np.asarray(curve.evaluate(jnp.asarray([0.0, 1.0]), 1))
    constraints = [sculpt.Derivative(0.0, d0), sculpt.Derivative(1.0, (1 + step) * d1)]
    return _run(curve, False, constraints + _ends(False), kinds)
