"""What the rclpy node of the ROS 2 publisher serves: parameters, services and diagnostics.

Runs in the publisher process (``skinloc.live.sinks.ros2.publisher``) beside the topics, on a
thread of its own spinning the node (``rclpy`` callbacks), while the publisher's main thread
reads the records of the pipeline's process. The skins live in that other process, so every
parameter set and service call becomes a request there (a JSON line on the publisher's answer
pipe, which the sink reads between frames and applies through ``skinloc.live.control``) and
waits, bounded, for its answer (a ``CONTROL`` record). Per skin ``S`` (``ros_name`` spelling):

* parameters ``S.<key>`` and ``S.gestures.<key>`` (``skinloc.live.sinks.ros2.params``);
* services ``/skinloc/S/tare`` and ``/skinloc/S/reset_tracks`` (``std_srvs/srv/Trigger``);
* one ``diagnostic_msgs/DiagnosticStatus`` in every ``/diagnostics`` array (about 1 Hz).
"""

from __future__ import annotations

import itertools
import logging
import threading
from collections.abc import Callable
from typing import Any

from skinloc.live.sinks.ros2.params import param_specs, skin_key
from skinloc.ros2.names import topic_base

log = logging.getLogger(__name__)

__all__ = ["NodeServices"]

#: how long a parameter set waits for the skin's process, s
SET_TIMEOUT_S = 5.0
#: how long a tare waits (its capture is ``baseline_frames`` frames: 0.5 s at 100 Hz)
TARE_TIMEOUT_S = 20.0


class NodeServices:
    """Parameters, services and ``/diagnostics`` of the skins on an rclpy node.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (its parameter services are rclpy's own).
    ask : callable(dict)
        Sends a request to the skins' process (the publisher's answer pipe).
    """

    def __init__(self, node: Any, ask: Callable[[dict[str, Any]], None]) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile

        self.node = node
        self._ask = ask
        self._ids = itertools.count(1)
        self._waiting: dict[int, tuple[threading.Event, list[dict[str, Any]]]] = {}
        self._lock = threading.Lock()
        self._declaring = False
        self._skins: set[str] = set()
        self._services: list[Any] = []
        self._diag = node.create_publisher(DiagnosticArray, "/diagnostics", QoSProfile(depth=10))
        node.add_on_set_parameters_callback(self._on_set)
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, name="skinloc-ros2-node", daemon=True)
        self._rclpy = rclpy
        self._thread.start()

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - the context was shut down: the node is closing
            log.debug("the node's executor ended", exc_info=True)

    # ------------------------------------------------------------------ requests
    def _request(self, op: str, skin: str, timeout_s: float, **fields: Any) -> dict[str, Any]:
        """Send a request to the skins' process and wait (bounded) for its answer."""
        rid = next(self._ids)
        event, box = threading.Event(), []
        with self._lock:
            self._waiting[rid] = (event, box)
        try:
            self._ask({"request": rid, "op": op, "skin": skin, **fields})
            if not event.wait(timeout_s):
                return {"ok": False, "message": f"skinloc did not answer within {timeout_s:.0f} s"}
            return box[0]
        finally:
            with self._lock:
                self._waiting.pop(rid, None)

    def control(self, message: dict[str, Any]) -> None:
        """A ``CONTROL`` message from the skins' process (the publisher's main thread)."""
        if "answer" in message:
            with self._lock:
                waiting = self._waiting.get(message["answer"])
            if waiting is not None:
                waiting[1].append(message)
                waiting[0].set()
        elif "settings" in message:
            for skin, values in message["settings"].items():
                self._add_skin(skin, values)
        elif "diagnostics" in message:
            self._publish_diagnostics(message["diagnostics"])

    # ------------------------------------------------------------------ parameters
    def _add_skin(self, skin: str, values: dict[str, Any]) -> None:
        from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
        from std_srvs.srv import Trigger

        key = skin_key(skin)
        if key in self._skins:
            return
        self._skins.add(key)
        declared = []
        for spec in param_specs():
            d = ParameterDescriptor(description=spec.description, read_only=spec.read_only)
            if spec.kind == "float":
                d.floating_point_range = [
                    FloatingPointRange(from_value=spec.low, to_value=spec.high, step=0.0)
                ]
            elif spec.kind == "int":
                d.integer_range = [
                    IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)
                ]
            if spec.choices:
                d.additional_constraints = "one of: " + ", ".join(spec.choices)
            value = values.get(spec.key, spec.default)
            if spec.kind == "float":  # a skins file's 8 for 8.0: the parameter is a double
                value = float(value)
            declared.append((f"{key}.{spec.key}", value, d))
        self._declaring = True
        try:
            self.node.declare_parameters("", declared)
        finally:
            self._declaring = False
        base = topic_base(skin)
        for op in ("tare", "reset_tracks"):
            self._services.append(
                self.node.create_service(Trigger, f"{base}/{op}", self._trigger(op, key))
            )

    def _on_set(self, params: list[Any]) -> Any:
        """Every parameter set: a request per skin; refused with the skin's reason."""
        from rcl_interfaces.msg import SetParametersResult

        if self._declaring:
            return SetParametersResult(successful=True)
        by_skin: dict[str, dict[str, Any]] = {}
        for p in params:
            skin, _, key = p.name.partition(".")
            if skin not in self._skins or not key:
                return SetParametersResult(successful=False, reason=f"unknown parameter {p.name}")
            by_skin.setdefault(skin, {})[key] = p.value
        for skin, values in by_skin.items():
            answer = self._request("set", skin, SET_TIMEOUT_S, values=values)
            if not answer.get("ok"):
                return SetParametersResult(successful=False, reason=str(answer.get("message")))
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ services
    def _trigger(self, op: str, skin: str) -> Callable[[Any, Any], Any]:
        def call(request: Any, response: Any) -> Any:
            answer = self._request(op, skin, TARE_TIMEOUT_S)
            response.success = bool(answer.get("ok"))
            response.message = str(answer.get("message", ""))
            return response

        return call

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self, statuses: list[dict[str, Any]]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        for s in statuses:
            msg.status.append(
                DiagnosticStatus(
                    level=bytes([int(s["level"])]),
                    name=str(s["name"]),
                    message=str(s["message"]),
                    hardware_id=str(s["hardware_id"]),
                    values=[KeyValue(key=k, value=str(v)) for k, v in s["values"].items()],
                )
            )
        self._diag.publish(msg)

    def close(self) -> None:
        """Stop spinning (the node is destroyed by its owner)."""
        for waiting in list(self._waiting.values()):
            waiting[1].append({"ok": False, "message": "skinloc is stopping"})
            waiting[0].set()
        self._executor.shutdown(timeout_sec=2.0)
        self._thread.join(2.0)
