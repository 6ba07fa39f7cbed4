"""The simulated touch stream the live benchmarks replay (``online``, ``many_skins``)."""

from __future__ import annotations

import numpy as np

__all__ = ["touch_stream"]


def touch_stream(
    n_frames: int, *, random_state: int = 0, n_baseline: int = 100
) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray]]]:
    """Raw frames ``(n, 64)`` uint16 of the simulated skin with a scripted finger.

    ``n_baseline`` untouched frames, then touches of 0.6-1.5 s with pauses of 0.3-0.6 s at
    100 Hz (about 75 % of frames touched). Returns the frames and the script
    ``(first frame, last frame, contact (3,) m)``.
    """
    import dataclasses

    from skinloc.geometry.mesh import sample_surface
    from skinloc.sim.skin import SimulatedSkin, SkinParams

    rng = np.random.default_rng(random_state)
    # Firm touches only: the stream times the live path and checks its events; the light
    # touches of a calibration (weak_touch_prob) can fall under its 8-sigma start threshold.
    firm = dataclasses.replace(SkinParams.default(), weak_touch_prob=0.0)
    skin = SimulatedSkin(params=firm, random_state=random_state)
    skin.connect()
    targets = sample_surface(skin.mesh, 512, rng)[0]
    frames = np.empty((n_frames, skin.n_sensors), dtype=np.uint16)
    script = []
    k = 0
    for k in range(min(n_baseline, n_frames)):
        frames[k] = skin.read().values
    k = min(n_baseline, n_frames)
    while k < n_frames:
        contact = skin.touch_near(targets[rng.integers(len(targets))], rng)
        hold = int(rng.uniform(60, 150))
        start = k
        for _ in range(hold):
            if k >= n_frames:
                break
            frames[k] = skin.read().values
            k += 1
        script.append((start, k - 1, contact))
        skin.release()
        for _ in range(int(rng.uniform(30, 60))):
            if k >= n_frames:
                break
            frames[k] = skin.read().values
            k += 1
    return frames, script
