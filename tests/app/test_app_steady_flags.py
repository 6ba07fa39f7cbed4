"""Issue 33, item 7: the weak-line flag of one RX line came and went on the same touches.

Headless Chromium on the simulated skin (its RX 3 is weak). A finished 20-touch calibration of
that skin is opened as a session: the Connect page names RX 3 weak, judged on the session's
sensor map. The calibration is resumed (Start says it is complete, as before a retake) and the
skin connected again: the touches are the same, so the line stays weak throughout, whatever
monitor or state of the session asks.
"""

from __future__ import annotations

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.calibration.session import SessionConfig, simulate_session  # noqa: E402
from skinloc.sim.skin import SimulatedSkin  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import ms, open_browser, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

# Counts, on the page, the line reports that name RX 3 weak and those that do not, once it
# was named.
WATCH_RX3 = """() => {
  const el = document.querySelector('#line-report');
  const weak = () => el.textContent.includes('RX 3: weak');
  window.__rx3 = {weak: weak() ? 1 : 0, gone: 0, seen: 0};
  new MutationObserver(() => {
    window.__rx3.seen++;
    if (weak()) window.__rx3.weak++;
    else if (window.__rx3.weak) window.__rx3.gone++;
  }).observe(el, {subtree: true, childList: true, characterData: true});
}"""


@pytest.mark.slow  # a sensor map fitted, Chromium
def test_a_weak_line_stays_weak_on_the_same_touches(chromium, server):
    url, app = server
    ws = app.state.workspace
    folder = ws.config.data_dir / "recordings"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "cone20.h5"
    skin = SimulatedSkin(ws.default_mesh, random_state=0)
    cfg = SessionConfig(n_points=20, mode="even", samples_per_touch=8, random_state=0)
    simulate_session(skin, ws.default_mesh, path, cfg)
    ws.connect(SourceOptions(source="sim"))
    ws.import_recording(str(path))
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=connect]")
        report = page.locator("#line-report")
        sync_api.expect(report).to_contain_text("RX 3: weak", timeout=ms(120_000))
        page.evaluate(WATCH_RX3)
        # The calibration resumed (as a retake does): it says it is complete.
        page.click("#nav button[data-page=calibrate]")
        page.click('.guided[data-kind="calibrate"] .start')
        _wait(lambda: ws.active.cal is not None and ws.message == "calibration complete", "resume")
        # The same skin connected again: a new reader and monitor, the same touches.
        page.click("#nav button[data-page=connect]")
        page.select_option("#source-select", "sim")
        page.click("#connect-btn")
        page.wait_for_function(
            "() => /connected to sim/.test(document.querySelector('#message').textContent)"
        )
        n = page.evaluate("window.__rx3.seen")
        # a few reports of the new monitor (one a second)
        page.wait_for_function(f"() => window.__rx3.seen >= {n + 5}", timeout=ms(60_000))
        said = page.evaluate("window.__rx3")
        assert said["gone"] == 0, f"RX 3 was named weak {said['weak']} and not {said['gone']} times"
        assert "RX 3: weak" in report.inner_text()
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
