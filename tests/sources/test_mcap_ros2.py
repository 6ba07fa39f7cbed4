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


def test_a_bag_grows_on_disk_while_it_is_written(tmp_path):
    """The size a recording shows is the file's: chunks reach the disk as frames come, not
    only at the end (mcap's default 1 MiB chunk kept a recording at its 36-byte header)."""
    from skinloc.live.sinks.ros2.bag import CHUNK_BYTES

    bag = tmp_path / "grow.mcap"
    sink = make_sink(f"mcap-ros2:{bag}")
    sink.open([SkinInfo("a", n_tx=8, n_rx=8)])
    rng = np.random.default_rng(0)
    start = sink.n_bytes
    for i in range(3 * CHUNK_BYTES // 256):  # three chunks of 64-value frames
        sink.emit_frame("a", rng.normal(1000, 5, 64), 0.01 * i, i)
    assert sink.n_bytes > start + 1000
    sink.close()
    assert sink.n_bytes == bag.stat().st_size


def test_a_missing_extra_leaves_no_file_behind(tmp_path, monkeypatch):
    """Without the ROS 2 messages (cyclonedds) the bag asks once, before any file exists."""
    from skinloc.errors import MissingExtraError
    from skinloc.live.sinks.ros2 import bag as bag_module

    def missing():
        raise MissingExtraError("the ROS 2 sink needs cyclonedds: pip install 'skinloc[live]'")

    monkeypatch.setattr(bag_module, "require_msgs", missing)
    with pytest.raises(MissingExtraError, match="skinloc\\[live\\]"):
        make_sink(f"mcap-ros2:{tmp_path / 'x.mcap'}").open([SkinInfo("a", n_tx=2, n_rx=2)])
    assert list(tmp_path.iterdir()) == []
