"""`ServoLoop`: the two-rate haptic loop — a ≥ 1 kHz servo thread and a slower physics thread.

Servo thread (every `1/rate_hz` s, paper 002 §4.2: haptics needs 1 kHz):
read the device → estimate velocity → render the current `Proxy` (pure Python, never a jitted
call) → clamp `|F| ≤ max_force` → rate-limit `|ΔF| ≤ max_force_rate / rate_hz` per tick →
multiply by the watchdog gain → write. The watchdog gain ramps linearly to 0 within `ramp_time`
when the proxy is older than `proxy_timeout` or the newest device sample is older than
`device_timeout`, and back to 1 when both are fresh again (it also ramps up at start). Zero force
is written when the loop stops, when either thread raises, and at interpreter exit.

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
import gc
import math
import os
import sys
import threading
import time

import numpy as np

from bsjax.device._shaping import ForceShaper, VelocityFilter, Watchdog
from bsjax.device.protocol import DeviceError, DeviceSample
from bsjax.device.proxy import Proxy
from bsjax.device.record import Recorder, Recording
from bsjax.device.telemetry import DROPPED_COUNTERS, ServoStats, log, percentiles

_WINDOW = 1 << 17  # ticks kept for percentiles (about two minutes at 1 kHz)
_SERVO_PRIORITY, _PHYSICS_PRIORITY = 10, 5  # SCHED_FIFO priorities (1..99), where permitted


class ServoLoop:
    """Run a haptic device against a model at `rate_hz`.

    **Arguments:**
    - `device`: a `HapticDevice` (`SimulatedDevice`, `SerialDevice`, `HidDevice`).
    - `model`: a physics model with `update(sample) -> Proxy` (and optionally `warmup()`), e.g.
      `bsjax.device.physics.SculptModel`; or a fixed `Proxy` (no physics thread, never stale).
    - `rate_hz`: servo rate (1000). `physics_hz`: physics rate (100).
    - `max_force`: newtons, the hard bound on `|F|` written. `max_force_rate`: N/s (default
      `100 · max_force`: full scale in 10 ms).
    - `proxy_timeout`, `device_timeout`: seconds before the watchdog ramps the force to zero;
      `ramp_time`: seconds of that ramp.
    - `velocity_tau`: seconds, time constant of the velocity low-pass (damping term).
    - `record`: False, True (keep a `Recording`, see `recording()`) or a path (saved on stop).
    - `realtime`: try `SCHED_FIFO` for the servo thread; `cpu`: pin it to this CPU (None: don't).
    - `spin_us`: busy-wait margin before each deadline; `switch_interval`: GIL switch interval
      while running (None: leave the interpreter's); `freeze_gc`: `gc.freeze()` the objects alive
      at start so that a garbage collection cannot stall a tick (undone on stop).
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
    ):
        positive = dict(
            rate_hz=rate_hz,
            max_force=max_force,
            physics_hz=physics_hz,
            proxy_timeout=proxy_timeout,
            device_timeout=device_timeout,
            ramp_time=ramp_time,
        )
        for name, value in positive.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        max_force_rate = 100.0 * max_force if max_force_rate is None else max_force_rate
        if not (math.isfinite(max_force_rate) and max_force_rate > 0):
            raise ValueError(f"max_force_rate: expected a finite number > 0, got {max_force_rate!r}")
        if not (isinstance(model, Proxy) or callable(getattr(model, "update", None))):
            raise TypeError(
                "model: expected a Proxy or an object with update(sample) -> Proxy, got "
                f"{type(model).__name__}"
            )
        self.device, self.model = device, model
        self.rate_hz, self.physics_hz = float(rate_hz), float(physics_hz)
        self.max_force, self.max_force_rate = float(max_force), float(max_force_rate)
        self.proxy_timeout, self.device_timeout, self.ramp_time = proxy_timeout, device_timeout, ramp_time
        self.velocity_tau = velocity_tau
        self.realtime, self.cpu, self.spin_ns = realtime, cpu, int(spin_us * 1e3)
        self.switch_interval = switch_interval
        self.freeze_gc = freeze_gc
        self._record_path = record if isinstance(record, (str, os.PathLike)) else None
        self._recorder = Recorder(int(rate_hz) * 16) if record else None
        self._static = isinstance(model, Proxy)
        self._proxy: Proxy = model if self._static else Proxy(stamp=-math.inf)
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
        self._device_errors = self._physics_errors = 0
        self._shaper = ForceShaper(self.max_force, math.inf)
        self._watchdog = Watchdog(self.ramp_time)
        self._force_sum = self._force_max = 0.0
        self._t_start = self._t_end = 0
        self._realtime_ok = False

    def start(self) -> "ServoLoop":
        """Warm up the model (compile its jitted functions), then start both threads."""
        if self._running:
            raise RuntimeError("ServoLoop.start: already running")
        if not self._static and callable(getattr(self.model, "warmup", None)):
            self.model.warmup()
        self._reset_counters()
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
        for thread in (self._servo, self._physics):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self._zero()
        atexit.unregister(self.stop)
        if self.freeze_gc:
            gc.unfreeze()
        if self._saved_switch is not None:
            sys.setswitchinterval(self._saved_switch)
            self._saved_switch = None
        if self._record_path is not None and self._recorder is not None:
            self.recording().save(self._record_path)
        stats = self.stats
        if self._ticks:
            log.info("haptic session finished\n%s", stats.report())
        error, self.error = self.error, None
        if error is not None and not isinstance(error, EOFError):
            raise DeviceError(f"servo loop failed: {error!r}") from error
        return stats

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
        return self._recorder.recording()

    def _zero(self) -> None:
        try:
            self.device.write((0.0, 0.0, 0.0))
        except Exception as err:
            log.error("could not write zero force: %r", err)

    # --- servo thread ---------------------------------------------------------------------------
    def _configure_thread(self) -> None:
        if self.cpu is not None and hasattr(os, "sched_setaffinity"):
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError as err:
                log.warning("servo: cannot pin to CPU %s: %s", self.cpu, err)
        if self.realtime and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(_SERVO_PRIORITY))
                self._realtime_ok = True
            except (OSError, PermissionError):
                self._realtime_ok = False

    def _servo_main(self) -> None:
        self._configure_thread()
        try:
            self._servo_loop()
        except BaseException as err:
            self.error = err
        finally:
            self._zero()
            self._running = False
            self._t_end = time.perf_counter_ns()
            self.finished.set()

    def _servo_loop(self) -> None:
        period = int(round(1e9 / self.rate_hz))
        self._shaper = ForceShaper(self.max_force, self.max_force_rate * period * 1e-9)
        self._watchdog = Watchdog(self.ramp_time)
        velocity = VelocityFilter(self.velocity_tau)
        prev: DeviceSample | None = None
        self._t_start = deadline = last_start = time.perf_counter_ns()
        while self._running:
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
            out = self._render(sample, velocity(sample, prev), (start - last_start) * 1e-9)
            self._write(out, sample, start)
            prev, last_start = sample, start
            self._ticks += 1
            deadline += period
            self._work[i] = time.perf_counter_ns() - start
            _wait_until(deadline, self.spin_ns)

    def _render(self, sample, velocity, elapsed: float) -> tuple[float, float, float]:
        """Proxy force (pure Python, never JAX) → clamp → rate limit → watchdog gain."""
        proxy = self._proxy  # one read of the reference the physics thread swaps
        if sample is None:
            force = (0.0, 0.0, 0.0)
        else:
            self._sample = sample
            force = proxy.force(sample.position, velocity)
        fx, fy, fz = self._shaper(*force)
        now = time.perf_counter()
        fresh = sample is not None and now - sample.received <= self.device_timeout
        fresh = fresh and (self._static or now - proxy.stamp <= self.proxy_timeout)
        gain = self._watchdog(fresh, elapsed)
        return fx * gain, fy * gain, fz * gain

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
        while self._running:
            sample = self._sample
            if sample is None:
                time.sleep(0.001)
                next_t = time.perf_counter()
                continue
            t0 = time.perf_counter_ns()
            try:
                proxy = self.model.update(sample)
                if not isinstance(proxy, Proxy):
                    raise TypeError(f"model.update: expected a Proxy, got {type(proxy).__name__}")
            except Exception as err:
                self._physics_errors += 1
                log.error("physics update failed, force ramps to zero: %r", err)
                self.physics_error = err
                return
            self._proxy = proxy  # one reference swap: the servo sees the old or the new proxy
            self._physics_ns[self._physics_updates % len(self._physics_ns)] = time.perf_counter_ns() - t0
            self._physics_updates += 1
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
        n = self._ticks
        end = self._t_end if (self._t_end and not self._running) else time.perf_counter_ns()
        elapsed = max(end - self._t_start, 1) * 1e-9 if self._t_start else 0.0
        count = min(max(n - 1, 0), _WINDOW)
        periods = self._periods[1:n] if n <= _WINDOW else self._periods.copy()
        periods = periods[:count]
        nominal = 1e9 / self.rate_hz
        jitter = np.abs(periods - nominal)
        work = self._work[: min(n, _WINDOW)]
        phys = self._physics_ns[: min(self._physics_updates, len(self._physics_ns))]
        p50, p99, pmax = percentiles(periods)
        j50, j99, jmax = percentiles(jitter)
        w50, w99, wmax = percentiles(work)
        f50, f99, _ = percentiles(phys)
        counters = dict(getattr(self.device, "counters", {}) or {})
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
            missed_deadlines=int(self._missed),
            max_late_ms=self._max_late * 1e-6,
            work_p50=w50,
            work_p99=w99,
            work_max=wmax,
            window=count,
            physics_updates=self._physics_updates,
            physics_rate_hz=self._physics_updates / elapsed if elapsed else 0.0,
            physics_p50=f50,
            physics_p99=f99,
            physics_errors=self._physics_errors,
            device_errors=self._device_errors,
            dropped_frames=sum(int(counters.get(k, 0)) for k in DROPPED_COUNTERS),
            watchdog_trips=self._watchdog.trips,
            watchdog_ticks=self._watchdog.attenuated,
            clamped=self._shaper.clamped,
            rate_limited=self._shaper.limited,
            nonfinite=self._shaper.nonfinite,
            force_mean=self._force_sum / n if n else 0.0,
            force_max=self._force_max,
            realtime=self._realtime_ok,
            device_counters=counters,
        )


def _wait_until(deadline_ns: int, spin_ns: int) -> None:
    """Sleep until `spin_ns` before `deadline_ns`, then spin on `perf_counter_ns`."""
    remaining = deadline_ns - time.perf_counter_ns()
    if remaining > spin_ns:
        time.sleep((remaining - spin_ns) * 1e-9)
    while time.perf_counter_ns() < deadline_ns:
        pass
