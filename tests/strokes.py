"""Synthetic hand-drawn strokes with a known truth, for `bsjax.sketch.recognise` (tests, benchmark).

A stroke is drawn along an ideal shape of unit size (a unit segment, circles and arcs of radius
½, polygons of unit side or width, a wave for the free spline), then

* **over-tracing**: a closed shape runs on past its start by up to a fifth of its perimeter (or
  stops up to 3 % short of it);
* **speed variation**: the pen slows to a quarter of its cruise speed at polygon corners and at
  both ends, and its cruise speed wanders by ±30 % (a smooth random profile); the samples are taken
  at a fixed rate, so they crowd where the pen is slow;
* **jitter**: the sampling interval varies by ±30 % (the time stamps are the true ones);
* **noise**: a smooth wobble across the path (amplitude `wobble` of the size) plus white noise of
  standard deviation `noise` of the size;
* a similarity transform: a random rotation, a scale between 10⁻² and 10³ and a random position.

`draw(kind, rng)` returns a `Stroke` (points, times and the transformed truth). The truth holds
what the regularised primitive should recover: endpoints, centre and radius, axes and angle,
sweep, corners (in the drawing order of the stroke).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.interpolate import BSpline

from bsjax import sketch

KINDS = sketch.KINDS  # the classes the generator draws: every class recognise knows
CLOSED = ("circle", "ellipse", "triangle", "square", "rectangle", "diamond")


class Stroke(NamedTuple):
    kind: str
    points: np.ndarray  # (N, 2)
    times: np.ndarray  # (N,)
    truth: dict  # in the stroke's coordinates (after the similarity transform)
    scale: float  # the size of the shape (its unit)


# --- ideal shapes (unit size), as dense polylines and the arc-length positions of their corners --
def _polygon(corners: np.ndarray, start: float, closed: bool):
    """The polygon's outline from `start` (a fraction of its perimeter) once around (closed) or
    along (open), with the arc-length positions of its corners."""
    ring = np.concatenate([corners, corners[:1]]) if closed else corners
    edge = np.linalg.norm(np.diff(ring, axis=0), axis=1)
    at = np.concatenate([[0.0], np.cumsum(edge)])
    return ring, at, start * at[-1]


def _circle_points(s, radius, start):
    return radius * np.stack([np.cos(start + s / radius), np.sin(start + s / radius)], 1)


def _shape(kind: str, rng):
    """(path(s) → points for arc length s, total length L, corner positions, closed, truth)."""
    if kind == "line":
        truth = {"endpoints": np.array([[0.0, 0.0], [1.0, 0.0]])}
        return (lambda s: np.stack([s, 0 * s], 1)), 1.0, np.zeros(0), False, truth
    if kind in ("circle", "arc"):
        r, start = 0.5, rng.uniform(0, 2 * np.pi)
        sweep = 2 * np.pi if kind == "circle" else rng.uniform(np.radians(100), np.radians(280))
        sign = rng.choice([-1.0, 1.0])
        truth = {"centre": np.zeros(2), "radius": r, "sweep": sign * sweep}
        return (lambda s: _circle_points(sign * s, r, start)), r * sweep, np.zeros(0), kind == "circle", truth
    if kind == "ellipse":
        a, b = 0.5, 0.5 / rng.uniform(1.5, 3.0)
        dense = np.linspace(0, 2 * np.pi, 2001)
        ring = np.stack([a * np.cos(dense), b * np.sin(dense)], 1)
        start = rng.integers(0, 2000)
        ring = np.concatenate([ring[start:-1], ring[:start], ring[start : start + 1]])
        ring = ring[:: rng.choice([-1, 1])]
        at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))])
        path = lambda s: np.stack([np.interp(s % at[-1], at, ring[:, i]) for i in (0, 1)], 1)
        truth = {"centre": np.zeros(2), "axes": np.array([a, b]), "major": np.array([1.0, 0.0])}
        return path, at[-1], np.zeros(0), True, truth
    if kind == "spline":
        count = rng.integers(5, 8)
        x = np.linspace(0, 1, count)
        y = rng.uniform(0.15, 0.3, count) * np.where(np.arange(count) % 2 == 0, 1, -1) * rng.choice([-1, 1])
        y[0] = y[-1] = 0
        knots = np.concatenate([np.zeros(3), np.linspace(0, 1, count - 2), np.ones(3)])
        dense = BSpline(knots, np.stack([x, y], 1), 3)(np.linspace(0, 1, 2001))
        at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        path = lambda s: np.stack([np.interp(s, at, dense[:, i]) for i in (0, 1)], 1)
        return path, at[-1], np.zeros(0), False, {}
    corners, closed = _corners(kind, rng)
    if closed:
        first = rng.integers(0, len(corners)) if rng.uniform() < 0.5 else 0
        corners = np.roll(corners, -first, axis=0)[:: rng.choice([-1, 1])]
        mid_edge = rng.uniform() < 0.5
    else:
        mid_edge = False
    ring, at, _ = _polygon(corners, 0.0, closed)
    shift = rng.uniform(0.2, 0.8) * at[1] if mid_edge else 0.0  # start part-way along the first edge
    path = lambda s: np.stack(
        [np.interp((s + shift) % at[-1] if closed else s, at, ring[:, i]) for i in (0, 1)], 1
    )
    inner = at[1:-1] if not closed else at[:-1]
    corner_at = (inner - shift) % at[-1] if closed else inner
    order = np.argsort(corner_at) if closed else np.arange(len(corners))
    truth = {"corners": corners[order] if closed else corners}
    return path, at[-1], np.sort(corner_at), closed, truth


def _corners(kind: str, rng):
    if kind == "triangle":
        while True:
            a, b = rng.uniform(np.radians(35), np.radians(110), 2)
            if np.pi - a - b >= np.radians(35):
                break
        c = np.array([1.0, 0.0])
        apex = np.array([np.cos(a), np.sin(a)]) * np.sin(b) / np.sin(a + b)
        return np.array([[0.0, 0.0], c, apex]), True
    if kind in ("square", "rectangle"):
        w = 1.0 if kind == "square" else rng.uniform(1.5, 3.0)
        box = np.array([[0, 0], [w, 0], [w, 1], [0, 1]], float)
        return box + rng.normal(0, 0.015, box.shape), True
    if kind == "diamond":
        angle = rng.uniform(np.radians(45), np.radians(70))
        e1, e2 = np.array([1.0, 0.0]), np.array([np.cos(angle), np.sin(angle)])
        return np.array([0 * e1, e1, e1 + e2, e2]), True
    # polyline: an open zigzag of 2–4 segments, turns of 50°–130° alternating in sign
    count = rng.integers(3, 6)
    heading, point, out = 0.0, np.zeros(2), [np.zeros(2)]
    sign = rng.choice([-1.0, 1.0])
    for _ in range(count - 1):
        point = point + rng.uniform(0.5, 1.0) * np.array([np.cos(heading), np.sin(heading)])
        out.append(point)
        heading += sign * rng.uniform(np.radians(50), np.radians(130))
        sign = -sign
    return np.array(out), False


# --- drawing ------------------------------------------------------------------------------------
def _smooth_random(rng, s, length, amplitude, waves=3):
    out = np.zeros_like(s)
    for _ in range(waves):
        freq = rng.uniform(0.5, 3.0)
        out += rng.normal() * np.sin(2 * np.pi * freq * s / length + rng.uniform(0, 2 * np.pi))
    return amplitude * out / np.sqrt(waves)


def draw(
    kind: str, rng, noise: float = 0.004, wobble: float = 0.008, jitter: float = 0.3, samples=(60, 240)
) -> Stroke:
    """One synthetic stroke of `kind` (see the module's docstring)."""
    path, length, corner_at, closed, truth = _shape(kind, rng)
    over = rng.uniform(-0.03, 0.2) * length if closed else 0.0
    total = length + over
    grid = np.linspace(0, total, 4001)
    speed = 1 + _smooth_random(rng, grid, total, 0.3)
    speed = np.clip(speed, 0.4, 1.6)
    width = 0.03 * total
    again = corner_at + length if closed else np.zeros(0)  # an over-traced corner is slowed for again
    for c in np.concatenate([corner_at, again, [0.0, total]]):
        speed = speed * (1 - 0.75 * np.exp(-(((grid - c) / width) ** 2)))
    elapsed = np.concatenate([[0.0], np.cumsum(np.diff(grid) / (0.5 * (speed[1:] + speed[:-1])))])
    count = rng.integers(*samples)
    steps = np.clip(1 + jitter * rng.uniform(-1, 1, count - 1), 0.1, None)
    times = np.concatenate([[0.0], np.cumsum(steps)])
    times *= elapsed[-1] / times[-1]
    s = np.interp(times, elapsed, grid)
    points = path(s)
    tangent = np.gradient(points, axis=0)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    points = points + _smooth_random(rng, s, total, wobble)[:, None] * normal
    points = points + rng.normal(0, noise, points.shape)
    return _transform(kind, points, times, truth, rng)


def _transform(kind, points, times, truth, rng) -> Stroke:
    angle = rng.uniform(0, 2 * np.pi)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    scale = float(10 ** rng.uniform(-2, 3))
    shift = rng.uniform(-10, 10, 2) * scale
    move = lambda p: scale * p @ rot.T + shift
    out = {}
    for key, value in truth.items():
        if key in ("endpoints", "corners", "centre"):
            out[key] = move(np.asarray(value))
        elif key in ("radius", "axes"):
            out[key] = scale * np.asarray(value)
        elif key == "major":
            out[key] = rot @ value
        else:
            out[key] = value
    return Stroke(kind, move(points), times * scale, out, scale)


def strokes(count: int, seed: int = 0, kinds=KINDS, **options) -> list[Stroke]:
    """`count` strokes of each kind in `kinds` (interleaved), from one seed."""
    rng = np.random.default_rng(seed)
    return [draw(kind, rng, **options) for _ in range(count) for kind in kinds]
