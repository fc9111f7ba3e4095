"""`bsjax view`: the live 3-D view in the browser of a surface, curve set or recorded session.

```
bsjax view surface.json                 # a saved surface or curve set (.json, .3dm, .step, .iges)
bsjax view session.npz                  # a recorded haptic session: plays with a time slider
bsjax view surface.3dm --port 8765 --duration 60
```
Serves the page on 127.0.0.1 (prints its address) until Ctrl-C or `--duration` seconds; the
page works offline (its renderer ships with bsjax).
"""

from __future__ import annotations

import argparse
import sys

from bsjax._optional import require
from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it

INPUTS = (".json", ".3dm", ".step", ".stp", ".iges", ".igs", ".npz")


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax view", result=False)  # a server: its address is its output
    p.add_argument("file", type=c.input_file(*INPUTS), help="surface, curve set or recording (.npz)")
    p.add_argument("--port", type=c.count(0), default=0, help="TCP port on 127.0.0.1 (0: any free port)")
    p.add_argument("--duration", type=c.positive, help="seconds to serve (default: until Ctrl-C)")
    p.add_argument("--tool-radius", type=c.positive, default=0.25, help="tool radius drawn in a replay")
    return p


def _body(args) -> int:
    require("websockets", "view", "serving the view")  # before the file is read and the scene built
    from bsjax.view import ViewServer, from_file

    if args.port > 65535:
        raise c.UserError("--port", f"expected a port in [0, 65535], got {args.port}")
    scene, frame = from_file(args.file, tool_radius=args.tool_radius)
    return c.serve(ViewServer(scene, frame, port=args.port), "view", args.duration)


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
