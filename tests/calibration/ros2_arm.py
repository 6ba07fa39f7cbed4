"""A stand-in robot arm for ``Ros2Probe``, with the real rclpy, run in another process.

``python ros2_arm.py LOG MODE TIMEOUT_S [PORT]`` with ``ROS_DOMAIN_ID`` set. It follows the
contract of ``skinloc.calibration.probe_ros2`` under ``/skinloc/probe``: ``above`` to an
approach, the tip pose (the press pose plus ``TIP_OFFSET_M``, the arm's "measurement") then
``pressed`` to a press, ``lifted`` to a lift, ``stopped`` to a stop.

MODE ``ok`` answers everything; ``mute`` never answers a press (a lost arm); ``refuse`` answers
a press with ``error: joint limit``; ``overforce`` measures twice the force goal of a press to
a force; ``noforce`` sends no measured force; ``lose-first-answer`` does not answer its first
approach (an answer lost while discovery is under way: skinloc sends the approach again);
``skin`` answers everything and presses the virtual skin of PORT (``skinloc virtual-skin``) at
the measured tip (``touch x y z``, the base frame taken as the mesh frame), lifting its finger
on a lift or a stop.

A force goal on ``press_force`` is answered ``armed`` and kept for the next press only, which
stops ``FORCE_SHORT_M`` short of the press pose (where it "reaches the force") and sends the
goal's size as the measured force on ``force`` before ``pressed``. Every message it hears goes,
as it comes, to LOG (one JSON line each; an approach sent again with its stamp unchanged,
once); it prints ``ready`` once its node is up and exits after TIMEOUT_S or on SIGTERM/SIGINT.
Nothing here asserts.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Empty, String

TIP_OFFSET_M = (0.0003, -0.0002, 0.0001)
FORCE_SHORT_M = 0.001


def main() -> None:
    log_path, mode, timeout_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
    finger = os.open(sys.argv[4], os.O_WRONLY | os.O_NOCTTY) if mode == "skin" else None

    def touch(line: str) -> None:
        if finger is not None:
            os.write(finger, line.encode() + b"\n")

    rclpy.init()
    node = Node("stand_in_arm")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    p = "/skinloc/probe"
    state = node.create_publisher(String, f"{p}/state", qos)
    tip = node.create_publisher(PoseStamped, f"{p}/tip", qos)
    force = node.create_publisher(WrenchStamped, f"{p}/force", qos)
    goal: list = []  # the force goal of the next press, N (base frame), if any
    log = open(log_path, "a", encoding="utf-8")  # noqa: SIM115 - open for the whole run

    def note(kind: str, msg=None) -> None:
        row: dict = {"kind": kind}
        if isinstance(msg, WrenchStamped):
            f = msg.wrench.force
            row.update(frame=msg.header.frame_id, force=[f.x, f.y, f.z])
        elif msg is not None:
            pos, o = msg.pose.position, msg.pose.orientation
            row.update(
                frame=msg.header.frame_id,
                position=[pos.x, pos.y, pos.z],
                orientation=[o.x, o.y, o.z, o.w],
            )
        log.write(json.dumps(row) + "\n")
        log.flush()

    def say(word: str) -> None:
        state.publish(String(data=word))

    heard_approach: list = []  # the stamp of the last approach heard

    def on_approach(msg) -> None:
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        if heard_approach != [stamp]:  # the same stamp again: the same goal, sent again
            note("approach", msg)
        first = not heard_approach
        heard_approach[:] = [stamp]
        if mode == "lose-first-answer" and first:
            return  # as an answer published before this node matched skinloc's subscriber
        say("above")

    def on_press_force(msg) -> None:
        note("press_force", msg)
        f = msg.wrench.force
        goal[:] = [(f.x, f.y, f.z)]
        say("armed")

    def on_press(msg) -> None:
        note("press", msg)
        if mode == "mute":
            return
        if mode == "refuse":
            say("error: joint limit")
            return
        out = PoseStamped()
        out.header.frame_id = msg.header.frame_id
        out.header.stamp = node.get_clock().now().to_msg()
        out.pose = msg.pose
        short = [0.0, 0.0, 0.0]
        if goal:  # to a force: it is reached FORCE_SHORT_M before the press pose
            g = goal[0]
            size = sum(v * v for v in g) ** 0.5
            short = [-FORCE_SHORT_M * v / size for v in g]
        out.pose.position.x += TIP_OFFSET_M[0] + short[0]
        out.pose.position.y += TIP_OFFSET_M[1] + short[1]
        out.pose.position.z += TIP_OFFSET_M[2] + short[2]
        tip.publish(out)
        if goal and mode != "noforce":
            felt = WrenchStamped()
            felt.header = out.header
            scale = 2.0 if mode == "overforce" else 1.0
            felt.wrench.force.x, felt.wrench.force.y, felt.wrench.force.z = (
                scale * v for v in goal[0]
            )
            force.publish(felt)
        goal.clear()
        q = out.pose.position
        touch(f"touch {q.x:.6f} {q.y:.6f} {q.z:.6f}")
        say("pressed")

    def on_lift(msg) -> None:
        note("lift", msg)
        touch("lift")
        say("lifted")

    def on_stop(_msg) -> None:
        note("stop")
        touch("lift")
        say("stopped")

    subs = [  # noqa: F841 - kept alive for the run
        node.create_subscription(PoseStamped, f"{p}/approach", on_approach, qos),
        node.create_subscription(PoseStamped, f"{p}/press", on_press, qos),
        node.create_subscription(WrenchStamped, f"{p}/press_force", on_press_force, qos),
        node.create_subscription(PoseStamped, f"{p}/lift", on_lift, qos),
        node.create_subscription(Empty, f"{p}/stop", on_stop, qos),
    ]
    running = [True]

    def end(*_args) -> None:
        running[0] = False

    signal.signal(signal.SIGTERM, end)
    signal.signal(signal.SIGINT, end)
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    stop_at = time.monotonic() + timeout_s
    while running[0] and time.monotonic() < stop_at:
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.try_shutdown()
    log.close()
    if finger is not None:
        os.close(finger)


if __name__ == "__main__":
    main()
