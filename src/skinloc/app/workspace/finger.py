"""The scripted finger: the simulated skin's, or a ``skinloc virtual-skin`` driven over its port."""

from __future__ import annotations

import time

import numpy as np

from skinloc.app.workspace.state import WorkspaceState
from skinloc.calibration.session import ScriptedFinger
from skinloc.errors import SkinlocError


class _SerialFinger:
    """The scripted finger of ``skinloc virtual-skin``, driven over its port."""

    def __init__(self, source) -> None:
        self.source = source

    def prompt(self, index: int, target: np.ndarray) -> None:
        x, y, z = np.asarray(target, dtype=float).tolist()
        self.source.write(f"touch {x:.6f} {y:.6f} {z:.6f}\n".encode())

    def captured(self, index: int) -> None:
        self.source.write(b"lift\n")


class FingerActions(WorkspaceState):
    """Part of ``Workspace``: the finger that touches each target by itself.

    Its finger, when it presses next and whether it is down are ``WorkspaceState``'s (guided
    capture drives it).

    Attributes
    ----------
    finger_on : bool
        Whether the scripted finger touches the targets (switched on per session).
    """

    finger_on: bool = False

    def set_finger(self, on: bool) -> None:
        """Let the scripted finger touch each target (simulated or virtual skin)."""
        with self._lock:
            self.finger_on = bool(on)
            if not on:
                self._stop_capture_finger()
            elif self.capture is not None:
                self._setup_finger()
            self._publish_state()

    def _stop_capture_finger(self) -> None:
        """Lift the scripted finger if it is down, and forget it."""
        if self._finger_down and self._finger is not None:
            try:
                self._finger.captured(-1)
            except (SkinlocError, OSError):  # the port may be gone already
                pass
        self._finger, self._finger_due, self._finger_down = None, None, False

    def _setup_finger(self) -> None:
        if not self.finger_on or self.device is None:
            self._finger = None
            return
        source = self.device.source
        if self.device.is_sim:
            # The calibration module's scripted finger, without its simulated travel time
            # (the app's clock is the wall clock; finger_delay_s plays that part).
            self._finger = ScriptedFinger(source, random_state=int(time.time()), move_time_s=0.0)
        else:
            self._finger = _SerialFinger(source)
