"""The app's state and actions: the device, the open session, guided capture, training, live.

One ``Workspace`` serves every tab of one app process. The reader thread calls ``on_frame``;
HTTP handlers call the actions; both hold ``_lock``. Control belongs to one tab at a time (the
lease): another tab that tries to change anything is told the session is busy, and may take
over explicitly. Every touch is saved before anything else happens with it.

The actions live in one module per concern (``link``, ``sessions``, ``guided``, ``finger``,
``validation``, ``training``, ``live``, ...), each a part of ``Workspace``. The state they share
is declared in ``state.WorkspaceState`` (each part is a subclass of it); what a part keeps for
itself it declares in its own class and sets up in its ``__init__``. This module assembles the
parts and holds the lease, the pages' state and the state message.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from skinloc.app.hub import Hub
from skinloc.app.workspace.export import ExportFiles
from skinloc.app.workspace.finger import FingerActions
from skinloc.app.workspace.guided import GuidedCapture
from skinloc.app.workspace.link import LinkActions
from skinloc.app.workspace.live import LiveView
from skinloc.app.workspace.recalibration import RecalibrationFlow
from skinloc.app.workspace.record import LiveRecording
from skinloc.app.workspace.sessions import SessionActions
from skinloc.app.workspace.settings import LiveSettings
from skinloc.app.workspace.state import GUIDED_MODES, AppConfig, BusyError
from skinloc.app.workspace.traces import TraceViews
from skinloc.app.workspace.training import TrainingJobs
from skinloc.app.workspace.validation import ValidationActions

__all__ = ["Workspace"]


class Workspace(
    LinkActions,
    SessionActions,
    GuidedCapture,
    FingerActions,
    ValidationActions,
    RecalibrationFlow,
    TrainingJobs,
    LiveView,
    ExportFiles,
    LiveRecording,
    TraceViews,
    LiveSettings,
):
    """Everything one app process knows and does.

    Parameters
    ----------
    config : AppConfig
        Settings.
    hub : Hub
        Where messages to the tabs go.

    Attributes
    ----------
    lease : str or None
        The tab that has control of the skin and the session.
    page_states : dict
        The state of each app page by name (``skinloc.app.pages``; None for a page that keeps
        none).
    """

    lease: str | None
    page_states: dict[str, Any]

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        # Each part sets up the state it declares (``WorkspaceState`` first, then the parts).
        super().__init__(config, hub)
        self.lease = None
        self.page_states = {}

    def add_page_state(self, name: str, state: Any) -> None:
        """Keep the state of the app page ``name`` (``skinloc.app.pages``; None: it keeps none)."""
        if name in self.page_states:
            raise ValueError(f"the workspace has the state of a page named {name!r} already")
        self.page_states[name] = state

    def page_state(self, name: str) -> Any:
        """The state of the app page ``name`` (what its ``AppPage.state`` built, or None)."""
        try:
            return self.page_states[name]
        except KeyError:
            raise ValueError(f"no app page named {name!r}") from None

    def require(self, client: str | None) -> None:
        """Give ``client`` control if nobody has it; raise ``BusyError`` if another tab has."""
        client = client or "anonymous"
        with self._lock:
            if self._lease_free(client):
                self._set_lease(client)
            elif self.lease != client:
                raise BusyError(
                    "busy: this skin and session are in use in another tab; "
                    "close that tab or take over here"
                )

    def _lease_free(self, client: str) -> bool:
        """Whether control is free for ``client``: nobody holds it, or a tab that is gone."""
        return self.lease is None or self.lease not in self.hub.client_ids + [client]

    def take_over(self, client: str) -> None:
        """Give ``client`` control, whoever had it (the other tab is told)."""
        with self._lock:
            self._set_lease(client)

    def release(self, client: str) -> None:
        """A tab went away: free control if it had it and no tab of it remains."""
        with self._lock:
            if self.lease == client and client not in self.hub.client_ids:
                self.lease = None
                self._publish_state()

    def _stop_using_frames(self) -> None:
        """Stop what the frames are used for: guided capture (the finger lifted), live view."""
        self._stop_capture_finger()
        self.capture = None
        self._stop_live()

    def _set_lease(self, client: str) -> None:
        if self.lease != client:
            self.lease = client
            self._publish_state()

    def snapshot(self) -> dict[str, Any]:
        """Everything the tabs show, except the stream."""
        with self._lock:
            a = self.active
            guided = None
            if self.mode in GUIDED_MODES and a is not None:
                sess = self._session_of(self.mode)
                number, attempt = self.prompt_number(sess)
                guided = {
                    "number": number,  # the target's, for life (a retake keeps it)
                    "attempt": attempt,
                    "index": sess.n_done,
                    "total": len(sess.targets),
                    "target": None if sess.finished else sess.targets[sess.n_done],
                    "phase": self.capture.phase.value if self.capture else None,
                }
            return {
                "type": "state",
                "mode": self.mode.value,
                "message": self.message,
                "lease": self.lease,
                "finger": self.finger_on,
                "device": None
                if self.device is None
                else {**self.device.stats(), "options": asdict(self.device.options)},
                "session": None
                if a is None
                else {
                    "id": a.folder.id,
                    "name": a.info.get("name"),
                    "has_model": a.model is not None,
                    "holdout": a.info.get("holdout"),
                    "validation": a.info.get("validation"),
                    "validation_previous": a.info.get("validation_previous"),
                    "n_validation": a.info.get("n_validation", 20),
                    "mesh": a.info.get("mesh"),
                },
                "guided": guided,
                "recording": None if self.recorder is None else self.recorder.status(),
                "live_starting": self.live_starting,
                "training": self._session_training(),
                "data_dir": str(self.store.root),
                "default_mesh": self.config.mesh_name,
            }

    def _session_training(self) -> dict[str, Any] | None:
        """The training job of the open session; another session's job is not shown with it."""
        t, a = self.training, self.active
        if t is None or a is None or t.get("session") != a.folder.id:
            return None
        return t

    def _publish_state(self) -> None:
        self.hub.publish(self.snapshot())

    def shutdown(self) -> None:
        """Stop the reader and release the session (on server exit)."""
        with self._lock:
            old = self._detach_device()
            self._close_session()
        self._stop_device(old)
