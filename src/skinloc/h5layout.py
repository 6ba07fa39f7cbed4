"""The one owner of skinloc's HDF5 layout: the kinds of file, the names of their groups.

Every skinloc HDF5 file says what it is in its ``format`` attribute (``file_kind``):

- ``skinloc-recording`` (``data.recording``): mesh, baseline, point logs; a recording of the raw
  stream (``skinloc record``, the app's Record button, ``skinloc simulate --gestures``) adds the
  group ``stream`` (``frames``, ``times_s``, ``index``); the app's live recording adds ``live``
  (``contacts``, ``gestures``: one JSON line each, as the ``jsonl`` sink writes them); a
  simulated gesture stream adds ``truth`` (``fingers_m``, ``pressure`` per frame and
  ``gestures_json``).
- ``skinloc-model`` (``models.model_file``).
- ``skinloc-history`` (``history.h5`` of an app session, ``read_history``): one group per touch
  taken back or baseline replaced, ``{kind}_{n}``.

``check_kind`` is the one file-kind check (its errors name the file and what to give instead);
the readers and writers of each part call the functions here rather than spell the names.
``docs/formats.md`` describes the layout.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.errors import RecordingError

__all__ = [
    "HISTORY",
    "HISTORY_FILE",
    "LIVE",
    "LIVE_EVENTS",
    "MODEL",
    "RECORDING",
    "STREAM",
    "TRUTH",
    "TRUTH_FINGERS",
    "TRUTH_PRESSURE",
    "check_kind",
    "create_live_events",
    "create_stream",
    "file_kind",
    "is_kind",
    "read_history",
    "read_live_events",
    "read_stream",
    "read_truth_json",
    "set_kind",
    "stream_summary",
    "write_history",
    "write_truth_json",
]

#: The attribute that names a file's kind.
KIND_ATTR = "format"
RECORDING = "skinloc-recording"
MODEL = "skinloc-model"
HISTORY = "skinloc-history"

#: The raw stream of a recording: frames in arrival order, their times and the device counter.
STREAM = "stream"
#: The live pipeline's output beside the stream (the app's recording): JSON lines.
LIVE = "live"
LIVE_EVENTS = ("contacts", "gestures")
#: What a simulated gesture stream really did, beside its stream.
TRUTH = "truth"
TRUTH_FINGERS = "truth/fingers_m"
TRUTH_PRESSURE = "truth/pressure"
_TRUTH_GESTURES = "truth/gestures_json"
#: An app session's kept history (touches taken back, baselines replaced).
HISTORY_FILE = "history.h5"

#: What to give instead, and how to say what a file is, per kind.
_NAMES = {RECORDING: "recording", MODEL: "model", HISTORY: "session history"}
_GIVE = {
    RECORDING: "a recording ('skinloc record', 'collect' or 'simulate')",
    MODEL: "a model file ('skinloc train')",
}


# --------------------------------------------------------------------------------------------
# the kind of a file


def file_kind(f: Any) -> str | None:
    """The kind of an open HDF5 file (``RECORDING``, ``MODEL``, ``HISTORY``), None if unnamed."""
    kind = f.attrs.get(KIND_ATTR)
    return kind.decode() if isinstance(kind, bytes) else kind


def set_kind(f: Any, kind: str) -> None:
    """Name the kind of an open HDF5 file being written."""
    f.attrs[KIND_ATTR] = kind


def is_kind(path: str | Path, kind: str) -> bool:
    """Whether ``path`` is an HDF5 file of ``kind`` (False for anything else, or no file)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return file_kind(f) == kind
    except OSError:
        return False


def check_kind(f: Any, path: str | Path, want: str, error: type[Exception]) -> None:
    """Raise ``error`` naming ``path`` unless the open file ``f`` is of kind ``want``.

    Examples of the messages: ``m.h5 is a model, not a recording: give a recording ('skinloc
    record', 'collect' or 'simulate')``; ``x.h5 is an HDF5 file but not a skinloc model: give a
    model file ('skinloc train')``.
    """
    kind = file_kind(f)
    if kind == want:
        return
    give = _GIVE.get(want)
    if kind in _NAMES and give is not None:
        raise error(f"{path} is a {_NAMES[kind]}, not a {_NAMES[want]}: give {give}")
    hint = f": give {give}" if want == MODEL else ""
    raise error(f"{path} is an HDF5 file but not a skinloc {_NAMES[want]}{hint}")


# --------------------------------------------------------------------------------------------
# the raw stream


def create_stream(f: Any, n_sensors: int, chunk: int) -> dict[str, Any]:
    """The group ``stream`` of a new file: empty, resizable ``frames``, ``times_s``, ``index``.

    Their shapes: ``(0, n_sensors)`` float32, ``(0,)`` float64, ``(0,)`` int64.
    """
    g = f.create_group(STREAM)
    g.attrs["units"] = "frames in raw counts, times in s since the first frame"
    return {
        "frames": g.create_dataset(
            "frames",
            (0, n_sensors),
            np.float32,
            maxshape=(None, n_sensors),
            chunks=(chunk, n_sensors),
            compression="gzip",
            compression_opts=4,
        ),
        "times_s": g.create_dataset("times_s", (0,), np.float64, maxshape=(None,), chunks=(chunk,)),
        "index": g.create_dataset("index", (0,), np.int64, maxshape=(None,), chunks=(chunk,)),
    }


def read_stream(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The raw stream of a recording as ``(frames, times_s, index)``, or None if it has none."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if STREAM not in f:
                return None
            g = f[STREAM]
            return g["frames"][()], g["times_s"][()], g["index"][()]
    except (OSError, KeyError) as exc:  # KeyError: a stream group without its datasets
        raise RecordingError(f"cannot read the stream of {path}: {exc}") from exc


def stream_summary(path: str | Path) -> dict[str, Any] | None:
    """Frame count, length (s), rate (Hz) and lost frames of a recording's raw stream.

    Reads the stream's times and counters only, not its frames. None if there is no stream
    (a calibration recording, or a MATLAB file).
    """
    import h5py

    if Path(path).suffix.lower() not in (".h5", ".hdf5"):
        return None
    try:
        with h5py.File(path, "r") as f:
            if STREAM not in f:
                return None
            g = f[STREAM]
            n = int(g["frames"].shape[0])
            times = g["times_s"][()]
            index = g["index"][()]
    except (OSError, KeyError) as exc:  # KeyError: a stream group without its datasets
        raise RecordingError(f"cannot read the stream of {path}: {exc}") from exc
    seconds = float(times[-1] - times[0]) if n > 1 else 0.0
    return {
        "stream_frames": n,
        "stream_seconds": seconds,
        "stream_rate_hz": (n - 1) / seconds if seconds > 0 else None,
        # gaps in the device's counter are frames that never arrived
        "stream_lost_frames": int(index[-1] - index[0] + 1 - n) if n else 0,
    }


# --------------------------------------------------------------------------------------------
# the live pipeline's output, the simulated truth


def create_live_events(f: Any, chunk: int) -> dict[str, Any]:
    """The group ``live`` of a new file: resizable string datasets ``contacts``, ``gestures``."""
    import h5py

    live = f.create_group(LIVE)
    live.attrs["units"] = "one JSON line each, as the jsonl sink writes them"
    text = h5py.string_dtype()
    return {
        name: live.create_dataset(name, (0,), text, maxshape=(None,), chunks=(chunk,))
        for name in LIVE_EVENTS
    }


def read_live_events(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """The contacts and gestures of an HDF5 live recording, as dicts (``{}`` lists if none)."""
    import h5py

    with h5py.File(path, "r") as f:
        g = f.get(LIVE)
        return {
            name: [] if g is None or name not in g else [json.loads(s) for s in g[name].asstr()[()]]
            for name in LIVE_EVENTS
        }


def write_truth_json(f: Any, text: str) -> None:
    """Store (or replace) the gestures' and touches' truth, JSON, in the open recording ``f``."""
    t = f[TRUTH]
    name = _TRUTH_GESTURES.rpartition("/")[2]
    if name in t:
        del t[name]
    t[name] = text


def read_truth_json(path: str | Path) -> str | None:
    """The gestures' and touches' truth (JSON text) of a recording; None if it has none."""
    import h5py

    with h5py.File(path, "r") as f:
        if _TRUTH_GESTURES not in f:
            return None
        raw = f[_TRUTH_GESTURES][()]
    return raw.decode() if isinstance(raw, bytes) else str(raw)


# --------------------------------------------------------------------------------------------
# an app session's history


def read_history(path: Path) -> list[tuple[str, dict[str, np.ndarray], dict[str, Any]]] | None:
    """A session's ``history.h5`` in the order kept: ``(name, arrays, attrs)`` per entry.

    Names are ``{kind}_{n}`` (``touch``: a touch taken back, ``baseline``: a replaced one);
    attrs carry ``time`` and what the app knew (target, reason). None when ``path`` is an HDF5
    file of another kind; raises ``RecordingError`` when it cannot be read.
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if file_kind(f) != HISTORY:
                return None
            return [
                (
                    name,
                    {k: f[name][k][()] for k in f[name]},
                    {k: json.loads(v) for k, v in f[name].attrs.items()},
                )
                for name in sorted(f, key=lambda s: int(s.split("_")[-1]))
            ]
    except (OSError, ValueError, KeyError) as exc:
        raise RecordingError(f"cannot read {path}: {exc}") from exc


def write_history(
    path: Path, entries: list[tuple[str, dict[str, np.ndarray], dict[str, Any]]]
) -> None:
    """Write a whole ``history.h5`` (``entries`` as ``read_history`` gives them) to ``path``."""
    import h5py

    with h5py.File(path, "w") as f:
        set_kind(f, HISTORY)
        for name, arrays, meta in entries:
            g = f.create_group(name)
            for k, v in arrays.items():
                g[k] = v
            for k, v in meta.items():
                g.attrs[k] = json.dumps(v)
