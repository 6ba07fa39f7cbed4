"""Whether a skin's contacts keep coming after its faults, seen from a real rclpy.

Run by ``test_node.py`` as ``python faults_probe.py SKIN TIMEOUT_S`` with ``ROS_DOMAIN_ID``
set, beside ``faulty_run.py``: waits until ``/diagnostics`` shows the skin's frame error and
its failing sink, then counts the contacts that arrive after that; prints one JSON object.
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from rclpy.node import Node


def main() -> None:
    skin, end = sys.argv[1], time.monotonic() + float(sys.argv[2])
    rclpy.init()
    me = Node("skinloc_faults_probe")
    contacts: list[int] = [0]
    status: dict = {}

    def on_contacts(msg: PoseArray) -> None:
        if msg.poses:
            contacts[0] += 1

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if skin in st.name:
                status.clear()
                status.update(
                    name=st.name,
                    level=st.level[0] if isinstance(st.level, bytes) else int(st.level),
                    message=st.message,
                    values={kv.key: kv.value for kv in st.values},
                )

    subs = [
        me.create_subscription(PoseArray, f"/skinloc/{skin}/contacts", on_contacts, 100),
        me.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10),
    ]

    def spin_until(cond) -> bool:
        while time.monotonic() < end and not cond():
            rclpy.spin_once(me, timeout_sec=0.1)
        return bool(cond())

    def both_seen() -> bool:
        v = status.get("values", {})
        return int(v.get("errors", 0)) >= 1 and int(v.get("sink_errors", 0)) >= 1

    out: dict = {"faults_seen": spin_until(both_seen), "first_status": dict(status)}
    before = contacts[0]
    spin_until(lambda: contacts[0] - before >= 10)
    out["contacts_before"] = before
    out["contacts_after"] = contacts[0] - before
    out["last_status"] = dict(status)
    for sub in subs:
        me.destroy_subscription(sub)
    me.destroy_node()
    rclpy.shutdown()
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
