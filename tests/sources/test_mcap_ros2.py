"""Replaying a ROS 2 bag (MCAP) of skin frames: which image topic is the skin's."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mcap")

from skinloc.errors import RecordingError  # noqa: E402
from skinloc.live.sinks import SkinInfo, make_sink  # noqa: E402
from skinloc.sources.mcap_ros2 import McapReplaySource  # noqa: E402


def test_bag_source_topic_choice(tmp_path):
    bag = tmp_path / "two.mcap"
    sink = make_sink(f"mcap-ros2:{bag}")
    sink.open([SkinInfo("a", n_tx=4, n_rx=2), SkinInfo("b", n_tx=2, n_rx=2)])
    sink.emit_frame("a", np.ones(8), 1.0, 3)
    sink.emit_frame("b", np.ones(4), 1.0, 0)
    sink.close()
    src = McapReplaySource(bag, skin="a")
    assert (src.n_tx, src.n_rx, src.topic) == (4, 2, "/skinloc/a/frames")
    assert McapReplaySource(bag, skin="b").topic == "/skinloc/b/frames"
    with pytest.raises(RecordingError, match="several image topics"):
        McapReplaySource(bag, skin="c")
    with pytest.raises(RecordingError, match="no image topic"):
        McapReplaySource(bag, topic="/x")
