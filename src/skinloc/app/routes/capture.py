"""Guided capture (calibration, validation, their keys), training and the live view."""

from __future__ import annotations

from typing import Any

from skinloc.app.routes.bodies import (
    FlagBody,
    IndexBody,
    LeaveOutBody,
    TrainBody,
    ValidateBody,
)
from skinloc.app.routes.common import OK, PageContext, actions_router


def add_routes(ctx: PageContext) -> None:
    """Add the guided-capture, training and live actions.

    ``POST /api/calibrate/start``, ``/api/validate/start``, ``/api/capture/...``,
    ``/api/finger``, ``/api/train``, ``/api/train/leave_out``, ``/api/live/start``.
    """
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.post("/api/calibrate/start")
    def calibrate() -> dict[str, Any]:
        workspace.start_calibration()
        return OK

    @router.post("/api/validate/start")
    def validate(body: ValidateBody) -> dict[str, Any]:
        workspace.start_validation(body.n_points)
        return OK

    @router.post("/api/capture/retake")
    def retake(body: IndexBody) -> dict[str, Any]:
        workspace.retake(body.index, body.recording)
        return OK

    @router.post("/api/capture/{action}")
    def capture(action: str) -> dict[str, Any]:
        actions = {
            "now": workspace.capture_now,
            "undo": workspace.undo,
            "skip": workspace.skip,
            "stop": workspace.stop,
        }
        if action not in actions:
            raise ValueError(f"unknown capture action {action!r}; one of {', '.join(actions)}")
        actions[action]()
        return OK

    @router.post("/api/finger")
    def finger(body: FlagBody) -> dict[str, Any]:
        workspace.set_finger(body.on)
        return OK

    @router.post("/api/train")
    def train(body: TrainBody | None = None) -> dict[str, Any]:
        workspace.train(body.exclude if body is not None else None)
        return OK

    @router.post("/api/train/leave_out")
    def leave_out(body: LeaveOutBody) -> dict[str, Any]:
        workspace.leave_out(body.index, body.out)
        return OK

    @router.post("/api/live/start")
    def live() -> dict[str, Any]:
        workspace.start_live()
        return OK

    app.include_router(router)
