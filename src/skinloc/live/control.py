"""Live control of a runner's skins from a sink: settings, tare, track reset, diagnostics.

A sink that serves a control interface (the ROS 2 node of ``skinloc.live.sinks.ros2``: its
parameters, its ``tare`` and ``reset_tracks`` services, ``/diagnostics``) has a ``serve(control,
now)`` method, which the runner's loop calls between frames with its ``SkinControl``. So every
change reaches a skin's ``SkinCore`` on the loop's own thread and applies from the next frame.

Requests are JSON-ready dicts ``{"request": ID, "op": OP, "skin": KEY, ...}`` (``KEY``: the skin's
name as in ROS 2 names, ``skinloc.ros2.names.ros_name``):

* ``set``, ``values`` ``{key: value}`` (``skinloc.live.sinks.ros2.params``): checked by the
  settings' own rule and applied, or refused with the reason;
* ``tare``: a fresh baseline (``SkinCore.tare``), answered once it is captured, with what changed;
* ``reset_tracks``: ``SkinCore.reset_tracks``.

Answers are ``{"ok": bool, "message": str}``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from skinloc.live.sinks.ros2.params import apply_values, settings_of, skin_key
from skinloc.sensors.health import classify_sensors

log = logging.getLogger(__name__)

__all__ = ["SkinControl"]

#: a frame rate below this share of the expected one is a warning
RATE_WARN = 0.8
#: no frame for this long (s) with the link up is an error
STALL_S = 2.0


class SkinControl:
    """The control interface of a runner's skins, for the sinks that serve one.

    Parameters
    ----------
    runner : Runner
        Its ``skins`` (``SkinConfig``), ``cores`` (``SkinCore``), ``stats()`` and sinks.
    """

    def __init__(self, runner: Any) -> None:
        self.runner = runner
        self._pending: list[tuple[Any, int]] = []  # (request id, slot) of tares in progress
        self._rate: dict[int, tuple[float, int]] = {}  # slot -> (time, frames) of the last look
        self._seen: dict[int, dict[str, int]] = {}  # slot -> counters at the last diagnostics
        #: slot -> (the captured noise's bytes, its bad lines by state): the classification
        #: changes only with a capture (a tare), and took most of a skin's status (about 0.1 ms)
        self._lines: dict[int, tuple[bytes, dict[str, list[str]]]] = {}
        self.n_errors = 0  # failures of a sink's ``serve`` (logged once)

    # ------------------------------------------------------------------ the loop's call
    def serve(self, now: float) -> None:
        """Let every sink that serves a control interface do so (the runner's sweep)."""
        for sink in self.runner.all_sinks():
            serve = getattr(sink, "serve", None)
            if serve is None:
                continue
            try:
                serve(self, now)
            except Exception:  # noqa: BLE001 - serving a control interface never stops the loop
                self.n_errors += 1
                if self.n_errors == 1:
                    log.exception("serving the %s sink's requests failed", sink.name)

    # ------------------------------------------------------------------ requests
    def _slot(self, key: str) -> int | None:
        for i, s in enumerate(self.runner.skins):
            if skin_key(s.name) == key or s.name == key:
                return i
        return None

    def settings(self, name: str) -> dict[str, Any]:
        """The current settings of skin ``name`` as parameter values (``params.settings_of``)."""
        core = self.runner.cores[self._slot(name)]
        rec = getattr(core, "_recognizer", None)
        return settings_of(core.config, rec.cfg if rec is not None else self._gestures(core))

    def _gestures(self, core: Any) -> Any:
        slot = self.runner.cores.index(core)
        return self.runner.skins[slot].gestures

    def handle(self, request: dict[str, Any]) -> dict[str, Any] | None:
        """Apply one request; its answer, or None when it comes later (``finished``)."""
        slot = self._slot(str(request.get("skin", "")))
        if slot is None:
            return {"ok": False, "message": f"no skin {request.get('skin')!r}"}
        core = self.runner.cores[slot]
        op = request.get("op")
        try:
            if op == "set":
                rec = getattr(core, "_recognizer", None)
                gestures = rec.cfg if rec is not None else self._gestures(core)
                config, new_g = apply_values(core.config, gestures, dict(request["values"]))
                changed = core.update_config(config, new_g)
                self.runner.skins[slot].config = config
                return {"ok": True, "message": f"applied: {', '.join(changed) or 'no change'}"}
            if op == "tare":
                core.tare()
                self._pending.append((request["request"], slot))
                return None
            if op == "reset_tracks":
                n = core.reset_tracks()
                return {"ok": True, "message": f"tracks reset ({n} open track(s) dropped)"}
        except (ValueError, TypeError) as exc:
            return {"ok": False, "message": str(exc)}
        return {"ok": False, "message": f"unknown request {op!r}"}

    def finished(self) -> Iterator[tuple[Any, dict[str, Any]]]:
        """``(request id, answer)`` of every tare whose capture has ended since."""
        still = []
        for rid, slot in self._pending:
            core = self.runner.cores[slot]
            if core.taring:
                still.append((rid, slot))
                continue
            t = core.last_tare or {}
            yield (
                rid,
                {
                    "ok": True,
                    "message": (
                        f"tared from {core.config.baseline_frames} frames: baseline moved by "
                        f"{t.get('mean_shift_counts', math.nan):+.2f} counts on average "
                        f"(largest {t.get('max_abs_shift_counts', math.nan):.2f})"
                    ),
                },
            )
        self._pending = still

    # ------------------------------------------------------------------ diagnostics
    @property
    def skin_names(self) -> list[str]:
        """The runner's skins' names, in slot order (what ``diagnostics``' ``slots`` index)."""
        return [s.name for s in self.runner.skins]

    def diagnostics(
        self,
        now: float,
        extra: dict[str, dict[str, float]] | None = None,
        slots: Sequence[int] | None = None,
    ) -> list[dict[str, Any]]:
        """One status per skin, as ``diagnostic_msgs/DiagnosticStatus`` fields.

        Parameters
        ----------
        now : float
            ``time.monotonic()``, s.
        extra : dict, optional
            Per skin name, further values (the sink's latency p99 and publisher queue).
        slots : sequence of int, optional
            Only these skins (slot indices, ``skin_names``' order); default every skin. A sink
            asks for a few per sweep so that the loop never stops for all of them at once.

        Returns
        -------
        list of dict
            ``{"name", "hardware_id", "level" (0 OK, 1 WARN, 2 ERROR), "message", "values"
            {key: text}}``, in the skins' order.
        """
        out = []
        chosen = range(len(self.runner.skins)) if slots is None else slots
        for slot, d in zip(chosen, self.runner.stats(chosen), strict=True):
            skin, core = self.runner.skins[slot], self.runner.cores[slot]
            out.append(self._status(slot, skin, core, d, now, (extra or {}).get(skin.name, {})))
        return out

    def _bad_lines(self, slot: int, core: Any, h: dict[str, Any]) -> dict[str, list[str]]:
        """The dead, weak and noisy lines (``TX3``, ...) of the skin's last capture."""
        key = h["noise"].tobytes()
        got = self._lines.get(slot)
        if got is not None and got[0] == key:
            return got[1]
        health = classify_sensors(core.n_tx, core.n_rx, noise=h["noise"], stuck=h["stuck"])
        lines = {
            state: [
                f"{kind.upper()}{b['index']}"
                for kind in ("tx", "rx")
                for b in health.bad_lines(kind)
                if b["status"] == state
            ]
            for state in ("dead", "weak", "noisy")
        }
        self._lines[slot] = (key, lines)
        return lines

    def _status(
        self, slot: int, skin: Any, core: Any, d: dict[str, Any], now: float, extra: dict
    ) -> dict[str, Any]:
        warn: list[str] = []
        error: list[str] = []
        first = slot not in self._rate  # no rate before a second look
        t0, f0 = self._rate.get(slot, (now, d["frames"]))
        self._rate[slot] = (now, d["frames"])
        rate = (d["frames"] - f0) / (now - t0) if now > t0 else math.nan
        expected = float(skin.rate_hz)
        wire = d.get("wire") or {}
        counters = {
            "nonfinite_frames": int(d.get("nonfinite_frames", 0)),
            "dropped_frames": int(wire.get("n_dropped", 0)),
            "corrupt_frames": int(wire.get("n_corrupted", 0)),
            "errors": _count(d.get("errors", 0)),  # frames dropped because processing raised
            "sink_errors": _count(d.get("sink_errors", 0)),  # deliveries a sink refused
            "publisher_dropped": int(extra.get("publisher_dropped", 0)),
        }
        seen = self._seen.get(slot, {})
        self._seen[slot] = counters
        for key, n in counters.items():
            if n > seen.get(key, 0):
                warn.append(f"{n - seen.get(key, 0)} new {key.replace('_', ' ')}")
        if "link_up" in d:
            link = "up" if d["link_up"] else ("waiting" if d.get("waiting") else "down")
        else:
            link = "source " + str(d.get("source", skin.source))
        if link in ("down", "waiting"):
            error.append(f"link {link}")
        elif not first and math.isfinite(rate) and rate < RATE_WARN * expected:
            (error if rate == 0 and now - t0 >= STALL_S else warn).append(
                f"{rate:.0f} Hz of {expected:.0f}"
            )
        if not core.calibrated:
            warn.append("capturing baseline")
        h = core.health()
        values: dict[str, Any] = {
            "frame_rate_hz": f"{rate:.1f}",
            "expected_rate_hz": f"{expected:.1f}",
            "link": link,
            "reconnects": str(d.get("reconnects", 0)),
            **{k: str(v) for k, v in counters.items()},
            "calibrated": str(bool(core.calibrated)).lower(),
            "touching": str(bool(core.touching)).lower(),
        }
        if core.calibrated and np.isfinite(h["noise"]).all():
            for state, lines in self._bad_lines(slot, core, h).items():
                values[f"{state}_lines"] = " ".join(lines) or "none"
                if lines:
                    (error if state == "dead" else warn).append(f"{state} lines {' '.join(lines)}")
            drift = h["drift"]
            values["baseline_drift_mean_counts"] = f"{float(drift.mean()):.2f}"
            values["baseline_drift_max_counts"] = f"{float(np.abs(drift).max()):.2f}"
        p99 = extra.get("latency_p99_us", math.nan)
        values["latency_p99_us"] = f"{p99:.0f}" if math.isfinite(p99) else "n/a"
        if "publisher_queue_bytes" in extra:
            values["publisher_queue_bytes"] = str(extra["publisher_queue_bytes"])
        level = 2 if error else 1 if warn else 0
        return {
            "name": f"skinloc: {skin.name}",
            "hardware_id": str(d.get("port") or skin.source),
            "level": level,
            "message": "; ".join(error + warn) or "OK",
            "values": values,
        }


def _count(value: Any) -> int:
    """A counter of the runner's stats: a number, or a table of them (summed)."""
    if isinstance(value, dict):
        return sum(_count(v) for v in value.values())
    try:
        return int(value)
    except (TypeError, ValueError):
        return 0
