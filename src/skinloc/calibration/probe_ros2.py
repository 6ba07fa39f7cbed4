"""A robot's probe over ROS 2: ``Ros2Probe`` drives an arm through standard messages (rclpy).

The contract (docs/hardware.md, 4c), every topic under ``prefix`` (``/skinloc/probe``), all
reliable, volatile, depth 10; every pose is a ``geometry_msgs/msg/PoseStamped`` of the tool's
tip in the robot's base frame (``header.frame_id``: the skin's ``parent_frame`` from the skins
file), its orientation turning the tool's +z onto the press direction (into the skin, along
the surface's inward normal):

==========================  =========  ==================================================
topic                       skinloc    the arm
==========================  =========  ==================================================
``approach``  PoseStamped   publishes  moves the tip to the pose, clear of the skin (any
                                       collision-free path), then says ``above``
``press``     PoseStamped   publishes  moves the tip in a straight line along its +z from
                                       the approach pose to this pose (the target, the
                                       press depth past the surface), holds, publishes the
                                       measured tip on ``tip``, then says ``pressed``
``lift``      PoseStamped   publishes  straight back out along -z to this pose (the
                                       approach pose), then says ``lifted``
``stop``      std_msgs/Empty publishes halts now, backs off the skin, says ``stopped``;
                                       may come at any time, any number of times
``press_force`` WrenchStamped publishes  before a press to a force: the goal (``force``:
                                       the force the tip exerts on the skin, base frame,
                                       N, along the press direction); the arm keeps it
                                       for the next ``press`` only and says ``armed``
``tip``       PoseStamped   reads      where the tip really is at the bottom of the press
                                       (forward kinematics or tf of the tool frame)
``force``     WrenchStamped reads      after a press to a force: the force measured at
                                       the bottom of the press (before ``pressed``)
``state``     std_msgs/String reads    ``above``, ``armed``, ``pressed``, ``lifted``,
                                       ``stopped``, or ``error: <why>`` (skinloc stops
                                       the session)
==========================  =========  ==================================================

A press to a force is ``press_force`` (answered ``armed``), then ``press`` with the pose
``max_depth_m`` past the surface: the arm presses along its +z until the force reaches the
goal and never past that pose, then sends ``tip``, ``force`` and ``pressed``. A goal over
``max_force_n`` is refused before anything is published; a measured force over it stops the
session (``ProbeSafetyError``).

A MoveIt user wires ``approach`` to a planned move (``MoveGroupInterface.setPoseTarget``),
``press``/``lift`` to a Cartesian path (``computeCartesianPath``) and ``stop`` to the
controller's stop; ``tip`` is the tool frame from tf. skinloc waits for each answer at most
``timeout_s``; no answer is a lost arm (``ProbeLinkError``), on which the session stops the
probe (publishes ``stop``) and ends with a one-line error.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from skinloc.calibration.probe import (
    PressReport,
    ProbeError,
    ProbeLinkError,
    ProbeSafetyError,
    check_depth,
)

__all__ = ["DEFAULT_PREFIX", "STATES", "Ros2Probe", "tool_orientation"]

#: Topic prefix of the probe's contract.
DEFAULT_PREFIX = "/skinloc/probe"
#: The words the arm says on ``state`` (besides ``error: <why>``).
STATES = ("above", "armed", "pressed", "lifted", "stopped")
#: How long ``stop`` waits for the arm's ``stopped``, s (it never raises).
STOP_WAIT_S = 2.0
#: An unanswered approach is published again (the same message, its stamp unchanged) this
#: often, s: the arm's answer is lost when its publisher has not yet matched this node's
#: subscriber (discovery is still under way on a busy machine), and an approach is a pose
#: goal, so the same one again moves the arm nowhere new.
APPROACH_RESEND_S = 2.0

_INSTALL = "pip install 'skinloc[ros2]'"


def tool_orientation(press_direction: np.ndarray) -> tuple[float, float, float, float]:
    """Quaternion ``x, y, z, w`` turning the tool's +z onto ``press_direction (3,)``.

    The turn is the shortest one (no spin about the tool's axis is implied: the arm may
    choose it).
    """
    from scipy.spatial.transform import Rotation

    d = np.asarray(press_direction, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(d))
    if not (math.isfinite(n) and n > 0):
        raise ValueError(f"press_direction must be a non-zero vector, got {press_direction!r}")
    d = d / n
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ d)
    if c < -1 + 1e-12:  # straight down the -z: half a turn about x
        return (1.0, 0.0, 0.0, 0.0)
    axis = np.cross(z, d)
    s = math.sqrt(2.0 * (1.0 + c))
    q = Rotation.from_quat([*(axis / s), s / 2.0]).as_quat()
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


class Ros2Probe:
    """A ``Probe`` over ROS 2 topics (see the module for the contract), with the real rclpy.

    Parameters
    ----------
    frame_id : str
        The robot's base frame the poses are in (the skin's ``parent_frame``).
    prefix : str
        Topic prefix of the contract.
    timeout_s : float
        Longest wait for the arm's answer to a move, press or lift, s.
    connect_timeout_s : float
        Longest wait for the arm to appear (subscribed to ``approach``, publishing ``state``), s.
    max_depth_m : float
        Deepest press sent, m: a deeper one raises ``ProbeSafetyError`` before anything moves.
        A press to a force goes no deeper either (its press pose is this depth).
    max_force_n : float
        Strongest press to a force sent, N (``ProbeSafetyError`` before anything moves); a
        measured force over it raises ``ProbeSafetyError`` after the press.

    Raises
    ------
    ProbeError
        rclpy is not installed (the message names ``pip install 'skinloc[ros2]'``).
    ProbeLinkError
        No arm appeared within ``connect_timeout_s``.
    """

    def __init__(
        self,
        frame_id: str = "base_link",
        *,
        prefix: str = DEFAULT_PREFIX,
        timeout_s: float = 30.0,
        connect_timeout_s: float = 10.0,
        max_depth_m: float = 0.005,
        max_force_n: float = 10.0,
    ) -> None:
        for name, v in (
            ("timeout_s", timeout_s),
            ("connect_timeout_s", connect_timeout_s),
            ("max_depth_m", max_depth_m),
            ("max_force_n", max_force_n),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")
        try:
            import rclpy
            from geometry_msgs.msg import PoseStamped, WrenchStamped
            from rclpy.executors import SingleThreadedExecutor
            from rclpy.qos import QoSProfile, ReliabilityPolicy
            from std_msgs.msg import Empty, String
        except ImportError as exc:
            raise ProbeError(f"--probe ros2 needs rclpy ({exc}): {_INSTALL}") from None
        self.frame_id, self.prefix = frame_id, prefix.rstrip("/")
        self.timeout_s, self.max_depth_m = float(timeout_s), float(max_depth_m)
        self.max_force_n = float(max_force_n)
        self._PoseStamped, self._Empty, self._WrenchStamped = PoseStamped, Empty, WrenchStamped
        self._cond = threading.Condition()
        self._states: list[str] = []  # every word heard since the last command
        self._tip: Any = None  # the last tip pose heard since the last press
        self._force: Any = None  # the last measured force heard since the last press
        self._above: Any = None  # the last approach pose sent (the lift goes back there)
        self._closed = False
        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        try:
            self.node = rclpy.create_node("skinloc_probe", context=self._context)
            qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
            p = self.prefix
            self._pub = {
                name: self.node.create_publisher(PoseStamped, f"{p}/{name}", qos)
                for name in ("approach", "press", "lift")
            }
            self._stop_pub = self.node.create_publisher(Empty, f"{p}/stop", qos)
            self._force_pub = self.node.create_publisher(WrenchStamped, f"{p}/press_force", qos)
            self._subs = [
                self.node.create_subscription(String, f"{p}/state", self._on_state, qos),
                self.node.create_subscription(PoseStamped, f"{p}/tip", self._on_tip, qos),
                self.node.create_subscription(WrenchStamped, f"{p}/force", self._on_force, qos),
            ]
            self._executor = SingleThreadedExecutor(context=self._context)
            self._executor.add_node(self.node)
            self._thread = threading.Thread(
                target=self._spin, name="skinloc-ros2-probe", daemon=True
            )
            self._thread.start()
            self._wait_for_arm(float(connect_timeout_s))
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ rclpy side
    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - the context was shut down: the probe is closing
            pass

    def _on_state(self, msg: Any) -> None:
        with self._cond:
            self._states.append(str(msg.data).strip())
            self._cond.notify_all()

    def _on_tip(self, msg: Any) -> None:
        with self._cond:
            self._tip = msg
            self._cond.notify_all()

    def _on_force(self, msg: Any) -> None:
        with self._cond:
            self._force = msg
            self._cond.notify_all()

    def _wait_for_arm(self, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        topics = (f"{self.prefix}/approach", f"{self.prefix}/state")
        while time.monotonic() < end:
            if all(p.get_subscription_count() for p in self._pub.values()) and (
                self.node.count_publishers(topics[1])
            ):
                return
            time.sleep(0.05)
        raise ProbeLinkError(
            f"no arm answers on {self.prefix} (nothing subscribed to {topics[0]} or publishing "
            f"{topics[1]} within {timeout_s:g} s): start the arm's node, same ROS_DOMAIN_ID"
        )

    # ------------------------------------------------------------------ messages
    def _pose(self, point_m: np.ndarray, press_direction: np.ndarray) -> Any:
        msg = self._PoseStamped()
        msg.header.frame_id = self.frame_id
        msg.header.stamp = self.node.get_clock().now().to_msg()
        p = np.asarray(point_m, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"pose position must be 3 finite numbers, got {point_m!r}")
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in p)
        q = tool_orientation(press_direction)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = q
        return msg

    def _send(self, topic: str, msg: Any, want: str) -> None:
        """Publish ``msg`` on ``topic`` and wait for the arm's ``want`` (or its error)."""
        if self._closed:
            raise ProbeError("the ROS 2 probe is closed")
        with self._cond:
            self._states.clear()
            if topic == "press":
                self._tip = self._force = None
        pub = self._force_pub if topic == "press_force" else self._pub[topic]
        pub.publish(msg)
        sent = time.monotonic()
        end = sent + self.timeout_s
        resend_at = sent + APPROACH_RESEND_S if topic == "approach" else math.inf
        with self._cond:
            while True:
                for s in self._states:
                    if s == want:
                        return
                    if s.startswith("error") or s == "stopped":
                        why = s.partition(":")[2].strip() or s
                        raise ProbeError(f"the arm refused the {topic} on {self.prefix}: {why}")
                now = time.monotonic()
                left = end - now
                if left <= 0:
                    raise ProbeLinkError(
                        f"the arm did not say '{want}' on {self.prefix}/state within "
                        f"{self.timeout_s:g} s of the {topic} (lost link?)"
                    )
                if now >= resend_at:
                    pub.publish(msg)
                    resend_at = now + APPROACH_RESEND_S
                self._cond.wait(min(left, 0.2))

    # ------------------------------------------------------------------ Probe
    def move_above(self, approach_m: np.ndarray, press_direction: np.ndarray) -> None:
        """Publish the approach pose (base frame, m) and wait for ``above``."""
        msg = self._pose(approach_m, press_direction)
        self._send("approach", msg, "above")
        self._above = msg

    def press(
        self,
        target_m: np.ndarray,
        press_direction: np.ndarray,
        depth_m: float | None = None,
        force_n: float | None = None,
    ) -> PressReport:
        """Press at ``target_m (3,)`` m along the direction, to ``depth_m`` or ``force_n``.

        To a depth: the press pose ``depth_m`` past the target. To a force: the goal on
        ``press_force`` first (answered ``armed``), then the press pose ``max_depth_m`` past
        the target, the deepest the arm may go. Waits for ``pressed``; the report's tip is the
        arm's ``tip`` pose (base frame, m); to a force, its force is the arm's measured one and
        its depth the measured tip's along the direction.
        """
        if (depth_m is None) == (force_n is None):
            raise ValueError("give the press as depth_m or force_n, one of them")
        if depth_m is not None:
            check_depth(depth_m, self.max_depth_m)
        elif not (math.isfinite(force_n) and 0 < force_n <= self.max_force_n):
            raise ProbeSafetyError(
                f"press force {force_n:g} N is beyond the probe's limit of {self.max_force_n:g} N"
            )
        if self._above is None:
            raise ProbeError("move above the target before pressing")
        d = np.asarray(press_direction, dtype=np.float64).reshape(3)
        d = d / np.linalg.norm(d)
        target = np.asarray(target_m, dtype=np.float64).reshape(3)
        pose = self._pose(target + (self.max_depth_m if depth_m is None else depth_m) * d, d)
        if force_n is not None:
            goal = self._WrenchStamped()
            goal.header = pose.header  # the same stamp: the goal of this press
            f = goal.wrench.force
            f.x, f.y, f.z = (float(v) for v in force_n * d)
            self._send("press_force", goal, "armed")
        self._send("press", pose, "pressed")
        tip = self._answer("_tip", "pose", "tip")
        p = tip.pose.position
        tip_m = np.array([p.x, p.y, p.z], dtype=np.float64)
        if depth_m is not None:
            return PressReport(tip_m=tip_m, depth_m=depth_m)
        measured = self._answer("_force", "force", "force").wrench.force
        felt = float(np.linalg.norm([measured.x, measured.y, measured.z]))
        if not (math.isfinite(felt) and felt <= self.max_force_n):
            raise ProbeSafetyError(
                f"the arm measured {felt:.3g} N on {self.prefix}/force, over the limit of "
                f"{self.max_force_n:g} N"
            )
        return PressReport(tip_m=tip_m, depth_m=float((tip_m - target) @ d), force_n=felt)

    def _answer(self, attr: str, what: str, topic: str) -> Any:
        """The arm's message on ``topic`` for this press (it may lag 'pressed' a little)."""
        with self._cond:
            self._cond.wait_for(lambda: getattr(self, attr) is not None, timeout=1.0)
            msg = getattr(self, attr)
        if msg is None:
            raise ProbeError(f"the arm said 'pressed' but sent no {what} on {self.prefix}/{topic}")
        if msg.header.frame_id and msg.header.frame_id != self.frame_id:
            raise ProbeError(
                f"the arm's {topic} is in frame {msg.header.frame_id!r}, not the base frame "
                f"{self.frame_id!r}"
            )
        return msg

    def lift(self) -> None:
        """Publish the lift pose (the approach pose again) and wait for ``lifted``."""
        if self._above is None:
            raise ProbeError("nothing to lift from")
        self._above.header.stamp = self.node.get_clock().now().to_msg()
        self._send("lift", self._above, "lifted")

    def stop(self) -> None:
        """Publish ``stop`` and wait briefly for ``stopped``; never raises."""
        if self._closed:
            return
        try:
            with self._cond:
                self._states.clear()
            self._stop_pub.publish(self._Empty())
            with self._cond:
                self._cond.wait_for(lambda: "stopped" in self._states, timeout=STOP_WAIT_S)
        except Exception:  # noqa: BLE001 - a safety stop is best effort on a broken link
            pass

    def close(self) -> None:
        """Shut the node and its rclpy context down (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._context.try_shutdown()
        finally:
            thread = getattr(self, "_thread", None)
            if thread is not None:
                thread.join(timeout=5.0)
            node = getattr(self, "node", None)
            if node is not None:
                node.destroy_node()
