"""The servo process of `ServoLoop(mode="process")`: its entry point and its end of the links.

The parent (physics) process creates the shared-memory blocks (`_shm`), then spawns this process
(`multiprocessing` "spawn": a fresh interpreter, no lock shared with JAX). Here a `ServoLoop` in
thread mode runs its servo loop in the main thread, with a `ChildLink` in place of the physics
thread's shared attributes:

* the proxy is read from its seqlocked block every tick (never waiting: a torn or corrupt
  record keeps the previous proxy, which ages and lets the watchdog act);
* each new device sample is published to the sample block for the physics thread;
* every few ticks the counters and the last output go to the telemetry block;
* the loop ends when the parent sets the stop flag, when the parent process is gone (its pid is
  no longer our parent: killed or crashed) or on SIGINT/SIGTERM — on each of these, and on
  any exception, the servo's `finally` writes zero force to the device.

At the end the final `ServoStats`, the recording and the error (if any) go back through a pipe.
"""

from __future__ import annotations

import functools
import math
import os
import signal

from bsjax.device import _shm
from bsjax.device._proxy import Proxy

TELEMETRY_EVERY = 8  # ticks between telemetry records (125 Hz at 1 kHz)
PARENT_CHECK_EVERY = 20  # ticks between checks that the parent process is alive


def is_factory(device) -> bool:
    """A device given as something that makes one in the servo process (a class or a
    `functools.partial`), rather than a device object."""
    return isinstance(device, (type, functools.partial))


class ReachGate:
    """`accepts(sample)` of a model with a finite workspace (`SculptModel`): a finite position
    within `reach` of `centre`. Picklable, so the servo process applies the same gate as the
    physics (a pose the physics refuses is not rendered either)."""

    def __init__(self, centre, reach: float):
        self.centre, self.reach = tuple(float(c) for c in centre), float(reach)

    def __call__(self, sample) -> bool:
        try:
            x, y, z = map(float, sample.position)
        except (AttributeError, TypeError, ValueError):
            return False
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return False
        cx, cy, cz = self.centre
        return math.hypot(x - cx, y - cy, z - cz) <= self.reach


class ChildLink:
    """The servo process's end of the shared memory (see the module docstring)."""

    def __init__(self, names: dict, static: Proxy | None):
        self.proxy = _shm.SeqBlock(_shm.PROXY_SIZE, names["proxy"])
        self.sample = _shm.SeqBlock(_shm.SAMPLE_SIZE, names["sample"])
        self.telemetry = _shm.SeqBlock(_shm.TELEMETRY_SIZE, names["telemetry"])
        self.control = _shm.RingBlock(2, names["control"])
        self.periods = _shm.RingBlock(names["window"], names["periods"])
        self.work = _shm.RingBlock(names["window"], names["work"])
        self.static = static
        self.slot: tuple[int, Proxy] = (0, static if static is not None else Proxy())
        self.parent = os.getppid()
        self.stop_requested = False
        self._last_sample = None

    def alive(self, ticks: int) -> bool:
        if self.stop_requested or self.control.array[0] != 0:
            return False
        return ticks % PARENT_CHECK_EVERY != 0 or os.getppid() == self.parent

    def proxy_slot(self) -> tuple[int, Proxy]:
        if self.static is not None:
            return self.slot
        got = self.proxy.read()
        if got is not None and got[0] != self.slot[0]:
            try:
                self.slot = (got[0], _shm.decode_proxy(got[1]))
            except (ValueError, TypeError):
                pass  # a corrupt record is no new proxy: the old one ages
        return self.slot

    def publish_sample(self, sample) -> None:
        if sample is not self._last_sample and sample is not None:
            self._last_sample = sample
            self.sample.write(_shm.encode_sample(sample))

    def publish(self, loop, out, sample, now: int, gain: float) -> None:
        pos = sample.position if sample is not None else (math.nan,) * 3
        counters = getattr(loop.device, "counters", {}) or {}
        from bsjax.device._telemetry import DROPPED_COUNTERS

        self.telemetry.write(
            [
                loop._ticks,
                loop._t_start,
                now,
                loop._missed,
                loop._max_late,
                loop._device_errors,
                loop._bad_samples,
                loop._watchdog.trips,
                loop._watchdog.attenuated,
                loop._shaper.clamped,
                loop._shaper.limited,
                loop._shaper.nonfinite,
                loop._force_sum,
                loop._force_max,
                1.0 if loop._realtime_ok else 0.0,
                sum(int(counters.get(k, 0)) for k in DROPPED_COUNTERS),
                out[0],
                out[1],
                out[2],
                float(pos[0]),
                float(pos[1]),
                float(pos[2]),
                gain,
                -1.0 if loop._pinned is None else loop._pinned,
            ]
        )

    def close(self) -> None:
        for block in (self.proxy, self.sample, self.telemetry, self.control, self.periods, self.work):
            block.close()


def servo_process(config: dict, conn) -> None:
    """Entry point of the servo process: run the servo loop until told to stop, then report.

    `config["loop"]` is the `ServoLoop` class (sent by reference: this module does not import
    `servo`, which imports it)."""
    stop = {"now": False}

    def _stop(signum, frame):  # Ctrl-C to the process group, or a terminate: stop, write zero
        stop["now"] = True
        if link is not None:
            link.stop_requested = True

    link: ChildLink | None = None
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    result: dict = {"stats": None, "recording": None, "error": None}
    loop = None
    try:  # everything, set-up included: a failure is reported to the parent, never silent
        link = ChildLink(config["names"], config["static"])
        link.stop_requested = stop["now"]
        ServoLoop = config["loop"]
        device = config["device"]
        device = device() if is_factory(device) else device
        model = config["static"] if config["static"] is not None else _Remote(config["gate"])
        loop = ServoLoop(device, model, mode="thread", **config["options"])
        loop._link = link
        loop._periods, loop._work = link.periods.array, link.work.array
        loop._run_in_this_thread()
        result["stats"] = loop.stats
        if loop._recorder is not None:
            result["recording"] = loop.recording()
        result["error"] = loop.error
    except BaseException as err:  # the parent reports it
        result["error"] = err
    finally:
        try:
            conn.send(result)
        except Exception:
            try:
                conn.send({"stats": result["stats"], "recording": None, "error": repr(result["error"])})
            except Exception:
                pass
        if loop is not None:
            close = getattr(loop.device, "close", None)
            if callable(close):
                try:
                    close()
                except Exception:
                    pass
        if link is not None:
            link.close()


class _Remote:
    """The physics as the servo process sees it: it lives in the parent; `accepts` is the
    model's workspace gate when it has one (`ReachGate`)."""

    def __init__(self, gate):
        self._gate = gate

    def update(self, sample):  # never called in the servo process: there is no physics thread
        raise RuntimeError("the physics runs in the parent process")

    def accepts(self, sample) -> bool:
        return self._gate is None or self._gate(sample)


class ParentLink:
    """The physics process's end: creates (and finally unlinks) the blocks, publishes proxies,
    reads the newest device sample and the servo's telemetry."""

    def __init__(self, window: int):
        self.proxy = _shm.SeqBlock(_shm.PROXY_SIZE)
        self.sample = _shm.SeqBlock(_shm.SAMPLE_SIZE)
        self.telemetry = _shm.SeqBlock(_shm.TELEMETRY_SIZE)
        self.control = _shm.RingBlock(2)
        self.periods = _shm.RingBlock(window)
        self.work = _shm.RingBlock(window)
        self.window = window
        self._sample_version, self._sample = 0, None
        self._telemetry = dict.fromkeys(_shm.TELEMETRY, 0.0)

    @property
    def names(self) -> dict:
        blocks = ("proxy", "sample", "telemetry", "control", "periods", "work")
        return {name: getattr(self, name).name for name in blocks} | {"window": self.window}

    def publish_proxy(self, proxy: Proxy) -> None:
        self.proxy.write(_shm.encode_proxy(proxy))

    def latest_sample(self):
        got = self.sample.read()
        if got is not None and got[0] != self._sample_version:
            self._sample_version, self._sample = got[0], _shm.decode_sample(got[1])
        return self._sample

    def counters(self) -> dict:
        got = self.telemetry.read(tries=64)
        if got is not None:
            self._telemetry = dict(zip(_shm.TELEMETRY, got[1].tolist(), strict=True))
        return self._telemetry

    def request_stop(self) -> None:
        self.control.array[0] = 1

    def close(self) -> None:
        for block in (self.proxy, self.sample, self.telemetry, self.control, self.periods, self.work):
            block.close()
