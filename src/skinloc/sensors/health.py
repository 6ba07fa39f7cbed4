"""Dead, weak and noisy sensors and lines: the one rule, used by ``skinloc sensors`` and the app.

A TX or RX line fails as a whole far more often than one crossing (a broken trace, a loose
connector), and one crossing's gain is estimated from a handful of nearby touches, so:

* **weak / dead lines** are judged on the line's median gain (the fitted peak response of its
  crossings, ``sensors.sensor_map``): below ``WEAK_FRACTION`` of the median line the line is
  weak, below ``DEAD_FRACTION`` dead. A single crossing is never called weak, only dead (its
  gain below ``DEAD_FRACTION`` of the median crossing).
* **noisy** sensors have a no-touch noise above ``NOISY_FACTOR`` times the median and at least
  ``NOISY_MARGIN_COUNTS`` above it (the margin keeps quantised counts on a very quiet skin,
  median noise under a count, from flagging); a line is noisy when more than half its sensors
  are.
* **stuck** sensors (no change over a window of live frames, or at the ADC's rails) are dead; a
  line is dead when more than half its sensors are.

Without gains (a live stream and no calibration yet) only the noise and stuck rules apply.
Precedence per sensor: dead, then its line's state, then noisy.

A live stream is judged again every second on a window of its latest frames, which a touch
the touch detector does not see (a light one, at the skin's edge) sways for a moment.
``SteadyHealth`` keeps what is shown steady: a sensor's or line's state changes, flagged or
cleared, only once ``classify_sensors`` has said the new state ``STEADY_CONFIRM`` times in a
row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEAD_FRACTION",
    "DEAD_LEVEL",
    "STEADY_CONFIRM",
    "WEAK_CLEAR_FRACTION",
    "NOISY_FACTOR",
    "NOISY_MARGIN_COUNTS",
    "WEAK_FRACTION",
    "LineHealth",
    "SensorHealth",
    "SteadyHealth",
    "classify_sensors",
    "line_health",
]

#: A line whose median gain is below this fraction of the median line is weak ...
WEAK_FRACTION = 0.55
#: ... and below this fraction, dead (a crossing too, against the median crossing).
DEAD_FRACTION = 0.12
#: A line already shown weak or dead clears only above this fraction of the median line (a
#: band against a line's gain, estimated from a few touches, wavering around ``WEAK_FRACTION``).
WEAK_CLEAR_FRACTION = 0.65
#: A sensor whose no-touch noise exceeds this multiple of the median is noisy ...
NOISY_FACTOR = 3.0
#: ... if it is also this far above the median, counts.
NOISY_MARGIN_COUNTS = 2.0


@dataclass(frozen=True)
class SensorHealth:
    """The state of every sensor and line of a TX x RX skin.

    Attributes
    ----------
    status : (n_tx * n_rx,) str
        ``ok``, ``weak``, ``dead`` or ``noisy`` per sensor, TX-major.
    lines : dict
        ``{"tx": [n_tx states], "rx": [n_rx states]}``.
    line_gain : dict or None
        ``{"tx": [...], "rx": [...]}``: each line's median gain (median crossing 1); None
        without gains.
    """

    status: np.ndarray
    lines: dict[str, list[str]]
    line_gain: dict[str, list[float]] | None = None

    def bad_lines(self, kind: str) -> list[dict[str, object]]:
        """The lines of ``kind`` (``tx`` or ``rx``) that are not ok: ``{"index", "status"}``."""
        return [{"index": i, "status": s} for i, s in enumerate(self.lines[kind]) if s != "ok"]


def classify_sensors(
    n_tx: int,
    n_rx: int,
    *,
    gain: np.ndarray | None = None,
    noise: np.ndarray | None = None,
    stuck: np.ndarray | None = None,
    shown: dict[str, list[str]] | None = None,
) -> SensorHealth:
    """Classify every sensor and line (the rule of the module docstring).

    Parameters
    ----------
    n_tx, n_rx : int
        The grid.
    gain : (n_tx * n_rx,) float, optional
        Each crossing's gain (any scale; NaN where unknown).
    noise : (n_tx * n_rx,) float, optional
        Each sensor's no-touch noise, counts (NaN where unknown).
    stuck : (n_tx * n_rx,) bool, optional
        Sensors that did not change, or sit at the ADC's rails.
    shown : dict, optional
        ``{"tx": [...], "rx": [...]}``: the lines' states shown so far (``SteadyHealth``). A
        line shown weak or dead stays at least weak while its gain is under
        ``WEAK_CLEAR_FRACTION`` of the median line.

    Returns
    -------
    SensorHealth
    """
    n = n_tx * n_rx
    noisy = np.zeros(n, dtype=bool)
    if noise is not None:
        noise = np.asarray(noise, dtype=np.float64).reshape(n)
        if np.isfinite(noise).any():
            med = float(np.nanmedian(noise))
            limit = max(NOISY_FACTOR * med, med + NOISY_MARGIN_COUNTS)
            noisy = np.isfinite(noise) & (noise > limit)
    dead = np.zeros(n, dtype=bool) if stuck is None else np.asarray(stuck, dtype=bool).reshape(n)
    line_gain = None
    if gain is not None:
        gain = np.asarray(gain, dtype=np.float64).reshape(n)
        ref = float(np.nanmedian(gain))
        dead = dead | (gain < DEAD_FRACTION * ref)
        G = gain.reshape(n_tx, n_rx)
        line_gain = {"tx": np.nanmedian(G, axis=1), "rx": np.nanmedian(G, axis=0)}
    D, N = dead.reshape(n_tx, n_rx), noisy.reshape(n_tx, n_rx)
    status = np.full((n_tx, n_rx), "ok", dtype=object)
    lines: dict[str, list[str]] = {}
    for kind, axis in (("tx", 1), ("rx", 0)):
        n_lines = n_tx if kind == "tx" else n_rx
        ref = float(np.nanmedian(line_gain[kind])) if line_gain is not None else np.nan
        # each line's share of dead and of noisy sensors, all lines at once (the live
        # diagnostics classify every skin every second, on the loop's thread)
        dead_share, noisy_share = D.mean(axis=axis).tolist(), N.mean(axis=axis).tolist()
        states = []
        for i in range(n_lines):
            sl = (i, slice(None)) if axis == 1 else (slice(None), i)
            g = line_gain[kind][i] if line_gain is not None else np.nan
            was = shown[kind][i] if shown is not None and i < len(shown[kind]) else "ok"
            weak_below = WEAK_CLEAR_FRACTION if was in ("weak", "dead") else WEAK_FRACTION
            if g < DEAD_FRACTION * ref or dead_share[i] > 0.5:
                s = "dead"
            elif g < weak_below * ref:
                s = "weak"
            elif noisy_share[i] > 0.5:
                s = "noisy"
            else:
                s = "ok"
            states.append(s)
            if s != "ok":
                status[sl] = np.where(status[sl] == "dead", "dead", s)
        lines[kind] = states
    flat = status.ravel()
    flat[dead] = "dead"
    flat[(flat == "ok") & noisy] = "noisy"
    gains = None if line_gain is None else {k: [float(v) for v in g] for k, g in line_gain.items()}
    return SensorHealth(flat.astype(str), lines, gains)


#: Classifications in a row that must give a sensor or line its new state before it shows.
STEADY_CONFIRM = 3


class SteadyHealth:
    """What a live view shows of successive classifications: each state changes with evidence.

    The first classification is shown as it is. From then on a sensor's or a line's shown state
    changes (to a flag, another flag, or ``ok``) only once ``n_confirm`` classifications in a
    row gave it that same new state; one that disagrees starts the count again. A flag that a
    moment's frames raise (a touch counted as noise) therefore never shows, and one that shows
    does not clear on one good window. Every state comes from ``classify_sensors``; this only
    decides when it is shown.

    Parameters
    ----------
    n_confirm : int, default=STEADY_CONFIRM
        Classifications in a row a new state needs, >= 1 (1: every classification as is).
    """

    def __init__(self, n_confirm: int = STEADY_CONFIRM) -> None:
        if int(n_confirm) != n_confirm or n_confirm < 1:
            raise ValueError(f"n_confirm must be an integer >= 1, got {n_confirm!r}")
        self.n_confirm = int(n_confirm)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next classification is shown as it is."""
        self._shown: dict[str, np.ndarray] | None = None
        self._next: dict[str, np.ndarray] = {}
        self._count: dict[str, np.ndarray] = {}

    @staticmethod
    def _parts(health: SensorHealth) -> dict[str, np.ndarray]:
        return {
            "status": np.asarray(health.status, dtype=object).copy(),
            "tx": np.asarray(health.lines["tx"], dtype=object),
            "rx": np.asarray(health.lines["rx"], dtype=object),
        }

    @property
    def lines(self) -> dict[str, list[str]] | None:
        """The lines' states shown now (None before the first classification)."""
        if self._shown is None:
            return None
        return {k: [str(v) for v in self._shown[k]] for k in ("tx", "rx")}

    def update(self, health: SensorHealth) -> SensorHealth:
        """Take the latest classification; returns the states to show now.

        Parameters
        ----------
        health : SensorHealth
            ``classify_sensors``'s verdict on the latest window. Another grid than before
            starts afresh.

        Returns
        -------
        SensorHealth
            The shown states, with ``health``'s line gains.
        """
        raw = self._parts(health)
        shown = self._shown
        if shown is None or any(shown[k].shape != raw[k].shape for k in raw):
            self._shown = raw
            self._next = {k: v.copy() for k, v in raw.items()}
            self._count = {k: np.zeros(v.shape, dtype=np.int64) for k, v in raw.items()}
            return self._as_health(health)
        for k, now in raw.items():
            nxt, count = self._next[k], self._count[k]
            same = now == nxt
            count[:] = np.where(now == shown[k], 0, np.where(same, count + 1, 1))
            nxt[:] = now
            done = count >= self.n_confirm
            shown[k][done] = now[done]
            count[done] = 0
        return self._as_health(health)

    def _as_health(self, health: SensorHealth) -> SensorHealth:
        shown = self._shown
        assert shown is not None
        lines = {"tx": [str(v) for v in shown["tx"]], "rx": [str(v) for v in shown["rx"]]}
        return SensorHealth(shown["status"].astype(str), lines, health.line_gain)


#: A line whose sensors read less than this fraction of the median baseline is dead (a broken
#: or unconnected wire reads next to nothing).
DEAD_LEVEL = 0.05


@dataclass(frozen=True)
class LineHealth:
    """Dead and noisy lines found in a short no-touch baseline.

    Attributes
    ----------
    dead_tx, dead_rx : list of int
        Lines (0-based, in the order the board sends them) whose sensors read next to nothing,
        or never change (stuck).
    noisy_tx, noisy_rx : list of int
        Lines most of whose sensors are noisy (``skinloc.sensors.health``: over
        ``NOISY_FACTOR`` times the median sensor's noise).
    median_counts : float
        Median baseline level, counts.
    median_noise : float
        Median no-touch noise std of a sensor, counts.
    """

    dead_tx: list[int]
    dead_rx: list[int]
    noisy_tx: list[int]
    noisy_rx: list[int]
    median_counts: float
    median_noise: float

    @property
    def healthy(self) -> bool:
        """No dead or noisy line."""
        return not (self.dead_tx or self.dead_rx or self.noisy_tx or self.noisy_rx)


def line_health(frames: np.ndarray, n_tx: int, n_rx: int) -> LineHealth:
    """Dead and noisy lines of a no-touch baseline.

    Parameters
    ----------
    frames : (n_frames, n_tx * n_rx) float
        Raw counts, TX-major, nothing touching the skin; at least 10 frames.
    n_tx, n_rx : int
        Grid.
    """
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 2 or frames.shape[1] != n_tx * n_rx or len(frames) < 10:
        raise ValueError(f"need (>= 10, {n_tx * n_rx}) frames, got {frames.shape}")
    level = np.median(frames, axis=0)
    noise = frames.std(axis=0)
    med_level = float(np.median(level))
    med_noise = float(np.median(noise))
    # A wire that reads next to nothing is at the ADC's lower rail: stuck, like one that never
    # changes or sits at the upper rail. The one rule (sensors.health) decides the lines.
    stuck = (level < DEAD_LEVEL * med_level) | (noise == 0) | (level >= 65535)
    health = classify_sensors(n_tx, n_rx, noise=noise, stuck=stuck)
    tx, rx = health.lines["tx"], health.lines["rx"]
    dead_tx = [i for i, s in enumerate(tx) if s == "dead"]
    dead_rx = [j for j, s in enumerate(rx) if s == "dead"]
    noisy_tx = [i for i, s in enumerate(tx) if s == "noisy"]
    noisy_rx = [j for j, s in enumerate(rx) if s == "noisy"]
    return LineHealth(dead_tx, dead_rx, noisy_tx, noisy_rx, med_level, med_noise)
