"""Where the test suite's CPU and wall time go: per test, and per kind of process.

    python bench/suite_cpu.py --out bench/results/suite-cpu-DATE.json [-- PYTEST ARGS]

Runs ``python -m pytest -q -n 4`` (or the arguments after ``--``) with this file loaded in every
worker as a pytest plugin (``-p suite_cpu``), which records each test's wall time and the CPU
of the worker itself and of the children it reaped during the test (``getrusage``). A thread of
this process samples ``/proc`` every 0.5 s besides, to count what ``getrusage`` cannot see: the
processes not yet reaped (Chromium under Playwright's driver, the app servers a test keeps),
sorted by kind (chromium, node, simavr, ``skinloc`` commands, the pytest processes) and charged
to the test the worker they descend from was running. Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

_OUT_ENV = "SUITE_CPU_DIR"  # where the workers write (set by main for the plugin)


# --------------------------------------------------------------------- the plugin (workers)
def _cpu() -> tuple[float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


_started: dict[str, tuple[tuple[float, float], float]] = {}
_rows: list[dict] = []
_recording = True  # False in the controller of pytest -n, which hears of every worker's tests


def pytest_configure(config) -> None:
    global _recording
    _recording = hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None)


def _current(text: str) -> None:
    folder = os.environ.get(_OUT_ENV)
    if folder:
        Path(folder, f"now-{os.getpid()}").write_text(text)


def pytest_runtest_logstart(nodeid: str, location: object) -> None:
    if not _recording:
        return
    _started[nodeid] = (_cpu(), time.monotonic())
    _current(nodeid)


def pytest_runtest_logfinish(nodeid: str, location: object) -> None:
    if nodeid not in _started:
        return
    (own0, kids0), t0 = _started.pop(nodeid)
    own1, kids1 = _cpu()
    _rows.append(
        {
            "test": nodeid,
            "worker": os.environ.get("PYTEST_XDIST_WORKER", "main"),
            "wall_s": round(time.monotonic() - t0, 2),
            "cpu_own_s": round(own1 - own0, 2),
            "cpu_reaped_children_s": round(kids1 - kids0, 2),
        }
    )
    _current("(between tests)")


def pytest_sessionfinish(session: object) -> None:
    folder = os.environ.get(_OUT_ENV)
    if folder and _recording:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        Path(folder, f"rows-{worker}.json").write_text(json.dumps(_rows))


# --------------------------------------------------------------------- the sampler (main)
def _kind(pid: int, comm: str) -> str:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
        cmd = raw.replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        cmd = comm
    if "chrom" in comm:
        return "chromium"
    if comm.startswith("node"):
        return "node (Playwright's driver)"
    if "avrsim" in cmd or "simavr" in cmd:
        return "simavr (the emulated board)"
    if "-m skinloc" in cmd or "bin/skinloc" in cmd:
        return "skinloc commands"
    if "python" in comm:
        return "pytest and other Python"
    return "other"


def _processes() -> dict[tuple[int, str], tuple[int, float, str]]:
    """``(pid, start time) -> (parent pid, CPU s so far, comm)`` of every process."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            stat = Path(f"/proc/{name}/stat").read_text()
        except OSError:
            continue
        close = stat.rindex(")")
        fields = stat[close + 2 :].split()
        cpu = (int(fields[11]) + int(fields[12])) / tick
        out[(int(name), fields[19])] = (int(fields[1]), cpu, stat[stat.index("(") + 1 : close])
    return out


def sample(folder: Path, root: int, stop: threading.Event, into: dict) -> None:
    """Every 0.5 s until ``stop``: the new CPU of each process descending from ``root`` (the
    pytest process), by kind and by the test it serves."""
    seen: dict[tuple[int, str], float] = {}
    kinds: dict[tuple[int, str], str] = {}  # a process's kind, read once from /proc
    by_kind: collections.Counter = collections.Counter()
    by_test: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    first = True
    while not stop.wait(0.0 if first else 0.5):
        procs = _processes()
        running = {}
        for f in folder.glob("now-*"):
            try:
                running[int(f.name[4:])] = f.read_text()
            except (OSError, ValueError):
                pass
        parent = {pid: ppid for (pid, _), (ppid, _, _) in procs.items()}
        for key, (_, cpu, comm) in procs.items():
            new = cpu - seen.get(key, 0.0 if not first else cpu)
            seen[key] = cpu
            if new <= 0:
                continue
            pid, test, ours = key[0], None, False
            for _ in range(40):  # up to the worker it descends from, and to pytest
                if test is None and pid in running:
                    test = running[pid]
                if pid == root:
                    ours = True
                    break
                pid = parent.get(pid, 1)
                if pid <= 1:
                    break
            if not ours:  # another job on the machine
                continue
            if key not in kinds:
                kinds[key] = _kind(key[0], comm)
            kind = kinds[key]
            by_kind[kind] += new
            by_test[test or "(outside tests: start-up, the warm-up)"][kind] += new
        first = False
    into["by_kind_cpu_s"] = {k: round(v, 1) for k, v in by_kind.most_common()}
    into["by_test_cpu_s"] = {
        t: {k: round(v, 1) for k, v in c.most_common()}
        for t, c in sorted(by_test.items(), key=lambda tc: -sum(tc[1].values()))
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="JSON file to write")
    ap.add_argument("pytest_args", nargs="*", default=["-q", "-n", "4"])
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="suite-cpu-"))
    env = {
        **os.environ,
        _OUT_ENV: str(folder),
        "PYTHONPATH": os.pathsep.join(
            p for p in (str(Path(__file__).parent), os.environ.get("PYTHONPATH")) if p
        ),
    }
    result: dict = {"command": ["python", "-m", "pytest", *args.pytest_args, "-p", "suite_cpu"]}
    stop = threading.Event()
    t0, cpu0 = time.monotonic(), _cpu()[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "pytest", *args.pytest_args, "-p", "suite_cpu"], env=env
    )
    sampler = threading.Thread(target=sample, args=(folder, proc.pid, stop, result))
    sampler.start()
    proc.wait()
    stop.set()
    sampler.join()
    result["exit_code"] = proc.returncode
    result["wall_s"] = round(time.monotonic() - t0, 1)
    result["cpu_reaped_s"] = round(_cpu()[1] - cpu0, 1)
    rows = [r for f in sorted(folder.glob("rows-*.json")) for r in json.loads(f.read_text())]
    shutil.rmtree(folder, ignore_errors=True)
    result["tests"] = sorted(rows, key=lambda r: -r["wall_s"])
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wall {result['wall_s']} s, CPU of the reaped processes {result['cpu_reaped_s']} s")
    for kind, cpu in result["by_kind_cpu_s"].items():
        print(f"  {cpu:8.1f} CPU-s  {kind}")
    print("longest tests (wall s, CPU s of the worker and its reaped children):")
    for r in result["tests"][:15]:
        cpu = r["cpu_own_s"] + r["cpu_reaped_children_s"]
        print(f"  {r['wall_s']:6.1f} {cpu:6.1f}  {r['test']}")
    sys.exit(proc.returncode)


if __name__ == "__main__":
    main()
