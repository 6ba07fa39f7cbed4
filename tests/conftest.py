"""Shared fixtures: meshes and recordings built in code, and the real recordings when present."""

from __future__ import annotations

import functools
import os
import re
import shutil
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from threadpoolctl import threadpool_limits

from skinloc.data.recording import Recording
from skinloc.geometry.mesh import cone_skin, sample_targets

# One BLAS thread per test process, and in the commands a test starts (they inherit the
# variables). `pytest -n 2` runs one worker per core already, and OpenBLAS's extra threads
# busy-wait for a core they do not get: on a loaded machine that took tests/models/test_model.py
# from 37 to 60 CPU-s for no gain in wall time. A value set by the caller is kept.
_BLAS_THREADS = int(os.environ.setdefault("OPENBLAS_NUM_THREADS", "1"))
threadpool_limits(_BLAS_THREADS, user_api="blas")  # numpy's BLAS is loaded by now
# The OpenMP threads (numba's parallel batches, torch) still run two per process, so the tests
# still exercise the parallel paths; they sleep when idle instead of spinning (the same results,
# read by libgomp when numba or torch first loads it; test_model.py under load: 18 -> 8 CPU-s).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# A busy machine may stall any example for seconds: no per-example deadline, and slow data
# generation is no failure. Tests' own @settings override only what they name.
settings.register_profile("skinloc", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("skinloc")

REAL_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hiro-cone-skin"
#: Skips that must not pass unnoticed: the only test of the app in a real browser.
LOUD_SKIPS = ("tests/app/test_app_browser.py",)


#: Folders whose tests share a session fixture too costly to build in every worker of
#: ``pytest -n``: each runs in one worker (tests/firmware: the firmware and its emulator).
ONE_WORKER_DIRS = ("tests/firmware/",)
_SHARED_SCOPE = re.compile(r"""scope\s*=\s*["'](session|package|module|class)["']""")


@functools.cache
def _has_shared_fixture(module: Path) -> bool:
    """``module`` defines a session-, package-, module- or class-scoped fixture (one defined
    in a test module serves that module alone: its tests in two workers would build it twice,
    or one would wait idle on the other's lock)."""
    try:
        return bool(_SHARED_SCOPE.search(module.read_text(encoding="utf-8")))
    except OSError:
        return True


def worker_scope(nodeid: str, root: Path) -> str:
    """What ``pytest -n`` (``make test``) sends to one worker with the test ``nodeid``.

    Its folder when in ``ONE_WORKER_DIRS``; its module when the module defines a shared fixture
    of its own (session, package, module or class scope), built once so; else the test alone,
    for whichever worker is free.
    Session fixtures are built once per worker (``tests/_live.py``'s files once per run).
    """
    path = nodeid.split("::", 1)[0].replace("\\", "/")
    folder = next((d for d in ONE_WORKER_DIRS if path.startswith(d)), None)
    if folder:
        return folder
    return path if _has_shared_fixture(root / path) else nodeid


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist, called with -n only
def pytest_xdist_make_scheduler(config, log):
    """Tests sent to the workers by ``worker_scope`` (xdist's own ``--dist loadgroup`` reads
    no group under pytest 9.2: it renames ``item._nodeid``, which pytest no longer reads)."""
    from xdist.scheduler import LoadScopeScheduling

    class ByWorkerScope(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return worker_scope(nodeid, config.rootpath)

    return ByWorkerScope(config, log)


def _controller(config) -> bool:
    """This process runs workers of ``pytest -n`` (it runs no test itself)."""
    return bool(getattr(config.option, "numprocesses", None)) and not hasattr(config, "workerinput")


def pytest_configure(config) -> None:
    """The controller of ``pytest -n`` names the run (xdist's ``--testrunuid``) before it
    starts its workers, to remove what they shared (``tests/_live.py``) when the run ends, and
    keeps the order the workers list the tests in."""
    if _controller(config) and getattr(config.option, "testrunuid", None) is None:
        config.option.testrunuid = uuid.uuid4().hex
    if _controller(config):
        # the workers' order (slow units first, pytest_collection_modifyitems), not xdist's
        # own (the units with the most tests first)
        config.option.loadscopereorder = False


@pytest.hookimpl(tryfirst=True)  # before xdist's own, which starts the workers
def pytest_sessionstart(session) -> None:
    """The controller of ``pytest -n`` compiles the kernels once before its workers start
    (``tests._live.warm_kernels``); ``SKINLOC_TEST_WARM=0`` leaves it to the workers."""
    config = session.config
    if not _controller(config) or os.environ.get("SKINLOC_TEST_WARM") == "0":
        return
    os.environ["PYTEST_XDIST_TESTRUNUID"] = config.option.testrunuid  # the workers' shared folder
    from tests._live import warm_kernels

    tr = config.pluginmanager.get_plugin("terminalreporter")
    say = tr.write_line if tr is not None else print
    say("compiling the live kernels once for the workers (a fresh clone: about a minute)")
    t0 = time.monotonic()
    try:
        warm_kernels()
    except Exception as exc:  # noqa: BLE001 - the tests that need them report it themselves
        say(f"warming the kernels failed ({type(exc).__name__}: {exc}); the workers compile them")
    else:
        say(f"kernels ready in {time.monotonic() - t0:.0f} s")


def pytest_unconfigure(config) -> None:
    run = getattr(config.option, "testrunuid", None)
    if run and _controller(config):
        from tests._live import shared_dir

        shutil.rmtree(shared_dir(run), ignore_errors=True)


def pytest_collection_modifyitems(config, items) -> None:
    """``real`` on every test that reads the real recordings (through ``real_dir``), so
    ``-m "not real"`` runs without them; a mark on a fixture itself would have no effect.

    In a worker of ``pytest -n``, the tests are listed with the ``worker_scope`` units holding
    a ``slow`` test first (each unit kept whole, in its order): the scheduler hands them out in
    this order (``pytest_configure``), so a long test does not start last and leave the other
    worker idle at the end of the run.
    """
    for item in items:
        if "real_dir" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.real)
    if hasattr(config, "workerinput"):
        scopes = [worker_scope(item.nodeid, config.rootpath) for item in items]
        heavy = {
            s for s, item in zip(scopes, items, strict=True) if item.get_closest_marker("slow")
        }
        order = sorted(range(len(items)), key=lambda i: scopes[i] not in heavy)  # stable
        items[:] = [items[i] for i in order]


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2]).removeprefix("Skipped: ")
    return str(longrepr)


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """A banner when the browser test was skipped, with its reason (``-ra`` lists it too)."""
    loud = [
        r
        for r in terminalreporter.stats.get("skipped", [])
        if r.nodeid.replace("\\", "/").startswith(LOUD_SKIPS)
    ]
    if not loud:
        return
    terminalreporter.section("BROWSER TEST SKIPPED: the app was not tested in a browser", sep="!")
    for r in loud:
        terminalreporter.write_line(f"{r.nodeid}: {_skip_reason(r)}", yellow=True, bold=True)


@pytest.fixture(scope="session")
def cone():
    """The built-in paper cone."""
    return cone_skin()


@pytest.fixture(
    params=[0, 1, 2]
    if os.environ.get("SKINLOC_SEEDS") is None
    else [int(s) for s in os.environ["SKINLOC_SEEDS"].split(",")]
)
def seed(request) -> int:
    """Seeds a test must pass for; SKINLOC_SEEDS=0,1,...,99 sweeps more."""
    return request.param


def make_recording(
    n_points: int = 6, samples: int = 5, n_tx: int = 8, n_rx: int = 8, random_state: int = 0
) -> Recording:
    """A small synthetic recording: baseline ~ 8000 counts, each touch a bump at one sensor."""
    rng = np.random.default_rng(random_state)
    mesh = cone_skin()
    n = n_tx * n_rx
    baseline = 8000 + 500 * rng.random(n)
    base_frames = np.round(baseline + 5 * rng.standard_normal((20, n)))
    targets = sample_targets(mesh, n_points, "random", random_state=random_state)
    frames = np.round(baseline + 5 * rng.standard_normal((n_points, samples, n)))
    for i in range(n_points):
        frames[i, :, rng.integers(n)] += 150
    return Recording(
        n_tx=n_tx,
        n_rx=n_rx,
        vertices=mesh.vertices,
        faces=mesh.faces,
        baseline_frames=base_frames,
        targets=targets,
        frames=frames,
        meta={"description": "synthetic", "sampling_mode": "random"},
    )


@pytest.fixture
def recording_factory():
    """``recording_factory(n_points, samples, n_tx, n_rx, random_state)``."""
    return make_recording


@pytest.fixture(scope="session")
def real_dir() -> Path:
    """The real recordings; tests using it skip when ../shared/data is absent."""
    if not (REAL_DIR / "ConeSkinData80Points_RND_80PL_1.mat").is_file():
        pytest.skip(f"real recordings not found at {REAL_DIR}")
    return REAL_DIR


@pytest.fixture
def ros_domain(monkeypatch):
    """A ROS 2 domain of this test alone (``ros_domain_lease``), set as ``ROS_DOMAIN_ID``."""
    from tests._helpers import ros_domain_lease

    with ros_domain_lease() as domain:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
        yield domain
