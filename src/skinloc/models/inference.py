"""The names of the fast inference path before the engine: kept so that code using them runs.

``FastLocalizer(spec, constraint)`` and ``FastLocalizer.from_model(model)`` build the engine of
a spec, a model or a saved file (``skinloc.models.engine``); ``InferenceSpec`` is ``ModelSpec``
(``InferenceSpec.load(path)``, ``InferenceSpec.from_localizer(model)``). New code imports from
``skinloc.models.engine`` and ``skinloc.geometry.snap``.
"""

from __future__ import annotations

from typing import Any

from skinloc.geometry.snap import SnapIndex, closest_on_triangles
from skinloc.models.engine import Engine
from skinloc.models.engine import ModelSpec as InferenceSpec

__all__ = ["FastLocalizer", "InferenceSpec", "SnapIndex", "closest_on_triangles"]


class FastLocalizer:
    """The engine of a spec: ``FastLocalizer(spec, constraint)`` is ``spec.engine(constraint)``."""

    def __new__(cls, spec: InferenceSpec, constraint: str | None = None) -> Any:
        """``spec.engine(constraint)``: an engine, not a ``FastLocalizer``."""
        return spec.engine(constraint)

    from_model = staticmethod(Engine.from_model)
