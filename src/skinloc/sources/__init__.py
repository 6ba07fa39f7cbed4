"""Frame sources: anything that yields timestamped sensor images of a known TX x RX grid.

``SourceOptions`` names one, ``make_source`` builds it. Backends are imported lazily, so that
importing this package never pulls in pyserial or the simulator's dependencies.
"""

from skinloc.sources.base import Frame, FrameSource, SourceKind, SourceOptions, make_source

__all__ = ["Frame", "FrameSource", "SourceKind", "SourceOptions", "make_source"]
