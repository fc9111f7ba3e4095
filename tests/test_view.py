"""The live view (`bsjax.view`, `bsjax view`, `bsjax haptics --view`), in a real headless browser.

The browser is the system Chromium (Debian's `chromium-headless-shell` or `chromium`), driven
by Playwright without any browser download; the tests that need it are skipped when neither is
installed (`make test` installs it).
"""

import io
import json
import math
import time
import urllib.error
import urllib.request

import numpy as np
import pytest

from bsjax.cli import view as view_cli
from bsjax.device import Proxy, Recording, ServoLoop, SimulatedDevice, Workspace
from bsjax.view import SurfaceMesh, ViewServer, from_file, live
from bsjax.view._server import dumps
from tests.helpers import needs_browser, random_surface

WALL = dict(point=(0.5, 0.5, 0.1), normal=(0.0, 0.0, 1.0), stiffness=30.0, damping=0.3, tool_radius=0.1)


class Breathing:
    """Pure-Python physics for the view: a surface whose control net rises and falls, a wall."""

    def __init__(self):
        self.surface0 = random_surface(np.random.default_rng(0), 6, 5)
        self.ctrl = np.asarray(self.surface0.ctrl)
        self.ticks = 0
        self.tool_radius = 0.1

    def update(self, sample):
        self.ticks += 1
        lift = np.zeros_like(self.ctrl)
        lift[..., 2] = 0.1 * math.sin(self.ticks / 5.0)
        self.ctrl = np.asarray(self.surface0.ctrl) + lift
        return Proxy.plane(**WALL)


def circling(t):
    """The stylus circling over the surface, dipping into the wall (model units)."""
    return (0.5 + 0.3 * math.cos(2 * t), 0.5 + 0.3 * math.sin(2 * t), 0.15 + 0.1 * math.sin(5 * t)), 0


def pixels(png: bytes) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(io.BytesIO(png), format="png")[..., :3]


def frames_per_second(page, seconds=3.0) -> float:
    f0, t0 = page.evaluate("window.bsjax.frames"), time.perf_counter()
    time.sleep(seconds)
    f1, t1 = page.evaluate("window.bsjax.frames"), time.perf_counter()
    return (f1 - f0) / (t1 - t0)


@needs_browser
def test_live_view_streams_draws_and_reconnects(browser, tmp_path):
    empty = ViewServer(lambda: {"title": "", "surface": None, "tool_radius": 0.0, "replay": None})
    model = Breathing()
    device = SimulatedDevice(circling, workspace=Workspace())
    loop = ServoLoop(device, model, physics_hz=100, proxy_timeout=0.2, mode="thread")
    scene, frame = live(loop, model, title="test session")
    with empty, loop, ViewServer(scene, frame) as server:
        page = browser.new_page(viewport={"width": 640, "height": 480})
        page.goto(empty.url)
        page.wait_for_function("window.bsjax.scenes > 0 && window.bsjax.drawn > 0", timeout=20000)
        blank = pixels(page.screenshot())
        page.goto(server.url)
        page.wait_for_function("window.bsjax.frames > 5", timeout=20000)
        fps = frames_per_second(page, 3.0)
        assert fps >= 30.0, fps
        page.wait_for_function("window.bsjax.drawn > 2")
        shot = pixels(page.screenshot())
        changed = np.any(np.abs(shot - blank) > 0.1, axis=-1).mean()
        assert changed > 0.02, changed  # the surface and the tool cover part of the view
        last = page.evaluate("window.bsjax.lastFrame")
        assert last["mode"] == "thread" and last["ticks"] > 0 and len(last["tool"]) == 3
        assert "servo" in page.inner_text("#panel") and "frames/s" in page.inner_text("#panel")
        page.reload()  # a reload: the page connects again and frames flow again
        page.wait_for_function("window.bsjax.connected && window.bsjax.frames > 10", timeout=20000)
        assert frames_per_second(page, 1.0) >= 30.0
        page.close()
    assert server.frames_sent > 100


@needs_browser
def test_orbit_and_zoom_change_the_picture(browser, tmp_path):
    path = tmp_path / "surface.json"
    from bsjax import io as bio

    bio.save(random_surface(np.random.default_rng(1), 5, 4), path)
    scene, frame = from_file(path)
    with ViewServer(scene, frame) as server:
        page = browser.new_page(viewport={"width": 400, "height": 300})
        page.goto(server.url)
        page.wait_for_function("window.bsjax.scenes > 0 && window.bsjax.drawn > 0", timeout=20000)
        before = pixels(page.screenshot())
        page.mouse.move(200, 150)
        page.mouse.down()
        page.mouse.move(300, 180, steps=5)
        page.mouse.up()
        page.wait_for_timeout(200)
        orbited = pixels(page.screenshot())
        page.mouse.wheel(0, -600)
        page.wait_for_timeout(200)
        zoomed = pixels(page.screenshot())
        page.close()
    assert np.any(np.abs(orbited - before) > 0.1, axis=-1).mean() > 0.01
    assert np.any(np.abs(zoomed - orbited) > 0.1, axis=-1).mean() > 0.01


@needs_browser
def test_replay_plays_with_a_time_slider(browser, tmp_path):
    t = np.linspace(0.0, 2.0, 2001)
    pos = np.stack([0.5 + 0.3 * np.cos(3 * t), 0.5 + 0.3 * np.sin(3 * t), 0.1 + 0 * t], axis=1)
    force = np.stack([0 * t, 0 * t, 2.0 * (t > 1.0)], axis=1)
    rec = Recording(
        time=t,
        sequence=np.arange(len(t)),
        position=pos,
        orientation=np.tile([1.0, 0, 0, 0], (len(t), 1)),
        buttons=np.zeros(len(t), np.int64),
        device_time=t,
        force=force,
    )
    path = tmp_path / "session.npz"
    rec.save(path)
    scene, frame = from_file(path, tool_radius=0.05)
    replay = scene()["replay"]
    assert len(replay["time"]) == 201  # 100 Hz over 2 s
    with ViewServer(scene, frame) as server:
        page = browser.new_page(viewport={"width": 400, "height": 300})
        page.goto(server.url)
        page.wait_for_function("window.bsjax.scenes > 0 && window.bsjax.drawn > 0", timeout=20000)
        assert page.is_visible("#slider")
        page.evaluate("window.bsjaxReplay.setIndex(0)")
        start = pixels(page.screenshot())
        page.fill("#slider", "150")  # drag the slider to t = 1.5 s: tool moved, force drawn
        page.wait_for_timeout(200)
        later = pixels(page.screenshot())
        assert "1.50 s" in page.inner_text("#clock")
        assert "|F| 2.000 N" in page.inner_text("#panel")
        page.evaluate("window.bsjaxReplay.setIndex(0)")
        page.click("#play")
        page.wait_for_function("Number(document.getElementById('slider').value) > 20", timeout=10000)
        page.close()
    assert np.any(np.abs(later - start) > 0.1, axis=-1).mean() > 0.001


def test_static_files_only_from_the_package():
    with ViewServer(lambda: {"title": "", "surface": None, "tool_radius": 0.0, "replay": None}) as server:
        page = urllib.request.urlopen(server.url, timeout=10).read().decode()
        assert "<canvas" in page and "view.js" in page
        script = urllib.request.urlopen(server.url + "view.js", timeout=10).read().decode()
        assert "new WebSocket" in script
        for bad in ("..%2F__init__.py", "nothing.js", ".hidden"):
            with pytest.raises(urllib.error.HTTPError) as err:
                urllib.request.urlopen(server.url + bad, timeout=10)
            assert err.value.code == 404
    assert "://" not in script.replace("ws://${location.host}", "")  # offline: no external URL


def test_surface_mesh_matches_the_surface_and_json_is_finite():
    s = random_surface(np.random.default_rng(2), 6, 5)
    mesh = SurfaceMesh(s, 7, 9)
    ref = np.asarray(s.blending(7, 9).points(s.ctrl))
    np.testing.assert_allclose(mesh.points(s.ctrl), ref, atol=1e-12)
    assert json.loads(dumps({"a": [1.0, math.nan, math.inf]})) == {"a": [1.0, None, None]}


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(scene=None), "scene: expected a callable"),
        (dict(frame=3), "frame: expected a callable or None"),
        (dict(port=70000), r"port: expected an int in \[0, 65535\], got 70000"),
        (dict(rate_hz=0.0), r"rate_hz: expected a rate in \(0, 1000\] Hz, got 0.0"),
        (dict(rate_hz=math.nan), "rate_hz"),
    ],
)
def test_view_server_arguments_are_checked(kwargs, match):
    args = dict(scene=lambda: {}) | kwargs
    with pytest.raises((TypeError, ValueError), match=match):
        ViewServer(**args)


def test_view_cli_errors(tmp_path, capsys):
    bad = tmp_path / "notes.txt"
    bad.write_text("x")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    cases = [
        ([str(tmp_path / "missing.json")], "missing.json: no such file"),
        ([str(bad)], "expected a .json"),
        ([str(junk)], "junk.npz: cannot read haptics recording"),
        ([str(junk), "--duration", "-1"], "--duration"),
    ]
    for argv, needle in cases:
        assert view_cli.main(argv) == 2
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_view_cli_serves_a_file_for_its_duration(tmp_path, capsys):
    from bsjax import io as bio

    path = tmp_path / "surface.json"
    bio.save(random_surface(np.random.default_rng(3), 4, 4), path)
    assert view_cli.main([str(path), "--duration", "0.3"]) == 0
    assert "bsjax view: http://127.0.0.1:" in capsys.readouterr().out


def test_haptics_cli_view_port_is_checked(capsys):
    from bsjax.cli import haptics

    assert haptics.main(["--proxy-only", "--view", "--port", "70000"]) == 2
    err = capsys.readouterr().err
    assert "--port: expected a port in [0, 65535], got 70000" in err and "Traceback" not in err


def test_haptics_cli_serves_the_view_with_the_servo_in_its_own_process(capsys):
    from bsjax.cli import haptics

    assert haptics.main(["--proxy-only", "--servo-process", "--view", "--duration", "0.5"]) == 0
    out, err = capsys.readouterr()  # progress on stderr, the servo's statistics (the result) on stdout
    assert "servo process" in err and "live view at http://127.0.0.1:" in err and "zero force written" in err
    assert out.startswith("servo ") and ("SCHED_FIFO" in out or "normal priority" in out)
