"""Settings of the per-skin live processing (``PipelineConfig``) and the touch states."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import Any, TypeVar

_T = TypeVar("_T")

__all__ = ["PipelineConfig", "TouchState", "settings_from_dict"]


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
    max_contacts : int
        K: contacts per frame and tracks (slots) at most. 1: the single-contact pipeline (one
        track per touch, ``track_id`` = ``touch_id``, slot 0), no per-frame assignment.
    track_gate_mm : float
        Largest move of a finger between two frames for its track to continue, mm.
    track_miss_frames : int
        Frames a track may go without a contact before it ends (0: it ends at once).
    track_confirm_frames : int
        Consecutive frames a new finger needs, during a touch, before its track starts. 4
        (40 ms at 100 Hz): the multi-contact search splits some single touches into two for
        a frame or two at a time, and such a ghost must not become a finger.
    gestures : bool
        Recognise gestures (``skinloc.live.gestures``) and send them to every sink.
    footprint_gestures : bool
        Let the touch's footprint (``live.footprint``: its image wider than one finger's, at
        the model's calibrated levels) make a one-track tap a two-finger tap or hold it back.
        Off by default: measured, it found no two-finger tap the other cues missed on the
        simulated skins and made 2 of 100 real single touches two-finger taps
        (docs/multitouch.md, "A second finger in the footprint").
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
    max_contacts: int = 3
    track_gate_mm: float = 30.0
    track_miss_frames: int = 1
    track_confirm_frames: int = 4
    gestures: bool = True
    footprint_gestures: bool = False

    def __post_init__(self) -> None:
        def need(name: str, ok: bool, allowed: str) -> None:
            if not ok:
                raise ValueError(
                    f"PipelineConfig.{name} must be {allowed}, got {getattr(self, name)!r}"
                )

        for name in (
            "baseline_frames",
            "debounce_on_frames",
            "debounce_off_frames",
            "max_contacts",
            "track_confirm_frames",
        ):
            v = getattr(self, name)
            need(name, isinstance(v, int) and not isinstance(v, bool) and v >= 1, "an int >= 1")
        v = self.track_miss_frames
        need(
            "track_miss_frames",
            isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "an int >= 0",
        )
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
            "track_gate_mm",
        ):
            v = getattr(self, name)
            need(name, _number(v) and math.isfinite(v) and v > 0, "a number > 0")
        beta = self.beta
        need("beta", _number(beta) and math.isfinite(beta) and beta >= 0, "a number >= 0")
        need("touch_off_z", self.touch_off_z <= self.touch_on_z, "<= touch_on_z")
        rf = self.release_fraction
        need("release_fraction", _number(rf) and 0 <= rf < 1, "in [0, 1)")
        need("filter", self.filter in ("one-euro", "none"), "one of one-euro, none")
        for name in ("drift_tracking", "emit_idle", "gestures", "footprint_gestures"):
            need(name, isinstance(getattr(self, name), bool), "true or false")

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "pipeline settings") -> PipelineConfig:
        """Build from a dict (a config file section); unknown keys raise, naming them."""
        return settings_from_dict(cls, d, where)


def _number(v: Any) -> bool:
    """A real number, not a flag (``true`` in a TOML file is no threshold)."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def settings_from_dict(cls: type[_T], d: Any, where: str) -> _T:
    """A settings dataclass from a config file's table; unknown keys raise, naming them.

    Keys may be spelt with ``-`` for ``_``. Used for ``PipelineConfig`` and ``GestureConfig``.
    """
    if not isinstance(d, dict):
        raise ValueError(f"{where} must be a table of settings, not {d!r}")
    known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    d = {str(k).replace("-", "_"): v for k, v in d.items()}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(
            f"unknown key(s) in {where}: {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
    return cls(**d)
