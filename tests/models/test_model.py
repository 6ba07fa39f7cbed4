import numpy as np
import pytest

from skinloc.errors import ModelFileError, NotFittedError
from skinloc.geometry.mesh import cone_skin, sample_targets
from skinloc.models.localizer import ContactLocalizer, group_means


def bump_images(targets, sensors, width=0.02, gain=150.0, rng=None):
    """Images of Gaussian bumps: a smooth, learnable map from contact point to 64 values."""
    d2 = ((targets[:, None, :] - sensors[None]) ** 2).sum(-1)
    img = gain * np.exp(-d2 / (2 * width**2))
    if rng is not None:
        img = img * rng.uniform(0.6, 1.6, (len(img), 1)) + rng.normal(0, 3, img.shape)
    return img


@pytest.fixture(scope="module")
def toy():
    mesh = cone_skin()
    sensors = sample_targets(mesh, 64, "even", random_state=1)
    rng = np.random.default_rng(0)
    Xtr_t = sample_targets(mesh, 150, "random", random_state=2)
    Xte_t = sample_targets(mesh, 40, "random", random_state=3)
    return (
        mesh,
        bump_images(Xtr_t, sensors, rng=rng),
        Xtr_t,
        bump_images(Xte_t, sensors, rng=rng),
        Xte_t,
    )


FAST = dict(arch="mlp", epochs=150, n_members=2, hidden=(64,))


@pytest.fixture(scope="module")
def mlp(toy):
    """The small network (FAST, seed 0, snapped to the toy surface), trained once for the tests
    that only use it (none changes it: ``recalibrate`` returns a copy, as a test checks)."""
    mesh, X, y, *_ = toy
    return ContactLocalizer(**FAST, random_state=0).fit(X, y, mesh=mesh)


@pytest.fixture(scope="module")
def rmap(toy):
    """The default response map of the toy skin, fitted once for the tests that only use it."""
    mesh, X, y, *_ = toy
    return ContactLocalizer().fit(X, y, mesh=mesh)


#: Predictions of the same model agree to a nanometre (m). Not bit for bit: BLAS may sum a
#: single frame and a batch, or another thread count, in a different order.
SAME_M = 1e-9


def assert_same_points(a: np.ndarray, b: np.ndarray, tol_m: float = SAME_M) -> None:
    """Points ``a`` and ``b`` (n, 3) m are the same contacts to within ``tol_m``."""
    np.testing.assert_allclose(a, b, rtol=0, atol=tol_m)


def test_learns_toy_skin(toy, mlp):
    mesh, X, y, Xt, yt = toy
    m = mlp
    err = 1e3 * np.linalg.norm(m.predict(Xt) - yt, axis=1)
    assert np.mean(err) < 12.0
    base = 1e3 * np.linalg.norm(yt - y.mean(0), axis=1).mean()
    assert np.mean(err) < base / 3


def test_paper_arch_is_64_32_3(toy):
    mesh, X, y, *_ = toy
    m = ContactLocalizer(arch="paper", epochs=20).fit(X, y)
    assert [w.shape for w in m.coefs_] == [(1, 64, 32), (1, 32, 3)]
    assert m.config_["activation"] == "tanh"


@pytest.mark.slow  # several ensembles
def test_deterministic_under_seed(toy, mlp):
    mesh, X, y, Xt, _ = toy
    a = mlp.predict(Xt)  # seed 0, trained earlier in this process: no state carried over
    b = ContactLocalizer(**FAST, random_state=0).fit(X, y, mesh=mesh).predict(Xt)
    c = ContactLocalizer(**FAST, random_state=4).fit(X, y, mesh=mesh).predict(Xt)
    # Same seed, same model: to a micrometre (a trained model, not bits; training summed in
    # another order on another machine may drift by more than a single prediction does).
    assert_same_points(a, b, tol_m=1e-6)
    assert np.abs(a - c).max() > 1e-4  # another seed: another model, 0.1 mm and more apart


def test_single_frame_and_batch_agree(toy, mlp):
    mesh, X, y, Xt, _ = toy
    m = mlp
    batch = m.predict(Xt)
    single = np.concatenate([m.predict(x) for x in Xt])
    assert_same_points(single, batch)


@pytest.mark.parametrize("constraint", ["snap", "project"])
def test_outputs_lie_on_surface(toy, mlp, constraint):
    from skinloc.geometry.mesh import nearest_on_surface

    mesh, X, y, Xt, _ = toy
    if constraint == mlp.constraint:  # "snap", the default: the shared network
        m = mlp
    else:
        m = ContactLocalizer(**FAST, constraint=constraint).fit(X, y, mesh=mesh)
    _, d, _ = nearest_on_surface(mesh, m.predict(Xt))
    assert d.max() < 1e-9


@pytest.mark.slow  # several ensembles
def test_uncertainty_from_ensemble(toy, mlp):
    mesh, X, y, Xt, _ = toy
    p = mlp.predict_full(Xt)
    assert p.uncertainty_mm.shape == (len(Xt),) and np.all(p.uncertainty_mm >= 0)
    single = (
        ContactLocalizer(arch="mlp", epochs=20, n_members=1, hidden=(8,)).fit(X, y).predict_full(Xt)
    )
    assert np.all(np.isnan(single.uncertainty_mm))


def test_save_load_roundtrip(toy, mlp, tmp_path):
    mesh, X, y, Xt, _ = toy
    m = mlp
    m.save(tmp_path / "m.h5")
    back = ContactLocalizer.load(tmp_path / "m.h5")
    for W, V in zip(back.coefs_, m.coefs_, strict=True):
        np.testing.assert_array_equal(W, V)  # the file keeps every weight exactly
    assert_same_points(back.predict(Xt), m.predict(Xt))
    assert back.config_ == m.config_
    assert back.meta_["skinloc_version"]


def test_model_file_is_self_describing(mlp, tmp_path):
    import json

    import h5py

    mlp.save(tmp_path / "m.h5")
    with h5py.File(tmp_path / "m.h5") as f:
        assert f.attrs["format"] == "skinloc-model" and f.attrs["format_version"] == 2
        assert json.loads(f.attrs["config"])["hidden"] == [64]
        assert f["network/layer0/weight"].shape == (2, 64, 64)
        assert f["surface/points"].shape == (14400, 3)


def test_not_fitted():
    with pytest.raises(NotFittedError, match="fit"):
        ContactLocalizer().predict(np.zeros(64))


def test_wrong_width_names_64(mlp):
    m = mlp
    with pytest.raises(ValueError, match="64"):
        m.predict(np.zeros((2, 63)))
    with pytest.raises(ValueError, match="NaN"):
        m.predict(np.full(64, np.nan))


@pytest.mark.parametrize(
    "param,value,match",
    [
        ("arch", "huge", "arch"),
        ("activation", "sigmoid", "activation"),
        ("n_members", 0, "n_members"),
        ("normalise", "max", "normalise"),
        ("constraint", "nearest", "constraint"),
        ("epochs", 0, "epochs"),
    ],
)
def test_bad_hyperparameters_named(toy, param, value, match):
    mesh, X, y, *_ = toy
    with pytest.raises(ValueError, match=match):
        ContactLocalizer(**{"arch": "mlp", param: value}).fit(X, y)


def test_parameter_of_another_kind_is_refused(toy):
    mesh, X, y, *_ = toy
    with pytest.raises(ValueError, match="'epochs' parameter does not apply to arch 'default'"):
        ContactLocalizer(epochs=10).fit(X, y, mesh=mesh)


def test_bad_training_shapes(toy):
    mesh, X, y, *_ = toy
    with pytest.raises(ValueError, match="shape"):
        ContactLocalizer(**FAST).fit(X, y[:-1])


def test_divergence_raises(toy):
    mesh, X, y, *_ = toy
    with pytest.raises(ValueError, match="diverged"):
        ContactLocalizer(arch="mlp", epochs=5, n_members=1, hidden=(8,), lr=1e30).fit(X * 1e30, y)


def test_load_errors(tmp_path):
    with pytest.raises(ModelFileError, match="not found"):
        ContactLocalizer.load(tmp_path / "none.h5")
    (tmp_path / "junk.h5").write_bytes(b"junk")
    with pytest.raises(ModelFileError):
        ContactLocalizer.load(tmp_path / "junk.h5")


def test_group_means():
    X = np.array([[1.0, 2.0], [3.0, 4.0], [10.0, 10.0]])
    y = np.array([[0, 0, 0], [0, 0, 2.0], [1, 1, 1.0]])
    Xm, ym = group_means(X, y, np.array([5, 5, 7]))
    np.testing.assert_array_equal(Xm, [[2, 3], [10, 10]])
    np.testing.assert_array_equal(ym, [[0, 0, 1], [1, 1, 1]])


# ------------------------------------------------------------------ response map (the default)


def test_map_learns_toy_skin(toy, rmap):
    mesh, X, y, Xt, yt = toy
    m = rmap
    assert m.config_["kind"] == "map"
    err = 1e3 * np.linalg.norm(m.predict(Xt) - yt, axis=1)
    assert np.mean(err) < 6.0


def test_a_map_fitted_without_its_count_rule_predicts_the_same_points(toy, rmap):
    """count_rule=False (cross-validation folds): the same single-touch answers, no rule."""
    mesh, X, y, Xt, yt = toy
    full = rmap
    light = ContactLocalizer(count_rule=False).fit(X, y, mesh=mesh)
    assert full.contact_rule_ is not None and light.contact_rule_ is None
    a, b = full.predict_full(Xt), light.predict_full(Xt)
    assert_same_points(a.points, b.points)
    np.testing.assert_allclose(a.uncertainty_mm, b.uncertainty_mm, rtol=1e-9, atol=1e-9)


def test_map_outputs_are_surface_points_with_uncertainty(toy, rmap):
    from skinloc.geometry.mesh import nearest_on_surface

    mesh, X, y, Xt, yt = toy
    pred = rmap.predict_full(Xt)
    _, d, _ = nearest_on_surface(mesh, pred.points)
    assert d.max() < 1e-9
    assert np.all(np.isfinite(pred.uncertainty_mm)) and np.all(pred.uncertainty_mm >= 0)


def test_map_uncertainty_grows_with_noise(toy, rmap):
    mesh, X, y, Xt, _ = toy
    m = rmap
    rng = np.random.default_rng(5)
    clean = m.predict_full(Xt).uncertainty_mm
    noisy = m.predict_full(Xt * 0.3 + rng.normal(0, 8, Xt.shape)).uncertainty_mm
    assert np.median(noisy) > np.median(clean)


def test_map_needs_a_surface(toy):
    _, X, y, *_ = toy
    with pytest.raises(ValueError, match="mesh"):
        ContactLocalizer().fit(X, y)


def test_map_save_load_roundtrip(toy, rmap, tmp_path):
    mesh, X, y, Xt, _ = toy
    m = rmap
    m.save(tmp_path / "m.h5")
    back = ContactLocalizer.load(tmp_path / "m.h5")
    assert_same_points(back.predict(Xt), m.predict(Xt))
    assert back.config_ == m.config_


def test_recalibration_recovers_a_moved_response(toy, rmap, tmp_path):
    """A new session where some sensors' responses changed: a few touches repair the map."""
    mesh, X, y, Xt, yt = toy
    m = rmap
    rng = np.random.default_rng(1)
    gains = rng.uniform(0.3, 2.0, X.shape[1])  # a re-mounted skin: every sensor's gain moved
    new_t = sample_targets(mesh, 15, "even", random_state=9)
    sensors = sample_targets(mesh, 64, "even", random_state=1)
    X_new = bump_images(new_t, sensors) * gains
    Xt_moved = Xt * gains

    def err(model):
        return (1e3 * np.linalg.norm(model.predict(Xt_moved) - yt, axis=1)).mean()

    re = m.recalibrate(X_new, new_t)
    assert err(re) < 0.7 * err(m)
    assert len(re.map_.layers) == 2 and len(m.map_.layers) == 1  # the original is untouched
    re.save(tmp_path / "re.h5")
    assert_same_points(ContactLocalizer.load(tmp_path / "re.h5").predict(Xt), re.predict(Xt))


def test_network_recalibration_fine_tunes(toy, mlp):
    mesh, X, y, Xt, yt = toy
    m = mlp
    re = m.recalibrate(X[:20], y[:20])
    assert not np.array_equal(re.coefs_[0], m.coefs_[0])
    assert re.recalibration_["method"] == "fine-tuned" and re.recalibration_["n_touches"] == 20
    assert re.predict(Xt).shape == yt.shape
