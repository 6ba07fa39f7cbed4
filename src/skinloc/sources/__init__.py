"""Frame sources: anything that yields timestamped sensor images of a known TX x RX grid.

Backends are imported lazily by ``make_source`` so that importing this package never pulls in
pyserial or the simulator's dependencies.
"""

from skinloc.sources.base import Frame, FrameSource, SourceKind, make_source

__all__ = ["Frame", "FrameSource", "SourceKind", "make_source"]
