"""Issue 22, section 4 in a real browser: export, record, train-page evidence, traces, settings.

The fixtures (the app on a free port, Debian's Chromium) are ``conftest.py``'s; the
session is prepared through the workspace, and the page does what a researcher would.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytest.importorskip("uvicorn")

from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.models.localizer import ContactLocalizer  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app import test_app_browser as base  # noqa: E402
from tests.app._app import ms, open_browser, settle, watch  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402


def _prepared(app, n_points: int = 6, n_validation: int = 3):
    """Connect the simulated skin; calibrate, train and validate a session; return the workspace."""
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
    ws.create_session("extra", n_points=n_points, samples=10, baseline_frames=20)
    ws.set_finger(True)
    ws.start_calibration()
    _wait(lambda: ws.message == "calibration complete", "calibration")
    ws.train()
    _wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
    assert ws.active.model is not None, ws.training
    if n_validation:
        ws.start_validation(n_validation)
        _wait(lambda: ws.active.info.get("validation") is not None, "validation")
        ws.stop()
    ws.set_finger(False)
    return ws


def _download(page, click, folder: Path) -> Path:
    """Click, wait for the download, save it under its suggested name; its path."""
    with page.expect_download() as info:
        click()
    d = info.value
    path = folder / d.suggested_filename
    d.save_as(path)
    return path


@pytest.mark.slow  # a session in Chromium
def test_export_downloads_every_file_and_view(chromium, server, tmp_path):
    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = _prepared(app)
    sid = ws.active.folder.id
    errors: list[str] = []
    got = tmp_path / "downloads"
    got.mkdir()
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900}, accept_downloads=True)
        watch(page, errors)
        page.goto(url)
        # The 3D view of the validation, saved from the view itself.
        page.click("#nav button[data-page=validate]")
        page.wait_for_function(
            "() => window.skinloc.session && window.skinloc.session.validation.done.length === 3"
        )
        svg = _download(page, lambda: page.click(".viewer-export [data-fmt=svg]"), got)
        text = svg.read_text()
        assert svg.name == f"{sid}-3d-view.svg"
        assert text.startswith("<svg") and text.rstrip().endswith("</svg>")
        assert text.count("<path") > 100  # the skin's triangles
        assert text.count("<circle") >= 1  # the dots in sight (the skin hides the rest)
        png = _download(page, lambda: page.click(".viewer-export [data-fmt=png]"), got)
        assert png.read_bytes().startswith(b"\x89PNG\r\n\x1a\n") and png.stat().st_size > 5000

        # Record 10 s of the live stream, a touch in it, from the Live page.
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        page.wait_for_function("() => window.skinloc.state && window.skinloc.state.mode === 'live'")
        page.locator("#record-panel .rec-start").click()
        _wait(lambda: ws.recorder is not None and ws.recorder.t_last > 2, "2 s recorded")
        ws.sim_touch(ws.active.targets[0].tolist())
        _wait(lambda: ws.recorder.n_contacts > 20, "contacts recorded")
        ws.sim_touch(None)
        _wait(lambda: ws.recorder.t_last >= 10, "10 s recorded")
        page.locator("#record-panel .rec-stop").click()
        expect(page.locator("#record-panel .rec-state a")).to_contain_text("live-")

        page.click("#nav button[data-page=export]")
        card = page.locator("#export-card")
        expect(card.locator(".export-files tbody")).to_contain_text("live-")
        # The view the Export page saves is the Live page's, as last seen (it was the
        # calibration's dots whatever page came last)
        shown = page.evaluate(
            "() => Object.fromEntries(Object.entries(window.skinloc.viewer.groups)"
            ".map(([k, g]) => [k, g.visible]))"
        )
        assert shown["live"] and not shown["done"] and not shown["planned"], shown
        names = card.locator(".export-files tbody a").all_inner_texts()
        assert {"calibration.h5", "validation.h5", "model.h5"} <= set(names)
        live = [n for n in names if n.startswith("live-")]
        assert len(live) == 1 and live[0].endswith(".h5")
        files = {}
        for name in names:
            link = card.locator(".export-files tbody a", has_text=name)
            files[name] = _download(page, link.click, got)
            assert files[name].name == f"{sid}-{name}"
        cal = read_recording(files["calibration.h5"])
        assert cal.n_point_logs == 6
        assert read_recording(files["validation.h5"]).n_point_logs == 3
        from skinloc.app.workspace.record import read_live_events
        from skinloc.sources.replay import stream_summary

        stream = stream_summary(files[live[0]])
        assert stream["stream_seconds"] >= 9.9, stream
        assert stream["stream_frames"] == ws.last_recording["frames"]  # every frame received
        assert len(read_live_events(files[live[0]])["contacts"]) > 20
        model = ContactLocalizer.load(files["model.h5"])
        assert np.all(np.isfinite(model.predict(cal.touch_means)))

        csv = _download(page, card.get_by_text("Errors (CSV)").click, got)
        lines = csv.read_text().splitlines()
        assert lines[0].startswith("touch,status,target_x_mm") and len(lines) == 4
        for fmt, magic in (("PNG", b"\x89PNG"), ("SVG", b"<?xml")):
            f = _download(page, card.get_by_text(f"Error view ({fmt})").click, got)
            assert f.read_bytes().startswith(magic), f
        base.ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(base.ARTIFACTS / "09-export.png"))
        page.set_viewport_size({"width": 800, "height": 900})
        assert page.evaluate("document.documentElement.scrollWidth") <= 800
        page.screenshot(path=str(base.ARTIFACTS / "narrow-export.png"))
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_record_the_live_stream_from_the_page(chromium, server, tmp_path):
    """Record HDF5 while the live view runs and a finger presses, see it grow, stop, download;
    then MCAP, ended by disconnecting the skin: both files are whole."""
    from skinloc.app.workspace.record import read_live_events
    from skinloc.sources.replay import read_stream

    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = _prepared(app, n_validation=0)
    folder = ws.active.folder.path
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900}, accept_downloads=True)
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        page.wait_for_function("() => window.skinloc.state && window.skinloc.state.mode === 'live'")
        panel = page.locator("#record-panel")
        expect(panel.locator(".rec-state")).to_have_text("Not recording.")
        panel.locator(".rec-format").select_option("h5")
        panel.locator(".rec-start").click()
        expect(panel.locator(".rec-stop")).to_be_enabled()
        expect(panel.locator(".rec-start")).to_be_disabled()
        _wait(lambda: ws.recorder is not None and ws.recorder.n_frames > 300, "untouched frames")
        ws.sim_touch(ws.active.targets[0].tolist())
        _wait(lambda: ws.recorder.n_contacts > 20, "contacts recorded")
        ws.sim_touch(None)
        # The line shows the duration and size as they grow.
        page.wait_for_function(
            "() => { const t = document.querySelector('#record-panel .rec-state').textContent;"
            " return /^([2-9]|[1-9][0-9]+)\\.[0-9] s, [0-9.]+ (kB|MB): /.test(t); }"
        )
        text = panel.locator(".rec-state").inner_text()
        assert "contacts" in text and "frames" in text
        base.ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(base.ARTIFACTS / "10-live-recording.png"))
        panel.locator(".rec-stop").click()
        expect(panel.locator(".rec-state a")).to_contain_text(".h5")
        got = _download(page, panel.locator(".rec-state a").click, tmp_path)
        frames, _, _ = read_stream(got)
        events = read_live_events(got)
        assert len(frames) > 300 and len(events["contacts"]) > 20
        assert read_recording(got).n_tx == 8

        # MCAP, ended by disconnecting: the file is finished all the same.
        panel.locator(".rec-format").select_option("mcap")
        panel.locator(".rec-start").click()
        _wait(lambda: ws.recorder is not None and ws.recorder.n_frames > 100, "mcap frames")
        # its size grows on the page while it runs (it stayed at the 36-byte header)
        page.wait_for_function(
            "() => / [0-9.]+ (kB|MB): /.test("
            "document.querySelector('#record-panel .rec-state').textContent)"
        )
        name = ws.recorder.path.name
        page.click("#nav button[data-page=connect]")
        page.click("#disconnect-btn")
        page.click("#nav button[data-page=live]")
        expect(panel.locator(".rec-state a")).to_contain_text(name)
        expect(panel.locator(".rec-start")).to_be_enabled()
        browser.close()
    from tests.app.test_app_record import mcap_counts

    assert mcap_counts(folder / name)["/skinloc/skin/frames"] > 100
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_train_page_shows_each_touch_error_on_the_skin_and_as_a_histogram(chromium, server):
    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = _prepared(app, n_points=8, n_validation=0)
    te = ws.active.info["holdout"]["touch_errors"]
    assert len(te["index"]) == 8
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=train]")
        result = page.locator("#train-result")
        expect(result.locator(".evidence h3")).to_contain_text("Error of each touch")
        expect(result.locator(".evidence")).to_contain_text("cross-validation, 8 touches")
        counts = [
            int(c)
            for c in result.locator("svg.hist rect.bin").evaluate_all(
                "els => els.map(e => e.dataset.count)"
            )
        ]
        assert sum(counts) == 8
        assert result.locator("svg.hist .mark-mean").count() == 1
        # Error against touches: this session with and without the map prior, the real skin's
        # three reference curves (dashed) and the probing floor.
        curve = ws.active.info["holdout"]["prior_curve"]
        assert curve["sizes"] and len(curve["prior_mm"]) == len(curve["sizes"])
        expect(result.locator("svg.curve path")).to_have_count(5)
        assert (
            result.locator("svg.curve .line-prior title")
            .text_content()
            .startswith("this session, with the prior")
        )
        assert result.locator("svg.curve .line-paper").count() == 1
        assert result.locator("svg.curve line.floor").count() == 1
        expect(result.locator(".prior-curve")).to_contain_text("Dashed: the real skin")
        worst = int(np.argmax(te["error_mm"]))
        expect(result.locator(".evidence .hint")).to_contain_text(f"#{te['number'][worst]}: ")
        # One dot per touch on the 3D skin, at its target, with its number, shown on the Train
        # page only.
        dots = page.evaluate(
            "() => { const g = window.skinloc.evidence.group;"
            " const m = g.children.filter(o => o.isMesh);"
            " return { visible: g.visible, n: m.length, errors: m.map(o => o.userData.error_mm),"
            " numbers: g.children.filter(o => o.userData.label).map(o => o.userData.label.text)"
            " }; }"
        )
        assert dots["visible"] and dots["n"] == 8
        assert sorted(dots["numbers"], key=int) == [str(k) for k in te["number"]]
        np.testing.assert_allclose(sorted(dots["errors"]), sorted(te["error_mm"]))
        assert page.locator("#viewer").is_visible()
        settle(page)  # the view draws the dots (for the picture)
        base.ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(base.ARTIFACTS / "04c-train-evidence.png"))
        page.set_viewport_size({"width": 800, "height": 900})
        assert page.evaluate("document.documentElement.scrollWidth") <= 800
        page.screenshot(path=str(base.ARTIFACTS / "narrow-train-evidence.png"))
        page.click("#nav button[data-page=calibrate]")
        assert not page.evaluate("window.skinloc.evidence.group.visible")
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_traces_of_a_sensor_a_live_track_and_a_touch(chromium, server):
    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = _prepared(app, n_validation=0)
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)

        # A sensor of the Connect page's heat map: its trace, baseline and band.
        page.click("#nav button[data-page=connect]")
        page.wait_for_function("() => document.querySelector('#heat-connect')._heat")
        base.hover_cell(page, "#heat-connect", 3, 4)
        page.mouse.down()
        page.mouse.up()
        pop = page.locator('.trace-pop[data-kind="sensor"]')
        expect(pop.locator(".trace-title")).to_have_text("Sensor TX 3, RX 4: last 10 s")
        page.wait_for_function(
            "() => Number(document.querySelector('.trace-pop[data-kind=sensor]')"
            ".dataset.points) > 100"
        )
        expect(pop.locator(".trace-note")).to_contain_text("baseline")
        expect(pop.locator(".trace-note")).to_contain_text("± 3 σ")
        base.ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(base.ARTIFACTS / "02b-connect-sensor-trace.png"))
        pop.locator(".trace-close").click()
        expect(pop).to_be_hidden()

        # A touch of the calibration: its mean image and its frames, one by one.
        page.click("#nav button[data-page=calibrate]")
        row = page.locator('.guided[data-kind="calibrate"] .touches tbody tr').last
        expect(row).to_contain_text("1")
        row.locator("td").first.click()
        touch = page.locator('.trace-pop[data-kind="touch"]')
        expect(touch.locator(".trace-title")).to_have_text("Calibration touch #1")
        assert touch.get_attribute("data-frames") == "10"
        touch.locator(".frame-slider").fill("7")
        expect(touch.locator(".frame-no")).to_have_text("7")
        page.screenshot(path=str(base.ARTIFACTS / "03c-calibrate-touch-frames.png"))
        touch.locator(".trace-close").click()

        # Live: a held finger draws its strength and position over time.
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        page.wait_for_function("() => window.skinloc.state && window.skinloc.state.mode === 'live'")
        ws.sim_touch(ws.active.targets[1].tolist())
        page.wait_for_function(
            "() => { const p = document.querySelector('.live-plot');"
            " return p && Number(p.dataset.points) > 20 && p.dataset.tracks === '1'; }"
        )
        page.screenshot(path=str(base.ARTIFACTS / "06c-live-plot.png"))
        ws.sim_touch(None)
        # Once nothing touches (no contacts come) the plot goes on: the track scrolls out.
        page.wait_for_function("() => document.querySelector('.live-plot').dataset.tracks === '0'")
        page.set_viewport_size({"width": 800, "height": 900})
        assert page.evaluate("document.documentElement.scrollWidth") <= 800
        page.screenshot(path=str(base.ARTIFACTS / "narrow-live-plot.png"))
        browser.close()
    assert not errors, f"the page logged errors: {errors}"


@pytest.mark.slow  # a session in Chromium
def test_live_settings_are_saved_to_the_skins_file_and_latency_is_shown(chromium, server):
    from skinloc.live.skins_file import load_skins

    url, app = server
    sync_api.expect.set_options(timeout=ms(60_000))
    expect = sync_api.expect
    ws = _prepared(app, n_validation=0)
    errors: list[str] = []
    with open_browser(chromium) as browser:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        watch(page, errors)
        page.goto(url)
        page.click("#nav button[data-page=live]")
        page.click("#live-start")
        page.wait_for_function("() => window.skinloc.state && window.skinloc.state.mode === 'live'")
        panel = page.locator(".live-settings")
        panel.locator("summary").click()
        expect(panel.locator(".settings-where")).to_contain_text("the defaults", ignore_case=True)
        expect(panel.locator("#set-touch_on_z")).to_have_value("8")
        panel.locator("#set-touch_on_z").fill("9.5")
        panel.locator("#set-filter").select_option("none")
        panel.locator("#set-gestures").uncheck()
        old = ws._live_pipeline
        panel.locator(".settings-save").click()
        expect(panel.locator(".settings-where")).to_contain_text("skinloc run --config")
        expect(panel).to_contain_text("(default 8)")
        skins, _ = load_skins(ws.active.folder.path / "skins.toml")
        cfg = skins[0].config
        assert (cfg.touch_on_z, cfg.filter, cfg.gestures) == (9.5, "none", False)
        _wait(lambda: ws._live_pipeline is not None and ws._live_pipeline is not old, "live again")
        page.wait_for_function("() => window.skinloc.state.mode === 'live'")
        # A touch: the latency of its contacts is shown.
        ws.sim_touch(ws.active.targets[0].tolist())
        page.wait_for_function(
            "() => Number(document.querySelector('#live-latency').dataset.n) > 10"
        )
        assert page.locator("#live-latency").inner_text().endswith("ms)")
        ws.sim_touch(None)
        base.ARTIFACTS.mkdir(parents=True, exist_ok=True)
        side = page.locator("#page-live .card.side")
        side.screenshot(path=str(base.ARTIFACTS / "06d-live-settings.png"))
        page.set_viewport_size({"width": 800, "height": 900})
        assert page.evaluate("document.documentElement.scrollWidth") <= 800
        panel.locator("summary").scroll_into_view_if_needed()
        page.screenshot(path=str(base.ARTIFACTS / "narrow-live-settings.png"))
        # Back to the defaults.
        page.set_viewport_size({"width": 1440, "height": 900})
        panel.locator(".settings-defaults").click()
        expect(panel.locator("#set-touch_on_z")).to_have_value("8")
        assert load_skins(ws.active.folder.path / "skins.toml")[0][0].config.filter == "one-euro"
        browser.close()
    assert not errors, f"the page logged errors: {errors}"
