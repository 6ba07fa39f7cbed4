"""Record a raw stream of a simulated skin while a scripted hand performs gestures.

``record_gestures`` runs a ``GestureScript`` on a ``SimulatedSkin`` (noise and drift on) and
writes a ``skinloc record``-style recording: the header (mesh, a no-touch baseline capture),
the ``stream`` group (``frames``, ``times_s``, ``index``) and a ``truth`` group for diagnosis:

- ``truth/fingers_m (n, 2, 3)`` float32, each frame's finger positions (NaN: no finger in that
  slot) and ``truth/pressure (n, 2)`` float32 (0: none);
- ``truth/gestures_json``: JSON ``{"truth_gestures": [...], "truth_touches": [...]}``, which
  ``read_gesture_truth`` returns and ``skinloc info --json`` prints.

Frames go to a side file (``NAME.partial.h5``) in chunks, so memory stays bounded however long
the stream; the side file is renamed over the output when the script is complete.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.data.appender import StreamAppender
from skinloc.errors import RecordingError
from skinloc.files import cannot_write, side_path, written_through_side
from skinloc.h5layout import (
    TRUTH,
    TRUTH_FINGERS,
    TRUTH_PRESSURE,
    read_truth_json,
    write_truth_json,
)
from skinloc.sim.gestures import MAX_FINGERS, GestureScript, ScriptItem, Stroke
from skinloc.sim.signal import sensor_image

log = logging.getLogger(__name__)

__all__ = ["make_felt", "read_gesture_truth", "record_gestures"]

_FELT_SIGMA = 6.0  # as for a calibration touch: 2 sensors above 6 noise stds, or press harder
_TAIL_S = 1.0  # untouched after the last item


def make_felt(skin, stroke: Stroke) -> None:
    """Raise a stroke's pressure until the skin feels it where it lands (a person would)."""
    felt = _FELT_SIGMA * skin.layout.noise_std_counts
    image = sensor_image(
        skin.layout, skin.params, stroke.path_m[0], stroke.pressure, stroke.radius_m
    )
    second = float(np.sort(image / felt)[-2])
    if second < 1.0:
        stroke.pressure *= 1.1 / max(second, 1e-3)


#: The truth, per frame, beside the stream: dataset -> (shape of one frame's value, dtype).
_TRUTH_COLUMNS = {
    TRUTH_FINGERS: ((MAX_FINGERS, 3), np.float32),
    TRUTH_PRESSURE: ((MAX_FINGERS,), np.float32),
}


def _write_truth(f, truth: dict[str, Any]) -> None:
    """Store the gestures' and touches' truth (JSON) in the open recording ``f``."""
    write_truth_json(f, json.dumps(truth))
    f.flush()


def record_gestures(
    skin,
    path: str | Path,
    script: GestureScript,
    *,
    partial: str | Path | None = None,
    baseline_frames: int = 50,
    chunk_frames: int = 1024,
    meta: dict[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Run ``script`` on ``skin`` and write the raw stream and its truth to ``path``.

    Parameters
    ----------
    skin : SimulatedSkin
        The skin (not connected); its mesh must be ``script.mesh``.
    path : str or Path
        The ``.h5`` file to write; replaced only when the stream is complete.
    script : GestureScript
        The gestures and touches.
    partial : str or Path, optional
        Where the side file goes (``NAME.partial.h5`` next to it); ``path`` by default.
    baseline_frames : int
        Untouched frames captured before the stream, for the recording's baseline.
    chunk_frames : int
        Frames held in memory before they are appended to the file.
    meta : dict, optional
        Stored with the recording.
    progress : callable, optional
        ``progress(items_done, items_total)``.

    Returns
    -------
    dict
        ``{"truth_gestures": [...], "truth_touches": [...], "n_frames": n, "seconds": s}``.

    Raises
    ------
    Interrupted
        On Ctrl-C: the side file keeps the stream up to the end of the last complete item,
        with the truth of the items so far.
    """
    path = Path(path)
    side = side_path(partial if partial is not None else path, "partial")
    was_connected = skin.is_connected
    if not was_connected:
        skin.connect()
    skin.touch([])
    base = np.stack([skin.read().values for _ in range(baseline_frames)])
    writer = None
    try:
        writer = StreamAppender(
            side,
            n_tx=skin.n_tx,
            n_rx=skin.n_rx,
            mesh=script.mesh,
            baseline_frames=base,
            meta=meta,
            chunk=chunk_frames,
            columns=_TRUTH_COLUMNS,
        )
        writer.file[TRUTH].attrs["units"] = (
            "finger positions in m (NaN: no finger in that slot), pressure relative"
        )
    except BaseException as exc:
        if writer is not None:
            with contextlib.suppress(OSError):
                writer.close()
            side.unlink(missing_ok=True)
        if not was_connected:
            skin.disconnect()
        if isinstance(exc, OSError):  # a full disk: name the file the user asked for
            raise cannot_write(path, exc) from None
        raise
    gestures: list[dict[str, Any]] = []
    touches: list[dict[str, Any]] = []
    t0 = skin.time_s  # stream time 0: the first frame after the baseline capture
    buf: dict[str, list] = {k: [] for k in ("frames", "times", "index", "fingers", "pressure")}

    def flush() -> None:
        if buf["frames"]:
            writer.append(
                np.asarray(buf["frames"]),
                np.asarray(buf["times"]),
                np.asarray(buf["index"]),
                **{
                    TRUTH_FINGERS: np.asarray(buf["fingers"]),
                    TRUTH_PRESSURE: np.asarray(buf["pressure"]),
                },
            )
            for v in buf.values():
                v.clear()

    def run_until(t_end: float, item: ScriptItem | None) -> None:
        ramp = script.timing.ramp_s
        while skin.time_s - t0 < t_end - 1e-9:
            t = skin.time_s - t0
            pos = np.full((MAX_FINGERS, 3), np.nan, dtype=np.float32)
            prs = np.zeros(MAX_FINGERS, dtype=np.float32)
            fingers = []
            for s in item.strokes if item is not None else ():
                f = s.finger_at(t, ramp)
                if f is not None:
                    fingers.append(f)
                    pos[s.slot], prs[s.slot] = f.position_m, f.pressure
            skin.touch(fingers)
            frame = skin.read()
            buf["frames"].append(frame.values)
            buf["times"].append(frame.timestamp_s - t0)
            buf["index"].append(frame.index)
            buf["fingers"].append(pos)
            buf["pressure"].append(prs)
            if len(buf["frames"]) >= chunk_frames:
                flush()

    safe = 0  # frames up to the end of the last complete item

    def kept() -> tuple[int, int]:
        return len(gestures) + len(touches), script.n_items

    with written_through_side(side, path, kept, "gestures and touches", "gesture"):
        try:
            for done, item in enumerate(script.items()):
                for s in item.strokes:
                    make_felt(skin, s)
                run_until(item.start_s, None)
                run_until(item.end_s, item)
                flush()
                safe = writer.n_frames
                (gestures if item.kind not in ("rest", "drag") else touches).append(item.truth)
                if progress is not None:
                    progress(done + 1, script.n_items)
            last = max((d["end_s"] for d in gestures + touches), default=0.0)
            run_until(last + _TAIL_S, None)
            flush()
        except KeyboardInterrupt:
            writer.truncate(safe)
            raise
        finally:
            skin.touch([])
            if not was_connected:
                skin.disconnect()
            truth = {
                "truth_gestures": gestures,
                "truth_touches": sorted(touches, key=lambda d: d["start_s"]),
            }
            if writer.file.id.valid:
                _write_truth(writer.file, truth)
            writer.close()
    n = writer.n_frames
    return {**truth, "n_frames": n, "seconds": n / skin.rate_hz}


def read_gesture_truth(path: str | Path) -> dict[str, Any] | None:
    """``{"truth_gestures": [...], "truth_touches": [...]}`` of a gesture stream, else None.

    Each entry has ``kind``, ``direction`` (swipes; else null), ``start_s`` and ``end_s`` (the
    stream's time, s), ``n_fingers``, ``position_m`` (the first landing); swipes and drags add
    ``speed_m_s``, ``length_m`` and ``path_m`` (start and end), double taps ``gap_s``.
    """
    if Path(path).suffix.lower() not in (".h5", ".hdf5"):
        return None
    try:
        text = read_truth_json(path)
    except OSError as exc:
        raise RecordingError(f"cannot read the gesture truth of {path}: {exc}") from exc
    if text is None:
        return None
    try:
        truth = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{path}: the gesture truth is not valid JSON ({exc})") from exc
    return {"truth_gestures": truth["truth_gestures"], "truth_touches": truth["truth_touches"]}
