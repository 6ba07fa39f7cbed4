"""The skin itself: sensor map, coverage, active selection, and their commands."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from skinloc.calibration.active import select_point_logs, subset_recordings
from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.cli.main import app
from skinloc.data.recording import read_recording, write_recording
from skinloc.geometry.mesh import cone_skin
from skinloc.models.response_map import ResponseMap, shape_features
from skinloc.sensors import joint_fit as J
from skinloc.sensors import sensor_map as S
from skinloc.sensors.coverage import coverage_map
from skinloc.sensors.crossing_fit import fit_per_crossing
from skinloc.sim.skin import SimulatedSkin, SkinParams
from tests.conftest import make_recording

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def sim_path(tmp_path_factory):
    """A simulated session (skin seed 0: RX 3 weak, sensor TX 1 x RX 7 noisy), 80 even touches."""
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=0)
    skin.reseed(0)
    path = tmp_path_factory.mktemp("sim") / "sim.h5"
    cfg = SessionConfig(n_points=80, mode="even", samples_per_touch=8, random_state=0)
    simulate_session(skin, mesh, path, cfg)
    return path


@pytest.fixture(scope="module")
def sim_model(sim_path, tmp_path_factory):
    """``skinloc train`` on ``sim_path`` (the default model), trained once: read only."""
    model = tmp_path_factory.mktemp("model") / "m.h5"
    res = run("train", sim_path, "--out", model)
    assert res.exit_code == 0, res.output
    return model


@pytest.fixture(scope="module")
def joint_map(sim_path):
    """The sensor map of ``sim_path`` (whole-image model, no bootstrap), made once: read only."""
    return S.sensor_map_from_recordings([read_recording(sim_path)], n_boot=0)


@pytest.fixture(scope="module")
def crossing_map(sim_path):
    """The per-crossing sensor map of ``sim_path`` (no bootstrap), made once: read only."""
    return S.sensor_map_from_recordings([read_recording(sim_path)], n_boot=0, joint=False)


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_sensor_map_finds_the_simulated_crossings_and_faults(sim_path, joint_map):
    rec = read_recording(sim_path)
    smap = joint_map
    truth = S.truth_sensor_positions(rec.meta)
    assert truth.shape == (64, 3)
    err = S.position_errors_mm(smap.positions_m, truth)
    # The fitted simulator's person misses each target by 5.3 mm per axis (as on the real
    # skin), and the crossings are located from those labels. The whole-image model brings
    # this session from 3.3 / 6.3 mm (per-crossing fit) to under 2.5 / 4.5 mm.
    assert smap.method == "joint"
    assert np.median(err) < 2.5 and np.percentile(err, 90) < 4.5
    assert smap.line_status["rx"][3] == "weak"
    assert [s for i, s in enumerate(smap.line_status["rx"]) if i != 3] == ["ok"] * 7
    assert smap.line_status["tx"] == ["ok"] * 8
    assert smap.status[1 * 8 + 7] == "noisy"
    # The footprint is the half-maximum radius of a sensor's response. The simulator's kernel
    # is (1 + d^2 / w^2)^-gamma with w^2 = h^2 + a^2 (silicone thickness h, contact radius a),
    # whose half maximum lies at d = w * sqrt(2^(1 / gamma) - 1); h runs from the top's to the
    # base's thickness (6 to 13 mm), so the true footprint is 9.8 to 13.8 mm over the cone.
    # (The estimate used to be the median of ill-posed per-sensor widths: a fixed grid value,
    # 6.37 mm, on every sensor.)
    p = SimulatedSkin(cone_skin(), random_state=0).params
    half = np.sqrt(2.0 ** (1.0 / p.falloff_exponent) - 1.0)
    lo, hi = (
        1e3 * half * np.hypot(h, p.finger_radius_m)
        for h in (p.silicone_thickness_m, p.silicone_thickness_base_m)
    )
    assert 0.8 * lo < np.median(smap.footprint_mm) < 1.2 * hi
    d = smap.as_dict()
    assert len(d["sensors"]) == 64 and len(d["lines"]) == 16
    s9 = d["sensors"][9]
    assert (s9["tx"], s9["rx"]) == (1, 1) and len(s9["position_m"]) == 3
    assert s9["status"] in ("ok", "weak", "dead", "noisy")


def test_touches_move_from_their_labels_towards_where_the_finger_was(sim_path):
    """The labels carry the person's miss; the images say where each touch really landed."""
    rec = read_recording(sim_path)
    contacts = 1e3 * np.asarray(rec.meta["true_contacts"]).reshape(-1, 3)
    cands = rec.surface_points
    tree = cKDTree(1e3 * cands)
    moved = fit_per_crossing(rec.targets, rec.touch_means, cands, tree, 8, 8, True).touches_mm
    before = np.linalg.norm(1e3 * rec.targets - contacts, axis=1)
    after = np.linalg.norm(moved - contacts, axis=1)
    assert np.median(before) > 4.5  # the simulated person misses by 5.3 mm per axis
    assert np.median(after) < 0.8 * np.median(before)  # 5.4 -> 3.5 mm on this session
    kept = fit_per_crossing(rec.targets, rec.touch_means, cands, tree, 8, 8, True, 0.0).touches_mm
    np.testing.assert_allclose(kept, 1e3 * rec.targets)  # exact labels stay where they are


def test_sensor_map_rejects_bad_input():
    cands = cone_skin().vertices
    with pytest.raises(ValueError, match="images must be"):
        S.estimate_sensor_map(np.zeros((20, 3)), np.zeros((20, 63)), 8, 8, cands)
    with pytest.raises(ValueError, match="at least 10"):
        S.estimate_sensor_map(np.zeros((5, 3)), np.zeros((5, 64)), 8, 8, cands)
    with pytest.raises(ValueError, match="label_error_mm"):
        S.estimate_sensor_map(np.zeros((20, 3)), np.zeros((20, 64)), 8, 8, cands, label_error_mm=-1)


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_info_prints_the_truth_and_sensors_scores_against_it(sim_path, tmp_path):
    info = json.loads(run("info", sim_path, "--json").output)
    assert np.asarray(info["truth_sensor_positions_m"]).shape == (64, 3)
    assert "truth_sensor_positions_m" not in info["meta"]
    res = run("sensors", sim_path, "--json", "--boot", "2", "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["truth"]["median_mm"] < 4.5
    assert all(s["uncertainty_mm"] is not None and s["uncertainty_mm"] > 0 for s in out["sensors"])
    assert {ln["kind"] for ln in out["lines"]} == {"tx", "rx"}
    assert (tmp_path / "rep" / "sensors.json").is_file()
    assert (tmp_path / "rep" / "sensors.png").stat().st_size > 1000
    # A real recording (no truth) prints no truth block.
    plain = tmp_path / "plain.h5"
    write_recording(make_recording(12, 2), plain)
    res = run("sensors", plain, "--json", "--boot", "0")
    assert res.exit_code == 0, res.output
    assert "truth" not in json.loads(res.output)


def test_sensors_bad_input_is_one_line(tmp_path, sim_path):
    res = run("sensors", tmp_path / "missing.h5")
    assert res.exit_code == 1 and "not found" in res.output
    res = run("sensors", sim_path, "--out", sim_path)
    assert res.exit_code == 1 and "overwrite" in res.output
    few = tmp_path / "few.h5"
    write_recording(make_recording(5, 2), few)
    res = run("sensors", few)
    assert res.exit_code == 1 and "at least 10" in res.output
    assert "Traceback" not in res.output


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_sensors_and_coverage_from_a_model(sim_path, sim_model, tmp_path):
    model = sim_model
    res = run("sensors", model, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert len(out["sensors"]) == 64
    assert out["sensors"][0]["uncertainty_mm"] is None  # a model keeps no touches
    res = run("coverage", model, "--json", "--points", "150", "--out", tmp_path / "cov")
    assert res.exit_code == 0, res.output
    cov = json.loads(res.output)
    assert cov["n_points"] == 150 and cov["expected_error_mm"]["mean"] > 0
    assert (tmp_path / "cov" / "coverage.png").is_file()
    res = run("sensors", model, sim_path)
    assert res.exit_code == 1 and "not both" in res.output
    res = run("coverage", model, "--out", model)
    assert res.exit_code == 1 and "overwrite" in res.output
    res = run("coverage", tmp_path / "missing.h5")
    assert res.exit_code == 1 and "not found" in res.output


def test_coverage_from_recordings_calibrates_on_held_out_touches(sim_path):
    # the recordings' path fits a map and a temperature from held-out touches
    res = run("coverage", sim_path, "--json", "--points", "100")
    assert res.exit_code == 0, res.output
    cov = json.loads(res.output)
    assert cov["n_points"] == 100 and cov["temperature"] > 1.0
    assert 0 < cov["expected_error_mm"]["mean"] < 100


def test_coverage_is_worse_where_nobody_touched(sim_path):
    rec = read_recording(sim_path)
    half = rec.targets[:, 0] < 0  # calibrate one side of the cone only
    F = shape_features(rec.touch_means[half])
    cands = rec.surface_points if rec.surface_points is not None else rec.vertices
    rmap = ResponseMap.fit(rec.targets[half], F, cands)
    cov = coverage_map(rmap, F, n_points=200)
    touched = cov.points_m[:, 0] < -0.01
    untouched = cov.points_m[:, 0] > 0.01
    assert cov.expected_mm[untouched].mean() > 2 * cov.expected_mm[touched].mean()
    assert len(cov.blind_m) > 0 and (cov.blind_m[:, 0] > 0).mean() > 0.8


def test_select_strategies(sim_path):
    rec = read_recording(sim_path)
    pool = [rec.subset(slice(0, 40)), rec.subset(slice(40, 80))]
    for strategy in ("random", "even", "active"):
        picks = select_point_logs(pool, 7, strategy, random_state=1)
        assert len(picks) == 7 and len(set(picks)) == 7
        subs = subset_recordings(pool, picks)
        assert sum(r.n_point_logs for r in subs) == 7
    assert select_point_logs(pool, 7, "random", 1) != select_point_logs(pool, 7, "random", 2)
    with pytest.raises(ValueError, match="strategy"):
        select_point_logs(pool, 5, "greedy")
    with pytest.raises(ValueError, match="between 1 and 80"):
        select_point_logs(pool, 81, "even")
    with pytest.raises(ValueError, match="eval_at"):
        select_point_logs(pool, 7, "active", eval_at="everywhere")


@pytest.mark.parametrize("eval_at", ["pool", "surface"])
def test_active_never_reads_the_images_it_has_not_chosen(sim_path, eval_at):
    rec = read_recording(sim_path)
    first = select_point_logs([rec], 7, "active", random_state=0, eval_at=eval_at)
    # Garble every image except the first six chosen: the seventh choice must not change.
    garbled = rec.subset(slice(None))
    keep = {i for _, i in first[:6]}
    rng = np.random.default_rng(0)
    for i in range(garbled.n_point_logs):
        if i not in keep:
            garbled.frames[i] = rng.uniform(0, 60000, garbled.frames[i].shape)
    assert select_point_logs([garbled], 7, "active", random_state=0, eval_at=eval_at) == first


def test_train_select_cli(sim_path, tmp_path):
    out = tmp_path / "m.h5"
    res = run("train", sim_path, "--select", "12", "--strategy", "even", "--out", out)
    assert res.exit_code == 0, res.output
    assert "12 point logs" in res.output and out.is_file()
    res = run("train", sim_path, "--select", "12", "--strategy", "bogus", "--out", out, "--force")
    assert res.exit_code == 1 and "strategy must be one of" in res.output
    res = run("train", sim_path, "--select", "500", "--out", out, "--force")
    assert res.exit_code == 1 and "between 1 and 80" in res.output


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_repeated_targets_measure_the_probing_floor(tmp_path):
    from skinloc.evaluation.repeatability import repeated_pairs, session_repeatability

    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=0)
    cfg = SessionConfig(n_points=40, mode="even", samples_per_touch=4, random_state=3, n_repeats=4)
    rec = simulate_session(skin, mesh, tmp_path / "r.h5", cfg)
    assert rec.n_point_logs == 44
    assert len(repeated_pairs([rec])) == 4
    rep = session_repeatability(rec)
    assert rep["n_pairs"] == 4 and 0.0 < rep["rms_mm"] < 30.0
    res = run("sensors", tmp_path / "r.h5", "--boot", "0")
    assert res.exit_code == 0, res.output
    assert "your probing repeatability" in res.output
    with pytest.raises(ValueError, match="n_repeats"):
        SessionConfig(n_points=5, n_repeats=6)


def test_whole_image_model_beats_the_per_crossing_fit(sim_path, crossing_map, joint_map):
    """All touches' images explain every crossing at once (sensors.joint_fit)."""
    rec = read_recording(sim_path)
    truth = S.truth_sensor_positions(rec.meta)
    old, new = crossing_map, joint_map
    e_old = S.position_errors_mm(old.positions_m, truth)
    e_new = S.position_errors_mm(new.positions_m, truth)
    assert old.method == "per-crossing" and new.method == "joint"
    assert np.median(e_new) < 0.75 * np.median(e_old)
    assert np.percentile(e_new, 90) < 0.8 * np.percentile(e_old, 90)
    assert new.as_dict()["method"] == "joint"


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_whole_image_model_falls_back_when_it_does_not_fit(sim_path, crossing_map, monkeypatch):
    rec = read_recording(sim_path)
    old = crossing_map
    monkeypatch.setattr(J, "plausible", lambda *a, **k: False)
    smap = S.sensor_map_from_recordings([rec], n_boot=2)
    assert smap.method == "per-crossing"
    np.testing.assert_allclose(smap.positions_m, old.positions_m)
    assert np.isfinite(smap.uncertainty_mm).all()


def test_plausibility_check_of_the_whole_image_model():
    labels = np.zeros((40, 3))
    rng = np.random.default_rng(0)

    def fit(miss_mm: float, width_mm: float) -> J.JointFit:
        moved = labels + miss_mm * rng.standard_normal((40, 3)) * [1, 1, 0]
        return J.JointFit(
            positions_mm=np.zeros((4, 3)), touches_mm=moved, gain=np.ones(4),
            offset=np.zeros(4), pressure=np.ones(40), width_mm=np.full(4, width_mm),
            gamma=1.0, coupling=0.1, cost=0.0,
        )  # fmt: skip

    # Touches moved about as far as the person misses, footprint like the per-crossing one.
    assert J.plausible(fit(5.3, 12.0), labels, 12.0, 5.3)
    # Touches driven three misses away: the model does not describe this skin.
    assert not J.plausible(fit(16.0, 12.0), labels, 12.0, 5.3)
    # A footprint collapsed or blown up against the per-crossing fit's.
    assert not J.plausible(fit(5.3, 4.0), labels, 12.0, 5.3)
    assert not J.plausible(fit(5.3, 40.0), labels, 12.0, 5.3)
    # Exact labels: only the footprint is judged.
    assert J.plausible(fit(0.0, 12.0), labels, 12.0, 0.0)


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_dead_lines_are_found_without_false_alarms(tmp_path):
    """Injected with the simulator's own fault options: TX 2 and RX 5 nearly dead."""
    mesh = cone_skin()
    params = dataclasses.replace(
        SkinParams.default(), weak_tx_lines=(2,), weak_rx_lines=(5,), weak_line_gain=0.03
    )
    skin = SimulatedSkin(mesh, params=params, random_state=21)
    skin.reseed(21)
    cfg = SessionConfig(n_points=80, mode="even", samples_per_touch=8, random_state=21)
    rec = simulate_session(skin, mesh, tmp_path / "dead.h5", cfg)
    smap = S.sensor_map_from_recordings([rec], n_boot=0)
    assert smap.line_status["tx"] == ["ok", "ok", "dead"] + ["ok"] * 5
    assert smap.line_status["rx"] == ["ok"] * 5 + ["dead", "ok", "ok"]
    alive = smap.status != "dead"
    err = S.position_errors_mm(smap.positions_m, S.truth_sensor_positions(rec.meta))
    assert np.median(err[alive]) < 3.0


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_weak_line_is_judged_without_the_skin_wide_response_trend(tmp_path):
    """Skin seed 5: its weak RX 3 runs near the cone's thin-silicone top, where every line
    responds more; its raw peak gain is then close to the healthy lines at the base, while its
    own (electrical) gain stands out."""
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=5)
    skin.reseed(5)
    cfg = SessionConfig(n_points=80, mode="even", samples_per_touch=8, random_state=5)
    rec = simulate_session(skin, mesh, tmp_path / "s5.h5", cfg)
    cands = rec.surface_points
    tree = cKDTree(1e3 * cands)
    fit = fit_per_crossing(rec.targets, rec.touch_means, cands, tree, 8, 8, True)
    pos, width, moved = fit.positions_mm, fit.footprint_mm, fit.touches_mm
    jf = J.joint_fit(
        1e3 * rec.targets, rec.touch_means, pos, 1e3 * cands, tree, 8, 8,
        float(np.median(width)), rec.noise, init_touches_mm=moved,
    )  # fmt: skip

    def rx_lines(g: np.ndarray) -> np.ndarray:
        g = g / np.median(g)
        rx = np.median(g.reshape(8, 8), axis=0)
        return rx / np.median(rx)

    raw, own = rx_lines(jf.gain), rx_lines(jf.electrical_gain)
    assert own[3] < 0.5 and np.delete(own, 3).min() > 0.7
    assert own[3] / np.delete(own, 3).min() < raw[3] / np.delete(raw, 3).min()
    smap = S.sensor_map_from_recordings([rec], n_boot=0)
    assert smap.line_status["rx"][3] == "weak"
    assert [s for i, s in enumerate(smap.line_status["rx"]) if i != 3] == ["ok"] * 7


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_sensors_fields_flag_reaches_the_sensor_map(sim_path, sim_model, tmp_path, monkeypatch):
    # The fields are tried only where the whole-image model is not kept (as on the real cone):
    # refuse it here so the flag can show.
    monkeypatch.setattr(J, "plausible", lambda *a, **k: False)
    seen = []
    estimate = S.estimate_sensor_map

    def spy(*args, **kw):
        seen.append(kw.get("fields"))
        return estimate(*args, **kw)

    monkeypatch.setattr(S, "estimate_sensor_map", spy)
    plain = json.loads(run("sensors", sim_path, "--json", "--boot", "0").output)
    res = run("sensors", sim_path, "--boot", "0", "--fields", "--out", tmp_path / "rep")
    assert res.exit_code == 0, res.output
    assert "held-out misfit" in res.output  # the human summary says what the check found
    with_fields = json.loads((tmp_path / "rep" / "sensors.json").read_text())
    assert seen == [False, True]
    assert plain["method"] == "per-crossing" and "heldout" not in plain
    h = with_fields["heldout"]
    assert with_fields["method"] == ("fields" if h["fields_better"] else "per-crossing")
    assert h["per_crossing"] > 0 and min(h["fields"].values()) > 0
    if h["fields_better"]:
        assert with_fields["sensors"] != plain["sensors"]
    # A model keeps no touches: the flag is refused in one line.
    res = run("sensors", sim_model, "--fields")
    assert res.exit_code == 1 and "--fields" in res.output and "Traceback" not in res.output


@pytest.mark.slow  # sensor maps fitted on simulated sessions
def test_the_app_flags_a_recording_as_skinloc_sensors_does(sim_path):
    """One classifier (``sensors.health``): the Connect page and ``skinloc sensors`` agree."""
    from skinloc.app.device import SensorMonitor
    from skinloc.app.workspace.link import session_sensor_map

    res = run("sensors", sim_path, "--json", "--boot", "0")
    assert res.exit_code == 0, res.output
    cli = json.loads(res.output)
    rec = read_recording(sim_path)
    monitor = SensorMonitor(rec.n_tx, rec.n_rx)
    session_sensor_map(sim_path, rec, monitor, wait=True)
    for k, frame in enumerate(rec.baseline_frames):  # the live stream: the skin untouched
        monitor.add(frame, 0.01 * k)
    report = monitor.report()
    assert report["status"] == [s["status"] for s in cli["sensors"]]
    for kind in ("tx", "rx"):
        app_lines = {(ln["index"], ln["status"]) for ln in report[f"{kind}_lines"]}
        cli_lines = {
            (ln["index"], ln["status"])
            for ln in cli["lines"]
            if ln["kind"] == kind and ln["status"] != "ok"
        }
        assert app_lines == cli_lines
    # the seeded faults are there to agree on: RX 3 weak, sensor TX 1 x RX 7 noisy
    assert (3, "weak") in {(ln["index"], ln["status"]) for ln in report["rx_lines"]}
    assert report["status"][1 * 8 + 7] == "noisy"
