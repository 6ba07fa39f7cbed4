"""The live localisation pipeline: raw frames in, contacts on the skin out.

Per skin, ``SkinCore`` runs, for every frame::

    raw counts -> baseline subtraction (drift tracked only while untouched)
               -> touch detection (hysteresis + debouncing: touch-start / touch-end events)
               -> localiser (the model's engine, ``skinloc.models.engine``) -> surface constraint
               -> temporal filtering on the surface (One-Euro filter, then back onto the skin)
               -> ``Contact``

``SkinCore`` is pure (no I/O, no threads, no clock of its own) and takes either decoded frames
(``process_frame``) or wire bytes (``feed``); both return every contact of the frames.
``skinloc.live.runner.Pipeline`` (one skin) and ``skinloc.live.runner.Runner`` (many skins, one
process; ``skinloc.live.skins_file`` reads its configuration file) connect cores to frame
sources and to sinks (``skinloc.live.sinks``). ``Contact`` lives in ``live.contact`` (the sinks
import it from there), ``PipelineConfig`` and ``TouchState`` in ``live.config``; both are
re-exported here. The compiled steps are ``live.baseline`` (baseline subtraction, drift, and
``BaselineCapture``, the baseline's capture) and ``live.one_euro`` (the filter).

The touch detection here is deliberately not the calibration touch rule
(``calibration.capture``: a held press on a fixed baseline, judged by how many sensors it
moves, kept for a fixed number of frames): a live contact moves, on a baseline that tracks
drift, and starts and ends by hysteresis on the frame's largest z-score, compiled.

Units: metres in the mesh frame, times in seconds (``time.monotonic`` for arrival and output
times), latencies in microseconds, signals in raw counts or in noise standard deviations (z).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skinloc._jit import all_finite
from skinloc.live.baseline import BaselineCapture, subtract_baseline
from skinloc.live.config import PipelineConfig, TouchState
from skinloc.live.contact import Contact
from skinloc.live.footprint import FootprintWatch
from skinloc.live.gestures import GestureConfig, GestureRecognizer, SkinFrame
from skinloc.live.landing import LandingWatch
from skinloc.live.one_euro import one_euro, one_euro_onto
from skinloc.live.pair_prior import pair_prior
from skinloc.live.tracking import Track, Tracker, frame_contacts
from skinloc.models.engine import Engine, load_engine
from skinloc.models.multi_contact.search import SearchMemory
from skinloc.models.multi_contact.two_point import recogniser_mm, two_point_of

log = logging.getLogger(__name__)

__all__ = ["Contact", "PipelineConfig", "SkinCore", "TouchState"]


# --------------------------------------------------------------------------------------------
# one skin


def sensor_grid(name: str, n_sensors: int, n_tx: int | None, n_rx: int | None) -> tuple[int, int]:
    """The wire's ``(n_tx, n_rx)`` for a model of ``n_sensors``.

    By default 8 x 8 when it fits, else ``n x 1``; with one of them given, the other from the
    sensors.

    Raises
    ------
    ValueError
        When the grid does not hold ``n_sensors`` sensors (naming the skin).
    """
    n = n_sensors
    if n_tx is None and n_rx is None:
        n_tx, n_rx = (8, 8) if n == 64 else (n, 1)
    elif n_tx is None or n_rx is None:  # half a grid: the other half from the sensors
        n_tx, n_rx = (n // n_rx, n_rx) if n_tx is None else (n_tx, n // n_tx)
    if n_tx * n_rx != n:
        raise ValueError(
            f"skin {name!r}: a {n_tx} x {n_rx} grid has {n_tx * n_rx} sensors but the model "
            f"takes {n}"
        )
    return int(n_tx), int(n_rx)


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
        Grid, for ``feed`` (bytes); by default 8 x 8 when it matches the model (one of
        them given: the other from the model's sensors).
    wire_format : {"auto", "binary", "text"}, default="auto"
        Wire format for ``feed``.
    up : (3,) float, optional
        The skin's "up" in the mesh frame, for swipe directions (default: the mesh's long
        axis, ``skinloc.geometry.skin_frame.skin_up_axis``).
    gesture_config : GestureConfig, optional
        Thresholds of the gesture recogniser.

    Notes
    -----
    ``process_frame`` returns every contact of a frame (one per track); gesture events due at
    that frame wait in ``gestures`` until ``take_gestures`` collects them.

    Examples
    --------
    >>> core = SkinCore("model.h5")  # doctest: +SKIP
    >>> core.set_baseline(untouched_frames)  # doctest: +SKIP
    >>> contacts = core.process_frame(frame_values, timestamp_s=0.01, index=1)  # doctest: +SKIP
    """

    # what a core keeps, by concern (set up by the builders ``__init__`` calls)
    engine: Engine  # the model
    config: PipelineConfig
    name: str
    n_sensors: int
    n_tx: int  # the wire's grid (``feed``)
    n_rx: int
    wire_format: str
    #: Sinks that record raw frames (``emit_frame``), handed every frame before processing.
    frame_sinks: list[Any]
    #: Called with the exception of a frame whose processing raised (the frame is then
    #: dropped); None: the exception propagates. The runner counts and logs them.
    on_frame_error: Callable[[Exception], Any] | None
    # baseline: the capture, its arrays (the same objects, for the per-frame kernel), a tare
    _capture: BaselineCapture
    _baseline: np.ndarray
    _inv_sigma: np.ndarray
    calibrated: bool
    _tare_from: np.ndarray | None  # the baseline a tare in progress replaces
    #: what the last finished ``tare`` changed (None before one ends)
    last_tare: dict[str, float] | None
    # touch detection (hysteresis, debouncing) and drift tracking's clock
    _touching: bool
    _above: int
    _below: int
    _holdoff: int
    _touch_id: int
    _level: float  # the touch's smoothed peak z, for the release fraction
    _level_alpha: float
    _alpha: float  # drift tracking's step
    _dt: float
    _frozen_s: float  # how long drift tracking has been held off by a quiet-but-not-idle skin
    _last_ts: float | None
    _last_t_in: float
    _last_contact: Contact | None
    # per-frame scratch, allocated once: the hot path allocates nothing
    _delta: np.ndarray  # (n_sensors,) float32, the frame minus the baseline
    _out: np.ndarray  # (7,) the localiser's output
    _filt_state: np.ndarray  # (8,) the One-Euro filter's state
    _filt_prm: np.ndarray  # (3,) min cutoff Hz, beta, derivative cutoff Hz
    _pos: np.ndarray
    _tmp: np.ndarray
    # multi-contact tracking (None: K = 1)
    max_contacts: int
    #: this stream's memory of its last full multi-contact search (None: every frame
    #: searched in full, the answers' reference)
    search_memory: SearchMemory | None
    _tracker: Tracker | None
    # gestures (None: off)
    gestures: list[dict[str, Any]]  # events due, collected by ``take_gestures``
    _recognizer: GestureRecognizer | None
    _landing: LandingWatch | None  # a second finger in time
    _footprint: FootprintWatch | None  # a second finger in the image's shape
    # counters
    n_frames: int
    n_nonfinite: int  # frames dropped for a NaN or infinite value
    n_touches: int
    n_contacts: int

    def __init__(
        self,
        localizer: Any,
        config: PipelineConfig | None = None,
        *,
        name: str = "skin",
        n_tx: int | None = None,
        n_rx: int | None = None,
        wire_format: str = "auto",
        up: Sequence[float] | None = None,
        gesture_config: GestureConfig | None = None,
    ) -> None:
        self.engine = load_engine(localizer)
        self.config = PipelineConfig() if config is None else config
        self.name = name
        self.n_sensors = self.engine.n_features
        self.n_tx, self.n_rx = sensor_grid(name, self.n_sensors, n_tx, n_rx)
        self.wire_format = wire_format
        self._decoder: Any = None  # the wire decoder, built on the first ``feed``
        self.frame_sinks = []
        self.on_frame_error = None
        self.n_frames = self.n_nonfinite = self.n_touches = self.n_contacts = 0
        self._init_baseline()
        self._init_touch()
        self._init_scratch()
        self.max_contacts = self.config.max_contacts
        self.search_memory = SearchMemory()
        self._tracker = self._make_tracker(self.config)
        self._init_gestures(up, gesture_config)
        self._warm_up()

    def _init_baseline(self) -> None:
        self._capture = BaselineCapture(self.n_sensors)
        self._baseline = self._capture.baseline
        self._inv_sigma = self._capture.inv_sigma
        self.calibrated = False
        self._tare_from = None
        self.last_tare = None

    def _init_touch(self) -> None:
        self._touching = False
        self._above = self._below = self._holdoff = self._touch_id = 0
        self._level = 0.0
        self._level_alpha = 0.02
        self._alpha = 0.0
        self._dt = 0.01
        self._frozen_s = 0.0
        self._last_ts = None
        self._last_t_in = -math.inf
        self._last_contact = None

    def _init_scratch(self) -> None:
        cfg = self.config
        self._delta = np.zeros(self.n_sensors, dtype=np.float32)
        self._out = np.zeros(7, dtype=np.float64)
        self._filt_state = np.zeros(8, dtype=np.float64)
        self._filt_prm = np.array([cfg.min_cutoff_hz, cfg.beta, cfg.d_cutoff_hz])
        self._pos = np.zeros(3, dtype=np.float64)
        self._tmp = np.zeros(3, dtype=np.float64)

    def _init_gestures(self, up: Sequence[float] | None, config: GestureConfig | None) -> None:
        """The gesture recogniser and its watches, when ``config.gestures`` and a frame exist."""
        self.gestures = []
        self._recognizer = self._landing = self._footprint = None
        cfg = self.config
        spec, rule = self.engine.spec, self.engine.rule  # what every engine declares
        if not cfg.gestures or (spec.vertices is None and up is None):
            return
        change = float(rule.landing_change)
        # the footprint (opt-in) is read off the contact search's scratch: K > 1 only
        if cfg.footprint_gestures and self._tracker is not None and rule.footprint_on:
            tables = self.engine.search_tables()
            if tables is not None:
                self._footprint = FootprintWatch(tables, rule)
        # the skin's two-point threshold: tracks closer than it may be one finger
        two_point_mm, _ = recogniser_mm(two_point_of(spec.contact_rule))
        self._recognizer = GestureRecognizer(
            self.name,
            SkinFrame(spec.vertices, spec.faces, up),
            config,
            landing_change=change,
            landing_hold=float(rule.landing_hold),
            two_point_mm=two_point_mm,
            footprint_levels=None
            if self._footprint is None
            else (rule.footprint_two, rule.footprint_hold),
        )
        if change > 0:
            self._landing = LandingWatch(self.engine.noise_weights())

    def _make_tracker(self, cfg: PipelineConfig) -> Tracker | None:
        """The multi-contact tracker of ``cfg`` (None for the single-contact pipeline)."""
        if cfg.max_contacts <= 1:
            return None
        return Tracker(
            cfg.max_contacts,
            cfg.track_gate_mm,
            cfg.track_miss_frames,
            cfg.track_confirm_frames,
            self.engine.constrain_into,
            self._filt_prm if cfg.filter == "one-euro" else None,
            pair=pair_prior(self.engine, self._delta),
            surface=self.engine.surface,
        )

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the per-frame kernels now, not on a touch."""
        n = self.n_sensors
        scratch, base = np.zeros(n, dtype=np.float32), self._baseline.copy()
        for dtype in (np.float32, np.uint16):
            subtract_baseline(np.zeros(n, dtype=dtype), base, self._inv_sigma, scratch, 0.0, 1.0, 0)
            all_finite(np.zeros(n, dtype=dtype))
        one_euro(np.zeros(8), 0.0, 0.0, 0.0, 0.0, self._filt_prm, np.zeros(3))
        self.engine.constrain_into(0.0, 0.0, 0.0, np.zeros(3))
        if self._tracker is not None:
            s = self.engine.surface
            z3 = np.zeros(3)
            one_euro_onto(np.zeros(8), 0.0, 0.0, 0.0, 0.0, self._filt_prm, z3, s.mode, s.args, z3)
        if self._tracker is not None and self._tracker.pair is not None:
            # the pair prior fits in a touch's first frames: compiled there, it stalled the
            # loop, and the frames read after the stall arrived at once, stamped late
            self._tracker.pair.refit.warm_up()
        if self._landing is not None:
            self._landing.warm_up()
        if self._footprint is not None:
            self._footprint.warm_up()

    # ------------------------------------------------------------------ baseline
    def set_baseline(self, frames: np.ndarray) -> None:
        """Set the baseline and per-sensor noise from untouched raw frames ``(m, n_sensors)``."""
        self._capture.set_from(frames, self.config.noise_floor_counts)
        self._captured()

    def recalibrate(self) -> None:
        """Capture a fresh baseline from the next ``baseline_frames`` frames (keep untouched)."""
        self.calibrated = False
        self._capture.restart()
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
        cfg = self.config
        if self._capture.add(values, cfg.baseline_frames, cfg.noise_floor_counts):
            self._captured()
            log.info("%s: baseline from %d frames", self.name, self._capture.n_frames)

    def _captured(self) -> None:
        """A baseline capture ended: the skin is calibrated; a tare in progress is closed."""
        self.calibrated = True
        if self._tare_from is not None:
            shift = self._baseline - self._tare_from
            self.last_tare = {
                "mean_shift_counts": float(shift.mean()),
                "max_abs_shift_counts": float(np.abs(shift).max()),
            }
            self._tare_from = None

    # ------------------------------------------------------------------ live control
    def tare(self) -> None:
        """Re-baseline now: capture a fresh baseline from the next ``baseline_frames`` frames.

        Refused while the skin is touched (or a touch is starting), so a tare never makes a
        finger part of the baseline, and while a capture is in progress. When the capture
        ends, ``last_tare`` holds what changed: ``mean_shift_counts`` (the new baseline minus
        the one it replaced, averaged over the sensors) and ``max_abs_shift_counts``.

        Raises
        ------
        ValueError
            With the reason, when refused.
        """
        if self._touching or self._above:
            raise ValueError(f"skin {self.name!r} is touched; tare refused (release it first)")
        if not self.calibrated:
            raise ValueError(f"skin {self.name!r} is capturing its baseline; try again later")
        self._tare_from = self._baseline.copy()
        self.last_tare = None
        self.recalibrate()

    @property
    def taring(self) -> bool:
        """Whether a ``tare`` is capturing its baseline."""
        return self._tare_from is not None

    def reset_tracks(self) -> int:
        """Forget the tracks and filter state now (refused while touched); returns tracks dropped.

        Raises
        ------
        ValueError
            While the skin is touched (its open tracks would end without an ``end``).
        """
        if self._touching:
            raise ValueError(f"skin {self.name!r} is touched; reset refused (release it first)")
        n = 0
        if self._tracker is not None:
            n = len(self._tracker.end_all())
            self._tracker = self._make_tracker(self.config)
        if self.search_memory is not None:
            self.search_memory.reset()
        self._filt_state[:] = 0.0
        return n

    def update_config(
        self, config: PipelineConfig, gestures: GestureConfig | None = None
    ) -> list[str]:
        """Apply new settings from the next frame; returns the names of the fields changed.

        ``config`` is a checked ``PipelineConfig`` (its ``__post_init__`` is the one
        validation); ``gestures`` new gesture thresholds (None: unchanged). Thresholds, drift
        and filter settings apply at the next frame; ``baseline_frames`` and
        ``noise_floor_counts`` at the next capture (a tare). A change of the tracker's settings
        (``max_contacts``, ``track_*``, ``filter``) builds a new tracker and is refused while
        the skin is touched; ``gestures`` and ``footprint_gestures`` are fixed at start.

        Raises
        ------
        ValueError
            With the reason, when a change is refused; nothing is applied then.
        """
        old = self.config
        changed = [
            f.name
            for f in dataclasses.fields(old)
            if getattr(old, f.name) != getattr(config, f.name)
        ]
        fixed = [n for n in changed if n in ("gestures", "footprint_gestures")]
        if fixed:
            raise ValueError(f"{', '.join(fixed)} cannot change while running (restart instead)")
        rebuild = any(
            n == "max_contacts" or n.startswith("track_") or n == "filter" for n in changed
        )
        if rebuild and self._touching:
            raise ValueError(
                f"skin {self.name!r} is touched; {', '.join(changed)} can change only while "
                "nothing touches"
            )
        if gestures is not None and self._recognizer is not None:
            self._recognizer.cfg = gestures
        self.config = config
        self._filt_prm[:] = (config.min_cutoff_hz, config.beta, config.d_cutoff_hz)
        if "drift_time_constant_s" in changed and self._last_ts is not None:
            self._alpha = min(self._dt / config.drift_time_constant_s, 1.0)
        if rebuild:
            self.max_contacts = config.max_contacts
            self._tracker = self._make_tracker(config)
        return changed

    def health(self) -> dict[str, Any]:
        """What a maintainer monitors of this skin's signal (counts).

        Returns
        -------
        dict
            ``noise`` ``(n_sensors,)`` each sensor's no-touch std at the last capture (NaN
            before one); ``stuck`` ``(n_sensors,)`` bool, sensors that did not change at all
            over it; ``drift`` ``(n_sensors,)`` the baseline now minus the one captured (what
            drift tracking moved since).
        """
        sigma = self._capture.captured_sigma
        return {
            "noise": sigma.copy(),
            "stuck": sigma == 0.0,
            "drift": self._baseline - self._capture.captured_baseline,
        }

    # ------------------------------------------------------------------ frames
    def process_frame(
        self, values: np.ndarray, timestamp_s: float, index: int = -1, t_in: float | None = None
    ) -> Sequence[Contact]:
        """Process one frame of raw counts ``(n_sensors,)``; returns its contacts, by slot.

        One ``Contact`` per track (``start``, ``move`` or ``end``), none while nothing touches
        (one ``idle`` record with ``emit_idle``). Gesture events due at this frame are appended
        to ``gestures``. ``t_in`` is when the frame's bytes arrived (``time.monotonic()``), for
        the latency; by default now. With ``on_frame_error`` set, a frame that raises is handed
        to it and gives no contact.
        """
        if self.on_frame_error is None:
            return self._process_frame(values, timestamp_s, index, t_in)
        try:
            return self._process_frame(values, timestamp_s, index, t_in)
        except Exception as exc:  # noqa: BLE001 - one frame must not stop the skin
            self.on_frame_error(exc)
            return ()

    def _process_frame(
        self, values: np.ndarray, timestamp_s: float, index: int, t_in: float | None
    ) -> Sequence[Contact]:
        for sink in self.frame_sinks:
            sink.emit_frame(self.name, values, timestamp_s, index)
        out = self._frame(values, timestamp_s, index, t_in)
        rec = self._recognizer
        if rec is not None and (out or rec.busy):
            # releasing (signal below the release threshold, or the touch just ended): the
            # fading image's positions are not the finger's
            releasing = self._below > 0 or not self._touching
            change = self._landing.most if self._landing is not None else 0.0
            fw = self._footprint
            foot = fw.mean if fw is not None and fw.n else None
            leapt = self._tracker.leapt if self._tracker is not None else ()
            g = (
                rec.update(timestamp_s, out, releasing, change, foot, leapt)
                if out
                else rec.tick(timestamp_s)
            )
            if g:
                self.gestures += g
        return out

    @property
    def n_gestures(self) -> int:
        """Gesture events recognised so far."""
        return 0 if self._recognizer is None else self._recognizer.n_events

    # ------------------------------------------------------------------ bytes
    def feed(self, data: bytes, t_in: float | None = None) -> list[Contact]:
        """Parse wire bytes (``skinloc.hardware.framing``) and process every complete frame in them.

        Returns every contact of those frames, frame after frame (``process_frame`` each). The
        bytes are decoded by the one serial reader (``skinloc.hardware.link.WireDecoder``): the
        last frame of ``data`` is stamped ``t_in`` (arrival, ``time.monotonic()``), earlier ones
        back by the device counter times the measured frame period; indices are the device's
        counter, unwrapped (binary) or a running count (text).
        """
        if t_in is None:
            t_in = time.monotonic()
        if self._decoder is None:
            from skinloc.hardware.link import WireDecoder

            self._decoder = WireDecoder(self.wire_format, self.n_tx, self.n_rx)
        out: list[Contact] = []
        for frame in self._decoder.feed(data, t_in):
            out += self.process_frame(frame.values, frame.timestamp_s, frame.index, t_in)
        return out

    def reset_link(self) -> None:
        """Forget partial wire input after a reconnect (the touch state is kept)."""
        if self._decoder is not None:
            self._decoder.reset()

    @property
    def parser_stats(self) -> dict[str, int]:
        """Counters of the wire parser (empty before ``feed``)."""
        return {} if self._decoder is None else self._decoder.stats.as_dict()

    def take_gestures(self) -> list[dict[str, Any]]:
        """The gesture events due so far (JSON-ready dicts), oldest first; clears them."""
        g, self.gestures = self.gestures, []
        return g

    def _frame(
        self, values: np.ndarray, timestamp_s: float, index: int, t_in: float | None
    ) -> Sequence[Contact]:
        if t_in is None:
            t_in = time.monotonic()
        if values.shape[0] != self.n_sensors:
            raise ValueError(
                f"skin {self.name!r}: frame has {values.shape[0]} sensors, the model takes "
                f"{self.n_sensors}"
            )
        if not all_finite(values):
            # a NaN would poison the baseline for good (and the compiled kernels assume none)
            self.n_nonfinite += 1
            if self.n_nonfinite == 1:
                log.warning("skin %r: a frame with a NaN or infinite value, dropped", self.name)
            return ()
        self.n_frames += 1
        if not self.calibrated:
            self._accumulate(values)
            return ()
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
        z = subtract_baseline(
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
                    return self._end_all(timestamp_s, index, z, t_in)
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
                return [self._idle(timestamp_s, index, z, t_in)]
            return ()
        if self._landing is not None:
            if state is TouchState.START:
                self._landing.start()
            self._landing.step(self._delta)
        if self._tracker is not None:
            return self._localise_tracks(state, timestamp_s, index, z, t_in)
        return [self._localise(state, timestamp_s, index, z, t_in)]

    def _localise(self, state: TouchState, ts: float, index: int, z: float, t_in: float) -> Contact:
        out = self._out
        engine = self.engine
        engine.localise_into(self._delta, out)
        if self.config.filter == "one-euro":
            one_euro(self._filt_state, out[3], out[4], out[5], ts, self._filt_prm, self._tmp)
            engine.constrain_into(self._tmp[0], self._tmp[1], self._tmp[2], self._pos)
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
            self._touch_id,  # one track per touch: its tracking id is the touch's number
            0,
        )
        self._last_contact = c
        self._last_t_in = t_in
        self.n_contacts += 1
        return c

    def _localise_tracks(
        self, state: TouchState, ts: float, index: int, z: float, t_in: float
    ) -> list[Contact]:
        """K > 1: the frame's contacts, matched to tracks; one ``Contact`` per track."""
        mem = self.search_memory
        if mem is not None and state is TouchState.START:
            mem.reset()
        pos, raw, strength, unc = frame_contacts(
            self.engine, self._delta, self.max_contacts, self._out, mem
        )
        if self._footprint is not None:
            # read off this frame's search before anything else searches
            if state is TouchState.START:
                self._footprint.start()
            self._footprint.step()
        events = self._tracker.update(
            ts, pos, raw, strength, unc, state is TouchState.START, self._below == 0
        )
        self._last_t_in = t_in
        out = [self._track_contact(tr, st, ts, index, z, t_in) for tr, st in events]
        self.n_contacts += len(out)
        if out:
            self._last_contact = out[-1]
        return out

    def _track_contact(
        self, tr: Track, state: str, ts: float, index: int, z: float, t_in: float
    ) -> Contact:
        cfg = self.config
        spread = tr.uncertainty_mm
        conf = 1.0 - math.exp(-max(z - cfg.touch_off_z, 0.0) / cfg.touch_on_z)
        if spread == spread:  # not nan
            conf *= math.exp(-spread / 10.0)
        p, r = tr.position_m.tolist(), tr.raw_m.tolist()
        return Contact(
            self.name,
            ts,
            index,
            state,
            (p[0], p[1], p[2]),
            (r[0], r[1], r[2]),
            conf,
            z,
            spread,
            (time.monotonic() - t_in) * 1e6,
            self._touch_id,
            tr.track_id,
            tr.slot,
            tr.strength,
        )

    def _end_all(self, ts: float, index: int, z: float, t_in: float) -> list[Contact]:
        """The touch ended: an ``end`` for every track."""
        if self._tracker is None:
            return [self._end(ts, index, z, t_in)]
        out = [self._track_contact(tr, "end", ts, index, z, t_in) for tr in self._tracker.end_all()]
        self.n_contacts += len(out)
        return out

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
            self._touch_id,
            0,
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

    def end_stale(self, now: float | None = None) -> list[Contact]:
        """The source stopped delivering; ends a touch whose frames are over ``stale_s`` old.

        Call it periodically while a link is down. Returns the ``end`` of every track, if due
        (gestures they complete go to ``gestures``).
        """
        now = time.monotonic() if now is None else now
        if not (self._touching and now - self._last_t_in > self.config.stale_s):
            return []
        return self._end_now(now)

    def end_open(self, now: float | None = None) -> list[Contact]:
        """The pipeline stops: end the touch in progress now, stale or not.

        Returns the ``end`` of every open track (none when nothing touches); gestures they
        complete go to ``gestures``. ``now`` is ``time.monotonic()`` s, or ``math.inf`` when
        the stream ended (the ends then carry the last frame's time).
        """
        if not self._touching:
            return []
        return self._end_now(time.monotonic() if now is None else now)

    def _end_now(self, now: float) -> list[Contact]:
        """End every track at ``now``: the last frame's time plus the time since it arrived."""
        self._touching = False
        self._below = 0
        last = self._last_contact
        gap = max(now - self._last_t_in, 0.0)  # inf: the stream ended, the last frame's time
        if last is not None and math.isfinite(gap):
            ts = last.timestamp_s + gap
        else:
            ts = self._last_ts if self._last_ts is not None else 0.0
        out = self._end_all(ts, last.index if last else -1, math.nan, now)
        if self._recognizer is not None and out:
            self.gestures += self._recognizer.update(ts, out, releasing=True)
        return out

    def flush_gestures(self) -> None:
        """The stream ended: every gesture still waiting (a tap's open window) is due now."""
        if self._recognizer is not None and self._last_ts is not None:
            self.gestures += self._recognizer.flush(self._last_ts)
