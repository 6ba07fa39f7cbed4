"""Issue 33, item 7: the page says "Link lost" only when the server says the skin's link is lost.

Headless Chromium on the simulated skin. A busy server (a frame handler that stalls the
reader for two seconds now and then) during fast mouse strokes: the tab hears no frame for
a while but the server counts no link loss, and the page must not say "Link lost" either. A
real link drop (the server counts it) followed by a server busy for seconds: the page goes on
saying "Link lost", never that the app is not answering.
"""

from __future__ import annotations

import threading
import time

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.errors import FrameTimeoutError  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import ms, open_browser, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402
from tests.app.test_app_whole_flow import DRAG_LINE, SETTLED, STROKE  # noqa: E402

# Counts, on the page, every time the page showed the skin's link as lost, and every time it
# said that the app itself is not answering.
WATCH_LINK = """() => {
  window.__lost = 0; window.__silent = 0;
  const seen = () => {
    const pill = document.querySelector('#pill-device').textContent;
    const lost = document.body.classList.contains('link-lost');
    if (lost && pill.includes('link lost')) window.__lost++;
    if (!document.querySelector('#offline').classList.contains('hidden')) window.__silent++;
  };
  const o = new MutationObserver(seen);
  o.observe(document.body, {attributes: true, subtree: true, childList: true,
                            characterData: true});
}"""


def _open_calibrate(page, url: str, wait_state) -> None:
    page.goto(url)
    page.wait_for_function("() => window.skinloc.state !== null")
    page.click("#nav button[data-page=calibrate]")
    wait_state("s.device && s.device.rate_hz > 0 && s.session")
    page.wait_for_function(
        "() => document.querySelector('#pill-device').textContent.includes('Hz')"
    )
    page.wait_for_function(SETTLED)


def _state_waiter(page):
    def wait_state(expr: str, timeout: float = 60_000) -> None:
        page.wait_for_function(
            f"() => {{ const s = window.skinloc.state; return !!({expr}); }}", timeout=ms(timeout)
        )

    return wait_state


@pytest.mark.slow  # Chromium
def test_a_busy_server_during_fast_strokes_is_not_a_lost_link(chromium, server):
    """The reader thread stalls 2 s now and then (a handler busy on a loaded machine) while
    the mouse strokes the skin fast: no frame reaches the tab for over a second, yet the skin
    streams and the server counts no loss; the page never says "Link lost"."""
    url, app = server
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim"))
    ws.create_session("busy", n_points=8, samples=10, baseline_frames=20)
    busy = threading.Event()
    stalls = []
    keep_recent = ws.keep_recent

    def slow_keep_recent(frame):
        # Called for every frame on the reader thread, under the workspace's lock.
        if busy.is_set() and frame.index % 200 == 0:
            stalls.append(frame.index)
            time.sleep(2.0)
        return keep_recent(frame)

    ws.keep_recent = slow_keep_recent
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        wait_state = _state_waiter(page)
        _open_calibrate(page, url, wait_state)
        line = page.evaluate(DRAG_LINE)
        assert line is not None, "no stroke fits on the skin in the view"
        ax, ay, bx, by, _ = line
        page.evaluate(WATCH_LINK)
        busy.set()
        deadline = time.monotonic() + 60
        k = 0
        while len(stalls) < 4 and time.monotonic() < deadline:
            ends = [ax, ay, bx, by] if k % 2 == 0 else [bx, by, ax, ay]
            page.evaluate(STROKE, [*ends, 300])
            page.wait_for_timeout(200)
            k += 1
        busy.clear()
        page.wait_for_timeout(1500)  # a late verdict would show by now
        assert len(stalls) >= 4, "the server never stalled"
        assert ws.device.link_losses == 0  # the server saw the skin streaming throughout
        said = page.evaluate("[window.__lost, window.__silent]")
        assert said == [0, 0], (
            f"the page said 'link lost' {said[0]} and 'not answering' "
            f"{said[1]} times while the server counted no loss"
        )
        assert "Hz" in page.inner_text("#pill-device")
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # Chromium
def test_a_busy_server_after_a_real_link_drop_still_says_link_lost(chromium, server):
    """The skin stops sending (the server counts a loss), then the server's event loop is busy
    for 3.5 s (no heartbeat meanwhile, as on a loaded machine). The page goes on saying "Link
    lost" and never takes the busy app for a silent one ("not answering: reconnecting")."""
    url, app = server
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim"))
    ws.create_session("drop", n_points=8, samples=10, baseline_frames=20)
    source = ws.device.source
    read = source.read
    quiet = threading.Event()

    def gated_read(timeout_s=None):
        if quiet.is_set():  # the skin sends nothing: the reader's wait runs out
            time.sleep(timeout_s or 0.2)
            raise FrameTimeoutError("no frame (test: the skin is silent)")
        return read(timeout_s)

    source.read = gated_read
    link_status = ws.link_status
    stall = threading.Event()

    def slow_link_status():
        # Runs on the server's event loop (the heartbeat): blocking it blocks every message.
        if stall.is_set():
            stall.clear()
            time.sleep(3.5)
        return link_status()

    ws.link_status = slow_link_status
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        wait_state = _state_waiter(page)
        _open_calibrate(page, url, wait_state)
        page.evaluate(WATCH_LINK)
        quiet.set()
        _wait(lambda: ws.device.link_losses == 1, "the server to count the loss", 60)
        panel = page.locator('.guided[data-kind="calibrate"] .big-state')
        sync_api.expect(panel).to_contain_text("Link lost", timeout=ms(30_000))
        stall.set()
        _wait(lambda: not stall.is_set(), "the server to be busy", 30)
        page.wait_for_timeout(4500)  # the busy spell and a second after it
        assert page.evaluate("window.__silent") == 0, "the page took a busy app for a silent one"
        assert "Link lost" in panel.inner_text()
        quiet.clear()
        page.wait_for_selector("#linklost", state="hidden", timeout=ms(30_000))
        assert "Hz" in page.inner_text("#pill-device")
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
