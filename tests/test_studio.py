"""`bsjax studio` (`bsjax.view.Studio`): the session's commands directly, and the page in a real
headless Chromium driven by synthesised mouse strokes (Playwright, as tests/test_view.py).

The page only draws what Python sends, so each browser test checks the page's result against the
same pipeline called from Python — `sketch.unproject` → `sketch.recognise` → `sketch.compose` /
`bsjax.construct` / `bsjax.sculpt.min_norm` — to 1e-12.
"""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from bsjax import construct, io, sculpt, sketch
from bsjax.collide import Plane
from bsjax.view import Studio, ViewServer

CHROMIUM = shutil.which("chromium-headless-shell") or shutil.which("chromium")
needs_browser = pytest.mark.skipif(
    CHROMIUM is None, reason="no system Chromium (apt-get install chromium-headless-shell)"
)
DOCS = Path(__file__).parents[1] / "docs"
W, H = 800, 600
TOP = dict(yaw=-math.pi / 2, pitch=1.5, dist=4.0, target=[0.0, 0.0, 0.0])  # z = 0 nearly face-on


# --- strokes in pixels (the page's canvas), deterministic --------------------------------------
def _ring(cx, cy, rx, ry, turn, n, start=0.0, sweep=2 * math.pi):
    t = start + sweep * np.arange(n + 1) / n
    x, y = rx * np.cos(t), ry * np.sin(t)
    c, s = math.cos(turn), math.sin(turn)
    return np.stack([cx + c * x - s * y, cy + s * x + c * y], 1)


def _path(vertices, per_edge=16):
    v = np.asarray(vertices, float)
    pieces = [v[i] + np.linspace(0, 1, per_edge, endpoint=False)[:, None] * (v[i + 1] - v[i]) for i in range(len(v) - 1)]
    return np.concatenate([*pieces, v[-1:]])


def _polygon(vertices, per_edge=16):
    return _path([*vertices, vertices[0]], per_edge)


STROKES = {
    "line": _path([(220, 420), (520, 260)], 40),
    "circle": _ring(400, 300, 110, 110, 0.0, 64, sweep=2 * math.pi + 0.2),
    "ellipse": _ring(400, 300, 150, 70, 0.3, 72, sweep=2 * math.pi + 0.15),
    "arc": _ring(400, 330, 120, 120, 0.0, 48, start=0.2, sweep=2.4),
    "triangle": _polygon([(280, 420), (520, 420), (400, 200)]),
    "square": _polygon([(300, 200), (500, 200), (500, 400), (300, 400)]),
    "rectangle": _polygon([(250, 230), (560, 230), (560, 380), (250, 380)]),
    "diamond": _polygon([(400, 170), (480, 300), (400, 430), (320, 300)]),
    "polyline": _path([(220, 400), (330, 200), (450, 400), (570, 200)]),
    "spline": np.stack([np.linspace(200, 600, 60), 300 + 80 * np.sin(np.linspace(0, 1.6 * math.pi, 60))], 1),
}
VERTICES = {"triangle", "square", "rectangle", "diamond", "polyline"}  # the pen slows at corners


def _camera(data):
    eye, target, up = (np.asarray(data[k], np.float64) for k in ("eye", "target", "up"))
    return sketch.Camera(eye, target, up, fov=data["fov"], aspect=data["aspect"])


def _on_plane(command):
    """The pipeline from Python: the page's window points unprojected onto z = 0 (eqs. 5-1/5-2)."""
    pts = sketch.unproject(np.asarray(command["window"]), _camera(command["camera"]), Plane([0.0, 0, 0], [0.0, 0, 1]))
    return np.asarray(pts)


def _ctrl(spline):
    return np.asarray(spline["ctrl"], dtype=np.float64)


def _same_spline(got: dict, want, tol=1e-12):
    ref = io.to_dict(want)
    for key in ref:
        if key in ("ctrl", "knots", "knots_u", "knots_v", "weights"):
            if ref[key] is None:
                assert got[key] is None, key
            else:
                np.testing.assert_allclose(np.asarray(got[key]), np.asarray(ref[key]), rtol=0, atol=tol, err_msg=key)
        else:
            assert got[key] == ref[key], key


# --- the page ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        pytest.skip("no system Chromium")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM)
        yield b
        b.close()


@pytest.fixture(scope="module")
def studio_page(browser, tmp_path_factory):
    folder = tmp_path_factory.mktemp("studio")
    session = Studio(folder, samples=(16, 16))
    with ViewServer(session.scene, None, handle=session.handle, page="studio.html") as server:
        page = browser.new_page(viewport={"width": W, "height": H})
        page.goto(server.url)
        page.wait_for_function("window.bsjax.connected && window.bsjaxStudio.scene !== null", timeout=20000)
        page.evaluate(f"window.bsjaxCamera.set({json.dumps(TOP)})")
        yield page, session, folder
        page.close()


def _draw(page, pixels, corners=False):
    """One synthesised mouse stroke; returns the page's reply and the command it sent."""
    before = page.evaluate("window.bsjaxStudio.replies.length + window.bsjaxStudio.errors.length")
    pts = np.round(pixels).astype(int)
    page.mouse.move(int(pts[0, 0]), int(pts[0, 1]))
    page.mouse.down()
    turns = _turns(pts) if corners else set()
    for i, (x, y) in enumerate(pts[1:], 1):
        if i in turns:
            page.wait_for_timeout(40)  # a pen slows down at a corner
        page.mouse.move(int(x), int(y))
    page.mouse.up()
    page.wait_for_function(
        f"window.bsjaxStudio.replies.length + window.bsjaxStudio.errors.length > {before}", timeout=20000
    )
    reply = page.evaluate("window.bsjaxStudio.replies.concat(window.bsjaxStudio.errors).at(-1)")
    return reply, page.evaluate("window.bsjaxStudio.lastCommand")


def _turns(pts):
    d = np.diff(pts, axis=0).astype(float)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    ang = np.abs(np.arctan2(cross, np.einsum("ij,ij->i", d[:-1], d[1:])))
    return {i + 1 for i in np.flatnonzero(ang > 0.3)}


def _send(page, command):
    return page.evaluate(f"window.bsjaxStudio.send({json.dumps(command)})")


@needs_browser
def test_every_primitive_drawn_with_the_mouse_is_recognised_as_from_python(studio_page):
    page, session, _ = studio_page
    _send(page, {"cmd": "clear"})
    page.uncheck("#timed")  # headless Chromium's event times jitter by a frame: the shape alone
    for kind, pixels in STROKES.items():
        reply, command = _draw(page, pixels, corners=kind in VERTICES)
        assert reply["type"] == "update", reply
        px = np.round(pixels)
        np.testing.assert_allclose(command["window"], np.stack([px[:, 0] / W, 1 - px[:, 1] / H], 1), atol=1e-12)
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
                "(p) => { const v = window.bsjaxView, b = v.basis(); return p.map((q) => v.project(b, q, [0,0,0,0]).slice(0, 2)); }",
                stroke[::8].tolist(),
            )
            np.testing.assert_allclose(back, px[::8], atol=0.01)
    assert [i["kind"] for i in session.scene()["items"]] == list(STROKES)
    page.check("#timed")


def _rows(page, *ids):
    for i in ids:
        page.click(f"#list div[data-id='{i}']")


def _last_reply(page):
    page.wait_for_function("window.bsjaxStudio.pending() === 0", timeout=30000)
    return page.evaluate("window.bsjaxStudio.replies.concat(window.bsjaxStudio.errors).sort((a, b) => a.seq - b.seq).at(-1)")


@needs_browser
def test_a_composite_drag_and_save_load_from_the_page_equal_python(studio_page):
    page, session, folder = studio_page
    _send(page, {"cmd": "clear"})
    assert page.is_checked("#timed")
    circle, circle_cmd = _draw(page, _ring(330, 320, 100, 100, 0.0, 64, sweep=2 * math.pi + 0.2))
    line, line_cmd = _draw(page, _path([(520, 400), (520, 220)], 30))
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
    for step in range(1, 5):
        page.mouse.move(xy[0] + 3 * step, xy[1] - 10 * step)
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
    DOCS.mkdir(exist_ok=True)
    page.screenshot(path=str(DOCS / "studio.png"))

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
