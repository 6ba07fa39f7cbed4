import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skinloc.data.recording import Recording, read_recording, write_mat, write_recording
from skinloc.errors import RecordingError
from tests.conftest import make_recording


def assert_same(a: Recording, b: Recording, atol: float = 0.0) -> None:
    assert (a.n_tx, a.n_rx) == (b.n_tx, b.n_rx)
    np.testing.assert_allclose(a.frames, b.frames, atol=atol)
    np.testing.assert_allclose(a.baseline_frames, b.baseline_frames, atol=atol)
    np.testing.assert_array_equal(a.targets, b.targets)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


@settings(
    max_examples=15,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    n=st.integers(1, 5),
    s=st.integers(1, 4),
    tx=st.integers(1, 21),
    rx=st.integers(1, 12),
    seed=st.integers(0, 1000),
)
def test_h5_roundtrip_is_identical(tmp_path, n, s, tx, rx, seed):
    rec = make_recording(n, s, tx, rx, seed)
    path = tmp_path / f"r{seed}.h5"
    write_recording(rec, path)
    back = read_recording(path)
    assert_same(rec, back)
    assert back.meta["description"] == "synthetic"


def test_mat_roundtrip(tmp_path, recording_factory):
    rec = recording_factory(7, 5)
    write_mat(rec, tmp_path / "r.mat")
    back = read_recording(tmp_path / "r.mat")
    assert_same(rec, back, atol=1e-2)  # float32 raw counts around 8000
    np.testing.assert_allclose(back.touch_means, rec.touch_means, atol=1e-2)


def test_mat_layout_matches_paper(tmp_path, recording_factory):
    import scipy.io

    rec = recording_factory(3, 4)
    write_mat(rec, tmp_path / "r.mat")
    td = scipy.io.loadmat(tmp_path / "r.mat", squeeze_me=True, struct_as_record=False)["touchData"]
    assert (td.numTX, td.numRX, td.numSensors) == (8, 8, 64)
    assert td.CPL.sensorStateRaw.shape == (20, 64)
    assert len(td.PL) == 3 and td.PL[0].sensorStateRaw.shape == (4, 64)
    np.testing.assert_allclose(td.PL[1].sensorStateAvg, rec.touch_means[1], atol=1e-3)
    assert td.LIN.sensorStateRaw.shape == (12, 64) and td.LIN.touchPosRaw.shape == (12, 3)
    assert td.obj.f.min() == 1  # MATLAB indices


def test_real_mat_reads(real_dir):
    rec = read_recording(real_dir / "ConeSkinData80Points_RND_80PL_1.mat")
    assert (rec.n_point_logs, rec.samples_per_touch, rec.n_sensors) == (80, 50, 64)
    assert rec.surface_points.shape == (14400, 3)
    assert 3000 < rec.baseline.min() < rec.baseline.max() < 12000
    assert 3.4 < np.median(rec.noise) < 5.7
    # touch means equal the paper's stored sensorStateAvg
    import scipy.io

    td = scipy.io.loadmat(
        real_dir / "ConeSkinData80Points_RND_80PL_1.mat", squeeze_me=True, struct_as_record=False
    )["touchData"]
    np.testing.assert_allclose(rec.touch_means, td.LIN.sensorStateAvg, atol=2e-3)


def test_real_roundtrip_through_h5_and_mat(real_dir, tmp_path):
    rec = read_recording(real_dir / "ConeSkinData_RND_20PL_1.mat")
    write_recording(rec, tmp_path / "a.h5")
    write_mat(read_recording(tmp_path / "a.h5"), tmp_path / "b.mat")
    assert_same(rec, read_recording(tmp_path / "b.mat"), atol=2e-3)


def test_subset_and_append(recording_factory):
    rec = recording_factory(6, 3)
    sub = rec.subset([0, 2])
    assert sub.n_point_logs == 2
    np.testing.assert_array_equal(sub.frames[1], rec.frames[2])
    sub.append(rec.targets[5], rec.frames[5])
    assert sub.n_point_logs == 3
    with pytest.raises(RecordingError, match="shape"):
        sub.append(rec.targets[0], rec.frames[0][:2])


def test_a_subset_keeps_the_per_touch_meta_of_its_touches(recording_factory):
    rec = recording_factory(5, 3)
    rec.meta["true_contacts"] = [[float(i), 0.0, 0.0] for i in range(5)]
    rec.meta["probe_depths_m"] = [0.001, 0.002, 0.003]  # touches 4 and 5 pressed by hand
    rec.meta["description"] = "kept whole"
    sub = rec.subset([4, 1, 3])
    assert [c[0] for c in sub.meta["true_contacts"]] == [4.0, 1.0, 3.0]
    assert sub.meta["probe_depths_m"] == [None, 0.002]  # aligned; no entry for touch 4
    assert sub.meta["description"] == "kept whole"
    assert len(rec.meta["true_contacts"]) == 5  # the original untouched


@pytest.mark.parametrize(
    "content,match",
    [
        (b"", "empty"),
        (b"hello world, not a recording", "neither"),
        (b"\x89HDF\r\n\x1a\n" + b"\0" * 40, "cannot read"),
        (b"MATLAB 5.0 MAT-file, truncated", "cannot read"),
    ],
)
def test_bad_files_give_recording_error(tmp_path, content, match):
    p = tmp_path / "bad.h5"
    p.write_bytes(content)
    with pytest.raises(RecordingError, match=match):
        read_recording(p)


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="not found"):
        read_recording(tmp_path / "missing.h5")


def test_truncated_real_file(real_dir, tmp_path):
    data = (real_dir / "ConeSkinData_RND_20PL_1.mat").read_bytes()
    p = tmp_path / "cut.mat"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError):
        read_recording(p)


def test_nan_frames_rejected(recording_factory):
    rec = recording_factory(2, 2)
    frames = rec.frames.copy()
    frames[0, 0, 0] = np.nan
    with pytest.raises(RecordingError, match="NaN"):
        Recording(
            n_tx=8,
            n_rx=8,
            vertices=rec.vertices,
            faces=rec.faces,
            baseline_frames=rec.baseline_frames,
            targets=rec.targets,
            frames=frames,
        )


def test_grid_limits(recording_factory):
    with pytest.raises(RecordingError, match="21 x 1-12"):
        recording_factory(1, 1, n_tx=22, n_rx=8)


def test_write_is_atomic(tmp_path, recording_factory, monkeypatch):
    rec = recording_factory(2, 2)
    path = tmp_path / "r.h5"
    write_recording(rec, path)
    before = path.read_bytes()

    import h5py

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(h5py.File, "create_group", boom)
    with pytest.raises(OSError):
        write_recording(recording_factory(3, 2), path)
    assert path.read_bytes() == before
    assert list(tmp_path.iterdir()) == [path]  # no temporary left behind
