"""Traces over time: a sensor's recent signal with its baseline and noise, a touch's frames.

The reader thread keeps the last ``RECENT_S`` seconds of raw frames (``keep_recent``); a tab asks
for one sensor's part of them (``sensor_trace``). A recorded touch's frames come from its
recording (``touch_frames``).
"""

from __future__ import annotations

import collections
from typing import Any

import numpy as np

from skinloc.app.workspace.state import WorkspaceState, app_meta
from skinloc.sources.base import Frame

__all__ = ["MAX_POINTS", "RECENT_S", "TraceViews"]

#: Seconds of raw frames kept for the sensor traces.
RECENT_S = 20.0
#: Frames kept at most (20 s at 1 kHz).
MAX_RECENT = 20_000
#: Points of a trace sent at most (longer ones are thinned, keeping each stretch's extremes).
MAX_POINTS = 1200
#: Half-width of the noise band, in noise standard deviations.
BAND_SIGMA = 3.0


def thin(t: np.ndarray, v: np.ndarray, n_max: int) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``n_max`` points of ``(t, v)``: each stretch's minimum and maximum, in order.

    A plain stride would drop a short spike; the extremes of each stretch keep it.
    """
    n = len(t)
    if n <= n_max:
        return t, v
    k = int(np.ceil(2 * n / n_max))  # frames per stretch: two points each
    m = n // k
    tt, vv = t[: m * k].reshape(m, k), v[: m * k].reshape(m, k)
    lo, hi = vv.argmin(axis=1), vv.argmax(axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    second = np.where(first == second, k - 1, second)  # a flat stretch: its two ends
    rows = np.arange(m)
    idx_t = np.stack([tt[rows, first], tt[rows, second]], axis=1).ravel()
    idx_v = np.stack([vv[rows, first], vv[rows, second]], axis=1).ravel()
    return np.concatenate([idx_t, t[m * k :]]), np.concatenate([idx_v, v[m * k :]])


class TraceViews(WorkspaceState):
    """Part of ``Workspace``: what the trace views of the page ask for.

    Attributes
    ----------
    _recent : collections.deque or None
        ``(timestamp_s, values)`` of the last ``MAX_RECENT`` frames (made at the first frame).
    """

    _recent: collections.deque | None = None

    def keep_recent(self, frame: Frame) -> None:
        """Keep a frame for the traces (the reader thread, under the lock)."""
        if self._recent is None:
            self._recent = collections.deque(maxlen=MAX_RECENT)
        recent = self._recent
        recent.append((frame.timestamp_s, np.asarray(frame.values, dtype=np.float32)))
        while recent and frame.timestamp_s - recent[0][0] > RECENT_S:
            recent.popleft()

    def sensor_trace(self, tx: int, rx: int, seconds: float = 10.0) -> dict[str, Any]:
        """Sensor (``tx``, ``rx``) over the last ``seconds``: raw counts, baseline, noise band.

        ``t_s`` are seconds before the newest frame (<= 0); ``baseline`` is the level the heat
        maps subtract (``_reference``), ``noise`` the sensor's noise from untouched frames
        (robust std, counts); the band is ``baseline +- band_sigma * noise``.
        """
        with self._lock:
            device = self._need_device()
            n_tx, n_rx = device.source.n_tx, device.source.n_rx
            if not (0 <= tx < n_tx and 0 <= rx < n_rx):
                raise ValueError(f"no sensor TX {tx}, RX {rx}: the skin is {n_tx} TX x {n_rx} RX")
            k = tx * n_rx + rx
            frames = list(self._recent or ())
            ref = self._reference()
            noise = float(device.monitor.noise()[k])
        if frames:
            t = np.fromiter((f[0] for f in frames), float, len(frames))
            v = np.fromiter((f[1][k] for f in frames), float, len(frames))
            keep = t >= t[-1] - seconds
            t, v = thin(t[keep] - t[-1], v[keep], MAX_POINTS)
        else:
            t = v = np.zeros(0)
        return {
            "tx": tx,
            "rx": rx,
            "t_s": np.round(t, 4),
            "counts": np.round(v, 1),
            "baseline": None if ref is None else round(float(ref[k]), 2),
            "noise": noise if np.isfinite(noise) else None,
            "band_sigma": BAND_SIGMA,
            "seconds": seconds,
        }

    def touch_frames(self, index: int, recording: str) -> dict[str, Any]:
        """Touch ``index`` (0-based) of the session's ``recording``: its frames and mean image.

        ``frames`` ``(samples, n_sensors)`` and ``mean`` ``(n_sensors,)`` are counts above the
        recording's baseline; ``target`` m; ``times_s`` when recorded (s from the first frame).
        """
        with self._lock:
            a = self._need_session()
            sess = a.cal if recording == "calibration" else a.val
            path = a.folder.calibration if recording == "calibration" else a.folder.validation
            rec = sess.recording if sess is not None else None
            if rec is None and path.is_file():
                from skinloc.data.recording import read_recording

                rec = read_recording(path)
            n = 0 if rec is None else rec.n_point_logs
            if not 0 <= index < n:
                raise ValueError(f"no {recording} touch {index + 1}: {n} recorded")
            deltas = rec.frames[index].astype(np.float64) - rec.baseline
            times = None if rec.frame_times is None else rec.frame_times[index]
            meta = app_meta(rec)
            flags = meta.get("flags", [])
            return {
                "index": index,
                "recording": recording,
                "tx": rec.n_tx,
                "rx": rec.n_rx,
                "target": rec.targets[index],
                "mean": np.round(deltas.mean(axis=0), 2),
                "frames": np.round(deltas, 1),
                "times_s": None if times is None else np.round(times - times[0], 4),
                "flags": list(flags[index]) if index < len(flags) else [],
                "noise": np.round(rec.noise, 2),
            }
