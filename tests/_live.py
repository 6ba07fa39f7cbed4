"""Small trained models and streams for the live-path tests (built once per session).

Under ``pytest -n`` the workers of one run share them: the first to need one builds it into
a folder of that run (``shared_dir``), the others wait for it and read the file; the run's
controller removes the folder at its end (``tests/conftest.py``). A test never writes to them.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

#: Set by pytest-xdist in each worker, the same for every worker of one run.
RUN_ENV = "PYTEST_XDIST_TESTRUNUID"


def shared_dir(run_id: str) -> Path:
    """The folder the workers of run ``run_id`` build into."""
    return Path(tempfile.gettempdir()) / f"skinloc-live-tests-{run_id}"


if os.environ.get(RUN_ENV) and os.name == "posix":
    _DIR = shared_dir(os.environ[RUN_ENV])
    _DIR.mkdir(exist_ok=True)
else:
    _DIR = Path(tempfile.mkdtemp(prefix="skinloc-live-tests-"))  # per process: runs never share
    atexit.register(shutil.rmtree, _DIR, ignore_errors=True)


def shared_file(name: str) -> Path:
    """``name`` in the folder the workers of this run share (build it under ``build_once``)."""
    return _DIR / name


@contextlib.contextmanager
def build_once(path: Path) -> Iterator[bool]:
    """Held while ``path`` is found or built, one process at a time: yields True when it is
    not there yet (the caller builds it). A build that fails leaves no file behind."""
    import fcntl

    with open(path.with_name(path.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        build = not path.exists()
        try:
            yield build
        except BaseException:
            if build:
                path.unlink(missing_ok=True)
            raise


@functools.lru_cache(maxsize=1)
def calibration():
    """A simulated calibration: 30 touches x 5 frames on the paper cone."""
    from skinloc.calibration.session import SessionConfig, simulate_session
    from skinloc.data.recording import read_recording
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sim.skin import SimulatedSkin

    path = _DIR / "cal.h5"
    with build_once(path) as build:
        if not build:
            return read_recording(path)  # simulate_session returns the file read back too
        mesh = cone_skin()
        with SimulatedSkin(mesh, random_state=0) as skin:
            return simulate_session(
                skin,
                mesh,
                path,
                SessionConfig(n_points=30, mode="even", samples_per_touch=5, random_state=0),
            )


@functools.cache
def model_path(kind: str) -> Path:
    """A saved model: ``map`` (the default), ``mlp`` (small relu ensemble), ``paper`` (tanh),
    ``gelu`` (one gelu network, l1 normalised)."""
    if kind not in ("map", "mlp", "paper", "gelu"):
        raise ValueError(kind)
    path = _DIR / f"{kind}.h5"
    with build_once(path) as build:
        if build:
            _train(kind).save(path)
    return path


def _train(kind: str):
    """The model ``kind`` of ``model_path``, trained on ``calibration()``."""
    from skinloc.evaluation.scoring import train_localizer

    cal = calibration()
    if kind == "map":
        model = train_localizer([cal], arch="default")
    elif kind == "mlp":
        model = train_localizer([cal], arch="mlp", epochs=5, hidden=(24, 16), n_members=3)
    elif kind == "paper":
        model = train_localizer([cal], arch="paper", epochs=30)
    elif kind == "gelu":
        model = train_localizer(
            [cal],
            arch="mlp",
            epochs=5,
            hidden=(16,),
            n_members=1,
            activation="gelu",
            normalise="l1",
            clip_negative=False,
        )
    return model


def warm_kernels() -> None:
    """Compile the live path's kernels into numba's on-disk cache, and build ``map.h5``.

    Called once by the controller of ``pytest -n`` before its workers start: on a fresh clone
    each worker otherwise compiled the same kernels at once (about 45 CPU-s each on this
    machine), and beside CPU-heavy jobs a test waiting on that compile ran out of time.
    """
    from skinloc.live.core import SkinCore

    SkinCore(model_path("map"))


@functools.lru_cache(maxsize=1)
def stream(n_frames: int = 1500) -> tuple[np.ndarray, list]:
    """Raw frames of the simulated skin with a scripted finger and the script."""
    from skinloc.bench.online import touch_stream

    return touch_stream(n_frames, random_state=0)  # seed 0: the skin the models know


@functools.lru_cache(maxsize=1)
def stream_recording() -> Path:
    """``stream()`` as a ``skinloc record`` style recording (100 Hz)."""
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sources.replay import write_stream_recording

    path = _DIR / "stream.h5"
    with build_once(path) as build:
        if not build:
            return path
        frames, _ = stream()
        write_stream_recording(
            path,
            n_tx=8,
            n_rx=8,
            mesh=cone_skin(),
            baseline_frames=frames[:100],
            frames=frames,
            times_s=np.arange(len(frames)) / 100.0,
            index=np.arange(len(frames)),
        )
    return path


@functools.lru_cache(maxsize=1)
def gesture_recording() -> Path:
    """A 100 Hz stream of the simulated skin (seed 0): a tap, a long press and a swipe.

    Scripted by hand, firm presses: 1.5 s untouched, a 0.12 s tap, a 1.0 s press, a 0.3 s
    swipe along the cone's long axis toward its base (about 50 mm), each 1.2 s apart.
    """
    path = _DIR / "gestures.h5"
    with build_once(path) as build:
        if build:
            _write_gestures(path)
    return path


def _write_gestures(path: Path) -> None:
    """``gesture_recording``'s stream, written to ``path``."""
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sim.skin import SimulatedSkin
    from skinloc.sources.replay import write_stream_recording

    mesh = cone_skin()
    v = np.asarray(mesh.vertices)
    skin = SimulatedSkin(mesh, random_state=0)
    skin.connect()
    frames = []

    def idle(n: int) -> None:
        skin.release()
        frames.extend(skin.read().values for _ in range(n))

    def press_path(points: np.ndarray) -> None:
        for p in points:
            skin.press(p, pressure=1.0, finger_radius_m=0.008)
            frames.append(skin.read().values)

    # a surface point 30 % along the long axis, and a path 50 mm from it "up" the skin
    import trimesh

    from skinloc.geometry.skin_frame import skin_up_axis

    up = skin_up_axis(v)
    s = (v - v.mean(axis=0)) @ up
    mid = v[np.argmin(np.abs(s - np.quantile(s, 0.3)) + 10 * np.abs(v[:, 0]))]
    line = mid + np.linspace(0.0, 0.05, 30)[:, None] * up
    swipe = trimesh.proximity.closest_point(mesh, line)[0]
    idle(150)
    press_path(np.repeat(mid[None], 12, axis=0))
    idle(120)
    press_path(np.repeat(mid[None], 100, axis=0))
    idle(120)
    press_path(swipe)
    idle(120)
    skin.disconnect()
    frames = np.asarray(frames)
    write_stream_recording(
        path,
        n_tx=8,
        n_rx=8,
        mesh=mesh,
        baseline_frames=frames[:100],
        frames=frames,
        times_s=np.arange(len(frames)) / 100.0,
        index=np.arange(len(frames)),
    )


@functools.cache
def held_recording(held_s: float, rate_hz: float = 100.0) -> Path:
    """A recording of the simulated skin (seed 0) that ends touched: 1.5 s untouched, then a
    firm press held for ``held_s`` up to the last frame (a replay that stops mid-touch)."""
    path = _DIR / f"held_{held_s:g}s_{rate_hz:g}hz.h5"
    with build_once(path) as build:
        if build:
            _write_held(path, held_s, rate_hz)
    return path


def _write_held(path: Path, held_s: float, rate_hz: float) -> None:
    """``held_recording``'s stream, written to ``path``."""
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sim.skin import SimulatedSkin
    from skinloc.sources.replay import write_stream_recording

    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=0)
    skin.connect()
    idle = [skin.read().values for _ in range(150)]
    skin.press(skin.sensor_positions[27], pressure=1.0, finger_radius_m=0.008)
    pressed = np.asarray([skin.read().values for _ in range(100)])
    skin.disconnect()
    n_held = max(int(round(held_s * rate_hz)), 10)
    frames = np.concatenate([np.asarray(idle), np.resize(pressed, (n_held, pressed.shape[1]))])
    write_stream_recording(
        path,
        n_tx=8,
        n_rx=8,
        mesh=mesh,
        baseline_frames=frames[:100],
        frames=frames,
        times_s=np.arange(len(frames)) / rate_hz,
        index=np.arange(len(frames)),
    )
