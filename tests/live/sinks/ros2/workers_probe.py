"""What a ROS 2 user sees of ``skinloc run --workers 2 --sink ros2``, from a real rclpy.

Run by ``test_node.py`` as ``python workers_probe.py NODE[,NODE...] SKIN[,SKIN...] TIMEOUT_S``
with ``ROS_DOMAIN_ID`` set; prints one JSON object: the nodes in the graph, each node's
parameters, the services, the ``/tf_static`` writers, the skins named in ``/diagnostics`` and
a tare answer per skin.
"""

from __future__ import annotations

import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import ListParameters
from rclpy.node import Node
from std_srvs.srv import Trigger


def main() -> None:
    nodes, skins = sys.argv[1].split(","), sys.argv[2].split(",")
    end = time.monotonic() + float(sys.argv[3])
    rclpy.init()
    me = Node("skinloc_workers_probe")
    diag: set = set()
    sub = me.create_subscription(
        DiagnosticArray, "/diagnostics", lambda m: diag.update(s.name for s in m.status), 10
    )

    def spin_until(cond, limit: float = 1e9) -> bool:
        stop = min(end, time.monotonic() + limit)
        while time.monotonic() < stop and not cond():
            rclpy.spin_once(me, timeout_sec=0.1)
        return bool(cond())

    def call(client, request, limit: float = 30.0):
        if not client.wait_for_service(timeout_sec=max(min(limit, end - time.monotonic()), 0.1)):
            return None
        future = client.call_async(request)
        spin_until(future.done, limit)
        return future.result() if future.done() else None

    spin_until(lambda: all((n, "/") in me.get_node_names_and_namespaces() for n in nodes))
    out: dict = {"nodes": sorted(n for n, _ in me.get_node_names_and_namespaces())}
    params: dict = {}
    for n in nodes:
        lister = me.create_client(ListParameters, f"/{n}/list_parameters")
        got: list = []

        def listed(lister=lister, got=got) -> bool:
            r = call(lister, ListParameters.Request(), 10.0)
            got[:] = list(r.result.names) if r is not None else []
            return any(".pipeline." in name for name in got)

        spin_until(listed, 90.0)
        params[n] = sorted({name.split(".")[0] for name in got if ".pipeline." in name})
    out["params"] = params
    out["services"] = sorted(n for n, _ in me.get_service_names_and_types())
    # /tf_static: each worker's publisher writes its skins' transforms (a DDS writer each)
    spin_until(lambda: len(me.get_publishers_info_by_topic("/tf_static")) >= len(nodes), 60.0)
    out["tf_static_publishers"] = len(me.get_publishers_info_by_topic("/tf_static"))
    spin_until(lambda: all(any(s in d for d in diag) for s in skins), 60.0)
    out["diagnostics"] = sorted(diag)
    tares: dict = {}
    for s in skins:
        client = me.create_client(Trigger, f"/skinloc/{s}/tare")

        def answered(client=client, s=s) -> bool:
            r = call(client, Trigger.Request(), 30.0)
            if r is not None:
                tares.setdefault(s, []).append([bool(r.success), r.message])
            return bool(tares.get(s))

        spin_until(answered, 90.0)
    out["tares"] = tares
    me.destroy_subscription(sub)
    me.destroy_node()
    rclpy.shutdown()
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
