"""Objects named by a dotted string, and optional dependencies, imported only when first used.

Registries (sources, sinks, model files) name their backends as ``"package.module:attr"`` so the
registry module has no import edge to them: a backend may import the registry's base classes
without making a circle, and importing the registry never pulls in a backend's dependencies.

Every import of an optional dependency (the ``nets``, ``export`` and ``live`` extras) goes
through ``require_extra``, so a plain install (``pip install skinloc``) that asks for one gets a
``MissingExtraError`` naming the extra to install, which the command line prints as one line.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from skinloc.errors import MissingExtraError

__all__ = ["EXTRAS", "extra_installed", "missing_extra_message", "require_extra", "resolve"]

#: Each optional dependency by its top-level module: (the extra that installs it, its name).
#: ``tests/test_lazy.py`` checks this against pyproject.toml's optional dependencies.
EXTRAS: dict[str, tuple[str, str]] = {
    "torch": ("nets", "PyTorch"),
    "onnx": ("export", "onnx"),
    "onnxruntime": ("export", "onnxruntime"),
    "foxglove": ("live", "foxglove-sdk"),
    "pylsl": ("live", "pylsl"),
    "cyclonedds": ("live", "cyclonedds"),
    "mcap": ("live", "mcap"),
    "distributed": ("cluster", "dask.distributed"),
}


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


def missing_extra_message(module: str, purpose: str, exc: BaseException | None = None) -> str:
    """One line: what needs ``module``, why it is not there, and the extra that installs it.

    Parameters
    ----------
    module : str
        A module of an optional dependency (``"cyclonedds.domain"``); its top-level package
        must be in ``EXTRAS``.
    purpose : str
        What needs it, as the start of a sentence (``"the LSL sink"``).
    exc : BaseException, optional
        Why the import failed; ``None`` or a ``ModuleNotFoundError`` of the package itself
        means it is not installed, anything else that it is installed but does not load.
    """
    top = module.partition(".")[0]
    extra, name = EXTRAS[top]
    absent = exc is None or (
        isinstance(exc, ModuleNotFoundError) and (exc.name or top).partition(".")[0] == top
    )
    if absent:
        return f"{purpose} needs {name}: pip install 'skinloc[{extra}]'"
    why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return f"{purpose} needs {name}, which does not load ({why}): pip install 'skinloc[{extra}]'"


def require_extra(module: str, purpose: str) -> ModuleType:
    """``module`` imported, or a one-line ``MissingExtraError`` naming the extra to install.

    Parameters
    ----------
    module : str
        The module to import (``"pylsl"``, ``"mcap.writer"``); its top-level package must be
        in ``EXTRAS``.
    purpose : str
        What needs it, for the message (``"the LSL sink"``).

    Raises
    ------
    MissingExtraError
        When the import fails: not installed, or installed without its native library
        (``pylsl`` raises ``RuntimeError`` without liblsl, a broken wheel ``OSError``).
    """
    if module.partition(".")[0] not in EXTRAS:
        raise KeyError(f"{module} is not an optional dependency of skinloc (see EXTRAS)")
    try:
        return importlib.import_module(module)
    except (ImportError, OSError, RuntimeError) as exc:
        raise MissingExtraError(missing_extra_message(module, purpose, exc)) from None


def extra_installed(module: str) -> bool:
    """Whether ``module`` (of an optional dependency) imports, for work that can leave it out."""
    try:
        require_extra(module, "")
    except MissingExtraError:
        return False
    return True
