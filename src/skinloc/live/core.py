"""The live localisation pipeline: raw frames in, contacts on the skin out.

Per skin, ``SkinCore`` runs, for every frame::

    raw counts -> baseline subtraction (drift tracked only while untouched)
               -> touch detection (hysteresis + debouncing: touch-start / touch-end events)
               -> localiser (the model's engine, ``skinloc.models.engine``) -> surface constraint
               -> temporal filtering on the surface (One-Euro filter, then back onto the skin)
               -> ``Contact``

``SkinCore`` is pure (no I/O, no threads, no clock of its own) and takes either decoded frames
(``process``) or wire bytes (``feed``). ``skinloc.live.runner.Pipeline`` (one skin) and
``skinloc.live.runner.Runner`` (many skins, one process; ``skinloc.live.skins_file`` reads its
configuration file) connect cores to frame sources and to sinks (``skinloc.live.sinks``).
``Contact`` lives in ``live.contact`` (the sinks import it from there) and is re-exported here.

Units: metres in the mesh frame, times in seconds (``time.monotonic`` for arrival and output
times), latencies in microseconds, signals in raw counts or in noise standard deviations (z).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import Any

import numpy as np

from skinloc._jit import jit
from skinloc.live.contact import Contact
from skinloc.models.engine import Engine, load_engine

log = logging.getLogger(__name__)

__all__ = [
    "Contact",
    "PipelineConfig",
    "SkinCore",
    "TouchState",
    "load_fast_localizer",
]


class TouchState(StrEnum):
    """Touch state carried by every output."""

    START = "start"  #: first frame of a touch (after debouncing)
    MOVE = "move"  #: a frame while the touch lasts
    END = "end"  #: the touch ended (after debouncing); position is the last one
    IDLE = "idle"  #: nothing touches (emitted only with ``emit_idle``)

    @classmethod
    def _missing_(cls, value: object) -> TouchState:
        valid = ", ".join(m.value for m in cls)
        raise ValueError(f"unknown touch state {value!r}; choose one of: {valid}")


@dataclass
class PipelineConfig:
    """Settings of the per-skin processing; every field is checked in ``__post_init__``.

    Attributes
    ----------
    baseline_frames : int
        Untouched frames averaged at start for the baseline and per-sensor noise.
    drift_tracking : bool
        Let the baseline follow slow drift while nothing touches.
    drift_time_constant_s : float
        Time constant of the baseline's exponential tracking, s.
    quiet_z : float
        Untouched frames whose peak signal exceeds this (in noise std) do not update the
        baseline (a finger approaching), unless that lasts ``max_freeze_s``: then it is drift.
        During a touch, sensors below it (far from the finger) keep tracking; those under the
        finger are frozen, so a held touch is never tracked away.
    max_freeze_s : float
        Longest pause of idle tracking because of a raised sensor, s.
    release_fraction : float
        A touch also ends when its signal falls below this fraction of its level during the
        touch (a release after a long hold, when the frozen sensors have drifted).
    touch_on_z, touch_off_z : float
        Hysteresis: a touch starts above ``touch_on_z`` and ends below ``touch_off_z``.
    debounce_on_frames, debounce_off_frames : int
        Consecutive frames beyond a threshold before a touch starts or ends.
    noise_floor_counts : float
        Smallest per-sensor noise std used, counts (a silent sensor does not blow up z).
    filter : {"one-euro", "none"}
        Temporal filter of the position on the surface.
    min_cutoff_hz, beta, d_cutoff_hz : float
        One-Euro filter: cutoff at rest, Hz; speed coefficient, s/m; cutoff of the speed, Hz.
    emit_idle : bool
        Also output one ``idle`` record per untouched frame.
    stale_s : float
        A touch whose frames stop for longer than this (link lost) is ended, s.
    """

    baseline_frames: int = 50
    drift_tracking: bool = True
    drift_time_constant_s: float = 3.0
    quiet_z: float = 3.0
    max_freeze_s: float = 2.0
    release_fraction: float = 0.25
    touch_on_z: float = 8.0
    touch_off_z: float = 4.0
    debounce_on_frames: int = 2
    debounce_off_frames: int = 3
    noise_floor_counts: float = 2.0
    filter: str = "one-euro"
    min_cutoff_hz: float = 2.0
    beta: float = 20.0
    d_cutoff_hz: float = 1.0
    emit_idle: bool = False
    stale_s: float = 1.0

    def __post_init__(self) -> None:
        def need(name: str, ok: bool, allowed: str) -> None:
            if not ok:
                raise ValueError(
                    f"PipelineConfig.{name} must be {allowed}, got {getattr(self, name)!r}"
                )

        for name in ("baseline_frames", "debounce_on_frames", "debounce_off_frames"):
            v = getattr(self, name)
            need(name, isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an int >= 1")
        for name in (
            "drift_time_constant_s",
            "touch_on_z",
            "touch_off_z",
            "quiet_z",
            "max_freeze_s",
            "noise_floor_counts",
            "min_cutoff_hz",
            "d_cutoff_hz",
            "stale_s",
        ):
            v = getattr(self, name)
            need(name, isinstance(v, int | float) and math.isfinite(v) and v > 0, "a number > 0")
        need("beta", isinstance(self.beta, int | float) and self.beta >= 0, "a number >= 0")
        need("touch_off_z", self.touch_off_z <= self.touch_on_z, "<= touch_on_z")
        rf = self.release_fraction
        need("release_fraction", isinstance(rf, int | float) and 0 <= rf < 1, "in [0, 1)")
        need("filter", self.filter in ("one-euro", "none"), "one of one-euro, none")

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "pipeline settings") -> PipelineConfig:
        """Build from a dict (a config file section); unknown keys raise, naming them."""
        known = {f.name for f in fields(cls)}
        d = {str(k).replace("-", "_"): v for k, v in d.items()}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(
                f"unknown key(s) in {where}: {', '.join(unknown)}; "
                f"known: {', '.join(sorted(known))}"
            )
        return cls(**d)


# --------------------------------------------------------------------------------------------
# compiled per-frame steps


@jit()
def _prep(
    values: np.ndarray,
    baseline: np.ndarray,
    inv_sigma: np.ndarray,
    delta: np.ndarray,
    alpha: float,
    quiet_z: float,
    mode: int,
) -> float:  # pragma: no cover - compiled
    """``delta = values - baseline``; returns the peak ``delta / sigma``.

    Drift tracking moves the baseline ``alpha`` of the way towards ``values``: ``mode`` 0 not
    at all; 1 every sensor if the peak is below ``quiet_z``; 2 every sensor; 3 only sensors
    below ``quiet_z`` (during a touch: those away from the finger).
    """
    n = values.shape[0]
    peak = -np.inf
    for i in range(n):
        d = values[i] - baseline[i]
        delta[i] = d
        z = d * inv_sigma[i]
        if z > peak:
            peak = z
    if alpha > 0.0:
        if mode == 2 or (mode == 1 and peak < quiet_z):
            for i in range(n):
                baseline[i] += alpha * (values[i] - baseline[i])
        elif mode == 3:
            for i in range(n):
                if delta[i] * inv_sigma[i] < quiet_z:
                    baseline[i] += alpha * (values[i] - baseline[i])
    return peak


@jit()
def _one_euro(
    state: np.ndarray, p0: float, p1: float, p2: float, t: float, prm: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """One-Euro filter (Casiez et al. 2012) of a 3D point; ``state`` = [init, t, x3, dx3].

    ``prm`` = [min_cutoff_hz, beta, d_cutoff_hz]. Writes the filtered point to ``out (3,)``.
    """
    if state[0] == 0.0:
        state[0] = 1.0
        state[1] = t
        state[2] = p0
        state[3] = p1
        state[4] = p2
        state[5] = 0.0
        state[6] = 0.0
        state[7] = 0.0
        out[0] = p0
        out[1] = p1
        out[2] = p2
        return
    dt = t - state[1]
    if dt <= 0.0:
        dt = 1e-3
    state[1] = t
    ad = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * prm[2] * dt))
    speed = 0.0
    for k in range(3):
        p = p0 if k == 0 else (p1 if k == 1 else p2)
        dx = (p - state[2 + k]) / dt
        state[5 + k] += ad * (dx - state[5 + k])
        speed += state[5 + k] * state[5 + k]
    cutoff = prm[0] + prm[1] * math.sqrt(speed)
    a = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))
    for k in range(3):
        p = p0 if k == 0 else (p1 if k == 1 else p2)
        state[2 + k] += a * (p - state[2 + k])
        out[k] = state[2 + k]


# --------------------------------------------------------------------------------------------
# one skin


def load_fast_localizer(model: Any) -> Engine:
    """The warmed-up engine of a model path, a ``ContactLocalizer``, a spec or an engine."""
    return load_engine(model)


class SkinCore:
    """The per-skin processing chain, pure and single-threaded.

    Parameters
    ----------
    localizer : Engine, ContactLocalizer or path
        The model.
    config : PipelineConfig, optional
        Detection, drift and filter settings.
    name : str, default="skin"
        Name carried by every ``Contact``.
    n_tx, n_rx : int, optional
        Grid, for ``feed`` (bytes); by default 8 x 8 when it matches the model.
    wire_format : {"auto", "binary", "text"}, default="auto"
        Wire format for ``feed``.

    Examples
    --------
    >>> core = SkinCore("model.h5")  # doctest: +SKIP
    >>> core.set_baseline(untouched_frames)  # doctest: +SKIP
    >>> contact = core.process(frame_values, timestamp_s=0.01, index=1)  # doctest: +SKIP
    """

    def __init__(
        self,
        localizer: Any,
        config: PipelineConfig | None = None,
        *,
        name: str = "skin",
        n_tx: int | None = None,
        n_rx: int | None = None,
        wire_format: str = "auto",
    ) -> None:
        self.fast = load_fast_localizer(localizer)
        self.config = PipelineConfig() if config is None else config
        self.name = name
        n = self.fast.n_features
        self.n_sensors = n
        if n_tx is None or n_rx is None:
            n_tx, n_rx = (8, 8) if n == 64 else (n, 1)
        if n_tx * n_rx != n:
            raise ValueError(
                f"skin {name!r}: a {n_tx} x {n_rx} grid has {n_tx * n_rx} sensors but the model "
                f"takes {n}"
            )
        self.n_tx, self.n_rx = int(n_tx), int(n_rx)
        self.wire_format = wire_format
        self._parser = None
        self._baseline = np.zeros(n, dtype=np.float64)
        self._inv_sigma = np.ones(n, dtype=np.float64)
        self._acc = np.zeros(n, dtype=np.float64)
        self._acc2 = np.zeros(n, dtype=np.float64)
        self._n_acc = 0
        self.calibrated = False
        self._delta = np.zeros(n, dtype=np.float32)
        self._out = np.zeros(7, dtype=np.float64)
        self._filt_state = np.zeros(8, dtype=np.float64)
        self._filt_prm = np.array(
            [self.config.min_cutoff_hz, self.config.beta, self.config.d_cutoff_hz]
        )
        self._pos = np.zeros(3, dtype=np.float64)
        self._tmp = np.zeros(3, dtype=np.float64)
        self._touching = False
        self._above = 0
        self._below = 0
        self._holdoff = 0
        self._touch_id = 0
        self._last_contact: Contact | None = None
        self._last_t_in = -math.inf
        self._last_counter: int | None = None
        self._counter_base = 0
        self.n_frames = 0
        self.n_touches = 0
        self.n_contacts = 0
        self._alpha = 0.0
        self._dt = 0.01
        self._level_alpha = 0.02
        self._level = 0.0
        self._frozen_s = 0.0
        self._last_ts: float | None = None
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the per-frame kernels now, not on a touch."""
        n = self.n_sensors
        scratch = np.zeros(n, dtype=np.float32)
        for dtype in (np.float32, np.uint16):
            _prep(
                np.zeros(n, dtype=dtype),
                self._baseline.copy(),
                self._inv_sigma,
                scratch,
                0.0,
                1.0,
                0,
            )
        _one_euro(np.zeros(8), 0.0, 0.0, 0.0, 0.0, self._filt_prm, np.zeros(3))
        self.fast.constrain_into(0.0, 0.0, 0.0, np.zeros(3))

    # ------------------------------------------------------------------ baseline
    def set_baseline(self, frames: np.ndarray) -> None:
        """Set the baseline and per-sensor noise from untouched raw frames ``(m, n_sensors)``."""
        F = np.asarray(frames, dtype=np.float64).reshape(-1, self.n_sensors)
        if len(F) == 0 or not np.all(np.isfinite(F)):
            raise ValueError("baseline frames must be a non-empty array of finite counts")
        self._baseline[:] = F.mean(axis=0)
        sigma = F.std(axis=0) if len(F) > 1 else np.zeros(self.n_sensors)
        self._inv_sigma[:] = 1.0 / np.maximum(sigma, self.config.noise_floor_counts)
        self.calibrated = True
        self._n_acc = 0

    def recalibrate(self) -> None:
        """Capture a fresh baseline from the next ``baseline_frames`` frames (keep untouched)."""
        self.calibrated = False
        self._n_acc = 0
        self._acc[:] = 0.0
        self._acc2[:] = 0.0
        self._touching = False
        self._above = self._below = 0

    @property
    def baseline(self) -> np.ndarray:
        """Current baseline, ``(n_sensors,)`` counts."""
        return self._baseline.copy()

    @property
    def noise(self) -> np.ndarray:
        """Per-sensor noise std used for detection, ``(n_sensors,)`` counts."""
        return 1.0 / self._inv_sigma

    @property
    def touching(self) -> bool:
        """Whether a touch is in progress."""
        return self._touching

    def _accumulate(self, values: np.ndarray) -> None:
        v = np.asarray(values, dtype=np.float64)
        self._acc += v
        self._acc2 += v * v
        self._n_acc += 1
        if self._n_acc >= self.config.baseline_frames:
            m = self._n_acc
            mean = self._acc / m
            var = np.maximum(self._acc2 / m - mean * mean, 0.0) * m / max(m - 1, 1)
            self._baseline[:] = mean
            self._inv_sigma[:] = 1.0 / np.maximum(np.sqrt(var), self.config.noise_floor_counts)
            self.calibrated = True
            log.info("%s: baseline from %d frames", self.name, m)

    # ------------------------------------------------------------------ frames
    def process(
        self, values: np.ndarray, timestamp_s: float, index: int = -1, t_in: float | None = None
    ) -> Contact | None:
        """Process one frame of raw counts ``(n_sensors,)``; returns its output, if any.

        ``t_in`` is when the frame's bytes arrived (``time.monotonic()``), for the latency; by
        default now.
        """
        if t_in is None:
            t_in = time.monotonic()
        if values.shape[0] != self.n_sensors:
            raise ValueError(
                f"skin {self.name!r}: frame has {values.shape[0]} sensors, the model takes "
                f"{self.n_sensors}"
            )
        self.n_frames += 1
        if not self.calibrated:
            self._accumulate(values)
            return None
        cfg = self.config
        if self._last_ts is not None:
            dt = timestamp_s - self._last_ts
            if 0.0 < dt < 1.0:
                self._dt = dt
                self._alpha = min(dt / cfg.drift_time_constant_s, 1.0)
                self._level_alpha = min(dt / 0.5, 1.0)  # touch level: 0.5 s time constant
        self._last_ts = timestamp_s
        mode = 0
        if cfg.drift_tracking:
            if self._touching:
                mode = 3  # only sensors away from the finger: the touch is never tracked away
            elif self._above == 0 and self._holdoff == 0:
                mode = 2 if self._frozen_s > cfg.max_freeze_s else 1
        z = _prep(
            values, self._baseline, self._inv_sigma, self._delta, self._alpha, cfg.quiet_z, mode
        )
        if mode == 1 and z >= cfg.quiet_z:
            self._frozen_s += self._dt
        elif mode != 2 or z < cfg.quiet_z:
            self._frozen_s = 0.0
        if self._holdoff:
            self._holdoff -= 1
        state = None
        if self._touching:
            level = self._level
            self._level = level + self._level_alpha * (z - level) if level > 0 else z
            if z < cfg.touch_off_z or z < cfg.release_fraction * level:
                self._below += 1
                if self._below >= cfg.debounce_off_frames:
                    self._touching = False
                    self._below = 0
                    self._holdoff = cfg.debounce_off_frames
                    return self._end(timestamp_s, index, z, t_in)
            else:
                self._below = 0
            state = TouchState.MOVE
        elif z >= cfg.touch_on_z:
            self._above += 1
            if self._above >= cfg.debounce_on_frames:
                self._touching = True
                self._above = 0
                self._below = 0
                self._touch_id += 1
                self.n_touches += 1
                self._level = 0.0
                self._filt_state[0] = 0.0
                state = TouchState.START
        else:
            self._above = 0
        if state is None:
            if cfg.emit_idle:
                return self._idle(timestamp_s, index, z, t_in)
            return None
        return self._localise(state, timestamp_s, index, z, t_in)

    def _localise(self, state: TouchState, ts: float, index: int, z: float, t_in: float) -> Contact:
        out = self._out
        fast = self.fast
        fast.localise_into(self._delta, out)
        if self.config.filter == "one-euro":
            _one_euro(self._filt_state, out[3], out[4], out[5], ts, self._filt_prm, self._tmp)
            fast.constrain_into(self._tmp[0], self._tmp[1], self._tmp[2], self._pos)
        else:
            self._pos[:] = out[3:6]
        o = out.tolist()
        pos = self._pos.tolist()
        spread = o[6]
        cfg = self.config
        conf = 1.0 - math.exp(-max(z - cfg.touch_off_z, 0.0) / cfg.touch_on_z)
        if spread == spread:  # not nan
            conf *= math.exp(-spread / 10.0)
        c = Contact(
            self.name,
            ts,
            index,
            state.value,
            (pos[0], pos[1], pos[2]),
            (o[0], o[1], o[2]),
            conf,
            z,
            spread,
            (time.monotonic() - t_in) * 1e6,
            self._touch_id,
        )
        self._last_contact = c
        self._last_t_in = t_in
        self.n_contacts += 1
        return c

    def _end(self, ts: float, index: int, z: float, t_in: float) -> Contact:
        last = self._last_contact
        pos = last.position_m if last else (math.nan,) * 3
        raw = last.raw_m if last else (math.nan,) * 3
        self.n_contacts += 1
        return Contact(
            self.name,
            ts,
            index,
            TouchState.END.value,
            pos,
            raw,
            last.confidence if last else 0.0,
            z,
            last.uncertainty_mm if last else math.nan,
            (time.monotonic() - t_in) * 1e6,
            self._touch_id,
        )

    def _idle(self, ts: float, index: int, z: float, t_in: float) -> Contact:
        nan3 = (math.nan, math.nan, math.nan)
        return Contact(
            self.name,
            ts,
            index,
            TouchState.IDLE.value,
            nan3,
            nan3,
            0.0,
            z,
            math.nan,
            (time.monotonic() - t_in) * 1e6,
            self._touch_id,
        )

    def link_lost(self, now: float | None = None) -> Contact | None:
        """The source stopped delivering; ends a touch whose frames are over ``stale_s`` old.

        Call it periodically while a link is down. Returns the ``end`` event, if one is due.
        """
        now = time.monotonic() if now is None else now
        if self._touching and now - self._last_t_in > self.config.stale_s:
            self._touching = False
            self._below = 0
            last = self._last_contact
            ts = (last.timestamp_s if last else 0.0) + (now - self._last_t_in)
            return self._end(ts, last.index if last else -1, math.nan, now)
        return None

    # ------------------------------------------------------------------ bytes
    def feed(self, data: bytes, t_in: float | None = None) -> list[Contact]:
        """Parse wire bytes (``skinloc.hardware.framing``) and process every complete frame in them.

        Frame timestamps are ``t_in`` (arrival, ``time.monotonic()``); indices are the device's
        counter, unwrapped (binary) or a running count (text).
        """
        if t_in is None:
            t_in = time.monotonic()
        if self._parser is None:
            from skinloc.hardware.framing import make_parser

            self._parser = make_parser(self.wire_format, self.n_tx, self.n_rx)
        out: list[Contact] = []
        for raw in self._parser.feed(data):
            counter = raw.counter
            if counter is None:
                index = self.n_frames
            else:
                if self._last_counter is not None and counter < self._last_counter:
                    self._counter_base += 1 << 16
                self._last_counter = counter
                index = self._counter_base + counter
            c = self.process(raw.values, t_in, index, t_in)
            if c is not None:
                out.append(c)
        return out

    def reset_link(self) -> None:
        """Forget partial wire input after a reconnect (the touch state is kept)."""
        if self._parser is not None:
            self._parser.reset()
        self._last_counter = None
        self._counter_base = (self._counter_base >> 16) + 1 << 16

    @property
    def parser_stats(self) -> dict[str, int]:
        """Counters of the wire parser (empty before ``feed``)."""
        return {} if self._parser is None else self._parser.stats.as_dict()


ContactCallback = Callable[[Contact], None]
