"""Guided capture: prompting targets, capturing touches, undo, retake and skip."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from skinloc.app.capture import (
    CapturePhase,
    TouchCapture,
    baseline_drift_sigma,
    touch_flags,
)
from skinloc.app.device import DeviceLink
from skinloc.app.hub import Hub
from skinloc.app.workspace.state import (
    CAPTURED,
    GUIDED_MODES,
    ActiveSession,
    AppConfig,
    Mode,
    WorkspaceState,
    app_meta,
    fill_per_touch,
    ordinal,
    pop_point_log,
    touch_numbers,
)
from skinloc.calibration.session import CalibrationSession, SessionConfig
from skinloc.calibration.touch_check import check_recording
from skinloc.errors import FrameTimeoutError, RecordingError, SourceNotConnectedError
from skinloc.sources.base import Frame


class GuidedCapture(WorkspaceState):
    """Part of ``Workspace``: calibration and validation touch by touch.

    Attributes
    ----------
    _quiet : list of numpy.ndarray
        The last untouched frames (at most 100), ``(n_sensors,)`` counts each: the baseline's
        drift is judged from them when a touch is stored.
    _baseline_again : callable or None
        Set while a baseline capture waits for frames after its link stalled: starts it again.
    """

    _quiet: list[np.ndarray]
    _baseline_again: Callable[[], None] | None

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        super().__init__(config, hub)
        self._quiet = []
        self._baseline_again = None

    def start_calibration(self) -> None:
        """Resume the session's calibration, or capture its baseline and start it."""
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            resumed = a.cal is None and a.folder.calibration.is_file()
            if a.cal is None:
                a.cal = self._calibration_session(a, device)
            if a.cal.recording is None:  # a new session, or its baseline capture was cut short
                self._capture_baseline(a.cal, Mode.CALIBRATE)
                return
            if a.cal.recording.n_sensors != device.source.n_sensors:
                raise RecordingError(
                    f"the session has {a.cal.recording.n_sensors} sensors but the skin "
                    f"has {device.source.n_sensors}"
                )
            if resumed:
                self._choose_next(a.cal)
            self._begin(Mode.CALIBRATE, a.cal)

    @staticmethod
    def _calibration_session(a: ActiveSession, device: DeviceLink) -> CalibrationSession:
        """The calibration stored in the session folder, resumed, or a new one (no baseline)."""
        if a.folder.calibration.is_file():
            sess = CalibrationSession.resume(device.source, a.folder.calibration)
            sess.skipped = np.asarray(app_meta(sess.recording).get("skipped", [])).reshape(-1, 3)
            return sess
        fields = SessionConfig.__dataclass_fields__
        cfg = SessionConfig(**{k: v for k, v in a.info["config"].items() if k in fields})
        return CalibrationSession(
            device.source,
            a.mesh,
            a.folder.calibration,
            cfg,
            targets=a.targets,
            source_name=device.name,
        )

    def _capture_baseline(self, sess: CalibrationSession, then: Mode) -> None:
        """Capture the session's baseline (it writes the recording), then start guided capture."""

        def read(source) -> None:
            sess.source = source  # the skin may have been reconnected since
            sess.capture_baseline()

        self._baseline(read, lambda _: self._begin(then, sess))

    def _baseline(self, read: Callable[[Any], Any], then: Callable[[Any], None]) -> None:
        """Run ``read(source)`` on the reader thread while the skin is untouched; then ``then``.

        The mode is ``BASELINE`` meanwhile; a failure is reported and ends in ``IDLE``.
        """
        device = self._need_device()
        self._stop_using_frames()
        self.mode = Mode.BASELINE
        self.message = "keep the skin untouched: capturing the baseline"
        self._publish_state()

        def job(source) -> Any:
            clear = getattr(source, "clear", None)
            if callable(clear):  # drop frames buffered before the request
                clear()
            return read(source)

        def submit() -> None:
            self._baseline_again = None
            device.run_exclusive(job).add_done_callback(done)

        def done(f) -> None:
            with self._locked_for(device) as ok:
                if not ok or self.mode is not Mode.BASELINE:
                    return
                exc = None if f.cancelled() else f.exception()
                if isinstance(exc, FrameTimeoutError | SourceNotConnectedError):
                    # A stalled or lost link is no reason to give up: the baseline is
                    # captured again from the next frame that comes (``_baseline_frame``).
                    self._baseline_again = submit
                    self.message = (
                        f"no frames from {device.name} for the baseline: it is captured again "
                        "when they come back (keep the skin untouched)"
                    )
                elif f.cancelled() or exc is not None:
                    self.mode = Mode.IDLE
                    self.message = f"baseline capture failed: {exc or 'cancelled'}"
                else:
                    then(f.result())
                self._publish_state()

        submit()

    def _baseline_frame(self) -> None:
        """A frame came while the baseline waited for the link: capture it now (reader thread)."""
        again, self._baseline_again = self._baseline_again, None
        if again is not None:
            again()

    def _begin(self, mode: Mode, sess: CalibrationSession) -> None:
        rec = sess.recording
        assert rec is not None and sess.detector is not None
        self._stop_using_frames()
        self.detector = sess.detector
        cfg = sess.config
        self.capture = TouchCapture(
            sess.detector,
            cfg.samples_per_touch,
            settle_frames=cfg.settle_frames,
        )
        self.capture.phase = CapturePhase.WAIT_RELEASE
        self.mode = mode
        self._quiet = []
        self._setup_finger()
        if sess.finished:
            self._finish(mode)
        else:
            self.message = f"touch target {sess.n_done + 1} of {len(sess.targets)}"
        self._publish_state()

    def _session_of(self, mode: Mode) -> CalibrationSession:
        a = self._need_session()
        sess = {Mode.CALIBRATE: a.cal, Mode.VALIDATE: a.val, Mode.RECALIBRATE: a.recal}.get(mode)
        if sess is None or sess.recording is None:
            raise ValueError(
                "nothing to capture: start calibrating, validating or recalibrating first"
            )
        return sess

    def _guided(self) -> CalibrationSession:
        if self.mode not in GUIDED_MODES:
            raise ValueError("not calibrating, validating or recalibrating now")
        return self._session_of(self.mode)

    def _finish(self, mode: Mode) -> None:
        self.mode = Mode.IDLE
        self._stop_using_frames()
        self.message = f"{CAPTURED[mode]} complete"
        if mode is Mode.CALIBRATE:
            self._update_session_snr()  # the sensor map of the touches as they are now
        if mode is Mode.VALIDATE:
            self._summarise_validation()
        if mode is Mode.RECALIBRATE:
            self._recalibration_done()

    def stop(self) -> None:
        """Pause guided capture or live view (everything recorded is saved)."""
        with self._lock:
            was = self.mode
            self._stop_using_frames()
            self.mode = Mode.IDLE
            self.message = "paused"
            if was is Mode.CALIBRATE:
                self._update_session_snr()  # the sensor map of the touches so far
            self._publish_state()

    def capture_now(self) -> None:
        """Start capturing now, touch detected or not (the key fallback)."""
        with self._lock:
            self._guided()
            if self.capture is not None:
                self.capture.force()
                self._publish_state()

    def undo(self) -> None:
        """Take back the last touch (kept in history.h5) and prompt its target again."""
        with self._lock:
            sess = self._guided() if self.mode in GUIDED_MODES else None
            if sess is None:
                sess = self._session_of(Mode.CALIBRATE)
            rec = sess.recording
            if rec.n_point_logs == 0:
                raise ValueError("nothing to undo: no touch recorded yet")
            self._take_back(sess, rec.n_point_logs - 1, "undo")

    def retake(self, index: int, which: str = "calibration") -> None:
        """Take back touch ``index`` (kept in history.h5) and prompt its target next.

        Works at any time: during capture, after "complete", after training (the model is
        kept until the next training) and in a session opened again (its recording resumed).
        """
        with self._lock:
            mode = Mode.CALIBRATE if which == "calibration" else Mode.VALIDATE
            if self.mode is Mode.BASELINE:
                raise ValueError("wait for the baseline capture to end, then retake")
            sess = self._stored_session(mode)
            rec = sess.recording
            if not 0 <= index < rec.n_point_logs:
                raise ValueError(f"no touch {index + 1}: {rec.n_point_logs} recorded")
            self._take_back(sess, index, "retake")
            if self.mode is not mode:
                self._begin(mode, sess)
            number, attempt = self.prompt_number(sess)
            self.message = f"retake: touch target #{number} again ({ordinal(attempt)} attempt)"
            if mode is Mode.CALIBRATE and self.active.model is not None:
                self.message += "; train again afterwards for the model to use it"
            self._publish_state()

    def _stored_session(self, mode: Mode) -> CalibrationSession:
        """The open session's calibration or validation, resumed from its file if need be."""
        a = self._need_session()
        sess = a.cal if mode is Mode.CALIBRATE else a.val
        if sess is not None and sess.recording is not None:
            return sess
        path = a.folder.calibration if mode is Mode.CALIBRATE else a.folder.validation
        if not path.is_file():
            raise ValueError("nothing to retake: no touch recorded yet")
        device = self._need_device()
        if mode is Mode.CALIBRATE:
            sess = self._calibration_session(a, device)
        else:
            sess = CalibrationSession.resume(device.source, path)
        if sess.recording.n_sensors != device.source.n_sensors:
            raise RecordingError(
                f"the session has {sess.recording.n_sensors} sensors but the skin "
                f"has {device.source.n_sensors}"
            )
        if mode is Mode.CALIBRATE:
            a.cal = sess
        else:
            a.val = sess
        return sess

    def _take_back(self, sess: CalibrationSession, index: int, reason: str) -> None:
        a = self._need_session()
        rec = sess.recording
        n = rec.n_point_logs
        arrays = {"target": rec.targets[index], "frames": rec.frames[index]}
        if rec.frame_times is not None:
            arrays["frame_times"] = rec.frame_times[index]
        which = (
            "validation"
            if sess is a.val
            else CAPTURED[Mode.RECALIBRATE]
            if sess is a.recal
            else ("calibration")
        )
        fill_per_touch(rec)
        number, attempt = touch_numbers(rec)[index]
        # The history first: the touch must exist somewhere at every instant.
        a.folder.archive(
            "touch",
            arrays,
            {
                "reason": reason,
                "recording": which,
                "index": index,
                "target_number": number,
                "attempt": attempt,
            },
        )
        removed = pop_point_log(rec, index)
        # Its target is asked next (at the plan's position n - 1): the next touch there is
        # this target's next attempt, under its number.
        app_meta(rec).setdefault("next_numbers", []).insert(0, [number, attempt])
        sess.drop_point_log(index)
        if which == "validation":
            self._keep_attempt(rec, index, reason, removed)
        planned = rec.planned_targets if rec.planned_targets is not None else rec.targets
        rec.planned_targets = np.concatenate([rec.targets, removed["target"][None], planned[n:]])
        sess.targets = rec.planned_targets
        self._refresh_flags(sess)
        sess.save_plan_and_meta()
        if self.capture is not None:
            self.capture.restart(touched_now=True)
        self._stop_capture_finger()
        self._setup_finger()
        if which == "validation":
            self._summarise_validation()
        self.message = f"{reason}: touch target #{number} again ({ordinal(attempt + 1)} attempt)"
        self._update_session_snr()
        self._publish_state()

    def skip(self) -> None:
        """Drop the current target from the plan (noted in the recording) and go on."""
        with self._lock:
            sess = self._guided()
            rec = sess.recording
            n = rec.n_point_logs
            if sess.finished:
                raise ValueError("no target left to skip")
            target = sess.targets[n]
            app_meta(rec).setdefault("skipped", []).append(target.tolist())
            self._next_number(rec)  # the skipped target's number is not given to another
            sess.skipped = np.concatenate([np.reshape(sess.skipped, (-1, 3)), target[None]])
            rec.planned_targets = np.delete(sess.targets, n, axis=0)
            sess.targets = rec.planned_targets
            sess.save_plan_and_meta()
            self._choose_next(sess)
            if self.capture is not None:
                self.capture.restart(touched_now=True)
            self._stop_capture_finger()
            self._setup_finger()
            if sess.finished:
                self._finish(self.mode)
            else:
                self.message = f"skipped; touch target {n + 1} of {len(sess.targets)}"
            self._publish_state()

    def _guided_frame(self, frame: Frame, now: float) -> bool:
        cap = self.capture
        sess = self._session_of(self.mode)
        if cap.phase is CapturePhase.WAIT_TOUCH and not self.detector.is_touched(frame.values):
            self._quiet.append(frame.values)
            del self._quiet[:-100]
        if (
            self._finger is not None
            and cap.phase is CapturePhase.WAIT_TOUCH
            and not self._finger_down
            and not sess.finished
        ):
            if self._finger_due is None:
                self._finger_due = now + self.config.finger_delay_s
            elif now >= self._finger_due:
                self._finger.prompt(sess.n_done, sess.targets[sess.n_done])
                self._finger_down, self._finger_due = True, None
        before = cap.phase
        touch = cap.feed(frame.values, frame.timestamp_s)
        if touch is None:
            if cap.phase is not before:
                self._publish_state()
                return True
            return False
        self._store_touch(sess, touch)
        return True

    def _store_touch(self, sess: CalibrationSession, touch) -> None:
        rec = sess.recording
        meta = app_meta(rec)
        index = rec.n_point_logs
        target = sess.targets[index]
        peaks = meta.setdefault("peaks", [])
        ref = float(np.median(peaks)) if len(peaks) >= 3 else None
        flags, peak = touch_flags(touch, rec.baseline, self.detector, ref)
        if touch.forced:
            flags.append("forced")
        fill_per_touch(rec)
        number, attempt = self._next_number(rec)  # before the touch is stored: not counted
        sess.store_point_log(target, touch.frames, touch.times)  # on disk before anything else
        fill_per_touch(rec)
        meta["touch_flags"][index] = flags
        meta["target_numbers"][index], meta["attempts"][index] = number, attempt
        peaks.append(peak)
        if len(self._quiet) >= 20:
            drift = baseline_drift_sigma(np.stack(self._quiet), rec.baseline, rec.noise)
            meta.setdefault("baseline_checks", []).append(
                {"after": index, "drift_sigma": round(drift, 2)}
            )
            if drift > 2.0:
                self.message = (
                    f"the baseline has drifted by {drift:.1f} sigma since the session began: "
                    "finish soon or start a new session"
                )
        self._quiet = []
        if self.mode is Mode.VALIDATE:
            self._score_touch(rec, index)
        self._refresh_flags(sess)
        sess.save_plan_and_meta()
        if self._finger is not None and self._finger_down:
            self._finger.captured(index)
            self._finger_down = False
        what = CAPTURED[self.mode]
        self.hub.publish({"type": "touch", "recording": what, "index": index, "flags": flags})
        if self.mode is Mode.CALIBRATE:
            self._update_session_snr()
            self._choose_next(sess)
        if sess.finished:
            self._finish(self.mode)
        elif "drifted" not in self.message:
            self.message = f"touch target {sess.n_done + 1} of {len(sess.targets)}"
        self._publish_state()

    def _choose_next(self, sess: CalibrationSession) -> None:
        """In an ``active`` session, choose the next target from the touches recorded so far.

        Runs after each stored touch, after a skip (the skipped target is never chosen again)
        and on resuming; not after an undo or a retake: the target they put back is asked
        next. The plan in the recording shows the choice.
        Takes about a second (a map refit), under the lock: the next touch waits for it anyway.
        """
        rec = sess.recording
        if sess.config.mode != "active" or sess.finished or rec is None:
            return
        sess.target_for(sess.n_done)
        rec.planned_targets = sess.targets
        sess.save_plan_and_meta()

    @staticmethod
    def prompt_number(sess: CalibrationSession) -> tuple[int, int]:
        """The number and attempt of the target asked now (what ``_next_number`` will give)."""
        meta = app_meta(sess.recording)
        pending = meta.get("next_numbers", [])
        if pending:
            return int(pending[0][0]), int(pending[0][1]) + 1
        numbers = (k for k, _ in touch_numbers(sess.recording))
        used = max([int(meta.get("numbers_used", 0)), *numbers])
        return used + 1, 1

    @staticmethod
    def _next_number(rec) -> tuple[int, int]:
        """The number and attempt of the target asked now, taken (a touch or a skip uses it).

        A target put back by a retake or an undo is its next attempt; any other is the next
        number not given yet (a skipped target keeps its number: the others match the sheet).
        """
        meta = app_meta(rec)
        pending = meta.setdefault("next_numbers", [])
        if pending:
            number, attempt = pending.pop(0)
            return int(number), int(attempt) + 1
        used = max([int(meta.get("numbers_used", 0)), *(k for k, _ in touch_numbers(rec))])
        meta["numbers_used"] = used + 1
        return used + 1, 1

    @staticmethod
    def _refresh_flags(sess: CalibrationSession) -> None:
        """Every touch's flags: ``skinloc check``'s (``check_recording``), and ``forced``."""
        rec = sess.recording
        fill_per_touch(rec)
        meta = app_meta(rec)
        flags, _ = check_recording(rec)  # the session's detector settings are in its meta
        meta["flags"] = [
            f + (["forced"] if "forced" in own else [])
            for f, own in zip(flags, meta["touch_flags"], strict=True)
        ]
