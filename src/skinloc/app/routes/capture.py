"""Guided capture (calibration, validation, their keys), training and the live view."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from skinloc.app.routes.bodies import FlagBody, IndexBody, TrainBody, ValidateBody
from skinloc.app.routes.common import OK, ClientHeader
from skinloc.app.workspace import Workspace


def add_routes(app: FastAPI, workspace: Workspace) -> None:
    """Add the guided-capture, training and live actions.

    ``POST /api/calibrate/start``, ``/api/validate/start``, ``/api/capture/...``,
    ``/api/finger``, ``/api/train``, ``/api/live/start``.
    """

    @app.post("/api/calibrate/start")
    def calibrate(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_calibration()
        return OK

    @app.post("/api/validate/start")
    def validate(body: ValidateBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_validation(body.n_points)
        return OK

    @app.post("/api/capture/retake")
    def retake(body: IndexBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.retake(body.index, body.recording)
        return OK

    @app.post("/api/capture/{action}")
    def capture(action: str, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
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

    @app.post("/api/finger")
    def finger(body: FlagBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.set_finger(body.on)
        return OK

    @app.post("/api/train")
    def train(body: TrainBody | None = None, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.train(body.exclude if body is not None else None)
        return OK

    @app.post("/api/live/start")
    def live(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_live()
        return OK
