"""A ROS 2 node publishing contacts, when ``rclpy`` is present (a ROS 2 installation).

Per skin, on ``/skinloc/<skin>/contact`` a ``geometry_msgs/PointStamped`` (m, frame
``skin_<skin>``) and on ``/skinloc/<skin>/marker`` a ``visualization_msgs/Marker`` (a sphere,
green while touching, deleted when the touch ends). The node spins on its own executor thread,
stopped and joined by ``close``. ``rclpy`` comes with ROS 2 (e.g. ``apt install ros-jazzy-rclpy``
and ``source /opt/ros/jazzy/setup.bash``), not from PyPI.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any

from skinloc.sinks.base import Sink, SkinInfo

if TYPE_CHECKING:
    from skinloc.pipeline import Contact

log = logging.getLogger(__name__)

__all__ = ["Ros2Sink", "ros2_available"]


def ros2_available() -> bool:
    """Whether ``rclpy`` and the message packages import."""
    try:
        import geometry_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import visualization_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True


class Ros2Sink(Sink):
    """Publish ``PointStamped`` and ``Marker`` messages from a node named ``node_name``."""

    name = "ros2"

    def __init__(self, node_name: str = "skinloc") -> None:
        self.node_name = node_name
        self._node: Any = None
        self._executor: Any = None
        self._thread: threading.Thread | None = None
        self._pubs: dict[str, tuple[Any, Any]] = {}
        self._own_init = False

    def open(self, skins: list[SkinInfo]) -> None:
        """Create the node and its publishers; spin it on a thread."""
        if not ros2_available():
            raise ImportError(
                "the ROS 2 sink needs rclpy, geometry_msgs and visualization_msgs: install ROS 2 "
                "and source its setup script (rclpy is not on PyPI)"
            )
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        if self._node is not None:
            return
        if not rclpy.ok():
            rclpy.init()
            self._own_init = True
        self._node = rclpy.create_node(self.node_name)
        for s in skins:
            self._publishers(s.name)
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self._node)
        self._thread = threading.Thread(
            target=self._executor.spin, name="skinloc-ros2-sink", daemon=True
        )
        self._thread.start()

    def _publishers(self, skin: str) -> tuple[Any, Any]:
        pubs = self._pubs.get(skin)
        if pubs is None:
            from geometry_msgs.msg import PointStamped
            from visualization_msgs.msg import Marker

            pubs = self._pubs[skin] = (
                self._node.create_publisher(PointStamped, f"/skinloc/{skin}/contact", 10),
                self._node.create_publisher(Marker, f"/skinloc/{skin}/marker", 10),
            )
        return pubs

    def emit(self, contact: Contact) -> None:
        """Publish the point and the marker."""
        if self._node is None:
            self.open([])
        from geometry_msgs.msg import PointStamped
        from visualization_msgs.msg import Marker

        point_pub, marker_pub = self._publishers(contact.skin)
        stamp = self._node.get_clock().now().to_msg()
        frame = f"skin_{contact.skin}"
        x, y, z = contact.position_m
        marker = Marker()
        marker.header.stamp, marker.header.frame_id = stamp, frame
        marker.ns, marker.id, marker.type = "skinloc", 0, Marker.SPHERE
        if contact.state == "end" or x != x:
            marker.action = Marker.DELETE
        else:
            msg = PointStamped()
            msg.header.stamp, msg.header.frame_id = stamp, frame
            msg.point.x, msg.point.y, msg.point.z = float(x), float(y), float(z)
            point_pub.publish(msg)
            marker.action = Marker.ADD
            marker.pose.position.x, marker.pose.position.y = float(x), float(y)
            marker.pose.position.z = float(z)
            marker.pose.orientation.w = 1.0
            marker.scale.x = marker.scale.y = marker.scale.z = 0.01
            marker.color.g, marker.color.a = 0.8, 1.0
        marker_pub.publish(marker)

    def close(self) -> None:
        """Stop spinning, join the thread, destroy the node."""
        if self._executor is not None:
            self._executor.shutdown()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._node is not None:
            self._node.destroy_node()
            self._node = None
        if self._own_init:
            import rclpy

            rclpy.shutdown()
            self._own_init = False
        self._executor = None
        self._pubs.clear()
