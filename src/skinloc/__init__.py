"""skinloc: contact localisation on three-dimensional tactile artificial skin.

The package is light to import: torch, the CLI and plotting load only in the
modules that need them.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("skinloc")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
