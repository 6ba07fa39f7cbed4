"""ROS 2 names of a skin: its topic token and the prefix of its topics (no ROS needed)."""

from __future__ import annotations

import re

__all__ = ["ros_name", "topic_base"]


def ros_name(skin: str) -> str:
    """The skin's name as a ROS 2 topic name token: ``left-forearm`` -> ``left_forearm``.

    ROS 2 topic names allow letters, digits and underscores, not starting with a digit; frame
    ids keep the skin's own name (``skin/left-forearm``).
    """
    token = re.sub(r"[^A-Za-z0-9_]", "_", skin) or "_"
    return f"_{token}" if token[0].isdigit() else token


def topic_base(skin: str) -> str:
    """``/skinloc/<ros_name(skin)>``, the prefix of a skin's topics."""
    return f"/skinloc/{ros_name(skin)}"
