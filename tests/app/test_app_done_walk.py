"""Issue 33's "Done when", in Chromium: a 20-touch session with bad touches walked to export.

Two touches pressed away from their targets (60 and 90 mm, straight-line distance to the
nearest vertex that far) and one short touch (the finger lifted during its capture) are
flagged by the gate (the 60 mm one not always: below); the 60 mm one is retaken (the other
touches keep their numbers), the 90 mm and the short one are left out by hand, the Train
page shows its interval; then validation, live, a recording, and every command the Export page
prints, run as printed.

The gate's off-target check is not certain at 20 touches (docs/app.md). Over skin seeds 0-19
(``rate_hz`` 400, 10 samples, the same two distances, no short touch; the app's gate at
7c51c51) it flagged the 90 mm touch 20 times in 20, the 60 mm one 17 times in 20 (seeds 1, 6
and 17 missed it) and 11 of the 360 good touches; and the same seed does not give the same
frames twice (the scripted finger's timing). So the test requires the 90 mm and the short
touch flagged, and the 60 mm one flagged or not, said on the gate as it is: either way it is
retaken from the gate's list, which any touch can be. A good touch flagged besides is allowed.
"""

from __future__ import annotations

import numpy as np
import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.sources.base import SourceOptions  # noqa: E402
from tests._helpers import scaled, wait_until  # noqa: E402
from tests.app._app import ms, open_browser, run_as_printed, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

SEED = 0
N = 20
OFF = {5: 0.060, 12: 0.090}  # touch index -> how far from its target it is pressed, m
FAR = 12  # the 90 mm one: always flagged
SHORT = 16  # the touch whose finger lifts during its capture


def _at_distance(vertices: np.ndarray, target: np.ndarray, d: float) -> np.ndarray:
    """The mesh vertex whose distance from ``target`` is nearest ``d`` (m)."""
    r = np.linalg.norm(vertices - target, axis=1)
    return vertices[np.argmin(np.abs(r - d))]


def _manual(ws, index: int) -> None:
    """Stop the scripted finger before touch ``index`` and wait for its prompt."""
    wait_until(lambda: ws.active.cal.n_done >= index, f"{index} touches", 180, 0.005)
    ws.stop()
    ws.set_finger(False)
    while ws.active.cal.n_done > index:  # the scripted finger was quicker than the wait
        ws.undo()
    ws.start_calibration()
    _wait(lambda: ws.capture is not None and ws.capture.phase.value == "wait_touch", "prompt")


def _flags(ws, index: int) -> list[str]:
    return ws.session_detail()["calibration"]["flags"][index]


def _short_press(ws, skin, index: int) -> str | None:
    """After a short press's lift, whether it started a capture: ``landed`` or ``missed``.

    None while the finger is not lifted yet.

    The lift is made inside the frame read that follows the press's last frame, and the reader
    hands each frame to the capture before it reads the next: once the lift is made, every
    frame of the press has been judged. ``SHORT``'s target on skin seed 0 moves only 2 sensors
    past the gate's threshold in one press in ten, so its ten frames can miss the 5 touch
    frames in a row that start a capture (1 press in 300, more as the baselines drift).
    """
    if skin.moves_pending or skin.contact is not None:
        return None
    started = ws.active.cal.n_done > index or ws.capture.phase.value != "wait_touch"
    return "landed" if started else "missed"


def _calibrate(ws) -> int:
    """The session's 20 touches: the scripted finger, two pressed elsewhere, one lifted early.

    Returns how many presses the short touch took (one: a 25 ms press on the skin's frame
    clock; a press never felt as a touch is pressed again, and a touch that still came out
    whole would be undone and pressed again).
    """
    ws.set_finger(True)
    ws.start_calibration()
    _wait(lambda: ws.active.cal.recording is not None, "the baseline")
    presses = 0
    for index in sorted([*OFF, SHORT]):
        _manual(ws, index)
        target = np.asarray(ws.active.cal.targets[index])
        if index in OFF:
            ws.sim_touch(_at_distance(ws.active.mesh.vertices, target, OFF[index]).tolist())
            _wait(lambda i=index: ws.active.cal.n_done > i, "the touch elsewhere")
            ws.sim_touch(None)
        while index == SHORT:
            presses += 1
            assert presses <= 8, "a 25 ms press never made a short touch"
            # 25 ms of the skin's own frames (10 at 400 Hz): the finger lifts during the
            # capture whatever the machine's load (a lift timed on the wall clock came late)
            ws.sim_path([(0.0, target.tolist()), (0.025, None)])
            landed = _wait(lambda s=ws.device.source: _short_press(ws, s, SHORT), "the lift")
            if landed == "missed":
                continue  # never felt as a touch: pressed again
            _wait(lambda i=index: ws.active.cal.n_done > i, "the short touch")
            if "short" in _flags(ws, index):
                break
            _wait(lambda: ws.capture.phase.value == "wait_touch", "the prompt again")
            ws.undo()
            _wait(lambda i=index: ws.active.cal.n_done == i, "the undo")
        ws.set_finger(True)
    _wait(lambda: ws.message == "calibration complete", "calibration")
    return presses


@pytest.mark.slow  # a 20-touch session in Chromium
def test_mispressed_and_short_touches_are_flagged_and_the_session_walks_to_export(
    chromium, server, tmp_path
):
    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=SEED))
    ws.create_session("done when", n_points=N, samples=10, baseline_frames=20, n_validation=5)
    _calibrate(ws)
    flags = ws.session_detail()["calibration"]["flags"]
    flagged = [i for i, f in enumerate(flags) if f]
    # the 90 mm and the short touch, the 60 mm one in 17 of 20 skins, and maybe a good one
    # (the gate's false flags: docs/app.md)
    caught = {i: "off_target" in flags[i] for i in OFF}
    assert caught[FAR] and "short" in flags[SHORT], flags
    got = tmp_path / "downloads"
    got.mkdir()
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900}, accept_downloads=True)
        watch(page, errors)
        page.goto(url)

        def go(name: str) -> None:
            page.click(f"#nav button[data-page={name}]")
            page.wait_for_selector(f"#page-{name}.active")

        # The gate: the three flagged, listed first, and why.
        go("train")
        gate = page.locator("#train-gate")
        expect(gate).to_contain_text(f"{N} touches")
        expect(gate).to_contain_text(f"{len(flagged)} flagged")
        rows = gate.locator("tbody tr")
        first = {rows.nth(k).get_attribute("data-index") for k in range(len(flagged))}
        assert first == {str(i) for i in flagged}, first  # the flagged, listed first
        for i in OFF:
            row = expect(gate.locator(f"tr[data-index='{i}']"))
            (row.to_contain_text if caught[i] else row.not_to_contain_text)("off target")
        expect(gate.locator(f"tr[data-index='{SHORT}']")).to_contain_text("short")

        # #6 (60 mm off) retaken from the gate, this time on its target: it is #6 (2nd), and
        # every other touch keeps its number.
        gate.locator("button[data-gate-retake='5']").click()
        page.wait_for_selector("#page-calibrate.active")
        panel = page.locator('.guided[data-kind="calibrate"]')
        panel.locator(".finger").check()
        _wait(lambda: ws.message == "calibration complete" and ws.mode.value != "calibrate", "it")
        panel.locator(".finger").uncheck()
        expect(panel.locator(".touches tbody td.touch-name")).to_have_count(N)
        for i, name in ((N - 1, "#6 (2nd)"), (0, "#1"), (4, "#5"), (5, "#7"), (11, "#13"),
                        (15, "#17"), (N - 2, "#20")):  # fmt: skip
            cell = panel.locator(f".touches tbody tr[data-index='{i}'] td.touch-name")
            expect(cell).to_have_text(name)
        flags = ws.session_detail()["calibration"]["flags"]
        assert "off_target" not in flags[-1], flags  # the retake is where it should be

        # #13 (90 mm off) and #17 (short) left out by hand; trained: the interval, what went
        # in and what did not, and why.
        go("train")
        for i, name in ((11, "#13"), (15, "#17")):
            gate.locator(f"tr[data-index='{i}'] .leave-out").check()
            _wait(lambda i=i: ws.session_detail()["calibration"]["left_out"][i], f"{name} out")
        page.click("#train-btn")
        result = page.locator("#train-result")
        out = result.locator(".left-out-list")
        expect(out).to_contain_text("#13: left out by hand", timeout=int(1000 * scaled(300)))
        expect(out).to_contain_text("#17: left out by hand")
        expect(result).to_contain_text(f"Trained on {N - 2} of {N} touches")
        expect(result.locator(".went-in")).to_contain_text("#6 (2nd)")
        expect(result.locator(".result .ci")).to_contain_text("95 % interval")

        # Validation: five touches by the scripted finger.
        go("validate")
        vpanel = page.locator('.guided[data-kind="validate"]')
        vpanel.locator(".finger").check()
        vpanel.locator(".start").click()
        _wait(lambda: (ws.active.info.get("validation") or {}).get("n") == 5, "validation", 300)
        vpanel.locator(".finger").uncheck()
        expect(vpanel.locator(".val-result .result")).to_contain_text("mm")

        # Live, recorded: a touch is shown, and two seconds of the stream are written.
        go("live")
        page.click("#live-start")
        _wait(lambda: ws.mode.value == "live", "live", 300)
        expect(page.locator("#live-state")).to_have_text("not touched")
        rec = page.locator("#record-panel")
        rec.locator(".rec-format").select_option("h5")
        rec.locator(".rec-start").click()
        ws.sim_touch(np.asarray(ws.active.cal.targets[0]).tolist())
        expect(page.locator("#live-state")).not_to_have_text("not touched")
        ws.sim_touch(None)
        page.wait_for_function(
            "() => { const t = document.querySelector('#record-panel .rec-state').textContent;"
            " const m = /^([0-9.]+) s, /.exec(t); return m && Number(m[1]) >= 2; }",
            timeout=int(1000 * scaled(60)),
        )
        rec.locator(".rec-stop").click()
        expect(rec.locator(".rec-state a")).to_contain_text(".h5")
        page.click("#live-stop")
        _wait(lambda: ws.mode.value != "live", "live stopped")

        # Export: every file downloaded under its name, and every command the page prints
        # run as printed in that folder.
        go("export")
        card = page.locator("#export-card")
        expect(card.locator(".export-files tbody")).to_contain_text("skins.toml")
        links = card.locator(".export-files tbody a")
        for k in range(links.count()):
            with page.expect_download() as info:
                links.nth(k).click()
            info.value.save_as(got / info.value.suggested_filename)
        commands = [c for c in card.locator("code.open-with").all_inner_texts() if c.strip()]
        assert len(commands) >= 5, commands  # calibration, validation, model, skins, recording
        for command in commands:
            run_as_printed(command, got)
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
