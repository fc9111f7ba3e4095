"""`ViewServer`: the live 3-D view — a page and a WebSocket on 127.0.0.1, one port.

One asyncio thread serves the static page (`bsjax/view/static/`: HTML and a hand-written canvas
renderer, no network needed) through the WebSocket server's HTTP hook, and pushes frames to every
connected page at `rate_hz` (50 Hz by default, Gao & Gibson's visual loop beside the 1 kHz haptic
loop). A frame is built once per tick by the `source` callable and sent to each page; a page
that is slow keeps its one pending frame and skips the ones it missed (the newest wins). The
source reads only what the servo and the physics already published (`ServoLoop.snapshot()`,
the model's control net), so neither ever waits for a browser.

Messages (JSON): `{"type": "scene", ...}` once per connection (surface grid, tool radius, title,
an optional recording to replay), then `{"type": "frame", ...}` (tool position, force, watchdog
gain, servo and physics rates, and the surface's sample points when they changed).

With a `handle` callable (`bsjax studio`) the channel also runs the other way: each text message
a page sends is parsed as JSON and handed to `handle` in one worker thread, in arrival order
(the asyncio thread keeps serving meanwhile), and its reply goes back to that page. Such a server
only accepts pages of its own origin (a page from elsewhere, open in the same browser, cannot
send commands to it).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import mimetypes
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from importlib import resources

from bsjax._optional import require

log = logging.getLogger("bsjax.view")

_STATIC = "static"


def _clean(obj):
    """JSON-safe: non-finite floats become None (the page draws nothing for them)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def dumps(message: dict) -> str:
    return json.dumps(_clean(message), separators=(",", ":"), allow_nan=False)


class ViewServer:
    """Serve the live view of `source` on `http://host:port/`.

    **Arguments:**
    - `scene`: callable returning the scene message (dict: `surface` `{"shape": [m, n],
      "points": [...]}` or None, `tool_radius`, `title`, optional `replay`), sent on connect.
    - `frame`: callable returning the newest frame (dict), or None for a static scene; called
      `rate_hz` times a second in the server's thread, so keep it cheap (no waiting on locks).
    - `host`: `127.0.0.1` (the view is local); `port`: 0 picks a free one (see `url`).
    - `handle`: callable taking a page's message (the parsed JSON) and returning the reply (a
      dict), or None (a view only); `page`: the file of `static/` served at `/`.

    Serving needs the `view` extra (websockets).
    """

    def __init__(
        self,
        scene: Callable[[], dict],
        frame: Callable[[], dict | None] | None = None,
        host: str = "127.0.0.1",
        port: int = 0,
        rate_hz: float = 50.0,
        handle: Callable[[object], dict] | None = None,
        page: str = "index.html",
    ):
        if not callable(scene):
            raise TypeError(f"scene: expected a callable returning a dict, got {type(scene).__name__}")
        if frame is not None and not callable(frame):
            raise TypeError(f"frame: expected a callable or None, got {type(frame).__name__}")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port < 65536:
            raise ValueError(f"port: expected an int in [0, 65535], got {port!r}")
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
            raise ValueError(f"rate_hz: expected a rate in (0, 1000] Hz, got {rate_hz!r}")
        if handle is not None and not callable(handle):
            raise TypeError(f"handle: expected a callable or None, got {type(handle).__name__}")
        if _static(page) is None:
            raise ValueError(f"page: expected a file of bsjax/view/static/, got {page!r}")
        self.scene, self.frame, self.handle, self.page = scene, frame, handle, page
        self.commands = 0
        self._worker: ThreadPoolExecutor | None = None
        self.host, self.port, self.rate_hz = host, port, float(rate_hz)
        self.frames_sent = 0
        self.clients = 0
        self._latest: str | None = None
        self._tick = asyncio.Event()  # replaced in the server's loop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> "ViewServer":
        # checked here, in the caller's thread: a missing extra is not a port problem
        require("websockets.asyncio.server", "view", "bsjax.view.ViewServer")
        self._thread = threading.Thread(target=self._main, name="bsjax-view", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise OSError(f"view: cannot serve on {self.host}:{self.port}: {self._error}") from self._error
        return self

    def stop(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(5)
        if self._worker is not None:
            self._worker.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> "ViewServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- the server's thread ------------------------------------------------------------------
    def _main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as err:
            self._error = err
            self._ready.set()

    async def _serve(self) -> None:
        from websockets.asyncio.server import serve

        self._loop = asyncio.get_running_loop()
        self._stop, self._tick = asyncio.Event(), asyncio.Event()
        if self.handle is not None:
            self._worker = ThreadPoolExecutor(1, thread_name_prefix="bsjax-view-commands")
        async with serve(
            self._client, self.host, self.port, process_request=self._http, compression=None
        ) as server:
            self.port = server.sockets[0].getsockname()[1] if self.port == 0 else self.port
            self._ready.set()
            pump = asyncio.create_task(self._pump())
            await self._stop.wait()
            pump.cancel()

    async def _pump(self) -> None:
        """Build one frame per tick; wake every page's sender (the newest frame wins)."""
        period = 1.0 / self.rate_hz
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        while True:
            if self.frame is not None and self.clients:
                try:
                    frame = self.frame()
                except Exception as err:  # a broken source must not take the server down
                    log.warning("view: frame source failed: %r", err)
                    frame = None
                if frame is not None:
                    self._latest = dumps({"type": "frame", **frame})
                    self._tick.set()
                    self._tick = asyncio.Event()
            next_t += period
            delay = next_t - loop.time()
            if delay < -period:
                next_t, delay = loop.time(), 0.0
            await asyncio.sleep(max(delay, 0.0))

    async def _client(self, ws) -> None:
        if ws.request is None or ws.request.path.split("?")[0] != "/ws":
            await ws.close(1008, "unknown path")
            return
        if self.handle is not None and not self._same_origin(ws.request.headers.get("Origin")):
            await ws.close(1008, "commands only from this server's own page")
            return
        self.clients += 1
        reader = asyncio.create_task(self._commands(ws)) if self.handle is not None else None
        try:
            await ws.send(dumps({"type": "scene", **self.scene()}))
            if self.frame is None:  # a static scene: nothing to push; wait for the page to leave
                await (reader if reader is not None else ws.wait_closed())
            while self.frame is not None:
                await self._tick.wait()
                message = self._latest
                if message is not None:
                    await ws.send(message)  # only this page's task waits on its socket
                    self.frames_sent += 1
        except Exception:  # closed, reloaded, or gone: the page reconnects by itself
            pass
        finally:
            self.clients -= 1
            if reader is not None:
                reader.cancel()

    async def _commands(self, ws) -> None:
        """Each message of the page handled in the worker thread; the reply sent back."""
        loop = asyncio.get_running_loop()
        try:
            async for text in ws:
                reply = await loop.run_in_executor(self._worker, self._reply, text)
                await ws.send(reply)
        except Exception:  # the connection closed: `_client` cleans up
            pass

    def _reply(self, text) -> str:
        self.commands += 1
        try:
            message = json.loads(text)
        except (TypeError, ValueError) as err:
            return dumps({"type": "error", "seq": None, "error": f"message: expected JSON text ({err})"})
        try:
            return dumps(self.handle(message))  # pyright: ignore[reportOptionalCall]
        except Exception as err:  # the handler's own bug: reported to the page, not fatal
            log.warning("view: command handler failed: %r", err)
            return dumps({"type": "error", "seq": None, "error": f"internal error: {err!r}"})

    def _same_origin(self, origin: str | None) -> bool:
        """No Origin header (a local program, not a browser page) or this server's own."""
        allowed = {f"http://{h}:{self.port}" for h in (self.host, "localhost", "127.0.0.1")}
        return origin is None or origin in allowed

    def _http(self, connection, request):
        """Static files for plain HTTP requests; None lets a WebSocket upgrade through."""
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        if request.headers.get("Upgrade", "").lower() == "websocket":
            return None
        path = request.path.split("?")[0]
        name = self.page if path == "/" else path.lstrip("/")
        body = _static(name)
        if body is None:
            return Response(404, "Not Found", Headers([("Content-Type", "text/plain")]), b"not found\n")
        kind = mimetypes.guess_type(name)[0] or "application/octet-stream"
        headers = Headers([("Content-Type", kind), ("Cache-Control", "no-store")])
        return Response(200, "OK", headers, body)


def _static(name: str) -> bytes | None:
    """A file shipped in `bsjax/view/static/` (no path outside it)."""
    if not name or "/" in name or "\\" in name or name.startswith("."):
        return None
    entry = resources.files("bsjax.view").joinpath(_STATIC, name)
    return entry.read_bytes() if entry.is_file() else None
