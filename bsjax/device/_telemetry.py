"""Servo-loop telemetry: the `ServoStats` snapshot, a text report, and a plot of a recorded session."""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, dataclass, field

import numpy as np

from bsjax._declared import declared
from bsjax._optional import require

log = logging.getLogger("bsjax.device")

DROPPED_COUNTERS = ("crc_errors", "truncated", "malformed", "out_of_order", "unexpected_kind", "bad_pose")


@dataclass(frozen=True)
class ServoStats:
    """What the servo loop did. Times in milliseconds unless named otherwise.

    `period_*`: time between the starts of consecutive ticks; `jitter_*`: `|period − 1/rate_hz|`;
    `missed_deadlines`: ticks that started more than one whole period late (a slot was lost);
    `max_late_ms`: the latest any tick started after its scheduled time; `work_*`: time spent
    inside a tick (read, render, write). Percentiles cover the last `window` ticks, counts the
    whole session. Safety counters: `nonfinite` (NaN forces written as zero), `clamped`
    (forces saturated at `max_force`, overflowing ones included), `bad_samples` (device samples
    with a non-finite position, not rendered), `watchdog_trips` / `watchdog_ticks`.
    """

    ticks: int = 0
    elapsed_s: float = 0.0
    rate_hz: float = 0.0
    target_hz: float = 0.0
    period_p50: float = 0.0
    period_p99: float = 0.0
    period_max: float = 0.0
    jitter_p50: float = 0.0
    jitter_p99: float = 0.0
    jitter_max: float = 0.0
    missed_deadlines: int = 0
    max_late_ms: float = 0.0
    work_p50: float = 0.0
    work_p99: float = 0.0
    work_max: float = 0.0
    window: int = 0
    physics_updates: int = 0
    physics_rate_hz: float = 0.0
    physics_p50: float = 0.0
    physics_p99: float = 0.0
    physics_errors: int = 0
    device_errors: int = 0
    bad_samples: int = 0
    dropped_frames: int = 0
    watchdog_trips: int = 0
    watchdog_ticks: int = 0
    clamped: int = 0
    rate_limited: int = 0
    nonfinite: int = 0
    force_mean: float = 0.0
    force_max: float = 0.0
    realtime: bool = False
    device_counters: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)

    def report(self) -> str:
        """A few human-readable lines (what `bsjax haptics` prints and logs at the end)."""
        s = self
        return "\n".join(
            [
                f"servo    {s.ticks} ticks in {s.elapsed_s:.2f} s = {s.rate_hz:.1f} Hz (target "
                f"{s.target_hz:.0f}), "
                f"{'SCHED_FIFO' if s.realtime else 'normal priority'}",
                f"period   p50 {s.period_p50:.3f}  p99 {s.period_p99:.3f}  max {s.period_max:.3f} ms",
                f"jitter   p50 {s.jitter_p50:.3f}  p99 {s.jitter_p99:.3f}  max {s.jitter_max:.3f} ms; "
                f"missed deadlines {s.missed_deadlines}, latest start {s.max_late_ms:.3f} ms late",
                f"work     p50 {s.work_p50 * 1e3:.1f}  p99 {s.work_p99 * 1e3:.1f}  max "
                f"{s.work_max * 1e3:.1f} µs per tick",
                f"physics  {s.physics_updates} updates = {s.physics_rate_hz:.1f} Hz, step p50 "
                f"{s.physics_p50:.2f} "
                f"p99 {s.physics_p99:.2f} ms, errors {s.physics_errors}",
                f"safety   watchdog trips {s.watchdog_trips} ({s.watchdog_ticks} ticks attenuated), "
                f"clamped {s.clamped}, "
                f"rate-limited {s.rate_limited}, non-finite {s.nonfinite}",
                f"force    mean {s.force_mean:.3f} N, max {s.force_max:.3f} N",
                f"device   dropped frames {s.dropped_frames}, errors {s.device_errors}, bad samples "
                f"{s.bad_samples}, counters "
                f"{s.device_counters}",
            ]
        )


def percentiles(values_ns: np.ndarray) -> tuple[float, float, float]:
    """p50, p99 and max of a nanosecond array, in milliseconds (zeros when empty)."""
    if values_ns.size == 0:
        return 0.0, 0.0, 0.0
    p50, p99 = np.percentile(values_ns, [50, 99])
    return float(p50) * 1e-6, float(p99) * 1e-6, float(values_ns.max()) * 1e-6


@declared
def plot_recording(recording, path: str | os.PathLike, title: str = "haptic session") -> None:
    """Write a PNG: stylus position, force written, and tick period over a recorded session
    (the `plot` extra)."""
    Figure = require("matplotlib.figure", "plot", "bsjax.device.plot_recording").Figure

    t = recording.time - (recording.time[0] if len(recording) else 0.0)
    fig = Figure(figsize=(9, 7), tight_layout=True)
    ax = fig.subplots(3, 1, sharex=True)
    for k, name in enumerate("xyz"):
        ax[0].plot(t, recording.position[:, k], label=name)
    pressed = recording.buttons & 1
    if pressed.any():
        ax[0].fill_between(
            t,
            0,
            1,
            where=pressed > 0,
            transform=ax[0].get_xaxis_transform(),
            alpha=0.15,
            color="k",
            label="button",
        )
    ax[0].set_ylabel("position (model units)")
    ax[0].legend(loc="upper right", fontsize=8)
    for k, name in enumerate("xyz"):
        ax[1].plot(t, recording.force[:, k], lw=0.8, label=f"F{name}")
    ax[1].plot(t, np.linalg.norm(recording.force, axis=1), "k", lw=1.0, label="|F|")
    ax[1].set_ylabel("force (N)")
    ax[1].legend(loc="upper right", fontsize=8)
    if len(t) > 1:
        ax[2].plot(t[1:], np.diff(t) * 1e3, lw=0.5)
    ax[2].set_ylabel("tick period (ms)")
    ax[2].set_xlabel("time (s)")
    ax[0].set_title(title)
    fig.savefig(os.fspath(path), dpi=100)
