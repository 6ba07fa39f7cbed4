"""``skinloc.sources.make_source``: one name per kind of frame source."""

from __future__ import annotations

import pytest

from skinloc.hardware.serial import SerialSource
from skinloc.sim.skin import SimulatedSkin
from skinloc.sources import SourceOptions, make_source


def test_make_source_builds_the_simulator() -> None:
    src = make_source(SourceOptions("sim", seed=0, n_tx=4, n_rx=5))
    assert isinstance(src, SimulatedSkin)
    assert src.n_sensors == 20


def test_make_source_builds_serial_and_replay(tmp_path):
    src = make_source(SourceOptions("loop://", n_tx=21, n_rx=12))
    assert isinstance(src, SerialSource) and src.n_sensors == 252
    with pytest.raises(ValueError, match="n_tx"):
        make_source(SourceOptions("loop://", n_tx=30))
