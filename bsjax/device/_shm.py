"""Shared-memory blocks with a seqlock: how the servo process and the physics process talk.

A `SeqBlock` is one fixed-size record of float64 values in `multiprocessing.shared_memory`,
preceded by a sequence counter. One writer, any number of readers; the writer never waits and a
reader never blocks it (Lamport's sequence lock, as the Linux kernel's `seqlock_t`):

* write: `seq += 1` (odd: a write is in progress) → copy the record → `seq += 1` (even again);
* read: `s1 = seq`; if odd, retry; copy the record; `s2 = seq`; if `s1 != s2` the copy may be
  torn: retry. After `tries` failed attempts the reader gives up and returns None (the servo
  then keeps its previous proxy and the watchdog ages it): a reader never spins on a writer.

The counter and the record are written by single aligned 8-byte stores and copied with
`memcpy`; x86-64's total store order keeps the three steps ordered as seen by the reader. The
record's version is `seq // 2` (the number of completed writes).

The record layouts of a `Proxy`, a `DeviceSample` and the servo's telemetry are below.
"""

from __future__ import annotations

import math
from multiprocessing import shared_memory

import numpy as np

from bsjax.device._protocol import DeviceSample
from bsjax.device._proxy import NONE, PLANE, SPHERE, Proxy

_KINDS = (NONE, PLANE, SPHERE)
PROXY_SIZE = 13
SAMPLE_SIZE = 12
# telemetry record: the servo's counters, its last output and the stop/alive flags' companions
TELEMETRY = (
    "ticks",
    "t_start",
    "t_now",
    "missed",
    "max_late",
    "device_errors",
    "bad_samples",
    "watchdog_trips",
    "watchdog_ticks",
    "clamped",
    "rate_limited",
    "nonfinite",
    "force_sum",
    "force_max",
    "realtime",
    "dropped_frames",
    "fx",
    "fy",
    "fz",
    "x",
    "y",
    "z",
    "gain",
    "cpu",
)
TELEMETRY_SIZE = len(TELEMETRY)


class SeqBlock:
    """One seqlocked record of `size` float64 values in shared memory.

    **Arguments:** `size` (values per record); `name`: attach to an existing block (another
    process's), or None to create one (the creator `unlink()`s it when done).
    """

    def __init__(self, size: int, name: str | None = None):
        self.size = int(size)
        nbytes = 8 * (self.size + 1)
        self.owner = name is None
        self.shm = shared_memory.SharedMemory(name=name, create=self.owner, size=nbytes)
        buf = self.shm.buf
        assert buf is not None
        self._seq = np.ndarray((1,), np.uint64, buf, 0)
        self._data = np.ndarray((self.size,), np.float64, buf, 8)
        if self.owner:
            self._seq[0] = 0
            self._data[:] = 0.0

    @property
    def name(self) -> str:
        return self.shm.name

    @property
    def version(self) -> int:
        return int(self._seq[0]) // 2

    def write(self, values) -> None:
        """Publish `values` (`(size,)`): never waits."""
        seq = self._seq
        seq[0] += 1  # odd: readers retry
        self._data[:] = values
        seq[0] += 1

    def read(self, tries: int = 8) -> tuple[int, np.ndarray] | None:
        """`(version, copy of the record)`, or None when no consistent copy was had in `tries`."""
        seq, data = self._seq, self._data
        for _ in range(tries):
            s1 = int(seq[0])
            if s1 & 1:
                continue
            out = data.copy()
            if int(seq[0]) == s1:
                return s1 // 2, out
        return None

    def close(self) -> None:
        del self._seq, self._data
        _release(self.shm, self.owner)


class RingBlock:
    """A shared `(n,)` int64 array (the servo's period and work rings: written by one process,
    read for percentiles by the other; a reader may see a slot of the newest tick half a tick
    old, never a torn 8-byte value)."""

    def __init__(self, n: int, name: str | None = None):
        self.owner = name is None
        self.shm = shared_memory.SharedMemory(name=name, create=self.owner, size=8 * int(n))
        buf = self.shm.buf
        assert buf is not None
        self.array = np.ndarray((int(n),), np.int64, buf, 0)
        if self.owner:
            self.array[:] = 0

    @property
    def name(self) -> str:
        return self.shm.name

    def close(self) -> None:
        del self.array
        _release(self.shm, self.owner)


def _release(shm: shared_memory.SharedMemory, owner: bool) -> None:
    """Close a block; its creator also unlinks it (already gone is fine)."""
    shm.close()
    if owner:
        try:
            shm.unlink()
        except FileNotFoundError:
            pass


def encode_proxy(p: Proxy) -> list[float]:
    """A `Proxy` as `PROXY_SIZE` floats (kind index, point, normal, radius, inside, tool radius,
    stiffness, damping, stamp)."""
    return [
        float(_KINDS.index(p.kind)),
        *p.point,
        *p.normal,
        p.radius,
        1.0 if p.inside else 0.0,
        p.tool_radius,
        p.stiffness,
        p.damping,
        p.stamp,
    ]


def decode_proxy(v) -> Proxy:
    """The `Proxy` of a record written by `encode_proxy` (its checks run again: a corrupt record
    raises `ValueError`, which the servo treats as no new proxy)."""
    v = [float(x) for x in v]
    kind = int(v[0])
    if not (0 <= kind < len(_KINDS)) or kind != v[0]:
        raise ValueError(f"proxy record: bad kind {v[0]}")
    normal = (v[4], v[5], v[6])
    proxy = Proxy(_KINDS[kind], (v[1], v[2], v[3]), normal, v[7], v[8] != 0.0, v[9], v[10], v[11], v[12])
    if proxy.kind == PLANE and proxy.normal != normal and abs(math.hypot(*normal) - 1.0) < 1e-12:
        object.__setattr__(proxy, "normal", normal)  # unit already: keep it bit for bit
    return proxy


def encode_sample(s: DeviceSample) -> list[float]:
    """A `DeviceSample` as `SAMPLE_SIZE` floats (position, orientation, buttons, timestamp,
    sequence, received); integers up to 2**53 are exact."""
    p, q = s.position, s.orientation
    return [
        float(p[0]),
        float(p[1]),
        float(p[2]),
        float(q[0]),
        float(q[1]),
        float(q[2]),
        float(q[3]),
        float(s.buttons),
        float(s.timestamp),
        float(s.sequence),
        float(s.received),
        1.0,
    ]


def decode_sample(v) -> DeviceSample | None:
    """The sample of an `encode_sample` record (None for the empty record: no sample yet)."""
    if v[11] != 1.0:
        return None
    seq = v[9]
    return DeviceSample(
        position=np.array(v[0:3]),
        orientation=np.array(v[3:7]),
        buttons=int(v[7]),
        timestamp=float(v[8]),
        sequence=int(seq) if math.isfinite(seq) else 0,
        received=float(v[10]),
    )
