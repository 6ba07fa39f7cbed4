"""The app's state and actions (``Workspace``), one module per concern; see ``core``."""

from skinloc.app.workspace.core import Workspace
from skinloc.app.workspace.state import AppConfig, BusyError, Mode

__all__ = ["AppConfig", "BusyError", "Mode", "Workspace"]
