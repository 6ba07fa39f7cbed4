"""End to end in a real browser: headless Chromium driven by Playwright through a whole session.

Connect the simulated skin, create a session, calibrate 10 targets with the scripted finger,
train, validate, see a live point while the mouse touches the skin, and be told in a second tab
that the skin is busy. Screenshots go to
``build/test-artifacts/app/`` (or ``$SKINLOC_ARTIFACTS``). The test skips, saying why, where
Playwright or a Chromium (Debian's ``chromium``, which ``make test`` installs) is missing.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
uvicorn = pytest.importorskip("uvicorn")

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("SKINLOC_ARTIFACTS", ROOT / "build" / "test-artifacts" / "app"))
#: Calibration targets; docs/app.md's screenshots use SKINLOC_APP_POINTS=40.
N_POINTS = int(os.environ.get("SKINLOC_APP_POINTS", "10"))
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    # WebGL without a GPU.
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]


#: Why scripts/ensure-chromium.sh (make test) could not install Chromium, when it could not.
CHROMIUM_STATUS = ROOT / "build" / "chromium-status.txt"


def find_chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    why = "run 'sh scripts/ensure-chromium.sh' (make test does) or apt-get install chromium"
    if CHROMIUM_STATUS.is_file():
        why = CHROMIUM_STATUS.read_text().strip() or why
    pytest.skip(f"no Chromium (chromium, chromium-browser, google-chrome) on PATH: {why}")


@pytest.fixture
def server(tmp_path):
    """The app on a free loopback port, served by uvicorn on a thread."""
    # Bind here and hand uvicorn the socket: no window for another process to take the port.
    sock = socket.create_server(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    config = AppConfig(data_dir=tmp_path / "sessions", finger_delay_s=0.15)
    app = create_app(config)
    srv = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws="websockets-sansio"))
    thread = threading.Thread(target=srv.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 120
    while not srv.started:
        if time.monotonic() > deadline or not thread.is_alive():
            pytest.fail("the app server did not start")
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}/", app
    srv.should_exit = True
    thread.join(timeout=30)
    sock.close()


@pytest.fixture
def chromium() -> str:
    """The Chromium binary (looked up before the server starts, to skip early)."""
    return find_chromium()


def test_full_session_in_the_browser(chromium, server):
    url, app = server
    # Generous limits: a loaded 2-core machine renders WebGL in software.
    sync_api.expect.set_options(timeout=60_000)
    expect = sync_api.expect
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.set_default_timeout(60_000)

        def shot(name: str) -> None:
            page.screenshot(path=str(ARTIFACTS / f"{name}.png"))

        def wait_state(js: str, timeout_ms: int = 60_000) -> None:
            page.wait_for_function(
                f"() => {{ const s = window.skinloc.state; return !!s && ({js}); }}",
                timeout=timeout_ms,
            )

        page.goto(url)
        page.wait_for_selector("#page-sessions.active")

        # Connect the simulated skin and watch its sensor image.
        page.click("#nav button[data-page=connect]")
        page.click("#connect-btn")
        wait_state("s.device && s.device.rate_hz > 0")
        page.wait_for_function("() => window.skinloc.sensors !== null")
        shot("02-connect")

        # A new session of 10 targets.
        page.click("#nav button[data-page=sessions]")
        page.fill("#new-session [name=name]", "browser test")
        page.fill("#new-session [name=n_points]", str(N_POINTS))
        page.fill("#new-session [name=samples]", "20")
        page.fill("#new-session [name=baseline_frames]", "30")
        page.fill("#new-session [name=n_validation]", "5")
        page.click("#new-session button[type=submit]")
        page.wait_for_selector("#page-calibrate.active")

        # Calibrate: the first target waits for a touch; then the scripted finger does them all.
        panel = page.locator('.guided[data-kind="calibrate"]')
        panel.locator(".start").click()
        wait_state("s.mode === 'calibrate' && s.guided.phase === 'wait_touch'")
        expect(panel.locator(".big-state")).to_contain_text("Touch the red target")
        page.wait_for_timeout(1200)  # the view turns towards the target (for the picture only)
        shot("03-calibrate")
        panel.locator(".finger").check()
        wait_state("s.message === 'calibration complete'", timeout_ms=180_000)
        page.wait_for_function(
            "() => window.skinloc.session && "
            f"window.skinloc.session.calibration.done.length === {N_POINTS}"
        )
        expect(panel.locator(".count")).to_contain_text(f"{N_POINTS} of {N_POINTS}")
        shot("03b-calibrated")

        # Train.
        page.click("#nav button[data-page=train]")
        page.click("#train-btn")
        page.wait_for_selector("#train-result .result", timeout=180_000)
        expect(page.locator("#train-result")).to_contain_text("mm")
        shot("04-train")

        # Validate on 5 fresh touches.
        page.click("#nav button[data-page=validate]")
        vpanel = page.locator('.guided[data-kind="validate"]')
        vpanel.locator(".n-val").fill("5")
        vpanel.locator(".start").click()
        wait_state("s.session && s.session.validation && s.session.validation.n === 5", 180_000)
        vpanel.locator(".val-result .result").wait_for()
        shot("05-validate")

        # Live: press on the skin with the mouse, see the predicted point.
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        wait_state("s.mode === 'live'")
        page.check("#mouse-touch")
        box = page.locator("#viewer canvas").bounding_box()
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        page.wait_for_function(
            "() => document.querySelector('#live-state').textContent === 'touched'"
        )
        expect(page.locator("#live-point")).not_to_have_text("-")
        page.wait_for_function(
            "() => !['', '0px'].includes(document.querySelector('#live-conf').style.width)"
        )
        page.wait_for_timeout(500)  # let a short trail build up (for the picture only)
        shot("06-live")
        page.mouse.up()
        page.wait_for_function(
            "() => document.querySelector('#live-state').textContent === 'not touched'"
        )

        # A second tab may watch but is told the skin is busy when it tries to change anything.
        other = browser.new_page(viewport={"width": 1440, "height": 900})
        other.set_default_timeout(60_000)
        other.goto(url)
        other.click("#nav button[data-page=connect]")
        other.click("#rezero")
        other.wait_for_selector("#busy:not(.hidden)")
        expect(other.locator("#busy")).to_contain_text("in use in another tab")
        other.screenshot(path=str(ARTIFACTS / "07-second-tab-busy.png"))
        other.close()

        # The first page lists the session with its results.
        page.click("#nav button[data-page=sessions]")
        page.wait_for_selector("#session-list td:has-text('browser test')")
        shot("01-sessions")
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
    ws = app.state.workspace
    assert ws.active is not None and ws.active.model is not None
