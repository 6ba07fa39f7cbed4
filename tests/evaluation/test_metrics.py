import numpy as np
import pytest

from skinloc.evaluation.metrics import error_stats, localisation_errors_mm, mean_snr_db, snr_db


def test_snr_hand_example():
    baseline = np.array([[100.0, 10.0], [102.0, 12.0]])  # sigma = 1 count for both sensors
    touches = np.array([[10.0, 1.0], [100.0, -5.0]])  # deltas: peak 100 and 1
    np.testing.assert_allclose(snr_db(touches, baseline), [40.0, 0.0])
    assert mean_snr_db(touches, baseline) == pytest.approx(20.0)


def test_snr_undefined_for_non_positive_peak():
    baseline = np.array([[0.0], [2.0]])
    assert np.isnan(snr_db(np.array([[-3.0]]), baseline)[0])


def test_real_snr_matches_readme(real_dir):
    from skinloc.data.recording import read_recording

    rec = read_recording(real_dir / "ConeSkinData80Points_RND_80PL_1.mat")
    s = snr_db(rec.touch_means, rec.baseline_frames)
    assert 25 < np.nanmean(s) < 27  # README: mean 26 dB
    assert 30 < np.nanmax(s) < 40


def test_errors_and_stats():
    e = localisation_errors_mm(np.array([[0, 0, 0.003], [0, 0, 0]]), np.zeros((2, 3)))
    np.testing.assert_allclose(e, [3.0, 0.0])
    st = error_stats(np.arange(1, 101, dtype=float))
    assert (st.n, st.mean_mm, st.median_mm) == (100, 50.5, 50.5)
    assert st.p95_mm == pytest.approx(95.05)
    assert set(st.as_dict()) >= {"n", "mean_mm", "std_mm", "median_mm", "p95_mm"}
    with pytest.raises(ValueError):
        error_stats(np.array([]))
    with pytest.raises(ValueError, match="shape"):
        localisation_errors_mm(np.zeros((2, 3)), np.zeros((3, 3)))
