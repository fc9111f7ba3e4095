"""`ServoLoop`: the two-rate haptic loop — a ≥ 1 kHz servo thread and a slower physics thread.

Servo thread (every `1/rate_hz` s, Gao & Gibson §4.2: haptics needs 1 kHz):
read the device → estimate velocity → render the current `Proxy` (pure Python, never a jitted
call) → clamp `|F| ≤ max_force` → rate-limit `|ΔF| ≤ max_force_rate / rate_hz` per tick →
multiply by the watchdog gain → write. The watchdog gain ramps linearly to 0 within `ramp_time`
when the proxy arrived more than `proxy_timeout` ago or the newest device sample more than
`device_timeout` ago, and back to 1 when both are fresh again (it also ramps up at start). Zero
force is written when the loop stops, when either thread raises, and at interpreter exit.

Safety chain (Gao & Gibson §4.2's servo contract):

* **The watchdog uses only the servo's own monotonic clock** (`perf_counter_ns`). The servo stamps
  the *arrival* of each new proxy (a new version swapped in by the physics thread) and of each new
  device sample (a new `sequence` or device `timestamp`) itself; it never reads `Proxy.stamp` or
  `DeviceSample.received`, so a producer stamping on another clock (`time.time()`), in the future
  or with `inf` cannot keep the force on. An arrival that is not finite or lies in the future is
  stale. Once the physics thread dies or hangs, or the device stops answering, the force is zero
  within `timeout + ramp_time` plus one tick (defaults 50 + 20 ms; measured 69–72 ms).
* **Force shaping** (`_shaping.ForceShaper`): `|F| ≤ max_force` always; a force whose magnitude
  overflows (a very stiff wall) saturates at `max_force` along its direction; a NaN force is zero
  and counted (`stats.nonfinite`).
* **Poses**: a device sample with a non-finite position, or one the model's optional
  `accepts(sample)` refuses (`SculptModel`: out of its reach), is not rendered and not handed to
  the physics (counted in `stats.bad_samples`; the transports already drop non-finite and
  out-of-reach poses, this guards any other device — a wild pose would also poison the velocity
  estimate); the last good sample ages and the watchdog acts.
* **A dead servo is visible**: every argument is validated at construction; everything the servo
  thread does runs inside its `try`; if it dies, zero force is written, `running` is False,
  `error` holds the exception and `stop()` raises `DeviceError` naming it.

Process mode (`mode="process"`, the default): the servo runs in its own interpreter (a
`multiprocessing` "spawn" child, `_process`), pinned to the last allowed CPU (or `cpu`) and
`SCHED_FIFO` where permitted, while this process's threads — XLA's included — are kept off that
CPU. Proxy, device sample and telemetry cross through seqlocked shared memory (`_shm`): the
servo never waits on the physics and never renders a torn proxy (a torn or corrupt record keeps
the previous proxy, which ages). The device is reached from both processes: the servo process
gets a pickled copy of `device` (or makes one, when `device` is a factory: a class or a
`functools.partial`) and writes zero on every exit path (stop flag, SIGINT/SIGTERM, its parent
gone, an exception); this process keeps its own `device` object and writes zero through it as
soon as the servo process ends, killed or not (a factory is called once more for that, after
the servo process has released the device). The physics dying or being killed stops the
proxy arriving, so the servo's watchdog ramps the force to zero as in thread mode. Where
the servo ran is in `placement` (`mode`, `pid`, `cpu`, `realtime`). Thread mode (`mode="thread"`)
runs the servo as a thread of this process instead: for devices that cannot be sent to another
process (an open HID handle, a script given as a lambda) and for tests that inspect the device
object the servo writes to.

Physics thread (every `1/physics_hz` s): hands the newest sample to `model.update(sample)` (JAX:
collision, mass-spring, refit) and swaps in the `Proxy` it returns with one reference assignment.

Timing: ticks are scheduled on absolute `perf_counter_ns` deadlines; the wait sleeps until
`spin_us` before the deadline and spins the rest (Linux sleeps overshoot by 50–100 µs). The
servo thread asks for `SCHED_FIFO` where permitted (`realtime=True`) and can be pinned to a CPU;
the physics thread asks for a lower `SCHED_FIFO` priority, so that it is never descheduled by
other processes while it holds the GIL (the XLA work itself runs in XLA's own normal-priority
threads with the GIL released).
While the loop runs, the interpreter's GIL switch interval is lowered to `switch_interval`
(default 0.1 ms, restored on stop) so that Python work in the physics thread cannot hold the
servo off for the default 5 ms; and `gc.freeze()` keeps the cyclic garbage collector from
scanning the whole (JAX-sized) heap inside a servo tick. Both are process-wide and restored on stop.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import gc
import math
import numbers
import os
import pickle
import sys
import threading
import time
import types

import numpy as np

from bsjax.device import _process
from bsjax.device._protocol import DeviceError, DeviceSample, positive_number
from bsjax.device._proxy import Proxy
from bsjax.device._record import Recorder, Recording
from bsjax.device._shaping import ForceShaper, VelocityFilter, Watchdog, fresh
from bsjax.device._telemetry import DROPPED_COUNTERS, ServoStats, log, percentiles

_WINDOW = 1 << 17  # ticks kept for percentiles (about two minutes at 1 kHz)
_MAX_RATE_HZ = 1e5  # a period of 10 µs: beyond that the tick's own work cannot keep up
_SERVO_PRIORITY, _PHYSICS_PRIORITY = 10, 5  # SCHED_FIFO priorities (1..99), where permitted


class ServoLoop:
    """Run a haptic device against a model at `rate_hz`.

    **Arguments:**
    - `device`: a `HapticDevice` (`SimulatedDevice`, `SerialDevice`, `HidDevice`).
    - `model`: a physics model with `update(sample) -> Proxy` (and optionally `warmup()`, and
      `accepts(sample) -> bool`, asked in the servo thread for every new sample: keep it to a
      few microseconds), e.g. `bsjax.device._physics.SculptModel`; or a fixed `Proxy` (no
      physics thread, never stale).
    - `rate_hz`: servo rate (1000). `physics_hz`: physics rate (100).
    - `max_force`: newtons, the hard bound on `|F|` written. `max_force_rate`: N/s (default
      `100 · max_force`: full scale in 10 ms).
    - `proxy_timeout`, `device_timeout`: seconds since the last arrival of a new proxy / device
      sample (timed on the servo's clock) before the watchdog ramps the force to zero;
      `ramp_time`: seconds of that ramp. The force is zero at most `timeout + ramp_time` plus one
      tick after the last arrival.
    - `velocity_tau`: seconds, time constant of the velocity low-pass (damping term).
    - `record`: False, True (keep a `Recording`, see `recording()`) or a path (saved on stop).
    - `realtime`: try `SCHED_FIFO` for the servo thread; `cpu`: pin it to this CPU (an int the
      process may run on, or None: don't pin).
    - `spin_us`: busy-wait margin (≥ 0 µs) before each deadline; `switch_interval`: GIL switch
      interval while running (None: leave the interpreter's); `freeze_gc`: `gc.freeze()` the
      objects alive at start so that a garbage collection cannot stall a tick (undone on stop).
    - `mode`: `"process"` (default: the servo in its own process, see the module docstring;
      `device` must pickle or be a factory — a class or a `functools.partial` — else a
      `TypeError` at `start()` names it) or `"thread"` (a thread of this process). The servo
      process applies the workspace gate of a model with `reach` and a centre (`SculptModel`);
      any other `accepts` runs in the physics thread only: a refused pose is never fed to the
      physics, but the servo may render it against the last proxy (bounded by the clamp).

    Every number must be a finite real (Python or numpy scalar, not bool) and > 0 (`spin_us`
    ≥ 0, `rate_hz` ≤ 100 kHz); a bad argument raises `TypeError`/`ValueError` naming it.
    """

    def __init__(
        self,
        device,
        model,
        rate_hz: float = 1000.0,
        max_force: float = 3.0,
        max_force_rate: float | None = None,
        physics_hz: float = 100.0,
        proxy_timeout: float = 0.05,
        device_timeout: float = 0.05,
        ramp_time: float = 0.02,
        velocity_tau: float = 0.005,
        record: bool | str | os.PathLike = False,
        realtime: bool = True,
        cpu: int | None = None,
        spin_us: float = 150.0,
        switch_interval: float | None = 1e-4,
        freeze_gc: bool = True,
        mode: str = "process",
    ):
        positive = dict(
            rate_hz=rate_hz,
            max_force=max_force,
            physics_hz=physics_hz,
            proxy_timeout=proxy_timeout,
            device_timeout=device_timeout,
            ramp_time=ramp_time,
            velocity_tau=velocity_tau,
        )
        v = {name: positive_number(value, name) for name, value in positive.items()}
        if v["rate_hz"] > _MAX_RATE_HZ:
            raise ValueError(f"rate_hz: expected a rate <= {_MAX_RATE_HZ:.0f} Hz, got {rate_hz!r}")
        max_force_rate = 100.0 * v["max_force"] if max_force_rate is None else max_force_rate
        max_force_rate = positive_number(max_force_rate, "max_force_rate")
        spin_us = positive_number(spin_us, "spin_us", allow_zero=True)
        if switch_interval is not None:
            switch_interval = positive_number(switch_interval, "switch_interval")
        for name, flag in (("realtime", realtime), ("freeze_gc", freeze_gc)):
            if not isinstance(flag, (bool, np.bool_)):
                raise TypeError(f"{name}: expected a bool, got {type(flag).__name__} {flag!r}")
        if not isinstance(record, (bool, np.bool_, str, os.PathLike)):
            raise TypeError(f"record: expected a bool or a file path, got {type(record).__name__}")
        cpu = _check_cpu(cpu)
        if mode not in ("thread", "process"):
            raise ValueError(f"mode: expected 'thread' or 'process', got {mode!r}")
        factory = mode == "process" and _process.is_factory(device)
        for method in ("read", "write") if not factory else ():
            if not callable(getattr(device, method, None)):
                raise TypeError(
                    f"device: expected a HapticDevice with read() and write(force), got "
                    f"{type(device).__name__}"
                )
        if not (isinstance(model, Proxy) or callable(getattr(model, "update", None))):
            raise TypeError(
                "model: expected a Proxy or an object with update(sample) -> Proxy, got "
                f"{type(model).__name__}"
            )
        self.device, self.model = device, model
        self.rate_hz, self.physics_hz = v["rate_hz"], v["physics_hz"]
        self.max_force, self.max_force_rate = v["max_force"], max_force_rate
        self.proxy_timeout, self.device_timeout = v["proxy_timeout"], v["device_timeout"]
        self.ramp_time, self.velocity_tau = v["ramp_time"], v["velocity_tau"]
        self.realtime, self.cpu, self.spin_ns = bool(realtime), cpu, int(spin_us * 1e3)
        self.switch_interval = switch_interval
        self.freeze_gc = bool(freeze_gc)
        self.mode = mode
        # where the servo actually ran: {"mode", "pid", "cpu" (None: not pinned), "realtime"}
        self.placement: dict = {"mode": mode, "pid": None, "cpu": None, "realtime": False}
        self._link: _process.ChildLink | None = None  # set in the servo process (process mode)
        self._parent: _process.ParentLink | None = None  # the physics process's end of it
        self._proc = None
        self._final: tuple[ServoStats, Recording | None] | None = None
        self._stopping = False
        self._collect_lock = threading.Lock()
        self._pinned: int | None = None
        self._saved_affinity: dict[int, set[int]] = {}
        self._record_path = record if isinstance(record, (str, os.PathLike)) else None
        self._recorder = Recorder(int(self.rate_hz) * 16) if record else None
        self._static = isinstance(model, Proxy)
        # (version, proxy), swapped as one reference by the physics thread; the servo stamps the
        # arrival of each new version on its own clock (version 0: nothing arrived yet)
        self._proxy_slot: tuple[int, Proxy] = (0, model if self._static else Proxy())
        self._sample: DeviceSample | None = None
        self._running = False
        self._servo: threading.Thread | None = None
        self._physics: threading.Thread | None = None
        self._saved_switch: float | None = None
        self.error: BaseException | None = None
        self.physics_error: BaseException | None = None
        self.finished = threading.Event()  # set when the servo thread has ended (stop, EOF or error)
        self._reset_counters()

    # --- lifecycle ------------------------------------------------------------------------------
    def _reset_counters(self) -> None:
        self._periods = np.zeros(_WINDOW, np.int64)
        self._work = np.zeros(_WINDOW, np.int64)
        self._physics_ns = np.zeros(4096, np.int64)
        self._ticks = self._physics_updates = 0
        self._missed = self._max_late = 0
        self._device_errors = self._physics_errors = self._bad_samples = 0
        self._shaper = ForceShaper(self.max_force, math.inf)
        self._watchdog = Watchdog(self.ramp_time)
        self._force_sum = self._force_max = 0.0
        self._t_start = self._t_end = 0
        self._realtime_ok = False
        self._last_out = (0.0, 0.0, 0.0)

    def start(self) -> "ServoLoop":
        """Warm up the model (compile its jitted functions), then start both threads."""
        if self._running:
            raise RuntimeError("ServoLoop.start: already running")
        if not self._static and callable(getattr(self.model, "warmup", None)):
            self.model.warmup()
        self._reset_counters()
        if not self._static:  # a proxy or sample of an earlier run must not count as fresh
            self._proxy_slot, self._sample = (0, Proxy()), None
        if self._recorder is not None:
            self._recorder = Recorder(int(self.rate_hz) * 16)  # one recording per start()
        self.error = self.physics_error = None
        self.finished.clear()
        if self.switch_interval is not None:
            self._saved_switch = sys.getswitchinterval()
            sys.setswitchinterval(min(self._saved_switch, self.switch_interval))
        if self.freeze_gc:
            # Move every object alive now out of the collector's reach: a full collection of a
            # process holding JAX would otherwise scan them all, in whichever thread allocates
            # (measured: an 84 ms servo tick). Only objects made while the loop runs are scanned.
            gc.collect()
            gc.freeze()
        self._running = True
        if self.mode == "process":
            try:
                self._start_process()
            except BaseException:
                self._undo_process_settings()
                raise
        else:
            self._servo = threading.Thread(target=self._servo_main, name="bsjax-servo", daemon=True)
            self._servo.start()
        if not self._static:
            self._physics = threading.Thread(target=self._physics_main, name="bsjax-physics", daemon=True)
            self._physics.start()
        atexit.register(self.stop)
        return self

    def stop(self) -> ServoStats:
        """Stop both threads, write zero force, restore the switch interval; return the stats.

        Raises `DeviceError` (chained to the cause) if the servo thread died of an exception. A
        failed physics update stops only the physics thread (the watchdog ramps the force to
        zero); it is counted in `stats.physics_errors` and kept in `physics_error`.
        """
        self._running = False
        if self.mode == "process":
            self._stop_process()
        for thread in (self._servo, self._physics):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._zero()
        if self._parent is not None:
            self._parent.close()
            self._parent = None
        self._restore_affinity()
        atexit.unregister(self.stop)
        self._undo_process_settings()
        if self._record_path is not None and self._recorder is not None:
            self.recording().save(self._record_path)
        stats = self.stats
        if self._ticks:
            log.info("haptic session finished\n%s", stats.report())
        error, self.error = self.error, None
        if error is not None and not isinstance(error, EOFError):
            raise DeviceError(f"servo loop failed: {error!r}") from error
        return stats

    def _undo_process_settings(self) -> None:
        """Undo `start`'s interpreter-wide settings (garbage collector, switch interval)."""
        if self.freeze_gc:
            gc.unfreeze()
        if self._saved_switch is not None:
            sys.setswitchinterval(self._saved_switch)
            self._saved_switch = None

    def __enter__(self) -> "ServoLoop":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def started_at(self) -> float:
        """`time.perf_counter()` of the first tick (recording times are relative to it)."""
        return self._t_start * 1e-9

    @property
    def running(self) -> bool:
        return self._running and not self.finished.is_set()

    def recording(self) -> Recording:
        if self._recorder is None:
            raise ValueError("record: the loop was created with record=False")
        if self.mode == "process":
            if self._final is None or self._final[1] is None:
                raise ValueError("recording: the servo process has not reported one (still running?)")
            return self._final[1]
        return self._recorder.recording()

    def snapshot(self) -> dict:
        """The servo's newest output, cheap enough for a 50 Hz viewer: `position` (3,) of the
        tool (NaN before the first sample), `force` (3,) written, watchdog `gain`, `ticks`,
        `rate_hz` and `physics_updates`. Never waits on the servo (read from the shared memory in
        process mode, from the servo thread's last values in thread mode)."""
        if self._parent is not None:
            c = self._parent.counters()
            pos, force, gain, ticks = (
                (c["x"], c["y"], c["z"]),
                (c["fx"], c["fy"], c["fz"]),
                c["gain"],
                c["ticks"],
            )
            t0, now = c["t_start"], c["t_now"]
        else:
            sample, out = self._sample, self._last_out
            pos = tuple(sample.position) if sample is not None else (math.nan,) * 3
            force, gain, ticks = out, self._watchdog.gain, self._ticks
            t0, now = self._t_start, time.perf_counter_ns()
        elapsed = (now - t0) * 1e-9 if t0 else 0.0
        return {
            "position": [float(v) for v in pos],
            "force": [float(v) for v in force],
            "gain": float(gain),
            "ticks": int(ticks),
            "rate_hz": float(ticks / elapsed) if elapsed > 0 else 0.0,
            "physics_updates": int(self._physics_updates),
        }

    def _zero(self) -> None:
        """Write zero force from this process (in process mode: after the servo process ended,
        through the parent's own device object, or one made by the device factory)."""
        try:
            if _process.is_factory(self.device):
                if self.mode == "process" and self._proc is not None and self._proc.is_alive():
                    return  # the servo process holds the device and zeroes it itself
                device = self.device()
                try:
                    device.write((0.0, 0.0, 0.0))
                finally:
                    getattr(device, "close", lambda: None)()
            else:
                self.device.write((0.0, 0.0, 0.0))
        except Exception as err:
            log.error("could not write zero force: %r", err)

    # --- servo thread ---------------------------------------------------------------------------
    def _configure_thread(self) -> None:
        if self.cpu is not None and hasattr(os, "sched_setaffinity"):
            try:
                os.sched_setaffinity(0, {self.cpu})
                self._pinned = self.cpu
            except OSError as err:
                log.warning("servo: cannot pin to CPU %s: %s", self.cpu, err)
        if self.realtime and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(_SERVO_PRIORITY))
                self._realtime_ok = True
            except (OSError, PermissionError):
                self._realtime_ok = False

    def _servo_main(self) -> None:
        try:  # everything, thread configuration included: a failure here must be visible
            self._configure_thread()
            self._servo_loop()
        except BaseException as err:
            self.error = err
        finally:
            try:
                self._zero()
            except BaseException as err:  # even then the death must be visible
                self.error = self.error or err
            self._running = False
            self._t_end = time.perf_counter_ns()
            self.finished.set()

    def _run_in_this_thread(self) -> None:
        """Run the servo loop in the calling thread until stopped (the servo process's main)."""
        self._running = True
        self.finished.clear()
        if self.freeze_gc:
            gc.collect()
            gc.freeze()
        self._servo_main()

    def _servo_loop(self) -> None:
        period = int(round(1e9 / self.rate_hz))
        self._shaper = ForceShaper(self.max_force, self.max_force_rate * period * 1e-9)
        self._watchdog = Watchdog(self.ramp_time)
        velocity = VelocityFilter(self.velocity_tau)
        clock = _Arrivals(self.proxy_timeout, self.device_timeout, self._static)
        accepts = getattr(self.model, "accepts", None) if not self._static else None
        accepts = accepts if callable(accepts) else _always
        prev: DeviceSample | None = None
        link = self._link
        self._t_start = deadline = last_start = time.perf_counter_ns()
        while self._running:
            if link is not None and not link.alive(self._ticks):
                break
            start = time.perf_counter_ns()
            late = start - deadline
            self._max_late = max(self._max_late, late)
            if late >= period:  # whole slots lost: count them and resynchronise on this tick
                self._missed += late // period
                deadline = start
            i = self._ticks % _WINDOW
            if self._ticks:
                self._periods[i] = start - last_start
            try:
                sample = self.device.read()
            except EOFError as err:
                self.error = err
                break
            except Exception:
                self._device_errors += 1
                sample = prev
            if sample is not prev and sample is not None and not (_good(sample) and accepts(sample)):
                self._bad_samples += 1
                sample = prev  # never rendered, never handed to the physics; prev ages
            slot = self._proxy_slot if link is None else link.proxy_slot()
            proxy = clock.see(start, slot, sample)
            out = self._render(proxy, sample, velocity(sample, prev), clock.fresh(start), start - last_start)
            self._write(out, sample, start)
            if link is not None:
                link.publish_sample(sample)
                if self._ticks % _process.TELEMETRY_EVERY == 0:
                    link.publish(self, out, sample, start, self._watchdog.gain)
            prev, last_start = sample, start
            self._ticks += 1
            deadline += period
            self._work[i] = time.perf_counter_ns() - start
            _wait_until(deadline, self.spin_ns)

    def _render(self, proxy, sample, velocity, fresh: bool, elapsed_ns: int) -> tuple[float, float, float]:
        """Proxy force (pure Python, never JAX) → clamp → rate limit → watchdog gain."""
        if sample is None:
            force = (0.0, 0.0, 0.0)
        else:
            self._sample = sample  # what the physics thread reads next
            force = proxy.force(sample.position, velocity)
        fx, fy, fz = self._shaper(*force)
        gain = self._watchdog(fresh, elapsed_ns * 1e-9)
        self._last_out = out = (fx * gain, fy * gain, fz * gain)
        return out

    def _write(self, out, sample, start: int) -> None:
        try:
            self.device.write(out)
        except Exception:
            self._device_errors += 1
        f = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
        self._force_sum += f
        self._force_max = max(self._force_max, f)
        if self._recorder is not None and sample is not None:
            self._recorder.append((start - self._t_start) * 1e-9, sample, out)

    # --- physics thread -------------------------------------------------------------------------
    def _physics_main(self) -> None:
        # Real-time priority below the servo's: a normal-priority thread preempted by other
        # processes while it holds the GIL would hold the servo thread off for a whole time slice
        # (priority inversion through the GIL, measured at up to 12 ms on a loaded 2-core box).
        if self.realtime and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(_PHYSICS_PRIORITY))
            except (OSError, PermissionError):
                pass
        period = 1.0 / self.physics_hz
        next_t = time.perf_counter()
        parent = self._parent
        gate = getattr(self.model, "accepts", None)
        gate = gate if callable(gate) else _always
        while self._running:
            sample = self._sample if parent is None else parent.latest_sample()
            if sample is not None and parent is not None and not gate(sample):
                sample = None  # refused by the model: never fed to the physics (process mode)
            if sample is None:
                time.sleep(0.001)
                next_t = time.perf_counter()
                continue
            t0 = time.perf_counter_ns()
            try:
                proxy = self.model.update(sample)
                if not isinstance(proxy, Proxy):
                    raise TypeError(f"model.update: expected a Proxy, got {type(proxy).__name__}")
            except BaseException as err:  # any failure: the thread ends, the watchdog zeroes the force
                self._physics_errors += 1
                log.error("physics update failed, force ramps to zero: %r", err)
                self.physics_error = err
                return
            self._physics_updates += 1
            # one reference swap: the servo sees the old or the new (version, proxy) pair
            self._proxy_slot = (self._physics_updates, proxy)
            if parent is not None:
                parent.publish_proxy(proxy)
            self._physics_ns[(self._physics_updates - 1) % len(self._physics_ns)] = (
                time.perf_counter_ns() - t0
            )
            next_t += period
            pause = next_t - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
            elif pause < -period:  # more than a tick behind: drop the backlog, don't burst
                next_t = time.perf_counter()

    # --- telemetry ------------------------------------------------------------------------------
    @property
    def stats(self) -> ServoStats:
        """A snapshot of the telemetry (safe to call while running)."""
        if self.mode == "process":
            return self._process_stats()
        end = self._t_end if (self._t_end and not self._running) else time.perf_counter_ns()
        counters = dict(getattr(self.device, "counters", {}) or {})
        c = dict(
            ticks=self._ticks,
            t_start=self._t_start,
            t_now=end,
            missed=self._missed,
            max_late=self._max_late,
            device_errors=self._device_errors,
            bad_samples=self._bad_samples,
            watchdog_trips=self._watchdog.trips,
            watchdog_ticks=self._watchdog.attenuated,
            clamped=self._shaper.clamped,
            rate_limited=self._shaper.limited,
            nonfinite=self._shaper.nonfinite,
            force_sum=self._force_sum,
            force_max=self._force_max,
            realtime=self._realtime_ok,
            dropped_frames=sum(int(counters.get(k, 0)) for k in DROPPED_COUNTERS),
        )
        return self._stats_from(c, self._periods, self._work, counters)

    def _stats_from(self, c: dict, periods_ring, work_ring, counters: dict) -> ServoStats:
        n = int(c["ticks"])
        t0 = int(c["t_start"])
        elapsed = max(int(c["t_now"]) - t0, 1) * 1e-9 if t0 else 0.0
        count = min(max(n - 1, 0), _WINDOW)
        periods = np.array(periods_ring[1:n] if n <= _WINDOW else periods_ring)[:count]
        jitter = np.abs(periods - 1e9 / self.rate_hz)
        work = np.array(work_ring[: min(n, _WINDOW)])
        phys = self._physics_ns[: min(self._physics_updates, len(self._physics_ns))]
        p50, p99, pmax = percentiles(periods)
        j50, j99, jmax = percentiles(jitter)
        w50, w99, wmax = percentiles(work)
        f50, f99, _ = percentiles(phys)
        return ServoStats(
            ticks=n,
            elapsed_s=elapsed,
            rate_hz=(n - 1) / elapsed if n > 1 and elapsed else 0.0,
            target_hz=self.rate_hz,
            period_p50=p50,
            period_p99=p99,
            period_max=pmax,
            jitter_p50=j50,
            jitter_p99=j99,
            jitter_max=jmax,
            missed_deadlines=int(c["missed"]),
            max_late_ms=c["max_late"] * 1e-6,
            work_p50=w50,
            work_p99=w99,
            work_max=wmax,
            window=count,
            physics_updates=self._physics_updates,
            physics_rate_hz=self._physics_updates / elapsed if elapsed else 0.0,
            physics_p50=f50,
            physics_p99=f99,
            physics_errors=self._physics_errors,
            device_errors=int(c["device_errors"]),
            bad_samples=int(c["bad_samples"]),
            dropped_frames=int(c["dropped_frames"]),
            watchdog_trips=int(c["watchdog_trips"]),
            watchdog_ticks=int(c["watchdog_ticks"]),
            clamped=int(c["clamped"]),
            rate_limited=int(c["rate_limited"]),
            nonfinite=int(c["nonfinite"]),
            force_mean=c["force_sum"] / n if n else 0.0,
            force_max=float(c["force_max"]),
            realtime=bool(c["realtime"]),
            device_counters=counters,
        )

    # --- process mode ---------------------------------------------------------------------------
    def _process_stats(self) -> ServoStats:
        if self._final is not None:  # the servo process's own final stats, with our physics
            s = self._final[0]
            phys = self._physics_ns[: min(self._physics_updates, len(self._physics_ns))]
            f50, f99, _ = percentiles(phys)
            return dataclasses.replace(
                s,
                physics_updates=self._physics_updates,
                physics_rate_hz=self._physics_updates / s.elapsed_s if s.elapsed_s else 0.0,
                physics_p50=f50,
                physics_p99=f99,
                physics_errors=self._physics_errors,
            )
        if self._parent is None:
            return ServoStats(target_hz=self.rate_hz)
        c = self._parent.counters()
        return self._stats_from(c, self._parent.periods.array, self._parent.work.array, {})

    def _start_process(self) -> None:
        """Spawn the servo process (see `_process`) and wait until it ticks."""
        import multiprocessing

        cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        cpu = self.cpu if self.cpu is not None else (cpus[-1] if len(cpus) > 1 else None)
        self._parent = parent = _process.ParentLink(_WINDOW)
        gate = None
        if not self._static and hasattr(self.model, "reach") and hasattr(self.model, "_centre"):
            gate = _process.ReachGate(self.model._centre, self.model.reach)
        options = dict(
            rate_hz=self.rate_hz,
            max_force=self.max_force,
            max_force_rate=self.max_force_rate,
            physics_hz=self.physics_hz,
            proxy_timeout=self.proxy_timeout,
            device_timeout=self.device_timeout,
            ramp_time=self.ramp_time,
            velocity_tau=self.velocity_tau,
            record=self._recorder is not None,
            realtime=self.realtime,
            cpu=cpu,
            spin_us=self.spin_ns * 1e-3,
            switch_interval=None,
            freeze_gc=self.freeze_gc,
        )
        config = dict(
            loop=type(self),
            device=self.device,
            static=self.model if self._static else None,
            gate=gate,
            options=options,
            names=parent.names,
        )
        ctx = multiprocessing.get_context("spawn")
        self._conn, child_conn = ctx.Pipe(duplex=False)
        self._proc = proc = ctx.Process(
            target=_process.servo_process, args=(config, child_conn), name="bsjax-servo", daemon=True
        )
        self._final, self._stopping = None, False
        needs_main = _needs_main(config)
        try:
            with contextlib.nullcontext() if needs_main else _main_hidden():
                proc.start()
        except Exception as err:  # e.g. a device that cannot be pickled
            self._running = False
            parent.close()
            self._parent = None
            raise TypeError(
                f"device: process mode sends the device to the servo process; {type(self.device).__name__} "
                f"could not be sent ({err}); pass a picklable device or a factory (its class or a "
                "functools.partial), or mode='thread'"
            ) from err
        child_conn.close()
        deadline = time.monotonic() + 60.0
        while parent.counters()["ticks"] < 1:
            if not proc.is_alive() or time.monotonic() > deadline:
                self._collect(timeout=1.0)
                if proc.is_alive():
                    proc.kill()
                self._running = False
                self.finished.set()
                parent.close()
                self._parent = None
                error, self.error = self.error, None
                hint = (
                    "; what it was sent is defined in your __main__, which multiprocessing runs again "
                    'there: start the loop under `if __name__ == "__main__":` (or pass mode="thread")'
                    if needs_main
                    else ""
                )
                raise DeviceError(f"servo process failed to start: {error!r}{hint}") from error
            time.sleep(0.005)
        c = parent.counters()
        self._t_start = int(c["t_start"])
        self.placement = {
            "mode": "process",
            "pid": proc.pid,
            "cpu": None if c["cpu"] < 0 else int(c["cpu"]),
            "realtime": bool(c["realtime"]),
        }
        self._isolate(cpu, cpus)
        self._servo = threading.Thread(target=self._watch_process, name="bsjax-servo-watch", daemon=True)
        self._servo.start()

    def _isolate(self, cpu: int | None, cpus: list[int]) -> None:
        """Keep this process's threads (XLA's included) off the servo's CPU, where allowed."""
        others = set(cpus) - {cpu}
        if cpu is None or not others or not os.path.isdir("/proc/self/task"):
            return
        for tid in map(int, os.listdir("/proc/self/task")):
            try:
                self._saved_affinity[tid] = os.sched_getaffinity(tid)
                os.sched_setaffinity(tid, others)
            except OSError:
                pass

    def _restore_affinity(self) -> None:
        for tid, cpus in self._saved_affinity.items():
            try:
                os.sched_setaffinity(tid, cpus)
            except OSError:
                pass
        self._saved_affinity = {}

    def _watch_process(self) -> None:
        """Parent side: when the servo process ends (stopped, finished or killed) write zero force
        from here too, and make an unexpected death visible (`error`, `running` False)."""
        from multiprocessing.connection import wait

        proc = self._proc
        assert proc is not None
        if self.realtime and hasattr(os, "sched_setscheduler"):
            try:  # it sleeps until the servo process ends, then must write zero at once
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(_SERVO_PRIORITY))
            except (OSError, PermissionError):
                pass
        conn = self._conn
        if proc.sentinel not in wait([proc.sentinel, conn]):
            self._collect(timeout=0.0)  # the report comes before the exit: read it (or the child
        wait([proc.sentinel])  # blocks on a full pipe)
        unexpected = not self._stopping
        self._zero()  # first: a killed servo process wrote nothing on its way out
        self._collect(timeout=0.5)
        proc.join(1.0)  # reap it: its exit code
        if unexpected and self.error is None and proc.exitcode != 0:
            self.error = DeviceError(f"servo process died (exit code {proc.exitcode})")
        self._running = False
        self.finished.set()

    def _collect(self, timeout: float) -> None:
        """Receive the servo process's final report (stats, recording, error), if it sent one."""
        conn = getattr(self, "_conn", None)
        with self._collect_lock:
            if conn is None or self._final is not None:
                return
            self._receive(conn, timeout)

    def _receive(self, conn, timeout: float) -> None:
        try:
            if conn.poll(timeout):
                result = conn.recv()
                stats = result.get("stats")
                if stats is not None:
                    self._final = (stats, result.get("recording"))
                error = result.get("error")
                if error is not None:
                    self.error = error if isinstance(error, BaseException) else RuntimeError(str(error))
                    if self._final is not None:
                        self._t_end = self._t_start + int(self._final[0].elapsed_s * 1e9)
        except (EOFError, OSError):
            pass

    def _stop_process(self) -> None:
        self._stopping = True
        proc, parent = self._proc, self._parent
        if parent is not None:
            parent.request_stop()
        self._collect(timeout=3.0)  # before join: the report may not fit the pipe's buffer
        if proc is not None:
            proc.join(timeout=3.0)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=2.0)
        if self._servo is not None:
            self._servo.join(timeout=2.0)
        self._collect(timeout=0.5)
        if self._final is not None:
            self._ticks = self._final[0].ticks


class _Arrivals:
    """Arrival times of the newest proxy and device sample, on the servo's own clock.

    A proxy arrives when the physics thread swaps in a new version; a device sample arrives when
    its `(sequence, timestamp)` differs from the last one seen. Producers' own stamps are never
    read. `fresh(now)` holds while both arrivals are within their limits (`_shaping.fresh`).
    """

    __slots__ = ("device_at", "device_key", "device_limit", "proxy_at", "proxy_limit", "static", "version")

    def __init__(self, proxy_timeout: float, device_timeout: float, static: bool):
        self.proxy_limit, self.device_limit = int(proxy_timeout * 1e9), int(device_timeout * 1e9)
        self.static, self.version = static, 0
        self.proxy_at = self.device_at = -math.inf
        self.device_key: tuple | None = None

    def see(self, now: int, slot: tuple[int, Proxy], sample) -> Proxy:
        version, proxy = slot
        if version != self.version:
            self.version, self.proxy_at = version, now
        if sample is not None:
            t = sample.timestamp
            key = (sample.sequence, t if t == t else None)  # NaN ≠ NaN would look new every tick
            if key != self.device_key:
                self.device_key, self.device_at = key, now
        return proxy

    def fresh(self, now: int) -> bool:
        return fresh(now, self.device_at, self.device_limit) and (
            self.static or fresh(now, self.proxy_at, self.proxy_limit)
        )


def _always(sample) -> bool:
    return True


def _good(sample) -> bool:
    """A sample the servo may render: a finite `(3,)` position, a hashable sequence number and a
    timestamp (the arrival key), a velocity the filter can difference."""
    try:
        p = sample.position
        x, y, z = float(p[0]), float(p[1]), float(p[2])
        hash((sample.sequence, sample.timestamp))
    except Exception:
        return False
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(z)


def _check_cpu(cpu) -> int | None:
    """`cpu` as an int the process may run on, or None; `TypeError`/`ValueError` naming it."""
    if cpu is None:
        return None
    if isinstance(cpu, (bool, np.bool_)) or not isinstance(cpu, numbers.Integral):
        raise TypeError(f"cpu: expected an int or None, got {type(cpu).__name__} {cpu!r}")
    allowed = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if cpu < 0 or (allowed is not None and int(cpu) not in allowed):
        raise ValueError(
            f"cpu: expected one of the CPUs this process may use {sorted(allowed or [])}, got {cpu}"
        )
    return int(cpu)


def _wait_until(deadline_ns: int, spin_ns: int) -> None:
    """Sleep until `spin_ns` before `deadline_ns`, then spin on `perf_counter_ns`."""
    remaining = deadline_ns - time.perf_counter_ns()
    if remaining > spin_ns:
        time.sleep((remaining - spin_ns) * 1e-9)
    while time.perf_counter_ns() < deadline_ns:
        pass


def _needs_main(payload) -> bool:
    """Whether something sent to the servo process is defined in the caller's `__main__` (a
    device class written in the user's script): the child then has to run that script again
    to find it (multiprocessing's "spawn"). A payload that cannot be pickled is left to
    `Process.start` to report."""
    try:
        return b"__main__" in pickle.dumps(payload)
    except Exception:
        return True


@contextlib.contextmanager
def _main_hidden():
    """Start a "spawn" child without the caller's `__main__`: multiprocessing runs the parent's
    main script again in the child (to find what the parent defined there), which starts a
    second loop from a plain script with no `if __name__ == "__main__":` guard. The servo
    process needs only bsjax's modules, so for the start its main module is an empty one."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is not None:
            sys.modules["__main__"] = main
