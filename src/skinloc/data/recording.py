"""Calibration recordings: skinloc's HDF5 files and the paper's MATLAB ``touchData`` files.

A recording holds the skin mesh, the no-touch baseline capture and the point logs (a target
on the surface and the frames captured while it was touched). Frames are stored as raw counts;
``deltas`` subtracts the baseline mean, which is what the paper's point logs contain.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.errors import RecordingError
from skinloc.files import atomic_write
from skinloc.h5layout import RECORDING, check_kind, set_kind

log = logging.getLogger(__name__)

__all__ = [
    "FORMAT_VERSION",
    "PER_TOUCH_META",
    "file_meta",
    "read_recording",
    "Recording",
    "utc_now",
    "write_h5",
    "write_mat",
    "write_planned_targets",
    "write_recording",
]

#: Version of the HDF5 layout written by ``write_recording``.
FORMAT_VERSION = 1
#: Meta keys holding one entry per point log, in its order: where the finger really landed (a
#: simulated skin), and a robot probe's reported tip, depth and force (``collect --probe``).
PER_TOUCH_META = ("true_contacts", "probe_tips_m", "probe_depths_m", "probe_forces_n")
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_MAT_MAGIC = b"MATLAB 5.0 MAT-file"
MAX_TX, MAX_RX = 21, 12


def utc_now() -> str:
    """The current UTC time as ISO 8601 to the second, as files record it."""
    return datetime.now(UTC).isoformat(timespec="seconds")


@dataclass
class Recording:
    """One calibration session on one skin.

    Attributes
    ----------
    n_tx, n_rx : int
        Grid of transmit and receive lines; sensor k is TX ``k // n_rx``, RX ``k % n_rx``.
    vertices : (V, 3) float
        Skin mesh vertices, m.
    faces : (F, 3) int
        Skin mesh triangles, 0-based.
    baseline_frames : (m, n_tx * n_rx) float32
        No-touch capture, raw counts.
    targets : (n, 3) float
        Prompted touch points, m, one per point log.
    frames : (n, s, n_tx * n_rx) float32
        Raw counts captured at each target (s samples per touch).
    surface_points : (P, 3) float or None
        Discretised surface the paper snaps predictions to, m.
    planned_targets : (N, 3) float or None
        All targets of the session, done or not (resuming continues from ``n``).
    frame_times : (n, s) float or None
        Timestamp of each frame, s (source clock).
    meta : dict
        ``sampling_mode``, ``samples_per_touch``, ``description``, ``source``, ``created``,
        ``modified`` and anything else worth keeping; stored as JSON.
    """

    n_tx: int
    n_rx: int
    vertices: Points
    faces: np.ndarray
    baseline_frames: np.ndarray
    targets: Points
    frames: np.ndarray
    surface_points: Points | None = None
    planned_targets: Points | None = None
    frame_times: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.faces = np.asarray(self.faces, dtype=np.int64)
        self.baseline_frames = np.asarray(self.baseline_frames, dtype=np.float32)
        self.targets = np.asarray(self.targets, dtype=np.float64).reshape(-1, 3)
        n_sensors = self.n_tx * self.n_rx
        self.frames = np.asarray(self.frames, dtype=np.float32)
        if self.frames.size == 0:
            self.frames = self.frames.reshape(
                0, self.frames.shape[1] if self.frames.ndim == 3 else 0, n_sensors
            )
        self.validate()

    @property
    def n_sensors(self) -> int:
        """Number of sensors, ``n_tx * n_rx``."""
        return self.n_tx * self.n_rx

    @property
    def n_point_logs(self) -> int:
        """Point logs recorded so far."""
        return len(self.targets)

    @property
    def samples_per_touch(self) -> int:
        """Frames captured at each target."""
        return int(self.frames.shape[1]) if self.frames.ndim == 3 else 0

    @property
    def baseline(self) -> np.ndarray:
        """Mean no-touch counts, ``(n_sensors,)`` float64."""
        return self.baseline_frames.astype(np.float64).mean(axis=0)

    @property
    def noise(self) -> np.ndarray:
        """No-touch standard deviation per sensor, ``(n_sensors,)`` counts."""
        return self.baseline_frames.astype(np.float64).std(axis=0)

    @property
    def deltas(self) -> np.ndarray:
        """Baseline-subtracted frames, ``(n, s, n_sensors)`` float32 counts."""
        return (self.frames - self.baseline.astype(np.float32)).astype(np.float32)

    @property
    def touch_means(self) -> np.ndarray:
        """Mean baseline-subtracted image of each touch, ``(n, n_sensors)`` float32."""
        return self.deltas.mean(axis=1)

    @property
    def mesh(self):  # -> trimesh.Trimesh (imported lazily)
        """The skin surface as a trimesh mesh."""
        from skinloc.geometry.mesh import mesh_from_arrays

        return mesh_from_arrays(self.vertices, self.faces)

    def validate(self) -> None:
        """Raise ``RecordingError`` if shapes or values are inconsistent."""
        if not (1 <= self.n_tx <= MAX_TX and 1 <= self.n_rx <= MAX_RX):
            raise RecordingError(
                f"grid {self.n_tx} TX x {self.n_rx} RX is outside 1-{MAX_TX} x 1-{MAX_RX}"
            )
        n = self.n_sensors
        if self.baseline_frames.ndim != 2 or self.baseline_frames.shape[1] != n:
            raise RecordingError(
                f"baseline frames must have shape (m, {n}), got {self.baseline_frames.shape}"
            )
        if len(self.baseline_frames) < 2:
            raise RecordingError("the baseline capture needs at least 2 frames to measure noise")
        if self.frames.ndim != 3 or self.frames.shape[2] != n:
            raise RecordingError(f"frames must have shape (n, s, {n}), got {self.frames.shape}")
        if len(self.frames) != len(self.targets):
            raise RecordingError(
                f"{len(self.frames)} point logs of frames but {len(self.targets)} targets"
            )
        for name, arr in (
            ("baseline", self.baseline_frames),
            ("frames", self.frames),
            ("targets", self.targets),
        ):
            if not np.all(np.isfinite(arr)):
                raise RecordingError(f"recording has NaN or infinite values in its {name}")
        if self.frame_times is not None:
            self.frame_times = np.asarray(self.frame_times, dtype=np.float64)
            if self.frame_times.shape != self.frames.shape[:2]:
                raise RecordingError(
                    f"frame times must have shape {self.frames.shape[:2]}, "
                    f"got {self.frame_times.shape}"
                )

    def subset(self, index: np.ndarray | list[int] | slice) -> Recording:
        """A copy with only the chosen point logs."""
        idx = np.arange(self.n_point_logs)[index]
        return Recording(
            n_tx=self.n_tx,
            n_rx=self.n_rx,
            vertices=self.vertices,
            faces=self.faces,
            baseline_frames=self.baseline_frames,
            targets=self.targets[idx],
            frames=self.frames[idx],
            surface_points=self.surface_points,
            planned_targets=None,
            frame_times=None if self.frame_times is None else self.frame_times[idx],
            meta=self._meta_of(idx),
        )

    def _meta_of(self, idx: np.ndarray) -> dict[str, Any]:
        """The meta of the point logs ``idx``: per-touch lists (``PER_TOUCH_META``) cut to them.

        A list shorter than the point logs (touches added later by hand) has None for the
        point logs it has no entry for, and no trailing Nones.
        """
        meta = dict(self.meta)
        for key in PER_TOUCH_META:
            values = meta.get(key)
            if isinstance(values, list):
                cut = [values[i] if i < len(values) else None for i in idx]
                while cut and cut[-1] is None:
                    cut.pop()
                meta[key] = cut
        return meta

    def append(self, target: Points, frames: np.ndarray, times: np.ndarray | None = None) -> None:
        """Add one point log: ``target (3,)`` m and ``frames (s, n_sensors)`` raw counts."""
        frames = np.asarray(frames, dtype=np.float32)[None]
        target = np.asarray(target, dtype=np.float64).reshape(1, 3)
        if self.n_point_logs and frames.shape[1:] != self.frames.shape[1:]:
            raise RecordingError(
                f"point log frames must have shape {self.frames.shape[1:]}, got {frames.shape[1:]}"
            )
        self.frames = frames if self.n_point_logs == 0 else np.concatenate([self.frames, frames])
        self.targets = np.concatenate([self.targets, target])
        if times is not None or self.frame_times is not None:
            t = np.full(frames.shape[:2], np.nan) if times is None else np.asarray(times)[None]
            self.frame_times = (
                t
                if self.frame_times is None or len(self.frames) == 1
                else np.concatenate([self.frame_times, t])
            )
        self.meta["modified"] = utc_now()
        self.validate()


# --------------------------------------------------------------------------------------------
# reading


def read_recording(path: str | Path) -> Recording:
    """Read a recording: skinloc HDF5 or the paper's MATLAB ``touchData`` .mat.

    Raises
    ------
    RecordingError
        If the file is missing, empty, truncated or not a recording.
    """
    path = Path(path)
    if path.is_dir():
        raise RecordingError(f"{path} is a folder, not a recording")
    if not path.is_file():
        raise RecordingError(f"recording not found: {path}")
    try:
        with path.open("rb") as fh:
            head = fh.read(20)
    except OSError as exc:
        raise RecordingError(f"cannot read recording {path}: {exc.strerror or exc}") from None
    if not head:
        raise RecordingError(f"recording {path} is empty")
    try:
        if head.startswith(_HDF5_MAGIC):
            return _read_h5(path)
        if head.startswith(_MAT_MAGIC[:10]):
            return _read_mat(path)
    except RecordingError as exc:
        # Inconsistencies found by Recording.validate do not know the file: name it.
        if str(path) not in str(exc):
            raise RecordingError(f"{path}: {exc}") from None
        raise
    raise RecordingError(f"{path} is neither a skinloc HDF5 recording nor a MATLAB .mat file")


def _read_h5(path: Path) -> Recording:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            check_kind(f, path, RECORDING, RecordingError)
            version = int(f.attrs.get("format_version", -1))
            if version > FORMAT_VERSION:
                raise RecordingError(
                    f"{path} uses recording format {version}; this skinloc reads up to "
                    f"{FORMAT_VERSION}: upgrade skinloc"
                )
            g = f["point_logs"]
            opt = lambda grp, key: grp[key][()] if key in grp else None  # noqa: E731
            return Recording(
                n_tx=int(f.attrs["n_tx"]),
                n_rx=int(f.attrs["n_rx"]),
                vertices=f["mesh/vertices"][()],
                faces=f["mesh/faces"][()],
                surface_points=opt(f["mesh"], "surface_points"),
                baseline_frames=f["baseline/frames"][()],
                targets=g["targets"][()],
                frames=g["frames"][()],
                frame_times=opt(g, "frame_times"),
                planned_targets=opt(f, "planned_targets"),
                meta=json.loads(f.attrs.get("meta", "{}")),
            )
    except RecordingError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise RecordingError(f"cannot read recording {path}: {exc}") from exc


def _read_mat(path: Path) -> Recording:
    import scipy.io

    try:
        raw = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises several kinds for truncated files
        raise RecordingError(f"cannot read MATLAB file {path}: {exc}") from exc
    if "touchData" not in raw:
        keys = [k for k in raw if not k.startswith("__")]
        raise RecordingError(f"{path} has no touchData struct (variables: {', '.join(keys)})")
    td = raw["touchData"]
    try:
        n_tx, n_rx = int(td.numTX), int(td.numRX)
        baseline_frames = np.atleast_2d(np.asarray(td.CPL.sensorStateRaw, dtype=np.float64))
        baseline_mean = np.asarray(td.CPL.sensorStateAvg, dtype=np.float64)
        logs = np.atleast_1d(td.PL)
        targets = np.stack([np.asarray(p.touchPos, dtype=np.float64) for p in logs])
        # The paper stores point-log frames minus the baseline mean; we keep raw counts.
        frames = np.stack([np.atleast_2d(p.sensorStateRaw) for p in logs]).astype(np.float64)
        frames = frames + baseline_mean
        vertices = np.asarray(td.obj.v, dtype=np.float64)
        faces = np.asarray(td.obj.f, dtype=np.int64) - 1
        points = np.asarray(td.obj.Points, dtype=np.float64) if hasattr(td.obj, "Points") else None
    except (AttributeError, ValueError, TypeError) as exc:
        raise RecordingError(
            f"{path}: touchData is missing a field or has a bad shape ({exc})"
        ) from exc
    return Recording(
        n_tx=n_tx,
        n_rx=n_rx,
        vertices=vertices,
        faces=faces,
        surface_points=points,
        baseline_frames=baseline_frames,
        targets=targets,
        frames=frames,
        meta={
            "source": f"matlab:{path.name}",
            "sampling_mode": "edge",
            "samples_per_touch": int(frames.shape[1]),
            "description": path.stem,
        },
    )


# --------------------------------------------------------------------------------------------
# writing


def write_h5(f, rec: Recording, meta: dict[str, Any], appendable: bool = False) -> None:
    """Write ``rec`` into the open HDF5 file ``f`` (the layout of docs/formats.md).

    ``appendable`` makes the point-log datasets and the plan resizable along the first axis
    (point logs chunked one at a time), so ``RecordingAppender`` can add and take back point
    logs and change the plan without a rewrite;
    readers see the same shapes and dtypes either way.
    """
    set_kind(f, RECORDING)
    f.attrs["format_version"] = FORMAT_VERSION
    f.attrs["n_tx"], f.attrs["n_rx"] = rec.n_tx, rec.n_rx
    f.attrs["meta"] = json.dumps(meta)
    f.attrs["units"] = "positions in metres, frames in raw sensor counts"
    m = f.create_group("mesh")
    m["vertices"], m["faces"] = rec.vertices, rec.faces
    if rec.surface_points is not None:
        m["surface_points"] = rec.surface_points
    f["baseline/frames"] = rec.baseline_frames
    g = f.create_group("point_logs")
    s, n = rec.frames.shape[1:]
    grow: dict[str, Any] = {}
    if appendable:
        grow = {"maxshape": (None, s, n), "chunks": (1, max(s, 1), n)}
    g.create_dataset("targets", data=rec.targets, maxshape=(None, 3) if appendable else None)
    g.create_dataset("frames", data=rec.frames, compression="gzip", compression_opts=4, **grow)
    if rec.frame_times is not None or appendable:
        times = rec.frame_times
        if times is None:
            times = np.full(rec.frames.shape[:2], np.nan)
        g.create_dataset("frame_times", data=times, maxshape=(None, s) if appendable else None)
    if rec.planned_targets is not None:
        if appendable:
            write_planned_targets(f, rec.planned_targets)
        else:
            f["planned_targets"] = rec.planned_targets


def write_planned_targets(f, planned: np.ndarray) -> None:
    """Create ``planned_targets (N, 3)`` m in the open HDF5 file ``f``, resizable.

    The appendable layout's plan (``RecordingAppender.set_planned_targets`` changes it in
    place); readers see the same shape and dtype as a fixed one.
    """
    planned = np.asarray(planned, dtype=np.float64).reshape(-1, 3)
    f.create_dataset("planned_targets", data=planned, maxshape=(None, 3), chunks=(64, 3))


def file_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """The meta a recording's file stores: ``meta``, ``created`` added if new, the version."""
    from skinloc import __version__

    return {"created": utc_now(), **meta, "skinloc_version": __version__}


def write_recording(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` as a skinloc HDF5 recording, atomically (a crash leaves the old file)."""
    import h5py

    rec.validate()
    meta = file_meta(rec.meta)

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            write_h5(f, rec, meta)

    atomic_write(Path(path), write)


def write_mat(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` in the paper's MATLAB ``touchData`` layout (frames minus baseline)."""
    import scipy.io

    rec.validate()
    baseline = rec.baseline
    deltas = rec.frames.astype(np.float64) - baseline
    pl = np.empty(
        (1, rec.n_point_logs),
        dtype=[("sensorStateRaw", "O"), ("sensorStateAvg", "O"), ("touchPos", "O")],
    )
    for i in range(rec.n_point_logs):
        pl[0, i] = (deltas[i], deltas[i].mean(axis=0), rec.targets[i])
    s = rec.samples_per_touch
    obj = {"v": rec.vertices, "f": (rec.faces + 1).astype(np.float64)}
    if rec.surface_points is not None:
        obj["Points"] = rec.surface_points
    touch = {
        "numTX": float(rec.n_tx),
        "numRX": float(rec.n_rx),
        "numSensors": float(rec.n_sensors),
        "CPL": {
            "sensorStateRaw": rec.baseline_frames.astype(np.float64),
            "sensorStateAvg": baseline,
        },
        "PL": pl,
        "LIN": {
            "sensorStateAvg": deltas.mean(axis=1),
            "touchPos": rec.targets,
            "sensorStateRaw": deltas.reshape(-1, rec.n_sensors),
            "touchPosRaw": np.repeat(rec.targets, s, axis=0),
        },
        "obj": obj,
    }
    atomic_write(
        Path(path), lambda tmp: scipy.io.savemat(tmp, {"touchData": touch}, do_compression=True)
    )
