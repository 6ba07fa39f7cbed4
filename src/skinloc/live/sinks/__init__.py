"""Where contacts go: JSON lines, WebSocket, UDP, Foxglove (live and MCAP), LSL and ROS 2.

``make_sink("ws://127.0.0.1:8767")`` builds a sink from a short spec (see ``make_sink``);
backends with optional dependencies are imported only when used.
"""

from skinloc.live.sinks.base import SINK_SPECS, CallbackSink, ListSink, Sink, SkinInfo, make_sink

__all__ = ["SINK_SPECS", "CallbackSink", "ListSink", "Sink", "SkinInfo", "make_sink"]
