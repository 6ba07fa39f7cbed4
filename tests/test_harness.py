"""The suite's own promises: Chromium's installer waits for apt and never fails `make test`,
a skipped browser test is announced loudly with its reason, and no two tests share a ROS 2
domain."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "ensure-chromium.sh"
#: What ensure-chromium.sh and the fake apt-get below run (linked from the real PATH).
TOOLS = (
    "sh",
    "mkdir",
    "rm",
    "mktemp",
    "date",
    "grep",
    "sleep",
    "tail",
    "cat",
    "touch",
    "chmod",
    "dirname",
)

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="a POSIX shell script")


def fake_bin(tmp_path: Path, apt_get: str) -> Path:
    """A PATH with the script's tools, a fake ``apt-get`` and ``id`` (root), and no Chromium."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(parents=True)
    for tool in TOOLS:
        (bin_dir / tool).symlink_to(shutil.which(tool))
    for name, body in (("apt-get", apt_get), ("id", "echo 0\n")):
        (bin_dir / name).write_text("#!/bin/sh\n" + body)
        (bin_dir / name).chmod(0o755)
    return bin_dir


def ensure_chromium(tmp_path: Path, bin_dir: Path, wait_s: int) -> subprocess.CompletedProcess:
    env = {"PATH": str(bin_dir), "SKINLOC_APT_WAIT_S": str(wait_s), "HOME": str(tmp_path)}
    return subprocess.run(
        ["sh", str(SCRIPT)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )


# A fake apt-get that reports apt's lock busy until the file `free` exists (then "installs").
APT_BUSY = """
if [ ! -e free ]; then
    n=$(cat tries 2>/dev/null || echo 0); echo $((n + 1)) > tries
    [ "$n" -ge 1 ] && touch free
    echo "E: Could not get lock /var/lib/dpkg/lock-frontend. It is held by process 42 (apt-get)"
    exit 100
fi
case "$*" in *install*) printf '#!/bin/sh\\n' > "$(dirname "$0")/chromium"
    chmod +x "$(dirname "$0")/chromium";; esac
"""


def test_installer_waits_for_apt_lock(tmp_path):
    bin_dir = fake_bin(tmp_path, APT_BUSY)
    res = ensure_chromium(tmp_path, bin_dir, wait_s=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "waiting" in res.stdout and "chromium installed" in res.stdout
    assert (bin_dir / "chromium").exists()
    assert int((tmp_path / "tries").read_text()) == 2  # it retried instead of giving up
    assert not (tmp_path / "build" / "chromium-status.txt").exists()


def test_installer_gives_up_after_its_bound_and_says_why(tmp_path):
    busy_forever = 'echo "E: Could not get lock /var/lib/apt/lists/lock"; exit 100\n'
    res = ensure_chromium(tmp_path, fake_bin(tmp_path, busy_forever), wait_s=1)
    assert res.returncode == 0  # best effort: make test goes on
    status = (tmp_path / "build" / "chromium-status.txt").read_text()
    assert "lock was still held after 1 s" in status and "/var/lib/apt/lists/lock" in status
    assert "the browser test will skip" in res.stdout

    broken = 'echo "E: Unable to locate package chromium"; exit 100\n'
    res = ensure_chromium(tmp_path, fake_bin(tmp_path / "b", broken), wait_s=60)
    assert res.returncode == 0 and "Unable to locate package chromium" in res.stdout


def test_a_skipped_browser_test_is_announced_loudly(tmp_path):
    """Without Chromium on PATH the browser test skips, with a banner and its reason."""
    pytest.importorskip("playwright.sync_api")
    env = {
        **os.environ,
        "PATH": str(Path(sys.executable).parent),
        "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
    }
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
         str(ROOT / "tests" / "app" / "test_app_browser.py")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert "BROWSER TEST SKIPPED" in res.stdout
    assert "no Chromium (chromium, chromium-browser, google-chrome) on PATH" in res.stdout


def test_firmware_packages_that_cannot_be_had_are_reported(tmp_path):
    """The firmware group gives up like Chromium's, and leaves the reason for tests/firmware."""
    broken = 'echo "E: Unable to locate package gcc-avr"; exit 100\n'
    env = {"PATH": str(fake_bin(tmp_path, broken)), "SKINLOC_APT_WAIT_S": "5",
           "HOME": str(tmp_path)}  # fmt: skip
    script = ROOT / "scripts" / "ensure-packages.sh"
    res = subprocess.run(
        ["sh", str(script), "firmware"], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert res.returncode == 0
    status = (tmp_path / "build" / "firmware-status.txt").read_text()
    assert "Unable to locate package gcc-avr" in status
    assert "the firmware tests will skip" in res.stdout


def test_no_two_tests_share_a_ros2_domain():
    """Another process (another test worker) leasing every domain it can gets only the one
    not leased here, then is told that every id is held. Ids no test uses (200-202), so that
    the ROS 2 tests running beside it keep theirs."""
    from tests._helpers import ros_domain_lease

    ids = range(200, 203)
    code = (
        "import contextlib, sys; sys.path.insert(0, sys.argv[1])\n"
        "from tests._helpers import ros_domain_lease\n"
        "got, stack = [], contextlib.ExitStack()\n"
        "try:\n"
        "    while True: got.append(stack.enter_context(ros_domain_lease(range(200, 203))))\n"
        "except RuntimeError as exc: print(*got, '|', exc)"
    )
    with ros_domain_lease(ids) as mine, ros_domain_lease(ids) as also_mine:
        assert mine != also_mine and {mine, also_mine} <= set(ids)
        out = subprocess.check_output([sys.executable, "-c", code, str(ROOT)], text=True)
    theirs, why = out.split("|")
    assert {int(d) for d in theirs.split()} == set(ids) - {mine, also_mine}
    assert "held by another test" in why
