"""ROS 2 names of a skin: its topic token and the prefix of its topics (no ROS needed)."""

from __future__ import annotations

import re

__all__ = ["node_name_error", "ros_name", "topic_base"]


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


def node_name_error(name: str) -> str | None:
    """Why ``name`` is not a valid ROS 2 node name, or ``None`` when it is.

    ROS 2's rules (``rmw_validate_node_name``): not empty, at most 255 characters, only ASCII
    letters, digits and underscores, not starting with a digit.
    """
    if not name:
        return "a ROS 2 node name must not be empty"
    if len(name) > 255:
        return f"a ROS 2 node name has at most 255 characters, got {len(name)}"
    bad = sorted({c for c in name if not (c.isascii() and (c.isalnum() or c == "_"))})
    if bad:
        return (
            f"ROS 2 node name {name!r} may hold only letters, digits and underscores, "
            f"not {''.join(bad)!r}"
        )
    if name[0].isdigit():
        return f"ROS 2 node name {name!r} must not start with a digit"
    return None
