"""The Recalibrate tab in a real browser: pick a model, k touches, the before/after figure.

The fixtures (the app on a free port, Debian's Chromium) are ``conftest.py``'s; the session
and its old model are prepared through the workspace (a model of another day's touches of the
same 8 x 8 cone), the scripted finger presses the targets, and the page does the rest.
"""

from __future__ import annotations

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.evaluation.scoring import train_localizer  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import ARTIFACTS, ms, open_browser, settle, watch  # noqa: E402
from tests.conftest import make_recording  # noqa: E402


@pytest.mark.slow  # a session in Chromium
def test_recalibrate_tab_picks_a_model_and_shows_before_and_after(chromium, server):
    url, app = server
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
    ws.create_session("recal", n_points=4, samples=10, baseline_frames=20)
    sid = ws.active.folder.id
    old = ws.active.folder.model
    train_localizer([make_recording(12, 4, random_state=0)]).save(old)
    ws.set_finger(True)
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=recalibrate]")
        page.wait_for_selector(f".recal-model option[value='session:{sid}']", state="attached")
        page.select_option(".recal-model", f"session:{sid}")
        page.fill(".recal-k", "3")
        page.click(".recal-start")
        chart = page.locator(".recal-result svg.recal-chart")
        chart.wait_for(timeout=ms(60_000))
        text = page.inner_text(".recal-result")
        assert "old model untouched" in text and "recalibrated" in text
        assert "3 touches only" in text  # the honest caveat of few touches
        name = page.inner_text(".recal-file")
        assert name.startswith("model-recalibrated-") and (old.parent / name).is_file()
        assert chart.locator("circle").count() == 3  # each new touch's error before
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        settle(page)
        page.screenshot(path=str(ARTIFACTS / "recalibrate.png"), full_page=True)
    assert not errors, errors
