"""`bsjax studio` (`bsjax.view.Studio`): the session's commands directly, and the page in a real
headless Chromium driven by synthesised mouse strokes (Playwright, as tests/test_view.py).

The page only draws what Python sends, so each browser test checks the page's result against the
same pipeline called from Python — `sketch.unproject` → `sketch.recognise` → `sketch.compose` /
`bsjax.construct` / `bsjax.sculpt.min_norm` — to 1e-12.
"""

import io as _io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from bsjax import construct, io, sculpt, sketch
from bsjax.collide import Plane
from bsjax.view import Studio, ViewServer
from tests.helpers import needs_browser

DOCS = Path(__file__).parents[1] / "docs"
W, H = 800, 600
N = 41  # samples of every synthesised stroke (each a mouse move, ~30 ms in headless Chromium)
TOP = dict(yaw=-math.pi / 2, pitch=1.5, dist=4.0, target=[0.0, 0.0, 0.0])  # z = 0 nearly face-on

# how long the page waits for the server: a liveness bound, not a speed check (the server may
# compile a program first, which takes tens of seconds under CI load)
_REPLY_MS = 300_000  # 120 s was exceeded once with two workers and another process compiling


# --- strokes in pixels (the page's canvas), deterministic --------------------------------------
def _ring(cx, cy, rx, ry, turn, n, start=0.0, sweep=2 * math.pi):
    t = start + sweep * np.arange(n + 1) / n
    x, y = rx * np.cos(t), ry * np.sin(t)
    c, s = math.cos(turn), math.sin(turn)
    return np.stack([cx + c * x - s * y, cy + s * x + c * y], 1)


def _path(vertices, count=N):
    """`count` samples along the polyline through `vertices`, every vertex one of them (each edge
    gets samples in proportion to its length); every test stroke has N, one compiled shape."""
    v = np.asarray(vertices, float)
    length = np.linalg.norm(np.diff(v, axis=0), axis=1)
    steps = np.maximum(1, np.round(length / length.sum() * (count - 1)).astype(int))
    steps[np.argmax(steps)] += count - 1 - steps.sum()
    pieces = [
        v[i] + np.linspace(0, 1, k, endpoint=False)[:, None] * (v[i + 1] - v[i]) for i, k in enumerate(steps)
    ]
    return np.concatenate([*pieces, v[-1:]])


def _polygon(vertices):
    return _path([*vertices, vertices[0]])


STROKES = {
    "line": _path([(220, 420), (520, 260)]),
    "circle": _ring(400, 300, 110, 110, 0.0, N - 1, sweep=2 * math.pi + 0.2),
    "ellipse": _ring(400, 300, 150, 70, 0.3, N - 1, sweep=2 * math.pi + 0.15),
    "arc": _ring(400, 330, 120, 120, 0.0, N - 1, start=0.2, sweep=2.4),
    "triangle": _polygon([(280, 420), (520, 420), (400, 200)]),
    "square": _polygon([(300, 200), (500, 200), (500, 400), (300, 400)]),
    "rectangle": _polygon([(250, 230), (560, 230), (560, 380), (250, 380)]),
    "diamond": _polygon([(400, 170), (480, 300), (400, 430), (320, 300)]),
    "polyline": _path([(220, 400), (330, 200), (450, 400), (570, 200)]),
    "spline": np.stack([np.linspace(200, 600, N), 300 + 80 * np.sin(np.linspace(0, 1.6 * math.pi, N))], 1),
}


def _camera(data):
    eye, target, up = (np.asarray(data[k], np.float64) for k in ("eye", "target", "up"))
    return sketch.Camera(eye, target, up, fov=data["fov"], aspect=data["aspect"])


def _on_plane(command):
    """The pipeline from Python: the page's window points unprojected onto z = 0 (eqs. 5-1/5-2)."""
    pts = sketch.unproject(
        np.asarray(command["window"]), _camera(command["camera"]), Plane([0.0, 0, 0], [0.0, 0, 1])
    )
    return np.asarray(pts)


def _pixels(png: bytes) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(_io.BytesIO(png), format="png")[..., :3]


def _ctrl(spline):
    return np.asarray(spline["ctrl"], dtype=np.float64)


def _same_spline(got: dict, want, tol=1e-12):
    ref = io.to_dict(want)
    for key in ref:
        if key in ("ctrl", "knots", "knots_u", "knots_v", "weights"):
            if ref[key] is None:
                assert got[key] is None, key
            else:
                np.testing.assert_allclose(
                    np.asarray(got[key]), np.asarray(ref[key]), rtol=0, atol=tol, err_msg=key
                )
        else:
            assert got[key] == ref[key], key


# --- the page ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def studio_page(browser, tmp_path_factory):
    folder = tmp_path_factory.mktemp("studio")
    session = Studio(folder, samples=(16, 16))
    with ViewServer(session.scene, None, handle=session.handle, page="studio.html") as server:
        page = browser.new_page(viewport={"width": W, "height": H})
        page.goto(server.url)
        page.wait_for_function(
            "window.bsjax.connected && window.bsjaxStudio.scene !== null", timeout=_REPLY_MS
        )
        page.evaluate(f"window.bsjaxCamera.set({json.dumps(TOP)})")
        yield page, session, folder
        page.close()


def _draw(page, pixels):
    """One synthesised mouse stroke; returns the page's reply and the command it sent."""
    before = page.evaluate("window.bsjaxStudio.replies.length + window.bsjaxStudio.errors.length")
    pts = np.round(pixels).astype(int)
    page.mouse.move(int(pts[0, 0]), int(pts[0, 1]))
    page.mouse.down()
    for x, y in pts[1:]:
        page.mouse.move(int(x), int(y))
    page.mouse.up()
    page.wait_for_function(
        f"window.bsjaxStudio.replies.length + window.bsjaxStudio.errors.length > {before}", timeout=_REPLY_MS
    )
    reply = page.evaluate("window.bsjaxStudio.replies.concat(window.bsjaxStudio.errors).at(-1)")
    return reply, page.evaluate("window.bsjaxStudio.lastCommand")


def _send(page, command):
    return page.evaluate(f"window.bsjaxStudio.send({json.dumps(command)})")


@needs_browser
def test_every_primitive_drawn_with_the_mouse_is_recognised_as_from_python(studio_page):
    page, session, _ = studio_page
    _send(page, {"cmd": "clear"})
    page.uncheck("#timed")  # headless Chromium's event times jitter by a frame: the shape alone
    for kind, pixels in STROKES.items():
        reply, command = _draw(page, pixels)
        assert reply["type"] == "update", reply
        px = np.round(pixels)
        np.testing.assert_allclose(
            command["window"], np.stack([px[:, 0] / W, 1 - px[:, 1] / H], 1), atol=1e-12
        )
        pts = _on_plane(command)
        assert command["times"] is None
        rec = sketch.recognise(pts[:, :2])
        item = reply["scene"]["items"][-1]
        assert (item["kind"], rec.kind) == (kind, kind), (kind, item["kind"], rec.kind)
        assert item["score"] == pytest.approx(rec.score, abs=1e-12)
        c = rec.curve
        flat = np.column_stack([np.asarray(c.ctrl), np.zeros(c.n_ctrl)])
        np.testing.assert_allclose(_ctrl(item["spline"]), flat, rtol=0, atol=1e-12)
        if kind == "circle":
            stroke = np.asarray(item["stroke"]).reshape(-1, 3)  # the samples lie where they were drawn
            back = page.evaluate(
                "(p) => { const v = window.bsjaxView, b = v.basis();"
                " return p.map((q) => v.project(b, q, [0,0,0,0]).slice(0, 2)); }",
                stroke[::8].tolist(),
            )
            np.testing.assert_allclose(back, px[::8], atol=0.01)
    assert [i["kind"] for i in session.scene()["items"]] == list(STROKES)
    page.check("#timed")

    # over-sketch the spline (the last curve, selected by default): the pipeline of `_studio_geometry`
    page.click("[data-mode='oversketch']")
    xs = np.linspace(320, 460, N)
    over = np.stack([xs, 300 + 80 * np.sin((xs - 200) / 400 * 1.6 * math.pi) - 25], 1)
    reply, command = _draw(page, over)
    page.click("[data-mode='draw']")
    assert reply["type"] == "update" and reply["result"]["kind"] == "oversketched", reply
    pts = _on_plane(command)[:, :2]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    even = np.stack([np.interp(np.linspace(0, arc[-1], 64), arc, pts[:, i]) for i in range(2)], 1)
    tol = 5e-3 * float(np.linalg.norm(np.ptp(even, axis=0)))
    (fitted,) = sketch.fit_stroke(even, None, tol=tol, split=False)
    want = sketch.oversketch(rec.curve, fitted).curve  # rec: the spline, recognised last
    got = _ctrl(reply["scene"]["items"][-1]["spline"])
    np.testing.assert_allclose(got[:, :2], np.asarray(want.ctrl), rtol=0, atol=1e-12)


def _rows(page, *ids):
    for i in ids:
        page.click(f"#list div[data-id='{i}']")


def _last_reply(page):
    page.wait_for_function("window.bsjaxStudio.pending() === 0", timeout=_REPLY_MS)
    return page.evaluate(
        "window.bsjaxStudio.replies.concat(window.bsjaxStudio.errors).sort((a, b) => a.seq - b.seq).at(-1)"
    )


@needs_browser
def test_a_composite_drag_and_save_load_from_the_page_equal_python(studio_page):
    page, session, folder = studio_page
    _send(page, {"cmd": "clear"})
    assert page.is_checked("#timed")
    circle, circle_cmd = _draw(page, _ring(330, 320, 100, 100, 0.0, N - 1, sweep=2 * math.pi + 0.2))
    line, line_cmd = _draw(page, _path([(520, 400), (520, 220)]))
    a, b = (r["result"]["id"] for r in (circle, line))
    assert (circle["result"]["kind"], line["result"]["kind"]) == ("circle", "line")
    _rows(page, a, b)
    page.click("[data-op='compose']")
    built = _last_reply(page)
    assert built["type"] == "update" and built["result"]["op"] == "cylinder", built
    recs = [sketch.recognise(_on_plane(c)[:, :2], c["times"]) for c in (circle_cmd, line_cmd)]
    want = sketch.compose(recs)
    assert want.name == "cylinder"
    surface = built["scene"]["surfaces"][-1]
    _same_spline(surface["spline"], want.surface)  # the page's surface is Python's, to 1e-12

    # drag a sample of the surface up the screen: the minimum-norm edit of that point
    page.click("[data-mode='drag']")
    m, n = surface["shape"]
    i, j = m // 2, n - 1
    k = i * n + j
    xy = page.evaluate(
        "(k) => { const v = window.bsjaxView, s = window.bsjaxStudio.scene.surfaces.at(-1), P = s.points;"
        " return v.project(v.basis(), [P[3*k], P[3*k+1], P[3*k+2]], [0,0,0,0]).slice(0, 2); }",
        k,
    )
    before = session.state.bodies[-1].surface
    page.mouse.move(xy[0], xy[1])
    page.mouse.down()
    for step in range(1, 7):
        page.mouse.move(xy[0] + 2 * step, xy[1] - 15 * step)
    page.mouse.up()
    dragged = _last_reply(page)
    command = page.evaluate("window.bsjaxStudio.lastDrag")
    assert dragged["type"] == "update" and (command["u"], command["v"]) == (i / (m - 1), j / (n - 1))
    u, v = command["u"], command["v"]
    point = np.asarray(before.evaluate(np.asarray([u]), np.asarray([v]))).reshape(3)
    cam = _camera(command["camera"])
    target = np.asarray(sketch.unproject(np.asarray(command["window"]), cam, Plane(point, cam.frame()[0])))[0]
    want = sculpt.min_norm(before, [sculpt.Position(u, target, v)]).shape
    _same_spline(dragged["scene"]["surfaces"][-1]["spline"], want)
    moved = np.asarray(want.evaluate(np.asarray([u]), np.asarray([v]))).reshape(3)
    np.testing.assert_allclose(moved, target, atol=1e-12)  # the point went where it was dragged
    assert dragged["scene"]["history"]["undo"] == built["scene"]["history"]["undo"] + 1  # one step

    # the picture of the docs: a recognised circle and the built (and dragged) cylinder
    page.evaluate("window.bsjaxStudio.select([])")
    page.evaluate("window.bsjaxCamera.set({yaw: -1.2, pitch: 0.55, dist: 4.2, target: [0.1, 0.1, 0.3]})")
    page.wait_for_timeout(300)
    shot = page.screenshot(path=str(folder / "studio.png"))
    if os.environ.get("BSJAX_WRITE_DOCS") == "1":  # `BSJAX_WRITE_DOCS=1 pytest …` renews the docs' picture
        (DOCS / "studio.png").write_bytes(shot)
    picture = _pixels(shot)
    assert np.any(np.abs(picture - picture[H - 60, W // 2]) > 0.1, axis=-1).mean() > 0.05  # not blank

    # save and load through the page's buttons: the loaded surface is the one saved
    for name in ("model.3dm", "model.json"):
        page.fill("#name", name)
        page.click("#save")
        assert _last_reply(page)["type"] == "update" and (folder / name).is_file()
        page.click("#load")
        loaded = _last_reply(page)
        assert loaded["type"] == "update", loaded
        assert loaded["scene"]["surfaces"][-1]["op"] == "loaded"
        _same_spline(loaded["scene"]["surfaces"][-1]["spline"], session.state.bodies[0].surface)
        page.click("#undo")  # the load undone: the session as before it
        assert len(_last_reply(page)["scene"]["surfaces"]) == 1
    page.click("#redo")
    assert len(_last_reply(page)["scene"]["surfaces"]) == 2
    page.fill("#name", "../outside.json")
    page.click("#save")
    assert "save.name: expected a bare file name" in _last_reply(page)["error"]
    assert "save.name" in page.inner_text("#message")


@needs_browser
def test_every_construction_from_the_page_buttons(studio_page):
    """Strokes drawn with the mouse, selected, and each construction's button pressed: the
    page's surface is `bsjax.construct`'s of the page's own curves (revolve, loft, ruled) to
    1e-12, and extrude, sweep and Coons build from the same buttons."""
    page, session, _ = studio_page
    _send(page, {"cmd": "clear"})
    page.click("[data-mode='draw']")
    page.uncheck("#timed")
    page.evaluate(f"window.bsjaxCamera.set({json.dumps(TOP)})")
    t = np.linspace(0.0, 1.0, N)
    strokes = {
        "profile": np.stack([560 + 30 * np.sin(3 * t), 450 - 250 * t], 1),
        "axis": _path([(400, 470), (400, 180)]),
        "section": np.stack([250 + 300 * t, 430 + 15 * np.sin(2 * np.pi * t)], 1),
        "section2": np.stack([250 + 300 * t, 220 + 12 * np.sin(2 * np.pi * t)], 1),
        "bottom": _path([(250, 420), (550, 420)]),
        "top": _path([(250, 220), (550, 220)]),
        "left": _path([(250, 420), (250, 220)]),
        "right": _path([(550, 420), (550, 220)]),
    }
    ids = {}
    for name, pixels in strokes.items():
        _draw(page, pixels)
        reply = _last_reply(page)
        assert reply["type"] == "update", (name, reply)
        ids[name] = reply["result"]["id"]
    page.check("#timed")
    curve = {k: next(i.curve for i in session.state.items if i.id == v) for k, v in ids.items()}

    def build(op, names):
        page.evaluate(f"window.bsjaxStudio.select({json.dumps([ids[n] for n in names])})")
        page.click(f"[data-op='{op}']")
        reply = _last_reply(page)
        assert reply["type"] == "update" and reply["result"]["op"] == op, (op, reply)
        return reply["scene"]["surfaces"][-1]["spline"]

    ends = np.asarray(curve["axis"].evaluate(np.asarray([0.0, 1.0])))
    revolved = construct.revolve(curve["profile"], ends[0], ends[1] - ends[0])
    _same_spline(build("revolve", ["profile", "axis"]), revolved)
    _same_spline(
        build("loft", ["section", "section2"]), construct.loft([curve["section"], curve["section2"]])
    )
    _same_spline(
        build("ruled", ["section", "section2"]), construct.ruled(curve["section"], curve["section2"])
    )
    build("extrude", ["section", "axis"])
    build("sweep", ["profile", "section"])
    build("coons", ["bottom", "top", "left", "right"])


@needs_browser
def test_drop_and_press_from_the_page(studio_page):
    """The page's drop and press buttons act on the selected surface: the session's physics
    (checked against the physics itself in the session tests below) reaches the page."""
    page, session, _ = studio_page
    _send(page, {"cmd": "clear"})
    page.click("[data-mode='draw']")
    page.evaluate(f"window.bsjaxCamera.set({json.dumps(TOP)})")
    _draw(page, _path([(250, 220), (550, 220)]))
    first = _last_reply(page)  # the latest by sequence number (the module's page saw errors)
    _draw(page, _path([(250, 380), (550, 380)]))
    second = _last_reply(page)
    assert first["type"] == second["type"] == "update", (first, second)
    _rows(page, first["result"]["id"], second["result"]["id"])
    page.click("[data-op='loft']")
    sid = _last_reply(page)["result"]["id"]
    page.evaluate(f"window.bsjaxStudio.select([{sid}])")
    before = session.state.bodies[-1].surface
    page.click("#drop")
    dropped = _last_reply(page)
    assert dropped["type"] == "update" and dropped["command"] == "drop", dropped
    assert float(_grid(session.state.bodies[-1].surface)[..., 2].mean()) < float(_grid(before)[..., 2].mean())
    page.click("#undo")
    assert _last_reply(page)["scene"]["history"]["redo"] == 1
    page.click("#press")
    pressed = _last_reply(page)
    assert pressed["type"] == "update" and pressed["command"] == "press", pressed
    moved = np.linalg.norm(_grid(session.state.bodies[-1].surface) - _grid(before), axis=-1)
    assert np.all(np.isfinite(moved)) and moved[4, 4] > 0.5 * moved.max() > 0  # a dent in the middle


# --- the session, directly ----------------------------------------------------------------------
D, FOV = 5.0, 0.8
TOP_CAMERA = {
    "eye": [0.0, 0.0, D],
    "target": [0.0, 0.0, 0.0],
    "up": [0.0, 1.0, 0.0],
    "fov": FOV,
    "aspect": 1.0,
}


def _window(xy):
    """Window points of plane points `(N, 2)` on z = 0 seen by TOP_CAMERA (its pinhole inverted)."""
    h = math.tan(FOV / 2)
    return ((np.asarray(xy, float) / (D * h) + 1) / 2).tolist()


def _ok(session, command):
    reply = session.handle(command)
    assert reply["type"] == "update", reply
    return reply


def _stroke(session, xy):
    return _ok(session, {"cmd": "stroke", "window": _window(xy), "camera": TOP_CAMERA})["result"]["id"]


def _item(session, i):
    return next(x for x in session.state.items if x.id == i)


def _body(session, i):
    return next(x for x in session.state.bodies if x.id == i)


@pytest.fixture(scope="module")
def drawn(tmp_path_factory):
    """A session with curves: a profile, an axis, two sections, four Coons sides, a path."""
    s = Studio(tmp_path_factory.mktemp("session"), samples=(8, 8))
    t = np.linspace(0.0, 1.0, 40)
    ids = {
        "profile": _stroke(s, np.stack([0.4 + 0.15 * np.sin(3 * t), 1.2 * t - 0.6], 1)),
        "axis": _stroke(s, np.stack([0 * t - 0.2, 1.4 * t - 0.7], 1)),
        "section": _stroke(s, np.stack([1.2 * t - 0.6, -0.5 + 0.12 * np.sin(2 * np.pi * t)], 1)),
        "section2": _stroke(s, np.stack([1.2 * t - 0.6, 0.5 + 0.1 * np.sin(2 * np.pi * t)], 1)),
        "left": _stroke(s, np.stack([-0.6 + 0.1 * np.sin(2 * np.pi * t), t - 0.5], 1)),
        "right": _stroke(s, np.stack([0.6 - 0.1 * np.sin(2 * np.pi * t), t - 0.5], 1)),
    }
    return s, ids


def test_a_stroke_is_unprojected_and_recognised_in_the_plane(drawn):
    s, _ = drawn
    a = np.linspace(0, 2 * np.pi, 60)
    xy = np.stack([0.3 + 0.5 * np.cos(a), -0.1 + 0.5 * np.sin(a)], 1)
    i = _stroke(s, xy)
    item = _item(s, i)
    assert item.kind == "circle" and item.recognised.params["radius"] == pytest.approx(0.5, abs=2e-3)
    np.testing.assert_allclose(item.stroke[:, :2], xy, atol=1e-12)  # eq. 5-1's ray meets z = 0 here
    assert np.abs(item.stroke[:, 2]).max() < 1e-12
    cam = sketch.Camera(*(np.asarray(TOP_CAMERA[k]) for k in ("eye", "target", "up")), fov=FOV, aspect=1.0)
    pts = np.asarray(sketch.unproject(np.asarray(_window(xy)), cam, Plane([0.0, 0, 0], [0.0, 0, 1])))
    rec = sketch.recognise(pts[:, :2])
    np.testing.assert_allclose(np.asarray(item.curve.ctrl)[:, :2], np.asarray(rec.curve.ctrl), atol=1e-12)
    item_message = s.scene()["items"][-1]
    assert item_message["kind"] == "circle"
    assert item_message["params"]["radius"] == item.recognised.params["radius"]
    _ok(s, {"cmd": "delete", "id": i})


def test_every_construction_equals_bsjax_construct(drawn):
    s, ids = drawn
    c = {k: _item(s, v).curve for k, v in ids.items()}

    def build(op, names, **extra):
        reply = _ok(s, {"cmd": "build", "op": op, "curves": [ids[n] for n in names], **extra})
        return _body(s, reply["result"]["id"]).surface

    ends = np.asarray(c["axis"].evaluate(np.asarray([0.0, 1.0])))
    cases = [
        (build("revolve", ["profile", "axis"]), construct.revolve(c["profile"], ends[0], ends[1] - ends[0])),
        (build("loft", ["section", "section2"]), construct.loft([c["section"], c["section2"]])),
        (build("ruled", ["section", "section2"]), construct.ruled(c["section"], c["section2"])),
        (
            build("extrude", ["section"], vector=[0.0, 0.0, 0.7]),
            construct.extrude(c["section"], np.array([0.0, 0, 0.7])),
        ),
        (build("extrude", ["section", "axis"]), construct.extrude(c["section"], ends[1] - ends[0])),
    ]
    start = np.asarray(c["section"].evaluate(np.asarray([0.0])))[0, :2]
    flat = _item(s, ids["profile"]).flat
    local = flat.with_ctrl(np.asarray(flat.ctrl) - start)
    cases.append((build("sweep", ["profile", "section"]), construct.sweep(local, c["section"]).surface))
    for got, want in cases:
        _same_spline(io.to_dict(got), want, tol=1e-12)
    coons = build("coons", ["section", "section2", "left", "right"])
    for u, v, side in ((0.3, 0.0, "section"), (0.6, 1.0, "section2")):  # the sides are the patch's edges
        p = np.asarray(coons.evaluate(np.asarray([u]), np.asarray([v])))[0]
        q = np.asarray(c[side].evaluate(np.asarray([u])))[0]
        assert np.linalg.norm(p - q) < 0.05  # the corner snapping moves the ends only
    err = s.handle(
        {
            "cmd": "build",
            "op": "coons",
            "curves": [ids["section"], ids["section2"], ids["profile"], ids["axis"]],
        }
    )
    assert err["type"] == "error" and "do not meet at a corner" in err["error"]


def test_composites_of_chapter_3_and_adaptation(tmp_path):
    s = Studio(tmp_path, samples=(8, 8))
    a = np.linspace(0, 2 * np.pi, 64)
    circle = _stroke(s, np.stack([0.4 * np.cos(a), 0.4 * np.sin(a)], 1))
    line = _stroke(s, np.stack([np.full(30, 0.8), np.linspace(-0.3, 0.5, 30)], 1))
    reply = _ok(s, {"cmd": "build", "op": "compose", "curves": [circle, line]})
    want = sketch.compose([_item(s, circle).recognised, _item(s, line).recognised])
    assert reply["result"]["op"] == want.name == "cylinder"
    _same_spline(reply["scene"]["surfaces"][-1]["spline"], want.surface)
    # two crossing lines match no composite: the error lists what was seen; adapt adds the rule
    cross = _stroke(s, np.stack([np.linspace(0.5, 1.1, 30), np.full(30, 0.1)], 1))
    err = s.handle({"cmd": "build", "op": "compose", "curves": [line, cross]})
    assert err["type"] == "error" and err["error"].startswith(
        "build.curves: expected strokes that match a composite"
    )
    _ok(s, {"cmd": "adapt", "curves": [line, cross], "name": "cross", "construction": "ruled"})
    assert s.scene()["rules"][0] == "cross"
    assert _ok(s, {"cmd": "build", "op": "compose", "curves": [line, cross]})["result"]["op"] == "cross"
    _ok(s, {"cmd": "undo"})
    _ok(s, {"cmd": "undo"})  # the adaptation undone: the tree is the default one again
    assert s.scene()["rules"] == [r.name for r in sketch.default_tree().rules]


def test_oversketch_and_a_drawing_plane(tmp_path):
    s = Studio(tmp_path, samples=(8, 8))
    t = np.linspace(0.0, 1.0, 50)
    wave = _stroke(s, np.stack([2 * t - 1, 0.3 * np.sin(2 * np.pi * t)], 1))
    over = np.stack([0.4 * t - 0.2, 0.25 + 0 * t], 1)
    reply = _ok(s, {"cmd": "oversketch", "curve": wave, "window": _window(over), "camera": TOP_CAMERA})
    assert reply["result"]["kind"] == "oversketched"
    before = sketch.recognise(np.stack([2 * t - 1, 0.3 * np.sin(2 * np.pi * t)], 1)).curve
    pts = _item(s, wave).stroke[:, :2]  # the over-sketch stroke, fitted on 64 arc-length samples
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    even = np.stack([np.interp(np.linspace(0, arc[-1], 64), arc, pts[:, i]) for i in range(2)], 1)
    tol = 5e-3 * float(np.linalg.norm(np.ptp(even, axis=0)))
    (fitted,) = sketch.fit_stroke(even, None, tol=tol, split=False)
    want = sketch.oversketch(before, fitted).curve
    np.testing.assert_allclose(np.asarray(_item(s, wave).flat.ctrl), np.asarray(want.ctrl), atol=1e-9)
    circle = _stroke(s, np.stack([0.3 * np.cos(6 * t), 0.3 * np.sin(6 * t)], 1)[:47])
    err = s.handle({"cmd": "oversketch", "curve": circle, "window": _window(over), "camera": TOP_CAMERA})
    assert err["error"].startswith("oversketch.curve: expected a polynomial curve")
    # the plane y = 0.25 (seen from above, edge-on rays fail; tilt the camera): strokes lie on it
    _ok(s, {"cmd": "plane", "point": [0.0, 0.25, 0.0], "normal": [0.0, 1.0, 0.0]})
    side = {
        "eye": [0.3, -4.0, 0.5],
        "target": [0.0, 0.0, 0.0],
        "up": [0.0, 0.0, 1.0],
        "fov": 0.8,
        "aspect": 1.0,
    }
    a = np.linspace(0, 2 * np.pi, 60)
    i = _ok(
        s,
        {
            "cmd": "stroke",
            "window": (0.5 + 0.2 * np.stack([np.cos(a), np.sin(a)], 1)).tolist(),
            "camera": side,
        },
    )
    item = _item(s, i["result"]["id"])
    assert np.abs(item.stroke[:, 1] - 0.25).max() < 1e-12
    assert np.abs(np.asarray(item.curve.ctrl)[:, 1] - 0.25).max() < 1e-12  # the lifted curve too
    err = s.handle({"cmd": "stroke", "window": [[0.5, 0.5]] * 3, "camera": TOP_CAMERA})  # along the plane
    assert err["type"] == "error" and "window_xy" in err["error"]


def test_drag_is_the_minimum_norm_edit_and_one_undo_step_per_gesture(drawn):
    s, ids = drawn
    sid = _ok(s, {"cmd": "build", "op": "ruled", "curves": [ids["section"], ids["section2"]]})["result"]["id"]
    before, state = _body(s, sid).surface, s.state
    depth = len(s.undo_stack)
    bad = s.handle({"cmd": "drag", "surface": sid, "u": 0.5, "v": 0.5, "gesture": 7})  # no target
    assert bad["error"].startswith("drag.window: missing") and s.state is state
    assert len(s.undo_stack) == depth
    for k in range(1, 4):
        target = [0.1, 0.0, 0.1 * k]
        _ok(s, {"cmd": "drag", "surface": sid, "u": 0.5, "v": 0.5, "target": target, "gesture": 7})
    want = sculpt.min_norm(before, [sculpt.Position(0.5, np.asarray(target), 0.5)]).shape
    _same_spline(io.to_dict(_body(s, sid).surface), want)
    assert len(s.undo_stack) == depth + 1
    # by a window point: onto the plane through the point facing the camera
    reply = _ok(
        s, {"cmd": "drag", "surface": sid, "u": 0.2, "v": 0.7, "window": [[0.52, 0.55]], "camera": TOP_CAMERA}
    )
    point, target = np.asarray(reply["result"]["point"]), np.asarray(reply["result"]["target"])
    assert abs(target[2] - point[2]) < 1e-12  # the camera looks down z: the plane is z = const
    got = np.asarray(_body(s, sid).surface.evaluate(np.asarray([0.2]), np.asarray([0.7])))[0]
    np.testing.assert_allclose(got, target, atol=1e-12)
    _ok(s, {"cmd": "undo"})
    _ok(s, {"cmd": "undo"})
    _same_spline(io.to_dict(_body(s, sid).surface), before)
    _ok(s, {"cmd": "redo"})
    _same_spline(io.to_dict(_body(s, sid).surface), want)


def test_target_curve_sculpting_with_lambda(tmp_path):
    s = Studio(tmp_path, samples=(8, 8))
    t = np.linspace(0.0, 1.0, 30)
    a = _stroke(s, np.stack([t - 0.5, 0 * t - 0.5], 1))
    b = _stroke(s, np.stack([t - 0.5, 0 * t + 0.5], 1))
    sid = _ok(s, {"cmd": "build", "op": "loft", "curves": [a, b]})["result"]["id"]
    _ok(s, {"cmd": "plane", "point": [0.0, 0.0, 0.2], "normal": [0.0, 0.0, 1.0]})
    c = _stroke(s, np.stack([0.6 * t - 0.3, 0.2 * np.sin(3 * t)], 1) * (D - 0.2) / D)
    before, curve = _body(s, sid).surface, _item(s, c).curve
    reply = _ok(s, {"cmd": "target", "surface": sid, "curve": c, "lam": 0.5})
    want = sculpt.target_sculpt(before, curve, 0.5)
    assert reply["result"]["status"] == int(want.status)
    _same_spline(io.to_dict(_body(s, sid).surface), want.surface)
    assert s.handle({"cmd": "target", "surface": sid, "curve": c, "lam": 1.5})["error"].startswith(
        "target.lam: expected a number in [0.0, 1.0]"
    )


@pytest.fixture(scope="module")
def lofted(tmp_path_factory):
    """A session holding a flat lofted plate (1 × 1 in the plane z = 0)."""
    s = Studio(tmp_path_factory.mktemp("physics"), samples=(8, 8))
    t = np.linspace(0.0, 1.0, 30)
    a = _stroke(s, np.stack([t - 0.5, 0 * t - 0.5], 1))
    b = _stroke(s, np.stack([t - 0.5, 0 * t + 0.5], 1))
    return s, _ok(s, {"cmd": "build", "op": "loft", "curves": [a, b]})["result"]["id"]


def _grid(surface, n=9):
    return np.asarray(surface.blending(n, n).points(surface.ctrl))


def test_drop_the_surface_on_a_table_as_a_jelly_body(lofted):
    """The plate as a jelly shell released above a table: it falls (the table is 5 % of its size
    below the shell's lowest node) and comes to rest on it flat, its centre where it was (no
    sideways force), finite; one undo step restores it; bad fields are named."""
    s, sid = lofted
    before = _body(s, sid).surface
    reply = _ok(s, {"cmd": "drop", "surface": sid, "seconds": 0.3})
    p0, p1 = _grid(before), _grid(_body(s, sid).surface)
    size = float(np.linalg.norm(p0.reshape(-1, 3).max(0) - p0.reshape(-1, 3).min(0)))
    assert reply["result"]["steps"] > 10 and np.all(np.isfinite(p1))
    fall = float(np.mean(p0[..., 2] - p1[..., 2]))
    assert 0.05 * size <= fall <= (0.05 + 2 * 0.05 + 0.02) * size, fall / size  # gap (+ shell, sinking)
    assert np.ptp(p1[..., 2]) < 1e-3 * size  # resting flat
    np.testing.assert_allclose(p1[..., :2].mean((0, 1)), p0[..., :2].mean((0, 1)), atol=1e-6 * size)
    _ok(s, {"cmd": "undo"})
    assert _body(s, sid).surface is before
    bad = s.handle({"cmd": "drop", "surface": sid, "seconds": -1})
    assert bad["error"].startswith("drop.seconds: expected a number in [0.001, 5.0]")


def test_press_the_surface_with_a_sphere(lofted):
    """A sphere pushed into the plate's middle along its normal, the plate held from behind: a
    dent under the sphere (against the outward normal), deepest there, finite; one undo step."""
    s, sid = lofted
    before = _body(s, sid).surface
    reply = _ok(s, {"cmd": "press", "surface": sid, "u": 0.5, "v": 0.5, "depth": 0.02, "seconds": 0.3})
    p0, p1 = _grid(before), _grid(_body(s, sid).surface)
    assert reply["result"]["steps"] > 10 and np.all(np.isfinite(p1))
    size = float(np.linalg.norm(p0.reshape(-1, 3).max(0) - p0.reshape(-1, 3).min(0)))
    moved = np.linalg.norm(p1 - p0, axis=-1)
    assert moved[4, 4] > 1e-3 * size and moved[4, 4] == pytest.approx(moved.max())  # the dent's bottom
    assert moved[0, 0] < 0.25 * moved[4, 4]  # a corner, far from the sphere
    _ok(s, {"cmd": "undo"})
    assert _body(s, sid).surface is before
    assert s.handle({"cmd": "press", "surface": sid, "u": 1.5, "v": 0.5})["error"].startswith(
        "press.u: expected a number in [0.0, 1.0]"
    )


def test_undo_redo_clear_delete(tmp_path):
    s = Studio(tmp_path, samples=(8, 8))
    assert s.handle({"cmd": "undo"})["error"] == "undo: nothing to undo"
    a = _stroke(s, np.stack([np.linspace(0, 1, 20), np.zeros(20)], 1))
    b = _stroke(s, np.stack([np.linspace(0, 1, 20), np.ones(20)], 1))
    states = [s.state]
    _ok(s, {"cmd": "delete", "id": a})
    states.append(s.state)
    _ok(s, {"cmd": "clear"})
    assert s.scene()["items"] == []
    for expected in reversed(states):
        _ok(s, {"cmd": "undo"})
        assert s.state is expected
    assert [i.id for i in s.state.items] == [a, b]
    _ok(s, {"cmd": "redo"})
    assert [i.id for i in s.state.items] == [b]
    _stroke(s, np.stack([np.linspace(0, 1, 20), np.full(20, 2.0)], 1))  # a new step drops the redo
    assert s.handle({"cmd": "redo"})["error"] == "redo: nothing to redo"
    assert s.handle({"cmd": "scene", "seq": 41})["seq"] == 41


@pytest.fixture(scope="module")
def saving(tmp_path_factory):
    """A session with a circle (rational), two sections, their loft and the circle's extrusion."""
    s = Studio(tmp_path_factory.mktemp("saving"), samples=(8, 8))
    t, a = np.linspace(0.0, 1.0, 40), np.linspace(0, 2 * np.pi, 60)
    circle = _stroke(s, np.stack([0.3 * np.cos(a), 0.3 * np.sin(a)], 1))
    one = _stroke(s, np.stack([1.2 * t - 0.6, -0.5 + 0.12 * np.sin(2 * np.pi * t)], 1))
    two = _stroke(s, np.stack([1.2 * t - 0.6, 0.5 + 0.1 * np.sin(2 * np.pi * t)], 1))
    _ok(s, {"cmd": "build", "op": "loft", "curves": [one, two]})
    _ok(s, {"cmd": "build", "op": "extrude", "curves": [circle], "vector": [0.0, 0.0, 0.5]})
    return s


@pytest.mark.parametrize("ext", [".json", ".3dm", ".step"])
def test_save_load_round_trip(saving, ext):
    s = saving
    saved = s.state
    _ok(s, {"cmd": "save", "name": "round" + ext})
    reply = _ok(s, {"cmd": "load", "name": "round" + ext})
    new = reply["result"]["ids"]
    assert len(new) == len(saved.bodies) + len(saved.items)
    tol = 1e-12
    for old, body in zip(saved.bodies, s.state.bodies[len(saved.bodies) :]):
        _same_spline({**io.to_dict(body.surface), "periodic_u": old.surface.periodic_u}, old.surface, tol)
    for old, item in zip(saved.items, s.state.items[len(saved.items) :]):
        np.testing.assert_allclose(np.asarray(item.curve.ctrl), np.asarray(old.curve.ctrl), atol=tol)
    _ok(s, {"cmd": "undo"})
    assert s.state is saved


def test_a_file_the_writer_refuses_is_an_error_not_a_crash(drawn):
    s, ids = drawn
    built = not any(b.op == "coons" for b in s.state.bodies)  # this test may run first on its worker
    if built:
        sides = [ids[k] for k in ("section", "section2", "left", "right")]
        assert s.handle({"cmd": "build", "op": "coons", "curves": sides})["type"] != "error"
    reply = s.handle({"cmd": "save", "name": "coons.step"})  # OCCT: near-equal knots of the patch
    if built:
        s.handle({"cmd": "undo"})  # the shared session as the other tests left it
    assert reply["type"] == "error" and reply["error"].startswith(
        "save.name: expected a file the writer accepts"
    )


BAD = [
    ([1, 2], "message: expected a JSON object"),
    ({"seq": 1}, "cmd: missing"),
    ({"cmd": "paint"}, "cmd: expected one of plane, stroke"),
    ({"cmd": "stroke", "camera": TOP_CAMERA}, "stroke.window: missing"),
    (
        {"cmd": "stroke", "window": "abc", "camera": TOP_CAMERA},
        "stroke.window: expected a list of [x, y] window points",
    ),
    (
        {"cmd": "stroke", "window": [[0.1, 0.2], [0.3]], "camera": TOP_CAMERA},
        "stroke.window: expected a list of [x, y]",
    ),
    (
        {"cmd": "stroke", "window": [[0.1, 0.2]] * 2, "camera": TOP_CAMERA},
        "stroke.window: expected a list of at least 3",
    ),
    ({"cmd": "stroke", "window": [[0.1, None]] * 3, "camera": TOP_CAMERA}, "stroke.window: expected"),
    ({"cmd": "stroke", "window": [[0.1, 0.2], [0.2, 0.3], [0.4, 0.4]]}, "stroke.camera: expected an object"),
    (
        {"cmd": "stroke", "window": [[0.1, 0.2]] * 3, "camera": {**TOP_CAMERA, "fov": 4}},
        "stroke.camera.fov: expected a number",
    ),
    (
        {"cmd": "stroke", "window": [[0.1, 0.2]] * 3, "camera": {**TOP_CAMERA, "eye": [0, 1]}},
        "stroke.camera.eye: expected a list of 3",
    ),
    (
        {
            "cmd": "stroke",
            "window": [[0.1, 0.2], [0.2, 0.3], [0.4, 0.4]],
            "times": [0, 1, 1],
            "camera": TOP_CAMERA,
        },
        "stroke.times: expected strictly increasing",
    ),
    (
        {"cmd": "stroke", "window": [[0.1, 0.2]] * 3, "times": [0, 1], "camera": TOP_CAMERA},
        "stroke.times: expected a list of 3",
    ),
    ({"cmd": "build", "op": "twist", "curves": []}, "build.op: expected one of revolve"),
    ({"cmd": "build", "op": "loft", "curves": "1,2"}, "build.curves: expected a list of integer ids"),
    ({"cmd": "build", "op": "loft", "curves": [99, 98]}, "build.curves[0]: expected the id of a curve"),
    ({"cmd": "build", "op": "compose", "curves": []}, "build.curves: expected at least 2"),
    (
        {"cmd": "drag", "surface": 1.5, "u": 0, "v": 0, "target": [0, 0, 0]},
        "drag.surface: expected an integer id",
    ),
    (
        {"cmd": "drag", "surface": 99, "u": 0, "v": 0, "target": [0, 0, 0]},
        "drag.surface: expected the id of a surface",
    ),
    ({"cmd": "target", "surface": True, "curve": 1, "lam": 0.5}, "target.surface: expected an integer id"),
    ({"cmd": "plane", "point": [0, 0, 0], "normal": [0, 0, 0]}, "plane.normal: expected a nonzero vector"),
    (
        {"cmd": "plane", "point": [0, 0, "x"], "normal": [0, 0, 1]},
        "plane.point: expected a list of 3 numbers",
    ),
    (
        {"cmd": "adapt", "curves": [], "name": "", "construction": "ruled"},
        "adapt.name: expected a non-empty string",
    ),
    ({"cmd": "drop", "surface": 99}, "drop.surface: expected the id of a surface"),
    ({"cmd": "press", "surface": 99, "u": 0.5, "v": 0.5}, "press.surface: expected the id of a surface"),
    ({"cmd": "delete", "id": 12345}, "delete.id: expected the id of a curve or surface"),
    ({"cmd": "save", "name": "a/b.json"}, "save.name: expected a bare file name"),
    ({"cmd": "save", "name": "model.obj"}, "save.name: expected a file name ending in one of .json, .3dm"),
    ({"cmd": "load", "name": "missing.json"}, "load.name: expected a file in"),
    ({"cmd": "save", "name": 3}, "save.name: expected a non-empty string"),
]


@pytest.mark.parametrize(
    ("command", "needle"), BAD, ids=[n.split(":")[0] + str(i) for i, (_, n) in enumerate(BAD)]
)
def test_bad_commands_get_an_error_naming_the_field(tmp_path, command, needle):
    s = Studio(tmp_path, samples=(8, 8))
    state = s.state
    reply = s.handle(command)
    assert reply["type"] == "error" and reply["error"].startswith(needle), reply
    assert "\n" not in reply["error"] and s.state is state  # nothing changed
    json.dumps(reply)


def test_the_channel_answers_malformed_text_and_refuses_other_origins(tmp_path):
    from websockets.exceptions import ConnectionClosed, InvalidStatus
    from websockets.sync.client import connect

    s = Studio(tmp_path, samples=(8, 8))
    with ViewServer(s.scene, None, handle=s.handle, page="studio.html") as server:
        url = f"ws://127.0.0.1:{server.port}/ws"
        with connect(url) as ws:
            assert json.loads(ws.recv())["type"] == "scene"
            ws.send("{not json")
            assert json.loads(ws.recv())["error"].startswith("message: expected JSON text")
            ws.send(json.dumps({"cmd": "undo", "seq": 5}))
            assert json.loads(ws.recv()) == {"type": "error", "seq": 5, "error": "undo: nothing to undo"}
        with connect(url, origin="http://example.com") as ws:
            with pytest.raises((ConnectionClosed, InvalidStatus)):
                ws.recv(timeout=5)
        import urllib.request

        page = urllib.request.urlopen(server.url, timeout=10).read().decode()
        assert "studio.js" in page and "view.js" in page
        script = urllib.request.urlopen(server.url + "studio.js", timeout=10).read().decode()
        assert "://" not in script  # offline: no external address
    assert server.commands == 2


def test_studio_cli(tmp_path, capsys):
    from bsjax.cli import main

    assert main(["studio", "--dir", str(tmp_path), "--duration", "0.3"]) == 0
    assert "bsjax studio: http://127.0.0.1:" in capsys.readouterr().out
    assert main(["studio", "--dir", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "--dir: expected a folder" in err and len(err.strip().splitlines()) == 1
    assert main(["studio", "--dir", str(tmp_path), "--open", "none.json"]) == 2
    assert "--open: load.name: expected a file in" in capsys.readouterr().err
