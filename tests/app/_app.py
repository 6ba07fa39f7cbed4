"""What the app's tests share besides fixtures (those are in ``conftest.py``): the bounded wait
on the workspace, the browser's setup (Debian's Chromium driven by Playwright), and running a
command the page prints as printed.

Browser tests skip, saying why, where Playwright or a Chromium (Debian's ``chromium``, which
``make test`` installs) is missing.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests._helpers import scaled, wait_until

ROOT = Path(__file__).resolve().parents[2]
#: Where the browser tests save their screenshots (docs/app.md shows some).
ARTIFACTS = Path(os.environ.get("SKINLOC_ARTIFACTS", ROOT / "build" / "test-artifacts" / "app"))
#: Why scripts/ensure-chromium.sh (make test) could not install Chromium, when it could not.
CHROMIUM_STATUS = ROOT / "build" / "chromium-status.txt"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    # WebGL without a GPU.
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    # ... and the page composited in software, as Chromium does on a machine without a GPU:
    # compositing through SwiftShader redrew the whole page on every heat-map frame (~0.8 of
    # a core while the app streams the skin, against ~0.15).
    "--disable-gpu-compositing",
]
#: Every CSS transition and finite animation of the page has ended (progress bars, fades); a
#: looping one (a pulse) never does and is left out.
SETTLED_CSS = (
    "() => document.getAnimations().every((a) => a.playState !== 'running'"
    " || a.effect.getComputedTiming().endTime === Infinity)"
)


def wait(check: Callable[[], Any], what: str, timeout_s: float = 180.0) -> Any:
    """``check()``'s first true value, polled every 50 ms (the workspace's threads move on
    their own); fails naming ``what`` after ``timeout_s`` stretched by the load."""
    return wait_until(check, what, timeout_s, interval_s=0.05)


def ms(timeout_ms: float) -> float:
    """A Playwright timeout (ms) stretched by the machine's load, as every other wait is."""
    return scaled(timeout_ms / 1000.0) * 1000.0


def settle(page) -> None:
    """Wait until what the page has is on screen: its transitions ended, then two animation
    frames drawn (what a screenshot or a layout check waits for, instead of a fixed pause).

    Also a round trip through the page's event loop: a promise rejected by what came before
    is reported (``pageerror``) by then.
    """
    page.wait_for_function(SETTLED_CSS)
    page.evaluate(
        "() => { window.__settleFrames = 0; const f = () => { window.__settleFrames += 1;"
        " if (window.__settleFrames < 2) requestAnimationFrame(f); }; requestAnimationFrame(f); }"
    )
    page.wait_for_function("() => window.__settleFrames >= 2")


def find_chromium() -> str:
    """The Chromium binary on PATH; skips the test, saying why, where there is none."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    why = "run 'sh scripts/ensure-chromium.sh' (make test does) or apt-get install chromium"
    if CHROMIUM_STATUS.is_file():
        why = CHROMIUM_STATUS.read_text().strip() or why
    pytest.skip(f"no Chromium (chromium, chromium-browser, google-chrome) on PATH: {why}")


@contextlib.contextmanager
def open_browser(chromium: str) -> Iterator[Any]:
    """Headless ``chromium`` under Playwright (a ``playwright.sync_api.Browser``), closed after."""
    from playwright import sync_api

    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            if browser.is_connected():  # a test may have closed it itself
                browser.close()


def watch(page, errors: list[str]) -> None:
    """Collect the page's errors and three.js's warnings (it warns through console.warn).

    A refused action (409, busy) is what the second tab should meet, not an error.
    """

    def console(m) -> None:
        if "status of 409" in m.text:
            return
        if m.type == "error" or (m.type == "warning" and "THREE" in m.text):
            errors.append(f"{m.type}: {m.text}")

    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("console", console)
    # a page's own waits (clicks, wait_for_function) get the load's stretch, as wait_until does
    page.set_default_timeout(scaled(60.0) * 1000.0)


def run_as_printed(command: str, cwd: Path) -> None:
    """Run a ``skinloc ...`` command the page prints, as printed, in ``cwd`` (this checkout's
    skinloc): it must exit 0 without a traceback."""
    argv = shlex.split(command)
    assert argv[0] == "skinloc", command
    out = subprocess.run(
        [sys.executable, "-m", "skinloc", *argv[1:]],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )
    assert out.returncode == 0, f"{command}: {out.stderr}"
    assert "Traceback" not in out.stderr, command
