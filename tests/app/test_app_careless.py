"""Careless use in a real browser (issue 33, item 7): what a hurried researcher does.

A double click on *Create and open*, a reload in the middle of a capture, *Disconnect* while
touches are being taken: each does what the researcher meant and says what happened.
"""

from __future__ import annotations

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import ms, open_browser, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402


def test_double_click_reload_and_disconnect_mid_capture(chromium, server):
    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)

        # A double click on "Create and open" makes one session, not two.
        page.fill("#new-session [name=name]", "hurried")
        page.fill("#new-session [name=n_points]", "20")
        page.fill("#new-session [name=samples]", "10")
        page.fill("#new-session [name=baseline_frames]", "20")
        page.dblclick("#new-session button[type=submit]")
        page.wait_for_selector("#page-calibrate.active")
        _wait(lambda: ws.active is not None, "the session")
        sessions = ws.sessions()["sessions"]
        assert [s["name"] for s in sessions].count("hurried") == 1, sessions

        # A reload in the middle of the capture comes back on the Calibrate page.
        panel = page.locator('.guided[data-kind="calibrate"]')
        panel.locator(".start").click()
        page.wait_for_function(
            "() => window.skinloc.state && window.skinloc.state.mode === 'calibrate'"
        )
        page.reload()
        page.wait_for_selector("#page-calibrate.active")
        assert page.locator("#nav button.active").get_attribute("data-page") == "calibrate"

        # Disconnect with touches taken: the capture pauses, and the page says what was kept.
        ws.set_finger(True)
        _wait(lambda: ws.active.cal.n_done >= 2, "two touches")
        ws.set_finger(False)  # the capture waits for the next touch
        page.click("#nav button[data-page=connect]")
        page.click("#disconnect-btn")
        expect(page.locator("#message")).to_contain_text("calibration paused at target")
        expect(page.locator("#message")).to_contain_text("kept")
        n = ws.active.cal.n_done
        assert n >= 2 and ws.mode.value == "idle"
        # the touches taken are there when the skin comes back
        page.click("#connect-btn")
        _wait(lambda: ws.device is not None, "the skin again")
        assert ws.active.cal.n_done == n
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
