"""The ROS 2 publisher's use of cyclonedds internals holds for the version pyproject pins."""

from __future__ import annotations

import importlib.metadata
import re
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[4]


def _pinned() -> Requirement:
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    live = extras["optional-dependencies"]["live"]
    return next(Requirement(r) for r in live if re.match(r"cyclonedds\b", r))


def test_cyclonedds_is_pinned_to_one_minor_version():
    spec = _pinned().specifier
    assert any(s.operator == "<" for s in spec) and any(s.operator == ">=" for s in spec)


def test_the_private_cyclonedds_names_the_publisher_uses_are_there(monkeypatch):
    pytest.importorskip("cyclonedds")
    installed = importlib.metadata.version("cyclonedds")
    assert _pinned().specifier.contains(installed), f"cyclonedds {installed} is not the pinned one"
    from cyclonedds._clayer import ddspy_write  # used by _DdsBackend.write

    assert callable(ddspy_write)
    from skinloc.bench.sinks import LOOPBACK_DDS
    from skinloc.live.sinks.ros2.publisher import _DdsBackend
    from skinloc.ros2.msgs import PoseArray

    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK_DDS)
    backend = _DdsBackend(200)
    backend.advertise("/skinloc/check/contacts", PoseArray, latched=False)
    assert isinstance(backend._refs["/skinloc/check/contacts"], int)  # DataWriter._ref
    backend.write("/skinloc/check/contacts", PoseArray().serialize())  # through ddspy_write
