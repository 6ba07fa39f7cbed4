"""The live view: the live pipeline run on the app's frames, its contacts and gestures sent on.

After a fresh baseline, every frame goes to a ``skinloc.live.runner.Pipeline`` (the one
``skinloc run`` uses: detection, localisation, tracking, filtering, gestures) through a
``FrameQueue``; the pipeline delivers through ``TabSink`` (``skinloc.app.live_io``), so the page
shows whatever the pipeline finds: every contact of a frame, one per track, and each gesture.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np

from skinloc.app.hub import Hub
from skinloc.app.live_io import FrameQueue, TabSink
from skinloc.app.workspace.state import AppConfig, Mode, WorkspaceState
from skinloc.calibration.session import TouchDetector
from skinloc.sources.base import Frame

log = logging.getLogger(__name__)


class LiveView(WorkspaceState):
    """Part of ``Workspace``: the live view.

    Its baseline is ``WorkspaceState._live_base`` (the heat map counts above it).

    Attributes
    ----------
    live_sink : TabSink
        Where the live pipeline's contacts and gestures go to the tabs.
    _live_pipeline : skinloc.live.runner.Pipeline or None
        The running pipeline.
    _live_queue : FrameQueue or None
        The frames on their way to it.
    live_starting : bool
        Whether a Start is preparing the live pipeline (its engine: the first one compiles
        the kernels, up to a minute on a fresh install); Start is refused meanwhile.
    _live_engine : tuple or None
        ``(model, its engine)``, built once per model.
    _engine_lock : threading.Lock
        Held while an engine is built (``live_engine``): a second build waits for the first.
    """

    live_sink: TabSink
    live_starting: bool = False
    _live_pipeline: Any = None
    _live_queue: FrameQueue | None = None
    _live_engine: tuple[Any, Any] | None = None
    _engine_lock: threading.Lock

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        super().__init__(config, hub)
        self.live_sink = TabSink(hub)
        self.live_starting = False
        self._engine_lock = threading.Lock()

    @property
    def live_running(self) -> bool:
        """Whether the live pipeline runs."""
        return self._live_pipeline is not None

    def start_live(self) -> None:
        """Prepare the live pipeline, capture a fresh baseline, then run it on every frame.

        Returns at once: the preparation (the model's engine; the first one of a process
        compiles the kernels) runs on a thread, ``live_starting`` and the message say so, and
        another Start meanwhile is refused.
        """
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if self.live_starting:
                raise ValueError("live is starting: wait for it (the first start compiles)")
            if a.model is None:
                raise ValueError("train a model first: the live view needs one")
            if a.model.n_features_in_ != device.source.n_sensors:
                raise ValueError(
                    f"the model expects {a.model.n_features_in_} sensors but the skin has "
                    f"{device.source.n_sensors}"
                )
            model, n_tx, n_rx = a.model, device.source.n_tx, device.source.n_rx
            cfg = a.info["config"]
            self.live_starting = True
            self.message = (
                "live: preparing the localiser (the first start after installing compiles it: "
                "up to a minute)"
            )
            self._publish_state()
        threading.Thread(
            target=self._prepare_live,
            args=(a, device, model, n_tx, n_rx, cfg),
            name="skinloc-live-start",
            daemon=True,
        ).start()

    def _prepare_live(self, a, device, model, n_tx: int, n_rx: int, cfg: dict[str, Any]) -> None:
        """``start_live``'s thread: the pipeline (outside the lock: it may compile), then start.

        The fresh baseline is captured, and the pipeline started on it, as ``_baseline`` runs.
        """
        try:
            queue = FrameQueue(n_tx, n_rx, name=device.name)
            pipeline = self._make_live_pipeline(model, queue)
        except Exception as exc:  # reported to the tabs
            log.exception("the live pipeline could not be made")
            with self._lock:
                self.live_starting = False
                self.message = f"live failed: {exc}"
                self._publish_state()
            return
        n = int(cfg.get("n_baseline_frames", 50))

        def read(source) -> np.ndarray:
            frames, _ = source.read_many(n)
            return frames

        def then(frames: np.ndarray) -> None:
            base, noise = frames.mean(axis=0), frames.std(axis=0)
            self._live_base = base
            self.detector = TouchDetector(
                base, noise, cfg.get("threshold_sigma", 5.0), cfg.get("min_active", 2)
            )
            pipeline.core.set_baseline(frames)
            pipeline.start()
            self._live_pipeline, self._live_queue = pipeline, queue
            self.mode = Mode.LIVE
            self.message = "live: touch the skin"

        with self._lock:
            self.live_starting = False
            if self.active is not a or self.device is not device:
                pipeline.close()
                self.message = "live not started: the session or the skin changed meanwhile"
                self._publish_state()
                return
            self._baseline(read, then)

    def live_engine(self, model: Any) -> Any:
        """The engine of ``model``, built once (a build already running is waited for)."""
        from skinloc.models.engine import load_engine

        with self._engine_lock:
            cached = self._live_engine
            if cached is None or cached[0] is not model:
                cached = self._live_engine = (model, load_engine(model))
            return cached[1]

    def warm_live(self, model: Any) -> None:
        """Build ``model``'s engine on a thread now (after training), so Live starts at once."""

        def run() -> None:
            try:
                self.live_engine(model)
            except Exception:  # Start builds it again and reports the error
                log.exception("warming the live engine failed")

        threading.Thread(target=run, name="skinloc-live-warm", daemon=True).start()

    def _make_live_pipeline(self, model: Any, queue: FrameQueue) -> Any:
        """The live pipeline of ``model`` on ``queue``'s frames, delivering to ``live_sink``.

        Not started; ``core.set_baseline`` and ``start`` follow, ``close`` ends it.
        """
        from skinloc.live.runner import Pipeline

        return Pipeline(
            self.live_engine(model),
            queue,
            sinks=[self.live_sink, self.record_tee],
            config=self._live_config(),  # the session's skins file (workspace.settings)
            name="skin",
            n_tx=queue.n_tx,
            n_rx=queue.n_rx,
        )

    def _live_frame(self, frame: Frame) -> None:
        if self._live_queue is not None:
            self._live_queue.put(frame)

    def _stop_live(self) -> None:
        """End the live pipeline (its threads joined), if one runs."""
        pipeline, self._live_pipeline, self._live_queue = self._live_pipeline, None, None
        if pipeline is not None:
            pipeline.close()
