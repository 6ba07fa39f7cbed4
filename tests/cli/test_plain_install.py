"""The plain install (``pip install .``, no extras): bad input and missing extras are one line.

A fresh virtual environment is built once per session from a copy of this checkout, with
``pip install`` and nothing else, so the extras' modules (PyTorch, onnx, foxglove, pylsl,
cyclonedds, mcap) are really absent, as on a user's machine; every command below must then end
in one ``error:`` line on stderr and a non-zero exit, never a traceback, and before the engine's
kernels compile (about 25 s of CPU on a fresh install). Building it takes about 15 s on a warm
pip cache (the packages come from the cache, not the network).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from skinloc._lazy import EXTRAS
from tests._live import build_once, shared_file

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [
    pytest.mark.skipif(sys.platform == "win32", reason="POSIX venv layout"),
    pytest.mark.slow,  # a virtual environment built and installed
]


@pytest.fixture(scope="session")
def plain() -> Path:
    """The ``skinloc`` script of a fresh venv holding ``pip install .`` only (built once per
    run: under ``pytest -n`` the workers share it, ``tests/_live.py``)."""
    base = shared_file("plain-install")
    with build_once(base.with_name("plain-install.done")) as build:
        if build:
            shutil.rmtree(base, ignore_errors=True)  # a build that failed part way
            try:
                _build(base)
            except BaseException:
                shutil.rmtree(base, ignore_errors=True)
                raise
            base.with_name("plain-install.done").touch()
    return base / "venv" / "bin" / "skinloc"


def _build(base: Path) -> None:
    """``pip install .`` of a copy of this checkout into a new venv ``base / "venv"``."""
    # a copy, so that the build leaves nothing (build/, *.egg-info) in the checkout
    src = base / "checkout"
    src.mkdir(parents=True)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(
        ROOT / "src", src / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info")
    )
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    t0 = time.monotonic()
    # --no-compile: the commands below compile the modules they import, not every module of
    # every dependency (scipy's and sklearn's thousands, tests included) at install time
    pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    res = subprocess.run(
        [*pip, "--no-compile", str(src)],
        capture_output=True,
        text=True,
        env=env,
        timeout=1800,
    )
    assert res.returncode == 0, f"pip install . failed:\n{res.stderr[-3000:]}"
    print(f"plain install built in {time.monotonic() - t0:.0f} s")  # noqa: T201
    # honest: none of the extras' modules can be imported there
    probe = "import importlib.util as u, sys; print(*[m for m in sys.argv[1:] if u.find_spec(m)])"
    found = subprocess.run(
        [str(python), "-c", probe, *EXTRAS], capture_output=True, text=True, env=env, timeout=120
    )
    assert found.returncode == 0 and found.stdout.strip() == "", found.stdout + found.stderr


LIVE = "pip install 'skinloc[live]'"

#: ``skinloc run`` on the simulated skin (the simulator only when asked for)
RUN = ["run", "--model", "{model}", "--source", "sim"]
#: (arguments, text the one line must hold); {name} are the ``inputs`` files.
CASES = [
    # every sink spec whose extra is missing, and bad ones
    ([*RUN, "--sink", "lsl"], LIVE),
    ([*RUN, "--sink", "lsl:skin"], LIVE),
    ([*RUN, "--sink", "mcap:{out}/c.mcap"], LIVE),
    ([*RUN, "--sink", "foxglove://127.0.0.1:0"], LIVE),
    ([*RUN, "--sink", "foxglove://127.0.0.1:0?mcap={out}/f.mcap"], LIVE),
    ([*RUN, "--sink", "mcap-ros2:{out}/b.mcap"], LIVE),
    ([*RUN, "--sink", "ros2"], LIVE),
    ([*RUN, "--sink", "ros2:node"], LIVE),
    ([*RUN, "--sink", "mcap:"], LIVE),  # the missing extra first (check_sink)
    ([*RUN, "--sink", "bogus"], "unknown sink"),
    ([*RUN, "--sink", "ws://127.0.0.1:99999"], "bad port"),
    ([*RUN, "--sink", "udp://nohost.invalid:9870"], "cannot resolve"),
    (["run", "--model", "{model}", "--source", "{bag}"], LIVE),
    # commands whose extra is missing
    (["train", "{rec}", "--arch", "paper", "--out", "{out}/m.h5"], "pip install 'skinloc[nets]'"),
    (["export", "{model}", "--onnx", "{out}/m.onnx"], "pip install 'skinloc[export]'"),
    # the wrong kind of file (tests/cli/test_cli_file_kinds.py has them all, in process)
    (["coverage", "{stream}"], "raw stream"),
    (["evaluate", "{rec}", "{rec}"], "is a recording, not a model"),
    (["info", "{bag}"], LIVE),
    (["predict", "{model}", "{text}"], "notes.h5"),
    (["bench", "--sizes", "abc", "--out", "{out}/bench"], "--sizes"),
]


def _run(skinloc: Path, args: list[str]) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["ROS_DOMAIN_ID"] = "0"
    return subprocess.run(
        [str(skinloc), *args],
        capture_output=True,
        text=True,
        env=env,
        stdin=subprocess.DEVNULL,
        timeout=600,
    )


def test_every_command_with_bad_or_missing_extra_input_is_one_line(plain, wrong_inputs):
    names = {k: str(v) for k, v in wrong_inputs.items()}
    argvs = [[a.format(**names) for a in args] for args, _ in CASES]
    with ThreadPoolExecutor(max_workers=2) as pool:  # each is a process of its own
        results = list(pool.map(lambda argv: _run(plain, argv), argvs))
    bad = []
    for (_, needle), argv, res in zip(CASES, argvs, results, strict=True):
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        ok = (
            res.returncode not in (0, None)
            and "Traceback" not in res.stderr + res.stdout
            and len(lines) == 1
            and lines[0].startswith("error:")
            and needle in lines[0]
        )
        if not ok:
            bad.append(f"skinloc {' '.join(argv)} -> {res.returncode}:\n{res.stderr[-1500:]}")
    assert not bad, "\n\n".join(bad)
    # Bad input is refused before a model's kernels compile: numba's cache in the install
    # holds nothing yet (a compile writes an index file beside the module).
    compiled = sorted(p.name for p in (plain.parents[1] / "lib").rglob("skinloc/**/*.nbi"))
    assert not compiled, f"a command with bad input compiled kernels first: {compiled}"


def test_flags_read_as_flags_in_the_plain_install(plain):
    res = _run(plain, ["run", "--help"])
    assert res.returncode == 0, res.stderr
    assert "<bool>" not in res.stdout and "--fast" in res.stdout
