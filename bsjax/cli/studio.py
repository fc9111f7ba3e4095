"""`bsjax studio`: an interactive modelling page — draw, recognise, construct, sculpt — in the browser.

```
bsjax studio                            # serves http://127.0.0.1:<port>/ until Ctrl-C
bsjax studio --dir models --port 8765   # save/load .json, .3dm, .step in ./models
bsjax studio --open model.json          # start from a saved file of that folder
```
Draw strokes with the mouse or a pen on the drawing plane; each is recognised (line, circle,
ellipse, arc, polygons, polyline, spline: `bsjax.sketch.recognise`) and shown regularised.
Over-sketch a curve, build surfaces (revolve, loft, ruled, extrude, sweep, Coons, the ch. 3
composites), drag a surface point (minimum-norm sculpting) or sculpt towards a curve (λ),
undo/redo, save and load. Every command is computed here, in Python (`bsjax.view.Studio`); the
page only draws what comes back. The page works offline (its renderer ships with bsjax).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bsjax._optional import require
from bsjax.cli import _common as c

__all__ = ["main"]  # a command: `main(argv) -> exit code`; the rest serves it


def _parser() -> argparse.ArgumentParser:
    p = c.Parser("bsjax studio", result=False)  # a server: its address is its output
    p.add_argument("--dir", default=".", help="folder that save/load read and write (default: here)")
    p.add_argument("--open", metavar="NAME", help="a .json/.3dm/.step file of --dir to start from")
    p.add_argument("--port", type=c.count(0), default=0, help="TCP port on 127.0.0.1 (0: any free port)")
    p.add_argument("--duration", type=c.positive, help="seconds to serve (default: until Ctrl-C)")
    p.add_argument("--samples", type=c.grid, default=(24, 24), metavar="M,N", help="surface grid drawn")
    return p


def _body(args) -> int:
    require("websockets", "view", "serving the studio")
    from bsjax.view import Studio, ViewServer

    if args.port > 65535:
        raise c.UserError("--port", f"expected a port in [0, 65535], got {args.port}")
    if not Path(args.dir).is_dir():
        raise c.UserError("--dir", f"expected a folder, got {args.dir!r} (no such folder)")
    studio = Studio(args.dir, dtype=c.dtype(args), samples=args.samples)
    if args.open is not None:
        reply = studio.handle({"cmd": "load", "name": args.open})
        if reply["type"] == "error":
            raise c.UserError("--open", reply["error"])
    server = ViewServer(studio.scene, None, port=args.port, handle=studio.handle, page="studio.html")
    return c.serve(server, "studio", args.duration)


def main(argv: list[str] | None = None) -> int:
    return c.run(_parser(), _body, argv)


if __name__ == "__main__":
    sys.exit(main())
