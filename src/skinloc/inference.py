"""The names of the fast inference path before the engine: kept so that code using them runs.

``FastLocalizer`` is ``skinloc.engine.Engine`` (``FastLocalizer.from_model(model)`` builds the
engine of a model, a spec or a saved file) and ``InferenceSpec`` is ``ModelSpec``
(``InferenceSpec.load(path)``, ``InferenceSpec.from_localizer(model)``). New code imports from
``skinloc.engine`` and ``skinloc.surface``.
"""

from __future__ import annotations

from skinloc.engine import Engine as FastLocalizer
from skinloc.engine import ModelSpec as InferenceSpec
from skinloc.surface import SnapIndex, closest_on_triangles

__all__ = ["FastLocalizer", "InferenceSpec", "SnapIndex", "closest_on_triangles"]
