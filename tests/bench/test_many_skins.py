"""The 100-skin benchmark's plumbing: K, worker processes, the model cache (no timing asserted)."""

from __future__ import annotations

import pytest

from skinloc.bench.many_skins import many_skins
from skinloc.bench.online import model_code_stamp, train_bench_models
from tests._live import model_path


@pytest.mark.slow  # a multi-process benchmark
def test_many_skins_in_worker_processes_with_one_contact_per_frame():
    m = many_skins(
        model_path("map"), n_skins=4, rate_hz=50.0, duration_s=2.0, max_contacts=1, workers=2
    )
    assert m["workers"] == 2 and m["max_contacts"] == 1
    assert m["frames_sent"] == 400 and m["frames_dropped"] == 0
    assert m["parser_dropped_or_lost"] == 0
    assert m["contacts"] > 0 and m["loop_thread_cpu_s"] > 0


def test_many_skins_reports_the_pipelines_default_contacts_per_frame():
    m = many_skins(model_path("map"), n_skins=2, rate_hz=50.0, duration_s=1.0)
    assert m["workers"] == 1 and m["max_contacts"] == 3
    assert m["frames_sent"] == 100 and m["frames_dropped"] == 0


def test_many_skins_refuses_more_workers_than_skins():
    with pytest.raises(ValueError, match="workers must be 1..2"):
        many_skins(model_path("map"), n_skins=2, duration_s=1.0, workers=3)


def test_benchmark_models_trained_by_other_code_are_made_again(tmp_path):
    stale = tmp_path / "default.h5"
    stale.write_bytes(b"a model trained by older code")
    (tmp_path / "cal.h5").write_bytes(b"an older calibration")
    (tmp_path / "code-stamp").write_text("0123456789abcdef\n")
    assert train_bench_models(tmp_path, ()) == {}  # nothing asked: nothing trained
    assert not stale.exists() and not (tmp_path / "cal.h5").exists()
    # set aside, not deleted
    aside = tmp_path / "older-0123456789abcdef"
    assert (aside / "default.h5").read_bytes() == b"a model trained by older code"
    assert (aside / "cal.h5").read_bytes() == b"an older calibration"
    assert (tmp_path / "code-stamp").read_text().strip() == model_code_stamp()
    # the same code: the cache holds
    stale.write_bytes(b"current")
    assert train_bench_models(tmp_path, ("default",)) == {"default": stale}
    assert stale.read_bytes() == b"current"


def test_model_code_stamp_is_stable():
    a = model_code_stamp()
    assert a == model_code_stamp() and len(a) == 16 and int(a, 16) >= 0


@pytest.mark.slow  # a multi-process benchmark
def test_many_skins_in_worker_processes_with_the_ros2_sink(monkeypatch):
    from skinloc.bench.sinks import LOOPBACK_DDS

    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK_DDS)
    m = many_skins(
        model_path("map"), n_skins=2, rate_hz=50.0, duration_s=1.5, sinks=("ros2",), workers=2
    )
    # one sink per worker process, their statistics summed
    st = m["sink_stats"]["ros2"]
    assert m["workers"] == 2 and m["frames_processed"] > 0
    assert st["queued"] > 0 and st["sent"] == st["queued"] and st["pending"] == 0
    assert m["sink_frames_dropped"] == 0 and st["cpu_s"] > 0


@pytest.mark.slow  # a multi-process benchmark
def test_many_skins_through_rclpy_nodes_beside_busy_processes(monkeypatch):
    pytest.importorskip("rclpy", reason="the ROS 2 Jazzy wheels: pip install '.[ros2]'")
    m = many_skins(
        model_path("map"), n_skins=2, rate_hz=50.0, duration_s=1.5, sinks=("ros2",),
        workers=2, backend="rclpy", hogs=1,
    )  # fmt: skip
    assert m["ros2_backend"] == "rclpy" and m["cpu_heavy_processes_beside"] == 1
    assert len(m["load_average_before"]) == len(m["load_average_after"]) == 3
    st = m["sink_stats"]["ros2"]
    assert m["frames_processed"] > 0 and st["queued"] > 0 and st["sent"] == st["queued"]
    # the loop's CPU beside the single-contact NumPy baseline's, from the same processes
    assert m["baseline_cpu_us_per_frame"] > 0
    assert m["loop_cpu_over_baseline"] == pytest.approx(
        m["loop_cpu_us_per_frame"] / m["baseline_cpu_us_per_frame"]
    )
    with pytest.raises(ValueError, match="backend must be dds or rclpy"):
        many_skins(model_path("map"), n_skins=2, duration_s=1.0, backend="fastdds")
    with pytest.raises(ValueError, match="hogs must be 0 or more"):
        many_skins(model_path("map"), n_skins=2, duration_s=1.0, hogs=-1)


@pytest.mark.slow  # a multi-process benchmark
def test_many_skins_profiles_each_loop_and_splits_the_time(tmp_path):
    import pstats

    m = many_skins(
        model_path("map"), n_skins=2, rate_hz=50.0, duration_s=1.5, workers=2, nice=3,
        profile_dir=tmp_path,
    )  # fmt: skip
    assert m["loop_nice"] == 3 and m["frames_processed"] > 0 and m["contacts"] > 0
    for w in (0, 1):  # one profile per worker's loop, with the loop's turns in it
        stats = pstats.Stats(str(tmp_path / f"loop-{w}.prof")).stats  # type: ignore[attr-defined]
        assert any(func == "_step" for _file, _line, func in stats)
    assert m["queueing_median_us"] is not None and m["queueing_p99_us"] >= m["queueing_median_us"]
    assert m["turns"] > 0 and m["turn_cpu_max_us"] >= m["turn_cpu_p99_us"] >= 0
    assert len(m["loop_cpu_us_per_frame_each"]) == 2
    assert m["feeder_cpu_us_per_frame"] > 0 and m["loop_process_cpu_us_per_frame"] > 0
