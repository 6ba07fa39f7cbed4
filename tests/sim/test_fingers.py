"""Several fingers on the simulated skin (skinloc.sim.fingers): physics beyond a sum of images."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from skinloc.geometry.mesh import cone_skin
from skinloc.sim.fingers import Finger, multi_touch_image, nearest_lines, summed_image
from skinloc.sim.skin import SimulatedSkin, SkinParams, sensor_image

SEED = int(os.environ.get("SKINLOC_TEST_SEED", "0"))


@pytest.fixture(scope="module")
def skin() -> SimulatedSkin:
    return SimulatedSkin(cone_skin(), random_state=SEED)


def _ordinary(skin: SimulatedSkin) -> np.ndarray:
    """Sensor indices on no weak line (grid (n_tx, n_rx) of bools, raveled)."""
    p = skin.params
    ok = np.ones((skin.n_tx, skin.n_rx), dtype=bool)
    ok[list(p.weak_tx_lines), :] = False
    ok[:, list(p.weak_rx_lines)] = False
    return ok.ravel()


def _pair(skin: SimulatedSkin, kind: str) -> tuple[int, int]:
    """Two ordinary sensors far apart (> 40 mm) on one TX line, one RX line, or neither."""
    pos, ok, n_rx = skin.sensor_positions, _ordinary(skin), skin.n_rx
    best, best_d = None, 0.0
    for a in np.flatnonzero(ok):
        for b in np.flatnonzero(ok):
            ta, ra = divmod(int(a), n_rx)
            tb, rb = divmod(int(b), n_rx)
            same = {"tx": ta == tb and ra != rb, "rx": ra == rb and ta != tb}
            same["none"] = ta != tb and ra != rb
            d = float(np.linalg.norm(pos[a] - pos[b]))
            if same[kind] and d > best_d:
                best, best_d = (int(a), int(b)), d
    assert best is not None and best_d > 0.04
    return best


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_one_finger_is_the_single_image(skin: SimulatedSkin) -> None:
    p, lay = skin.params, skin.layout
    f = Finger(lay.sensor_positions[9], 1.3, 0.009)
    single = sensor_image(lay, p, f.position_m, f.pressure, f.radius_m)
    np.testing.assert_allclose(multi_touch_image(lay, p, [f]), single, rtol=1e-12)
    # the general path (two fingers, one pressing with zero force) gives it too
    ghost = Finger(lay.sensor_positions[-1], 0.0, 0.01)
    np.testing.assert_allclose(multi_touch_image(lay, p, [f, ghost]), single, rtol=1e-9, atol=1e-9)
    assert not multi_touch_image(lay, p, []).any()


@pytest.mark.parametrize("line", ["tx", "rx"])
def test_two_fingers_on_one_line_are_not_additive(skin: SimulatedSkin, line: str) -> None:
    p, lay = skin.params, skin.layout
    a, b = _pair(skin, line)
    fingers = [Finger(lay.sensor_positions[k], 1.0, 0.01) for k in (a, b)]
    phys = multi_touch_image(lay, p, fingers)
    summ = summed_image(lay, p, fingers)
    assert _rel(phys, summ) > 0.03
    # each finger's own crossing gives less than the sum: the line's field is shared
    assert phys[a] < 0.97 * summ[a] and phys[b] < 0.97 * summ[b]
    # and without the interaction terms the images add up
    linear = dataclasses.replace(
        p, body_retransmission=0.0, crossing_saturation_counts=1e9, line_saturation_counts=1e9
    )
    phys0 = multi_touch_image(lay, linear, fingers)
    assert _rel(phys0, summed_image(lay, linear, fingers)) < 1e-5


def test_far_apart_on_no_shared_line_is_nearly_additive(skin: SimulatedSkin) -> None:
    p, lay = skin.params, skin.layout
    a, b = _pair(skin, "none")
    fingers = [Finger(lay.sensor_positions[k], 1.0, 0.01) for k in (a, b)]
    phys = multi_touch_image(lay, p, fingers)
    summ = summed_image(lay, p, fingers)
    assert _rel(phys, summ) < 0.10
    assert phys[a] > 0.95 * summ[a] and phys[b] > 0.95 * summ[b]
    # a shared line costs each finger more of its own peak than no shared line does
    a2, b2 = _pair(skin, "tx")
    shared = [Finger(lay.sensor_positions[k], 1.0, 0.01) for k in (a2, b2)]
    loss_shared = 1 - multi_touch_image(lay, p, shared)[a2] / summed_image(lay, p, shared)[a2]
    assert loss_shared > 1 - phys[a] / summ[a]


def test_ghost_crossings_go_down_with_a_floating_body(skin: SimulatedSkin) -> None:
    """Body re-transmission lowers the crossings (TX of one finger, RX of the other)."""
    p, lay = skin.params, skin.layout
    a, b = _pair(skin, "none")
    fingers = [Finger(lay.sensor_positions[k], 1.0, 0.01) for k in (a, b)]
    (ta, ra), (tb, rb) = divmod(a, skin.n_rx), divmod(b, skin.n_rx)
    ghosts = [ta * skin.n_rx + rb, tb * skin.n_rx + ra]
    floating = dataclasses.replace(p, body_retransmission=0.5)
    grounded = dataclasses.replace(p, body_retransmission=0.0)
    for g in ghosts:
        assert (
            multi_touch_image(lay, floating, fingers)[g]
            < multi_touch_image(lay, grounded, fingers)[g] - 10
        )


def test_nearest_lines(skin: SimulatedSkin) -> None:
    k = 19
    assert nearest_lines(skin.layout, skin.sensor_positions[k]) == divmod(k, skin.n_rx)


def test_skin_touch_with_fingers(skin: SimulatedSkin) -> None:
    pos = skin.sensor_positions
    s = SimulatedSkin(
        cone_skin(),
        random_state=SEED,
        params=dataclasses.replace(
            skin.params,
            noise_std_counts=0.0,
            noise_std_min_counts=0.0,
            noise_std_max_counts=0.0,
            noisy_sensor_noise_std_counts=0.0,
            drift_std_counts=0.0,
        ),
    )
    with s:
        base = s.read().values
        s.touch([Finger(pos[9], 1.0, 0.01)])
        one = s.read().values - base
        s.press(pos[9], pressure=1.0, finger_radius_m=0.01)
        pressed = s.read().values - base
        np.testing.assert_allclose(one, pressed, atol=1.0)
        s.touch([Finger(pos[9], 1.0, 0.01), Finger(pos[50], 1.0, 0.01)])
        two = s.read().values - base
        assert two[50] > 50 and two[9] > 50
        np.testing.assert_allclose(s.contact, pos[9])
        s.touch([])
        assert s.contact is None
        np.testing.assert_allclose(s.read().values, base, atol=1.0)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("crossing_saturation_counts", 0.0),
        ("line_saturation_counts", -1.0),
        ("body_retransmission", 1.5),
    ],
)
def test_multi_finger_params_are_checked(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(SkinParams.default(), **{field: value})
