"""Where contacts go: JSON lines, WebSocket, UDP, Foxglove (live and MCAP), LSL and ROS 2.

``make_sink("ws://127.0.0.1:8767")`` builds a sink from a short spec (see ``make_sink``); a sink
is added by one registration (``register_sink`` or an entry of ``base._BUILTIN``), and backends
with optional dependencies are imported only when used.
"""

from skinloc.live.sinks.base import (
    SINK_SPECS,
    CallbackSink,
    ListSink,
    Sink,
    SinkSpec,
    SinkType,
    SkinInfo,
    make_sink,
    register_sink,
    sink_forms,
    sink_types,
    unregister_sink,
)

__all__ = [
    "SINK_SPECS",
    "CallbackSink",
    "ListSink",
    "Sink",
    "SinkSpec",
    "SinkType",
    "SkinInfo",
    "make_sink",
    "register_sink",
    "sink_forms",
    "sink_types",
    "unregister_sink",
]
