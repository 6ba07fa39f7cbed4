"""The app's capture: the touch rule and the quality checks, re-exported for the app.

The checks (a touch weak, short, saturated or off-target) are
``skinloc.calibration.touch_check``'s, shared with ``skinloc check``. The touch
rule itself (``TouchCapture``: wait for a steady touch, capture, wait for the release; the
``TouchDetector``) is ``skinloc.calibration.capture``'s, the one rule of every calibration
capture; it is re-exported here for the app.
"""

from __future__ import annotations

from skinloc.calibration.capture import (
    CapturedTouch,
    CapturePhase,
    TouchCapture,
    TouchDetector,
)
from skinloc.calibration.touch_check import (
    COUNTS_MAX,
    COUNTS_MIN,
    baseline_drift_sigma,
    off_target,
    touch_flags,
)

__all__ = [
    "COUNTS_MAX",
    "COUNTS_MIN",
    "CapturePhase",
    "CapturedTouch",
    "TouchCapture",
    "TouchDetector",
    "baseline_drift_sigma",
    "off_target",
    "touch_flags",
]
