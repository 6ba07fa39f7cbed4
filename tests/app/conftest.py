"""Fixtures of the app's tests: the app served on a free loopback port, and the Chromium binary.

The helpers that are not fixtures (the bounded wait, the browser's launch, the page's error
watch) are in ``tests/app/_app.py``.
"""

from __future__ import annotations

import socket
import threading

import pytest

from tests._helpers import wait_until
from tests.app._app import find_chromium


@pytest.fixture
def server(tmp_path):
    """The app on a free loopback port, served by uvicorn on a thread: ``(url, app)``."""
    uvicorn = pytest.importorskip("uvicorn")
    from skinloc.app.server import create_app
    from skinloc.app.workspace import AppConfig

    # Bind here and hand uvicorn the socket: no window for another process to take the port.
    sock = socket.create_server(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    config = AppConfig(data_dir=tmp_path / "sessions", finger_delay_s=0.15)
    app = create_app(config)
    srv = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws="websockets-sansio"))
    thread = threading.Thread(target=srv.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()

    def started() -> bool:
        if not thread.is_alive():
            pytest.fail("the app server's thread ended before it started")
        return srv.started

    wait_until(started, "the app server to start", 120.0, interval_s=0.05)
    yield f"http://127.0.0.1:{port}/", app
    srv.should_exit = True
    thread.join(timeout=30)
    sock.close()


@pytest.fixture
def chromium() -> str:
    """The Chromium binary (looked up before the server starts, to skip early)."""
    return find_chromium()
