"""The browser app: guided calibration on the 3D skin, training, validation and live view.

``skinloc app`` serves it (``skinloc.cli.webapp``); ``create_app`` builds the FastAPI application.
Importing this package loads no web framework; ``create_app`` does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fastapi import FastAPI

__all__ = ["create_app"]


def create_app(*args: Any, **kwargs: Any) -> FastAPI:
    """Build the app (see ``skinloc.app.server.create_app``)."""
    from skinloc.app.server import create_app as build

    return build(*args, **kwargs)
