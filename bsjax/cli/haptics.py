"""`bsjax haptics`: sculpt the teardrop with a sphere (or ellipsoid) tool on a haptic device.

```
bsjax haptics --simulated --duration 10          # the default: a scripted push/pull session
bsjax haptics --ellipsoid 0.3,0.2,0.2 --plot session.png
bsjax haptics --serial /dev/ttyACM0 --baud 921600
bsjax haptics --hid 1234:5678 [--hid-layout layout.json]
bsjax haptics --replay session.npz --plot session.png
bsjax haptics --view [--port 8765]              # live 3-D view in the browser (127.0.0.1)
bsjax haptics --servo-thread                    # the 1 kHz servo as a thread (default: its own process)
bsjax haptics --sculpt drag                     # the point under the stylus follows it (bsjax.sculpt)
```
Prints the servo telemetry at the end (also on Ctrl-C; zero force is written first). The
sculpting physics runs in float64 unless `--float32`.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import signal
import sys
import time

from bsjax._optional import require
from bsjax.cli import _common as c
from bsjax.device import (
    DeviceError,
    HidDevice,
    HidLayout,
    Proxy,
    SerialDevice,
    ServoLoop,
    SimulatedDevice,
    Workspace,
    plot_recording,
)

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _hid_ids(text: str) -> tuple[int, int]:
    vid, _, pid = text.partition(":")
    try:
        return int(vid, 16), int(pid, 16)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected VID:PID in hex (e.g. 046d:c62b), got {text!r}") from None


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax haptics")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--simulated", action="store_true", help="scripted virtual stylus (default)")
    src.add_argument("--serial", metavar="PORT", help="serial device speaking the bsjax frame protocol")
    src.add_argument("--hid", type=_hid_ids, metavar="VID:PID", help="USB HID device (hex ids)")
    src.add_argument(
        "--replay", type=c.input_file(".npz"), metavar="FILE", help="replay a recorded session (.npz)"
    )
    p.add_argument(
        "--hid-layout",
        type=c.input_file(".json"),
        metavar="JSON",
        help="HID report layout (default: HidLayout.generic)",
    )
    p.add_argument("--baud", type=c.count(), default=921600)
    p.add_argument(
        "--scale",
        type=c.positive,
        default=SimulatedDevice.DEFAULT_WORKSPACE.scale,
        help="model units per device metre",
    )
    p.add_argument("--duration", type=c.positive, default=10.0, help="seconds (> 0; Ctrl-C stops earlier)")
    p.add_argument("--rate", type=c.positive, default=1000.0, help="servo rate, Hz")
    p.add_argument("--physics-hz", type=c.positive, default=100.0)
    p.add_argument("--max-force", type=c.positive, default=3.0, help="newtons")
    p.add_argument("--tool-radius", type=c.positive, default=0.25, help="sphere tool radius, model units")
    p.add_argument(
        "--ellipsoid",
        type=c.vector("A,B,C", positive_at=(0, 1, 2)),
        metavar="A,B,C",
        help="ellipsoid tool semi-axes",
    )
    p.add_argument("--proxy-only", action="store_true", help="a fixed plane proxy, no physics (no JAX work)")
    p.add_argument(
        "--sculpt",
        choices=("lattice", "drag"),
        default="lattice",
        help="lattice: push/pull a mass-spring lattice (default); drag: with the button held, the "
        "surface point under the stylus follows it (minimum-norm edit, border rows blocked)",
    )
    p.add_argument("--record", type=c.output_file(".npz"), metavar="FILE", help="save the session (.npz)")
    p.add_argument("--plot", type=c.output_file(".png"), metavar="PNG", help="plot the session")
    p.add_argument("--cpu", type=c.count(0), help="pin the servo thread to this CPU")
    servo = p.add_mutually_exclusive_group()
    servo.add_argument(
        "--servo-process",
        action="store_true",
        help="run the servo in its own process, pinned, SCHED_FIFO where permitted (the default, "
        "except with --hid, whose open handle cannot cross to another process)",
    )
    servo.add_argument(
        "--servo-thread", action="store_true", help="run the servo as a thread of this process"
    )
    p.add_argument("--view", action="store_true", help="serve a live 3-D view on 127.0.0.1")
    p.add_argument("--port", type=c.count(0), default=0, help="view port (0: any free port)")
    return p


def _device(args, factory: bool = False):
    """The device, or (`factory=True`, for the servo process) something that makes it there."""
    workspace = Workspace(scale=args.scale)
    if factory and not args.hid:
        if args.serial:
            return functools.partial(SerialDevice, args.serial, baudrate=args.baud, workspace=workspace)
        if args.replay:
            return functools.partial(SimulatedDevice.replay, args.replay, realtime=True)
        return SimulatedDevice
    if args.serial:
        return SerialDevice(args.serial, baudrate=args.baud, workspace=workspace)
    if args.hid:
        vid, pid = args.hid
        if args.hid_layout:
            with open(args.hid_layout) as fh:
                try:
                    fields = json.load(fh)
                except json.JSONDecodeError as err:
                    raise c.UserError(args.hid_layout, f"not valid JSON ({err})") from None
            layout = HidLayout.from_dict({"vendor_id": vid, "product_id": pid, **fields})
        else:
            layout = HidLayout.generic(vid, pid)
        return HidDevice(layout, workspace=workspace)
    if args.replay:
        return SimulatedDevice.replay(args.replay, realtime=True)
    return SimulatedDevice()


def _model(args):
    if args.proxy_only:  # the teardrop's equator as a wall facing +x
        return Proxy.plane(
            (0.62, 0.0, 0.0),
            (1.0, 0.0, 0.0),
            stiffness=30.0,
            damping=0.3,
            tool_radius=args.tool_radius,
            stamp=0.0,
        )
    if args.sculpt == "drag":
        from bsjax.device import ConstraintSculptModel

        return ConstraintSculptModel(tool_radius=args.tool_radius, max_force=args.max_force)
    from bsjax.device import SculptModel

    return SculptModel(physics_hz=args.physics_hz, tool_radius=args.tool_radius, tool_axes=args.ellipsoid)


def _wait_for(finished, duration: float, slice_s: float = 0.2) -> None:
    """Wait until `finished` is set or `duration` s have passed, in slices of `slice_s`.

    A process-directed SIGINT may be delivered to any thread (the real-time servo thread, XLA's
    threads); Python runs its handler in the main thread only when that thread runs bytecode, so
    one long `Event.wait` could sleep through Ctrl-C. Waking 5 times a second lets the
    KeyboardInterrupt through at once, without a main thread that takes the GIL every few ms
    (which, at normal priority, could be descheduled holding it while the servo waits)."""
    deadline = time.monotonic() + duration
    while not finished.is_set():
        left = deadline - time.monotonic()
        if left <= 0:
            return
        finished.wait(min(slice_s, left))


def _view(args, loop, model):
    """The live view's server (a context manager; a null one without `--view`)."""
    if not args.view:
        return contextlib.nullcontext()
    from bsjax.view import ViewServer, live

    scene, frame = live(loop, model)
    return ViewServer(scene, frame, port=args.port)


def _require_extras(args) -> None:
    """Every extra the chosen options need, before anything starts (a device opened in the servo
    process would report a missing pyserial as a failed start)."""
    needs = (
        (args.serial, "serial", "haptics", "--serial"),
        (args.hid, "hid", "haptics", "--hid"),
        (args.view, "websockets", "view", "--view"),
        (args.plot, "matplotlib", "plot", "--plot"),
    )
    for wanted, module, extra, feature in needs:
        if wanted:
            require(module, extra, feature)


def _body(args) -> int:
    _require_extras(args)
    if args.view and args.port > 65535:
        raise c.UserError("--port", f"expected a port in [0, 65535], got {args.port}")
    if args.sculpt == "drag" and args.proxy_only:
        raise c.UserError("--sculpt", "drag needs the sculpting model; not with --proxy-only")
    if args.sculpt == "drag" and args.ellipsoid:
        raise c.UserError(
            "--ellipsoid", "the drag model's tool is a sphere (--tool-radius); not with --sculpt drag"
        )
    c.note("bsjax haptics", "building the model and compiling the physics…")
    model = _model(args)
    interrupted = False
    # the servo in its own process by default (not for HID, whose handle the servo process cannot
    # share): the device is opened there; this process writes zero through its own one if that dies
    if args.servo_process and args.hid:
        raise c.UserError(
            "--servo-process", "a HID device runs the servo as a thread (its handle cannot cross)"
        )
    factory = not (args.servo_thread or args.hid)
    try:
        device = _device(args, factory=factory)
    except (OSError, ValueError, DeviceError) as err:
        raise c.UserError("device", f"cannot open the device: {err}") from err
    opened = contextlib.nullcontext() if factory else device
    with opened:  # type: ignore[union-attr]  (a factory is opened in the servo process)
        loop = ServoLoop(
            device,
            model,
            rate_hz=args.rate,
            max_force=args.max_force,
            physics_hz=args.physics_hz,
            record=bool(args.record or args.plot),
            cpu=args.cpu,
            mode="process" if factory else "thread",
        )
        # Ctrl-C must stop the loop even where SIGINT was inherited ignored (a parent such as a
        # test runner's worker): Python then keeps it ignored at start-up
        signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            loop.start()
            name = getattr(device, "__name__", None) or type(device).__name__
            c.note("bsjax haptics", f"running ({name}, servo {loop.mode}); Ctrl-C to stop")
            with _view(args, loop, model) as server:
                if server is not None:
                    c.note("bsjax haptics", f"live view at {server.url}")
                _wait_for(loop.finished, args.duration)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            stats = loop.stop()  # writes zero force before anything else
    c.note("bsjax haptics", "zero force written" + (" (interrupted)" if interrupted else ""))
    result: dict = {"servo": stats.as_dict()}
    lines = [stats.report()]
    if args.record or args.plot:
        rec = loop.recording()
        if args.record:
            rec.save(args.record)
            result["recording"] = {"ticks": len(rec), "path": args.record}
            lines.append(f"recorded {len(rec)} ticks to {args.record}")
        if args.plot:
            plot_recording(rec, args.plot)
            result["plot"] = args.plot
            lines.append(f"plot written to {args.plot}")
    if hasattr(model, "ctrl"):
        import numpy as np

        moved = float(np.abs(np.asarray(model.ctrl) - np.asarray(model.surface0.ctrl)).max())
        result["sculpted"] = {"physics ticks": model.ticks, "largest displacement": moved}
        lines.append(
            f"sculpted surface: {model.ticks} physics ticks, largest control-point displacement {moved:.4f}"
        )
        if hasattr(model, "grabs"):  # --sculpt drag
            result["sculpted"].update(grabs=model.grabs, rollbacks=model.rollbacks)
            lines.append(f"drag interactions: {model.grabs}, rolled-back ticks: {model.rollbacks}")
    c.report(args, result, "\n".join(lines))
    return 130 if interrupted else 0


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv, errors=(DeviceError,))


if __name__ == "__main__":
    sys.exit(main())
