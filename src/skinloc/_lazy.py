"""Objects named by a dotted string, imported only when first used.

Registries (sources, sinks, model files) name their backends as ``"package.module:attr"`` so the
registry module has no import edge to them: a backend may import the registry's base classes
without making a circle, and importing the registry never pulls in a backend's dependencies.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["resolve"]


def resolve(target: str) -> Any:
    """The object ``target`` = ``"package.module:attr[.attr]"`` names, importing its module now.

    Examples
    --------
    >>> resolve("pathlib:Path.home").__name__
    'home'
    """
    module, _, attr = target.partition(":")
    obj: Any = importlib.import_module(module)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj
