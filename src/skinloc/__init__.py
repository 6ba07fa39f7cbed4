"""skinloc: contact localisation on three-dimensional tactile artificial skin.

The names a Python user needs are importable from here, whichever subpackage holds them::

    import skinloc

    rec = skinloc.read_recording("cal.h5")
    model = skinloc.ContactLocalizer.load("model.h5")
    engine = skinloc.load_engine(model)

They load on first use, so ``import skinloc`` stays light: torch, the CLI and plotting load only
in the modules that need them. ``docs/architecture.md`` describes the layout.
"""

from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("skinloc")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

#: Public name -> "module:attr" where it lives (resolved on first access).
_PUBLIC = {
    "ContactLocalizer": "skinloc.models.localizer:ContactLocalizer",
    "Engine": "skinloc.models.engine:Engine",
    "load_engine": "skinloc.models.engine:load_engine",
    "Recording": "skinloc.data.recording:Recording",
    "read_recording": "skinloc.data.recording:read_recording",
    "write_recording": "skinloc.data.recording:write_recording",
    "load_mesh": "skinloc.geometry.mesh:load_mesh",
    "cone_skin": "skinloc.geometry.mesh:cone_skin",
    "train_localizer": "skinloc.evaluation.scoring:train_localizer",
    "evaluate": "skinloc.evaluation.scoring:evaluate",
    "SimulatedSkin": "skinloc.sim.skin:SimulatedSkin",
    "Pipeline": "skinloc.live.runner:Pipeline",
    "Runner": "skinloc.live.runner:Runner",
    "Contact": "skinloc.live.contact:Contact",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str) -> Any:
    target = _PUBLIC.get(name)
    if target is None:
        raise AttributeError(f"module 'skinloc' has no attribute {name!r}")
    from skinloc._lazy import resolve

    obj = resolve(target)
    globals()[name] = obj  # resolve once
    return obj


def __dir__() -> list[str]:
    return sorted(__all__)
