"""Recording a haptic session to a file and reading it back.

A `Recorder` appends one row per servo tick into pre-allocated numpy arrays (no allocation in
the 1 kHz loop except when the capacity doubles); `Recording.save` writes an `.npz` file that
`Recording.load` reads back, and `SimulatedDevice.replay` plays it in real time or tick by tick.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields

import numpy as np

_COLUMNS = {  # name → (trailing shape, dtype)
    "time": ((), np.float64),  # host seconds since the session started
    "sequence": ((), np.int64),
    "position": ((3,), np.float64),  # model coordinates
    "orientation": ((4,), np.float64),
    "buttons": ((), np.int64),
    "device_time": ((), np.float64),
    "force": ((3,), np.float64),  # what was written to the device (after clamp, rate limit, watchdog)
}


@dataclass(frozen=True)
class Recording:
    """A recorded session: one row per servo tick (see `_COLUMNS` for units)."""

    time: np.ndarray
    sequence: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    buttons: np.ndarray
    device_time: np.ndarray
    force: np.ndarray

    def __len__(self) -> int:
        return len(self.time)

    def save(self, path: str | os.PathLike) -> None:
        with open(path, "wb") as fh:  # a file object keeps numpy from appending ".npz"
            np.savez(
                fh,
                format=np.array("bsjax-haptics-1"),
                **{f.name: getattr(self, f.name) for f in fields(self)},
            )

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Recording":
        try:
            with np.load(path, allow_pickle=False) as data:
                if "format" not in data or str(data["format"]) != "bsjax-haptics-1":
                    raise ValueError("not a bsjax haptics recording (missing format tag)")
                cols = {name: np.asarray(data[name]) for name in _COLUMNS}
        except (OSError, KeyError, ValueError, EOFError) as err:
            raise ValueError(f"{os.fspath(path)}: cannot read haptics recording: {err}") from None
        n = len(cols["time"])
        for name, (tail, _) in _COLUMNS.items():
            if cols[name].shape != (n, *tail):
                raise ValueError(
                    f"{os.fspath(path)}: column {name}: expected shape {(n, *tail)}, got {cols[name].shape}"
                )
        return cls(**cols)


class Recorder:
    """Append-only buffer of servo ticks; `recording()` snapshots it as a `Recording`."""

    def __init__(self, capacity: int = 16384):
        self._cols = {k: np.zeros((max(1, capacity), *tail), dtype) for k, (tail, dtype) in _COLUMNS.items()}
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def append(self, t: float, sample, force) -> None:
        if self._n == len(self._cols["time"]):
            self._cols = {k: np.concatenate([v, np.zeros_like(v)]) for k, v in self._cols.items()}
        i, c = self._n, self._cols
        c["time"][i] = t
        c["sequence"][i] = sample.sequence
        c["position"][i] = sample.position
        c["orientation"][i] = sample.orientation
        c["buttons"][i] = sample.buttons
        c["device_time"][i] = sample.timestamp
        c["force"][i] = force
        self._n = i + 1

    def recording(self) -> Recording:
        return Recording(**{k: v[: self._n].copy() for k, v in self._cols.items()})
