"""Calibration data a researcher can trust, in Chromium (issue 33, items 2 to 4).

A touch keeps its target's number for life (a retake is that target's next attempt, "#3
(2nd)"), in the touch list and on the Train page's dots; any touch, flagged or not, is left out
from the list and stays out across trainings until put back, and the result lists what went in
and what did not, and why; the Train page's error is cross-validated over every touch with an
interval; a validation belongs to the model it scored.
"""

from __future__ import annotations

import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

# The fixtures (server, chromium) are tests/app/conftest.py's; the browser's setup, _app's.
from tests.app._app import ARTIFACTS, ms, open_browser, settle, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

N = 10


def _name_cell(panel, index: int):
    return panel.locator(f".touches tbody tr[data-index='{index}'] td.touch-name")


def test_numbers_stay_touches_stay_out_and_the_figures_are_honest(chromium, server):
    url, app = server
    from skinloc.sources.base import SourceOptions

    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = app.state.workspace
    ws.config.influence_suspects = 0  # the cross-validation alone: quicker
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
    ws.create_session("trust", n_points=N, samples=10, baseline_frames=20)
    ws.set_finger(True)
    ws.start_calibration()
    _wait(lambda: ws.message == "calibration complete", "calibration")
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=calibrate]")
        panel = page.locator('.guided[data-kind="calibrate"]')
        expect(_name_cell(panel, 2)).to_have_text("#3")

        # Retake touch #3 from the list: the scripted finger touches its target again; the
        # later touches keep their numbers and the retake is #3's 2nd attempt.
        panel.locator("button[data-retake='2']").click()
        _wait(lambda: ws.message == "calibration complete", "the retake")
        expect(_name_cell(panel, N - 1)).to_have_text("#3 (2nd)")
        expect(_name_cell(panel, 2)).to_have_text("#4")
        expect(_name_cell(panel, 0)).to_have_text("#1")

        # The Train page lists every touch, flagged or not; #2 and then #6 left out by hand.
        page.click("#nav button[data-page=train]")
        gate = page.locator("#train-gate")
        expect(gate.locator("tbody tr")).to_have_count(N)
        gate.locator("tr[data-index='1'] .leave-out").check()
        _wait(lambda: ws.session_detail()["calibration"]["left_out"][1], "#2 left out")
        page.click("#train-btn")
        result = page.locator("#train-result")
        expect(result.locator(".left-out-list")).to_contain_text(
            "#2: left out by hand", timeout=ms(300_000)
        )
        expect(result).to_contain_text(f"Trained on {N - 1} of {N} touches")
        # Another box ticked: the first stays out (it was silently put back before).
        gate.locator("tr[data-index='4'] .leave-out").check()
        _wait(lambda: ws.session_detail()["calibration"]["left_out"][4], "#6 left out")
        expect(gate.locator("tr[data-index='1'] .leave-out")).to_be_checked()
        page.click("#train-btn")
        page.wait_for_function("() => window.skinloc.state.training?.running")
        out = result.locator(".left-out-list")
        expect(out).to_contain_text("#6: left out by hand", timeout=ms(300_000))
        expect(out).to_contain_text("#2: left out by hand")
        expect(result).to_contain_text(f"Trained on {N - 2} of {N} touches")
        went_in = result.locator(".went-in")
        expect(went_in).to_contain_text("#3 (2nd)")
        assert "#2," not in went_in.text_content() and "#6," not in went_in.text_content()

        # The figure: cross-validated over all the touches trained on, with its interval.
        expect(result.locator(".result .ci")).to_contain_text("95 % interval")
        expect(result).to_contain_text(f"cross-validation over all {N - 2} touches")
        h = ws.active.info["holdout"]
        low, high = h["ci95_mm"]
        assert low <= h["mean_mm"] <= high and len(h["touch_errors"]["error_mm"]) == N - 2

        # Each error dot on the 3D view carries its touch's number.
        texts = page.evaluate(
            "() => window.skinloc.viewer.groups.evidence.children"
            ".filter((o) => o.userData.label).map((o) => o.userData.label.text)"
        )
        assert sorted(texts) == sorted(["1", "3 (2nd)", "4", "5", "7", "8", "9", "10"]), texts
        settle(page)
        placed = page.evaluate("() => window.skinloc.viewer.labels.placed.map((p) => p.text)")
        assert placed and set(placed) <= set(texts), placed
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "13-train-left-out-and-numbers.png"))

        # Put back from the list: in again at the next training.
        gate.locator("tr[data-index='1'] .leave-out").uncheck()
        _wait(lambda: not ws.session_detail()["calibration"]["left_out"][1], "#2 put back")
        expect(gate.locator("tr[data-index='4'] .leave-out")).to_be_checked()

        # A validation belongs to the model it scored: trained again, none is shown as the
        # new model's.
        ws.start_validation(3)
        _wait(lambda: (ws.active.info.get("validation") or {}).get("n") == 3, "validation")
        page.click("#train-btn")
        page.wait_for_function("() => window.skinloc.state.training?.running")
        expect(result.locator(".left-out-list")).to_contain_text("#6", timeout=ms(300_000))
        page.click("#nav button[data-page=validate]")
        expect(page.locator(".guided[data-kind=validate] .val-result")).to_contain_text(
            "The model was trained again"
        )
        page.click("#nav button[data-page=sessions]")
        expect(page.locator("#sessions-table, table").first).to_contain_text(
            "an earlier model's validation"
        )
        assert not errors, errors


def test_live_start_says_what_it_does_and_takes_one_click(chromium, server, monkeypatch):
    """Issue 33 item 5: the first Live start (the engine's kernels compiled) gave 30-40 s of
    silence and repeat clicks queued; now Start is disabled at once, the page says what runs,
    and another start meanwhile is refused."""
    import threading

    url, app = server
    from skinloc.sources.base import SourceOptions

    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = app.state.workspace
    ws.config.influence_suspects = 0
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
    ws.create_session("live", n_points=8, samples=10, baseline_frames=20)
    ws.set_finger(True)
    ws.start_calibration()
    _wait(lambda: ws.message == "calibration complete", "calibration")
    ws.train()
    _wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
    # The preparation held until the test lets it go: a slow first start, made certain.
    release = threading.Event()
    make = ws._make_live_pipeline

    def slow(model, queue):
        release.wait(60)
        return make(model, queue)

    monkeypatch.setattr(ws, "_make_live_pipeline", slow)
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=live]")
        start = page.locator("#live-start")
        start.click()
        expect(start).to_be_disabled()
        expect(page.locator("#message")).to_contain_text("preparing the localiser")
        with pytest.raises(ValueError, match="live is starting"):
            ws.start_live()  # another start meanwhile (another tab, a key) is refused
        release.set()
        _wait(lambda: ws.mode.value == "live", "live")
        expect(start).to_be_enabled()
        expect(page.locator("#message")).to_contain_text("live: touch the skin")
        ws.stop()
    assert not [e for e in errors if "status of 400" not in e], errors
