"""The one recalibration entry point: an old model, a new session of its skin, a report.

A new session is one or more recordings of the same skin: each has its own fresh baseline
(its ``baseline_frames``) and k touches (k = 0: a baseline capture only). ``recalibrate``
adapts the model to them (``ContactLocalizer.recalibrate``: for a response map,
``skinloc.models.recalibration`` chooses by cross-validation over the k touches how much of the
old map to keep) and says what it did and what it gained:

- *before*: the old model untouched on the k new touches (their images against the new
  baseline), mm;
- *after*: the chosen candidate's cross-validated error over the same touches (each touch
  localised by a map fitted without it), mm; none below 2 touches or for a network (nothing
  cross-validated).

``skinloc train NEW --init OLD`` and the app's Recalibrate flow both call it. The baseline is
not part of a model (a model maps baseline-subtracted images), so with k = 0 the model comes
back unchanged and the fresh baseline is all that changes: a recording's ``baseline``, or on a
running pipeline ``SkinCore.tare`` (``docs/live.md``, "ROS 2").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skinloc.data.recording import Recording
from skinloc.evaluation.scoring import (
    check_compatible,
    check_same_skin,
    evaluate,
    training_arrays,
)

__all__ = ["FEW_TOUCHES", "Recalibrated", "RecalibrationReport", "recalibrate"]

#: Under this many new touches the report says its figures are rough.
FEW_TOUCHES = 10


@dataclass(frozen=True)
class RecalibrationReport:
    """What ``recalibrate`` did, and the error before and after, mm.

    Attributes
    ----------
    method : str
        What was kept: ``"old map"``, ``"old map + correction"``, ``"blend 0.5"`` (the share
        of the new map), ``"new touches alone"``, ``"old model"`` (k = 0, any kind) or what a
        network's recalibration says (``"fine-tuned"``).
    summary : str
        One line: the choice and why (``RecalibrationChoice.summary``).
    n_touches : int
        New touches (k).
    before_mm : float or None
        Mean error of the old model untouched on the new touches, mm (None: k = 0).
    before_std_mm : float or None
        Their standard deviation, mm.
    after_mm : float or None
        Cross-validated mean error of what was chosen over the new touches, mm (None when
        nothing was cross-validated: k < 2, or a network).
    cv_error_mm : dict of str to float
        Every candidate's cross-validated mean error, mm (empty: none).
    caveat : str or None
        Why the figures are rough (few touches), or None.
    """

    method: str
    summary: str
    n_touches: int
    before_mm: float | None = None
    before_std_mm: float | None = None
    after_mm: float | None = None
    cv_error_mm: dict[str, float] = field(default_factory=dict)
    caveat: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, figures rounded to 0.01 mm."""

        def r(v: float | None) -> float | None:
            return None if v is None else round(float(v), 2)

        return {
            "method": self.method,
            "summary": self.summary,
            "n_touches": self.n_touches,
            "before_mm": r(self.before_mm),
            "before_std_mm": r(self.before_std_mm),
            "after_mm": r(self.after_mm),
            "cv_error_mm": {k: r(v) for k, v in self.cv_error_mm.items()},
            "caveat": self.caveat,
        }

    def lines(self) -> list[str]:
        """What a person reads: the choice, before and after, the caveat."""
        out = [f"Recalibration: {self.summary}"]
        if self.before_mm is not None:
            after = (
                "n/a (nothing cross-validated)"
                if self.after_mm is None
                else (f"{self.after_mm:.1f} mm (cross-validated)")
            )
            out.append(
                f"On the {self.n_touches} new touches: old model untouched "
                f"{self.before_mm:.1f} mm, recalibrated {after}"
            )
        if self.caveat:
            out.append(f"Note: {self.caveat}")
        return out


@dataclass(frozen=True)
class Recalibrated:
    """The recalibrated model (a ``ContactLocalizer``) and its ``RecalibrationReport``."""

    model: Any
    report: RecalibrationReport


def _caveat(k: int) -> str | None:
    if k == 0:
        return "no new touch: the old model is kept as it is, with the fresh baseline"
    if k < FEW_TOUCHES:
        return (
            f"{k} touch{'es' if k > 1 else ''} only: each figure is a mean over {k} touches "
            "and may be several mm off; more touches make the choice and the figures surer"
        )
    return None


def recalibrate(
    old: Any,
    recordings: Sequence[Recording],
    *,
    progress: Callable[[int, int], None] | None = None,
) -> Recalibrated:
    """Adapt ``old`` to a new session of its skin, and report what was kept and gained.

    Parameters
    ----------
    old : ContactLocalizer
        The model of an earlier session (left unchanged).
    recordings : sequence of Recording
        The new session: each with its own fresh baseline, and k touches in all (k may be 0:
        a baseline capture only). Their frames are taken against their own baselines.
    progress : callable(done, total), optional
        Called as the recalibration proceeds.

    Returns
    -------
    Recalibrated
        ``model``: a new ``ContactLocalizer`` (the old one when k = 0, copied), its
        ``training_meta_`` holding the old training (``recalibrated_from``) and the choice
        (``recalibration``); ``report``: what was kept, the error before and after, mm.

    Raises
    ------
    RecordingError
        When the recordings do not fit the model: another sensor count or another mesh.
    """
    n = check_compatible(recordings, getattr(old, "n_features_in_", None), touches=False)
    check_same_skin(old, recordings)
    touched = [r for r in recordings if r.n_point_logs]
    if touched:
        X, y, groups = training_arrays(touched)
    else:  # a baseline capture only
        X, y, groups = np.zeros((0, n)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    model = old.recalibrate(X, y, groups=groups, progress=progress)
    previous = getattr(old, "meta_", {}).get("training") or getattr(old, "training_meta_", {})
    choice = dict(model.recalibration_)
    k = int(sum(r.n_point_logs for r in recordings))
    before = evaluate(old, touched).stats if touched else None
    cv = {str(a): float(b) for a, b in (choice.get("cv_error_mm") or {}).items()}
    report = RecalibrationReport(
        method=str(choice["method"]),
        summary=str(choice["summary"]),
        n_touches=k,
        before_mm=None if before is None else float(before.mean_mm),
        before_std_mm=None if before is None else float(before.std_mm),
        after_mm=cv.get(str(choice["method"])),
        cv_error_mm=cv,
        caveat=_caveat(k),
    )
    model.training_meta_ = {
        "recalibrated_from": previous,
        "n_recordings": len(recordings),
        "n_point_logs": k,
        "recalibration": model.recalibration_,
        "report": report.as_dict(),
    }
    return Recalibrated(model, report)
