"""Issue 22, section 3: a readable 3D view, in a real browser (headless Chromium).

The numbers never overlap and the current target's is always shown; the axes and the scale sit
in a corner inset; the camera faces the current target along the skin's normal; presets,
toggles and the keyboard help work; at 800 x 900 the target and the capture feedback are on
one screen; a mouse drag on the simulated skin moves its finger along the drag. Screenshots of
the view at 1440 and 800 px go to ``build/test-artifacts/app/`` (docs/app.md shows them).
"""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")

from tests.app._app import ARTIFACTS, ms, open_browser, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

# Every shown number's box on the page, and the view's own boxes.
LABEL_BOXES = """() => [...document.querySelectorAll('.view-label:not(.hidden)')].map((e) => {
  const r = e.getBoundingClientRect();
  return {text: e.textContent, target: e.classList.contains('target'),
          x: r.left, y: r.top, w: r.width, h: r.height};
})"""
BOX = """(sel) => { const e = document.querySelector(sel); if (!e) return null;
  const r = e.getBoundingClientRect(); return {x: r.left, y: r.top, w: r.width, h: r.height}; }"""
# The current target on the page (px) and in the skin's frame (m).
TARGET_ON_PAGE = """() => { const v = window.skinloc.viewer, p = v.targetPoint;
  const r = v.renderer.domElement.getBoundingClientRect(), s = p.clone().project(v.camera);
  return [r.left + (s.x + 1) / 2 * r.width, r.top + (1 - s.y) / 2 * r.height,
          p.x / 1000, p.y / 1000, p.z / 1000]; }"""
# The view is still: no flight under way and the labels laid out for this camera.
SETTLED = """() => { const v = window.skinloc.viewer; return !v.fly && !v.dirty
  && v.labels.key !== '' && document.querySelectorAll('.view-label:not(.hidden)').length > 0; }"""


def _overlap(a: dict, b: dict) -> bool:
    return (
        a["x"] < b["x"] + b["w"]
        and b["x"] < a["x"] + a["w"]
        and a["y"] < b["y"] + b["h"]
        and b["y"] < a["y"] + a["h"]
    )


def _assert_readable(page, where: str) -> list[dict]:
    """No two numbers overlap, none covers the inset or the toolbar, the target's is there."""
    page.wait_for_function(SETTLED)
    boxes = page.evaluate(LABEL_BOXES)
    clash = [(a["text"], b["text"]) for a, b in itertools.combinations(boxes, 2) if _overlap(a, b)]
    assert not clash, f"{where}: numbers overlap: {clash}"
    for sel in (".view-inset", ".view-toolbar"):
        other = page.evaluate(BOX, sel)
        assert not [b["text"] for b in boxes if _overlap(b, other)], (
            f"{where}: a number covers {sel}"
        )
    assert [b for b in boxes if b["target"]], f"{where}: the current target's number is not shown"
    return boxes


def on_skin(page, box: dict, x: float, y: float) -> list[float] | None:
    """The skin's point (m) under page point (x, y) of the view's canvas ``box``, or None."""
    return page.evaluate(
        "([x, y]) => { const v = window.skinloc.viewer;"
        " v.raycaster.setFromCamera({ x, y }, v.camera);"
        " const h = v.raycaster.intersectObject(v.skin)[0];"
        " return h ? [h.point.x / 1000, h.point.y / 1000, h.point.z / 1000] : null; }",
        [2 * (x - box["x"]) / box["width"] - 1, 1 - 2 * (y - box["y"]) / box["height"]],
    )


def _session_waiting_at_a_target(ws, n_points: int, n_done: int) -> None:
    """A session of ``n_points`` targets, ``n_done`` touched by the scripted finger, the next
    one waiting for a touch."""
    from skinloc.sources.base import SourceOptions

    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=0))
    ws.create_session("view", n_points=n_points, samples=10, baseline_frames=20)
    ws.set_finger(True)
    ws.start_calibration()
    _wait(lambda: ws.active.cal.n_done >= n_done, f"{n_done} touches")
    ws.set_finger(False)
    ws.stop()
    ws.start_calibration()
    _wait(lambda: ws.capture is not None and ws.capture.phase.value == "wait_touch", "the prompt")


@pytest.mark.slow  # a session in Chromium
def test_the_3d_view_is_readable_at_1440_and_800(chromium, server):  # noqa: F811
    url, app = server
    ws = app.state.workspace
    _session_waiting_at_a_target(ws, n_points=40, n_done=12)
    index = ws.active.cal.n_done  # the current target, 0-based
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=calibrate]")
        page.wait_for_function(
            "() => window.skinloc.viewer.targetRing && window.skinloc.session"
            f" && window.skinloc.session.calibration.done.length === {index}"
        )
        boxes = _assert_readable(page, "1440 x 900")
        assert len(boxes) >= 15, boxes  # most numbers are shown, not hidden to avoid overlaps
        assert [b["text"] for b in boxes if b["target"]] == [str(index + 1)]
        # The target's number is beside its ring, not over it.
        centre = page.evaluate(TARGET_ON_PAGE)
        t = next(b for b in boxes if b["target"])
        assert not (
            t["x"] <= centre[0] <= t["x"] + t["w"] and t["y"] <= centre[1] <= t["y"] + t["h"]
        )
        # Face-on: the camera looks along the skin's normal at the target.
        facing = page.evaluate(
            "() => window.skinloc.viewer.viewDirection().dot(window.skinloc.viewer.targetNormal)"
        )
        assert facing > 0.98, facing
        # The axes and the scale are in a small corner inset, not in the scene.
        assert not page.evaluate(
            "() => { let n = 0; window.skinloc.viewer.scene.traverse((o) => {"
            " if (o.type === 'AxesHelper') n++; }); return n; }"
        )
        view, inset = page.evaluate(BOX, "#viewer"), page.evaluate(BOX, ".view-inset")
        assert inset["x"] - view["x"] < 30 and inset["y"] - view["y"] < 30
        assert inset["w"] * inset["h"] < 0.03 * view["w"] * view["h"]
        expect(page.locator(".view-scale")).to_contain_text(" mm")
        page.screenshot(path=str(ARTIFACTS / "13-view3d.png"))

        # Headless Chromium draws WebGL on the CPU (SwiftShader): a flight is drawn at most
        # 20 times a second there (13 draws in its 700 ms here; 20 with no cap, as fast as
        # the draws go).
        assert page.evaluate("() => window.skinloc.viewer.minFrameMs") == 50
        page.evaluate(
            "() => { const v = window.skinloc.viewer, draw = v.renderer.render.bind(v.renderer);"
            " v.nDraws = 0;"  # the main view's draws (the inset is drawn by the same renderer)
            " v.renderer.render = (s, c) => { if (s === v.scene) v.nDraws++; draw(s, c); }; }"
        )
        page.keyboard.press("3")  # a flight from the target to the side view
        page.wait_for_function(SETTLED)
        draws = page.evaluate("() => window.skinloc.viewer.nDraws")
        assert 1 <= draws <= 700 / 50 + 3, draws
        # Asked for less motion, the view jumps: no flight, one draw (two if a state came).
        page.emulate_media(reduced_motion="reduce")
        page.evaluate("() => { window.skinloc.viewer.nDraws = 0; }")
        page.keyboard.press("1")
        page.wait_for_function(SETTLED)
        assert 1 <= page.evaluate("() => window.skinloc.viewer.nDraws") <= 2
        page.emulate_media(reduced_motion="no-preference")
        # Presets turn the camera; the numbers stay apart from every side.
        for key, preset, axis in (("1", "top", 2), ("2", "front", 1), ("3", "side", 0)):
            page.keyboard.press(key)
            page.wait_for_function(SETTLED)
            d = page.evaluate("() => window.skinloc.viewer.viewDirection().toArray()")
            assert abs(d[axis]) > 0.95, (preset, d)
            _assert_readable(page, f"{preset} view")
        page.locator(".view-toolbar [data-view=target]").click()
        page.wait_for_function(
            "() => !window.skinloc.viewer.fly && window.skinloc.viewer.viewDirection()"
            ".dot(window.skinloc.viewer.targetNormal) > 0.98"
        )
        page.locator(".view-toolbar [data-view=reset]").click()
        page.wait_for_function(
            "() => !window.skinloc.viewer.fly && window.skinloc.viewer.viewDirection()"
            ".dot(window.skinloc.viewer.homeDir) > 0.99"
        )
        # Toggles: numbers (the target's stays) and the inset.
        page.keyboard.press("l")
        page.wait_for_function(
            "() => [...document.querySelectorAll('.view-label:not(.hidden)')]"
            ".every((e) => e.classList.contains('target'))"
        )
        page.keyboard.press("l")
        page.keyboard.press("a")
        expect(page.locator(".view-inset")).to_be_hidden()
        page.locator(".view-toolbar [data-toggle=axes]").check()
        expect(page.locator(".view-inset")).to_be_visible()
        # The keyboard help.
        page.keyboard.press("?")
        expect(page.locator(".view-help")).to_be_visible()
        for words in ("Space", "drag on the skin", "face the current target"):
            expect(page.locator(".view-help")).to_contain_text(words)
        page.keyboard.press("Escape")
        expect(page.locator(".view-help")).to_be_hidden()
        page.keyboard.press("t")
        _assert_readable(page, "1440 x 900, back at the target")

        # 800 x 900: the target, the prompt, the capture buttons, the heat map and the touch
        # list are all on the first screen, and the numbers still never overlap.
        page.set_viewport_size({"width": 800, "height": 900})
        page.wait_for_function("() => document.documentElement.scrollWidth <= 800")
        page.wait_for_function(SETTLED)
        page.keyboard.press("t")
        boxes = _assert_readable(page, "800 x 900")
        # The whole skin in the narrower view: the camera at the distance that fits it.
        fit = page.evaluate(
            "() => { const v = window.skinloc.viewer;"
            " return v.camera.position.distanceTo(v.controls.target) / v.fitDistance(); }"
        )
        assert fit == pytest.approx(1.0, abs=0.02), fit
        t = next(b for b in boxes if b["target"])
        assert 0 <= t["x"] and t["x"] + t["w"] <= 800 and 0 <= t["y"] and t["y"] + t["h"] <= 900
        panel = '.guided[data-kind="calibrate"]'
        for sel in (".big-state", ".now", ".undo", ".skip", ".guided-heat", ".touches tbody tr"):
            b = page.evaluate(BOX, f"{panel} {sel}")
            assert b and b["w"] > 0, sel
            assert b["y"] >= 0 and b["y"] + b["h"] <= 900 and b["x"] + b["w"] <= 800, (sel, b)
        expect(page.locator(f"{panel} .big-state")).to_contain_text("Touch the red target")
        page.screenshot(path=str(ARTIFACTS / "13b-view3d-800.png"))
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_dragging_on_the_skin_moves_the_simulated_finger(chromium, server):  # noqa: F811
    url, app = server
    ws = app.state.workspace
    from skinloc.sources.base import SourceOptions

    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=0))
    ws.create_session("drag", n_points=6, samples=10, baseline_frames=20)
    # What the page asks of the simulated skin: every point (m) or None (lifted), in order,
    # and the page's event times of the points.
    pressed: list[list[float] | None] = []
    times: list[float] = []
    lock = threading.Lock()
    real = ws.sim_path

    def record(path):
        with lock:
            for t, point in path:
                pressed.append(None if point is None else list(point))
                times.append(t)
        real(path)

    ws.sim_path = record
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=calibrate]")
        page.wait_for_function("() => window.skinloc.viewer.skin && !window.skinloc.viewer.fly")
        expect(page.locator("#mouse-touch")).to_be_checked()  # on by itself on the simulated skin
        box = page.locator("#viewer canvas").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        start, end = (cx - 60, cy + 20), (cx + 60, cy - 20)
        hits = [on_skin(page, box, *start), on_skin(page, box, *end)]
        assert all(hits), "the drag's ends are not on the skin"
        # the pointer events' own times (s, the page's clock), as the page sees them first
        page.evaluate(
            "() => { window.__drag = []; for (const type of"
            " ['pointerdown', 'pointermove', 'pointerup']) window.addEventListener(type,"
            " (e) => window.__drag.push([type, e.timeStamp / 1000]), { capture: true }); }"
        )
        page.mouse.move(*start)
        page.mouse.down()
        steps = 12
        for k in range(1, steps + 1):
            f = k / steps
            page.mouse.move(start[0] + f * (end[0] - start[0]), start[1] + f * (end[1] - start[1]))
        page.mouse.up()
        _wait(lambda: pressed and pressed[-1] is None, "the finger lifted")
        with lock:
            points = [p for p in pressed if p is not None]
        assert len(points) >= 3, pressed
        a, b = np.array(hits[0]), np.array(hits[1])
        along = [float(np.dot(np.array(p) - a, b - a) / np.dot(b - a, b - a)) for p in points]
        assert along[0] == pytest.approx(0.0, abs=0.02), along
        assert along[-1] == pytest.approx(1.0, abs=0.02), along
        assert all(y >= x - 0.02 for x, y in itertools.pairwise(along)), along  # forward only
        assert pressed.count(None) == 1  # one lift, at the end
        # the path keeps the mouse's pace: each point carries its pointer event's own time,
        # from the press to the release (not the time the page got round to sending it)
        events = page.evaluate("() => window.__drag")
        down = next(t for kind, t in events if kind == "pointerdown")
        up = next(t for kind, t in events if kind == "pointerup")
        moved = [t for kind, t in events if kind == "pointermove" and down <= t <= up]
        assert len(times) == len(pressed) and len(moved) >= steps
        assert times[0] == pytest.approx(down, abs=1e-9)
        assert times[-1] == pytest.approx(up, abs=1e-9)
        for t in times[1:-1]:
            assert min(abs(t - m) for m in moved) < 1e-9, (t, moved)
        assert all(b >= a for a, b in itertools.pairwise(times)) and times[-1] > times[0]

        # A drag off the skin turns the view and touches nothing.
        n = len(pressed)
        corner = (box["x"] + 20, box["y"] + box["height"] - 60)
        assert on_skin(page, box, *corner) is None
        before = page.evaluate("() => window.skinloc.viewer.camera.position.toArray()")
        page.mouse.move(*corner)
        page.mouse.down()
        page.mouse.move(corner[0] + 120, corner[1] - 30, steps=6)
        page.mouse.up()
        page.wait_for_function(
            "(b) => { const p = window.skinloc.viewer.camera.position;"
            " return Math.hypot(p.x - b[0], p.y - b[1], p.z - b[2]) > 5; }",
            arg=before,
        )
        assert len(pressed) == n

        # With a target waiting, a press a few pixels beside it lands on it.
        ws.start_calibration()
        _wait(lambda: ws.capture is not None and ws.capture.phase.value == "wait_touch", "prompt")
        page.wait_for_function(
            "() => window.skinloc.viewer.targetPoint && !window.skinloc.viewer.fly"
        )
        at = page.evaluate(TARGET_ON_PAGE)
        page.mouse.move(at[0] + 7, at[1] - 5)
        page.mouse.down()
        _wait(lambda: len(pressed) > n, "the press")
        page.mouse.up()
        assert np.allclose(pressed[n], at[2:], atol=1e-5), (pressed[n], at[2:])
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_a_mouse_drag_on_the_live_page_is_tracked(chromium, server):  # noqa: F811
    """Trails and tracking without hardware: a mouse drag across the simulated skin on the Live
    page is followed by the live pipeline, its track's trail running along the drag. (Whether a
    stroke is also a swipe depends on its speed, which a loaded machine does not keep.)"""
    url, app = server
    ws = app.state.workspace
    from skinloc.sources.base import SourceOptions
    from tests.app.test_app_browser import _calibrate

    ws.connect(SourceOptions(source="sim", seed=0))
    # Enough targets for a model whose points follow the finger steadily (~10 mm).
    ws.create_session("drag", n_points=24, samples=10, baseline_frames=20)
    _calibrate(ws)
    ws.set_finger(False)
    ws.train()
    _wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
    assert ws.active.model is not None
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        page.wait_for_function(
            "() => document.querySelector('#live-state').textContent === 'not touched'"
        )
        page.wait_for_function("() => window.skinloc.viewer.skin && !window.skinloc.viewer.fly")
        box = page.locator("#viewer canvas").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        start, end = (cx - 150, cy), (cx + 150, cy)
        a, b = np.array(on_skin(page, box, *start)), np.array(on_skin(page, box, *end))
        # The live finger's dot, as a fraction of the way from the drag's start to its end.
        dots = (
            "() => window.skinloc.viewer.marks.filter((m) => m.live && m.dot.visible)"
            ".map((m) => m.dot.position.toArray())"
        )

        def along() -> list[float]:
            ab = b - a
            return [
                float(np.dot(np.array(p) / 1000 - a, ab) / np.dot(ab, ab))
                for p in page.evaluate(dots)
            ]

        page.mouse.move(*start)
        page.mouse.down()
        _wait(lambda: any(f < 0.35 for f in along()), "the finger at the drag's start", 120)
        page.mouse.move(*end, steps=25)
        # The finger rests at the end of the drag: its track follows it there.
        _wait(lambda: any(f > 0.65 for f in along()), "the finger at the drag's end", 120)
        page.wait_for_function("() => window.skinloc.viewer.marks.some((m) => m.live && m.n > 5)")
        page.mouse.up()
        page.wait_for_function(
            "() => document.querySelector('#live-state').textContent === 'not touched'"
        )
        page.click("#live-stop")
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
