"""Traces (issue 22, section 4): a sensor's recent signal with its baseline and noise band, and a
recorded touch's frames and mean image, over HTTP."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.app.workspace.traces import MAX_POINTS, thin  # noqa: E402
from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests._helpers import wait_until  # noqa: E402

A = {"X-Skinloc-Client": "tab-a"}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    data = tmp_path_factory.mktemp("traces")
    app = create_app(
        AppConfig(data_dir=data, finger_delay_s=0.05),
        SourceOptions(source="sim", rate_hz=400.0, seed=3),
    )
    with TestClient(app) as c:
        c.headers.update({"X-Skinloc-Token": app.state.token, **A})
        ws = app.state.workspace
        ws.create_session("traces", n_points=4, samples=12, baseline_frames=20)
        ws.set_finger(True)
        ws.start_calibration()
        wait_until(lambda: ws.message == "calibration complete", "calibration", 180, 0.05)
        ws.set_finger(False)
        yield c


def test_a_sensor_trace_has_its_baseline_and_noise_band(client):
    ws = client.app.state.workspace
    wait_until(lambda: ws.device.monitor.zero is not None, "the zero level", 60, 0.05)
    wait_until(lambda: len(ws._recent or ()) > 2000, "5 s of frames", 120, 0.05)
    r = client.get("/api/trace/sensor", params={"tx": 2, "rx": 5, "seconds": 4})
    assert r.status_code == 200, r.text
    d = r.json()
    t, v = np.asarray(d["t_s"]), np.asarray(d["counts"])
    assert (d["tx"], d["rx"]) == (2, 5) and 10 < len(t) <= MAX_POINTS + 2 and len(v) == len(t)
    assert t[-1] == 0 and t[0] >= -4.0 and np.all(np.diff(t) >= 0)
    assert d["noise"] > 0 and d["band_sigma"] == 3.0
    # Untouched: the signal sits in its band around the baseline, most of the time.
    band = d["band_sigma"] * d["noise"] + 1.0
    assert np.mean(np.abs(v - d["baseline"]) <= band) > 0.8


def test_bad_sensor_requests_say_so_in_one_line(client):
    for params, code, text in (
        ({"tx": 20, "rx": 0}, 400, "no sensor TX 20, RX 0: the skin is 8 TX x 8 RX"),
        ({"tx": 99, "rx": 0}, 422, "tx"),
        ({"tx": 0, "rx": 0, "seconds": 0}, 422, "seconds"),
        ({"tx": "a", "rx": 0}, 422, "tx"),
        ({"rx": 0}, 422, "tx"),
    ):
        r = client.get("/api/trace/sensor", params=params)
        assert r.status_code == code, (params, r.text)
        assert text in r.json()["detail"] and "\n" not in r.json()["detail"]


def test_a_touch_shows_its_frames_and_mean_image(client):
    ws = client.app.state.workspace
    rec = read_recording(ws.active.folder.calibration)
    r = client.get("/api/session/touch", params={"index": 1})
    assert r.status_code == 200, r.text
    d = r.json()
    frames, mean = np.asarray(d["frames"]), np.asarray(d["mean"])
    assert frames.shape == (12, 64) and mean.shape == (64,) and (d["tx"], d["rx"]) == (8, 8)
    np.testing.assert_allclose(mean, rec.touch_means[1], atol=0.05)
    np.testing.assert_allclose(frames.mean(axis=0), mean, atol=0.1)
    np.testing.assert_allclose(d["target"], rec.targets[1])
    assert len(d["times_s"]) == 12 and d["times_s"][0] == 0


def test_bad_touch_requests_say_so_in_one_line(client):
    for params, code, text in (
        ({"index": 4}, 400, "no calibration touch 5: 4 recorded"),
        ({"index": 0, "recording": "validation"}, 400, "no validation touch 1: 0 recorded"),
        ({"index": 0, "recording": "history"}, 422, "recording"),
        ({"index": -1}, 422, "index"),
    ):
        r = client.get("/api/session/touch", params=params)
        assert r.status_code == code, (params, r.text)
        assert text in r.json()["detail"] and "\n" not in r.json()["detail"]


def test_no_skin_or_session_is_refused(tmp_path):
    with TestClient(create_app(AppConfig(data_dir=tmp_path))) as c:
        r = c.get("/api/trace/sensor", params={"tx": 0, "rx": 0})
        assert r.status_code == 400 and r.json()["detail"].startswith("no skin connected")
        r = c.get("/api/session/touch", params={"index": 0})
        assert r.status_code == 400 and r.json()["detail"].startswith("no session open")


def test_thinning_keeps_spikes_and_order():
    t = np.arange(10_000) / 400.0
    v = np.zeros_like(t)
    v[5123] = 100.0
    v[7000] = -50.0
    tt, vv = thin(t, v, 500)
    assert len(tt) <= 502 and np.all(np.diff(tt) > 0)
    assert vv.max() == 100.0 and vv.min() == -50.0
    assert tt[np.argmax(vv)] == t[5123]
    short_t, short_v = thin(t[:100], v[:100], 500)
    assert len(short_t) == 100
