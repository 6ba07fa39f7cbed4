"""What a ROS 2 user sees of a running skinloc node, from a real rclpy in another process.

Run by ``test_node.py`` as ``python rclpy_probe.py SKIN[,SKIN...] TIMEOUT_S`` with
``ROS_DOMAIN_ID`` set; prints one JSON object of findings on stdout. Each check waits (bounded
by TIMEOUT_S overall) until it is answered; nothing here asserts: the test does.
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, PoseArray
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray


def main() -> None:
    skins = sys.argv[1].split(",")
    end = time.monotonic() + float(sys.argv[2])
    rclpy.init()
    me = Node("skinloc_probe")
    out: dict = {"skins": {}}

    def spin_until(cond, limit: float | None = None) -> bool:
        stop = end if limit is None else min(end, time.monotonic() + limit)
        while time.monotonic() < stop:
            if cond():
                return True
            rclpy.spin_once(me, timeout_sec=0.1)
        return bool(cond())

    def call(client, request, limit: float = 30.0):
        if not client.wait_for_service(timeout_sec=max(min(limit, end - time.monotonic()), 0.1)):
            return None
        future = client.call_async(request)
        spin_until(future.done, limit)
        return future.result() if future.done() else None

    # -------------------------------------------------------------- graph
    spin_until(lambda: ("skinloc", "/") in me.get_node_names_and_namespaces())
    out["nodes"] = sorted(f"{ns.rstrip('/')}/{n}" for n, ns in me.get_node_names_and_namespaces())
    # our own subscriptions: rclpy computes the type hash of its types for them
    got: dict[str, list] = {}
    diag: list = []
    latched = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    topics = {}
    for s in skins:
        topics[f"/skinloc/{s}/contacts"] = PoseArray
        topics[f"/skinloc/{s}/contact"] = PointStamped
        topics[f"/skinloc/{s}/markers"] = MarkerArray
    subs = [
        me.create_subscription(t, name, lambda m, n=name: got.setdefault(n, []).append(m), 10)
        for name, t in topics.items()
    ]
    for s in skins:
        name = f"/skinloc/{s}/mesh"
        subs.append(
            me.create_subscription(
                Marker, name, lambda m, n=name: got.setdefault(n, []).append(m), latched
            )
        )
        topics[name] = Marker
    subs.append(me.create_subscription(DiagnosticArray, "/diagnostics", diag.append, 10))
    topics["/diagnostics"] = DiagnosticArray

    def publishers_seen() -> bool:
        return all(me.get_publishers_info_by_topic(t) for t in topics)

    spin_until(publishers_seen)
    hashes = {}
    for t in topics:
        pubs = me.get_publishers_info_by_topic(t)
        mine = [i for i in me.get_subscriptions_info_by_topic(t) if i.node_name == "skinloc_probe"]
        hashes[t] = {
            "publishers": sorted(i.node_name for i in pubs),
            "equal": bool(pubs and mine)
            and all(str(i.topic_type_hash) == str(mine[0].topic_type_hash) for i in pubs),
        }
    out["topics"] = hashes
    # /tf_static comes from a DDS participant beside the node: discovered on its own time
    spin_until(lambda: "/tf_static" in dict(me.get_topic_names_and_types()), 60.0)
    graph = dict(me.get_topic_names_and_types())
    out["tf_static"] = {
        "types": graph.get("/tf_static", []),
        "publishers": len(me.get_publishers_info_by_topic("/tf_static")),
    }
    out["services"] = sorted(n for n, _ in me.get_service_names_and_types())

    # -------------------------------------------------------------- contacts, diagnostics
    def contacts_of(s: str) -> int:
        return sum(1 for m in got.get(f"/skinloc/{s}/contacts", []) if m.poses)

    spin_until(lambda: all(contacts_of(s) for s in skins), 60.0)

    def diag_names() -> set:
        return {st.name for a in diag for st in a.status}

    spin_until(lambda: all(any(s in n for n in diag_names()) for s in skins), 30.0)
    out["diagnostics"] = [
        {
            "name": st.name,
            "hardware_id": st.hardware_id,
            "level": st.level[0] if isinstance(st.level, bytes) else int(st.level),
            "message": st.message,
            "values": {kv.key: kv.value for kv in st.values},
        }
        for st in (diag[-1].status if diag else [])
    ]

    # -------------------------------------------------------------- parameters
    lister = me.create_client(ListParameters, "/skinloc/list_parameters")
    getter = me.create_client(GetParameters, "/skinloc/get_parameters")
    setter = me.create_client(SetParameters, "/skinloc/set_parameters")
    s0 = skins[0]
    spin_until(lambda: False, 0.5)  # the settings reach the node with its first sweep
    names: list = []

    def listed() -> bool:
        r = call(lister, ListParameters.Request(), 10.0)
        names[:] = list(r.result.names) if r is not None else []
        return f"{s0}.pipeline.touch_on_z" in names

    spin_until(listed, 60.0)
    out["param_names"] = sorted(names)

    def get(name: str):
        r = call(getter, GetParameters.Request(names=[name]))
        return r.values[0].double_value if r is not None and r.values else None

    def set_double(name: str, value: float):
        p = Parameter(
            name=name,
            value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value),
        )
        r = call(setter, SetParameters.Request(parameters=[p]))
        return None if r is None else (r.results[0].successful, r.results[0].reason)

    out["param_get"] = get(f"{s0}.pipeline.touch_on_z")
    out["param_set_good"] = set_double(f"{s0}.pipeline.touch_on_z", 9.0)
    out["param_after_good"] = get(f"{s0}.pipeline.touch_on_z")
    out["param_set_bad"] = set_double(f"{s0}.pipeline.touch_off_z", 50.0)  # above touch_on_z
    out["param_after_bad"] = get(f"{s0}.pipeline.touch_off_z")

    # -------------------------------------------------------------- tare
    tare = me.create_client(Trigger, f"/skinloc/{s0}/tare")
    answers: list = []

    def tared() -> bool:
        # the scripted finger touches for 0.6-1.5 s, then lifts for as long: both come
        r = call(tare, Trigger.Request(), 30.0)
        if r is not None:
            answers.append((r.success, r.message))
        spin_until(lambda: False, 0.05)
        return any(a[0] for a in answers) and any("touched" in a[1] for a in answers)

    spin_until(tared)
    out["tare_ok"] = [a for a in answers if a[0]][:2]
    out["tare_refused"] = [a for a in answers if not a[0]][:4]
    for sub in subs:
        me.destroy_subscription(sub)
    me.destroy_node()
    rclpy.shutdown()
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
