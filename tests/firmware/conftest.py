"""Fixtures of the firmware-in-the-loop tests: the firmware and its emulator, built once.

The build needs Debian's gcc-avr, avr-libc, arduino-core-avr, simavr and libsimavr-dev
(`.ci/run` installs them). Where they are missing every test here skips, and the session ends
with a banner that says so: a skip here means the firmware was not tested.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from skinloc.sim.emulated_board import PACKAGES, build_firmware, missing_tools

_SKIPPED: list[str] = []
#: Why scripts/ensure-packages.sh (make test) could not install the packages, when it could not.
STATUS = Path(__file__).resolve().parents[2] / "build" / "firmware-status.txt"


@pytest.fixture(scope="session")
def fw_build(tmp_path_factory):
    """The firmware (.elf) and the emulator, built into a fresh folder for this session."""
    if sys.platform == "win32":
        _SKIPPED.append("Windows has no pseudo-terminals")
        pytest.skip("the emulated board needs a POSIX pseudo-terminal")
    missing = missing_tools()
    if missing:
        why = f"missing {', '.join(missing)} (apt-get install {' '.join(PACKAGES)})"
        if STATUS.is_file():
            why += f"; {STATUS.read_text().strip()}"
        _SKIPPED.append(why)
        pytest.skip(f"firmware-in-the-loop tests: {why}")  # the banner below reads this prefix
    return build_firmware(tmp_path_factory.mktemp("firmware-build"))


def pytest_terminal_summary(terminalreporter) -> None:
    """A banner when the firmware tests skipped, with the reason. Read from the reports, not
    from ``_SKIPPED``: under ``pytest -n`` the skip happens in a worker process."""
    reasons = [
        str(r.longrepr[2]).removeprefix("Skipped: ")
        for r in terminalreporter.stats.get("skipped", [])
        if isinstance(r.longrepr, tuple) and len(r.longrepr) == 3
        and r.nodeid.replace("\\", "/").startswith("tests/firmware/")
    ]  # fmt: skip
    prefix = "firmware-in-the-loop tests: "
    found = [m.removeprefix(prefix) for m in reasons if m.startswith(prefix)]
    why = (_SKIPPED or found or [""])[0]
    if why:
        bar = "!" * 78
        terminalreporter.write_line(bar, red=True, bold=True)
        terminalreporter.write_line(
            "FIRMWARE NOT TESTED: the firmware-in-the-loop tests (tests/firmware) skipped: " + why,
            red=True,
            bold=True,
        )
        terminalreporter.write_line(bar, red=True, bold=True)
