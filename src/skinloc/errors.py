"""Exceptions raised by skinloc; every message says what went wrong and what to do."""


class SkinlocError(Exception):
    """Base of every error skinloc raises on purpose."""


class MeshError(SkinlocError, ValueError):
    """A skin mesh is missing, unreadable or unusable."""


class RecordingError(SkinlocError, ValueError):
    """A recording file is missing, truncated, malformed or inconsistent."""


class ModelFileError(SkinlocError, ValueError):
    """A model artifact is missing, malformed or from an unknown format version."""


class MissingExtraError(SkinlocError, ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


class NotFittedError(SkinlocError, ValueError, AttributeError):
    """A localiser was used before ``fit``."""


class SourceNotConnectedError(SkinlocError, ConnectionError):
    """A frame source was read before ``connect`` or after ``disconnect``."""


class SourceAlreadyConnectedError(SkinlocError, ConnectionError):
    """``connect`` was called on a source that is already connected."""


class FrameTimeoutError(SkinlocError, TimeoutError):
    """No frame arrived in time."""


class FrameFormatError(SkinlocError, ValueError):
    """A frame has the wrong size or non-finite values."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a long job; the message says what was kept, and where."""
