"""Model kinds: what a kind of model must provide, and the one registry of kinds.

A ``ContactLocalizer`` is fitted, saved, loaded, predicted and exported through its kind (the
``kind`` of its configuration): the localiser, the model file (``models.model_file``), the
exports (``models.export``) and, through the engine, the live pipeline call the ``ModelKind``
methods below and never branch on a kind's name. Built-in kinds: ``map`` (a response map,
``models.map_kind``) and ``network`` (an ensemble of networks, ``models.network_kind``).

A new kind is one registration: an entry of ``_BUILTIN`` (``"package.module:attr"``, imported
only when a model of the kind is used, so this module imports no backend) or, from code
outside the package, ``register_model_kind(kind)``. Its spec (a ``ModelSpec`` subclass) builds
its engine (an ``Engine`` subclass); see ``docs/architecture.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from skinloc._lazy import resolve

if TYPE_CHECKING:
    import numpy as np

    from skinloc.models.engine import ModelSpec

__all__ = ["ModelKind", "model_kind", "model_kinds", "register_model_kind", "unregister_model_kind"]


@runtime_checkable
class ModelKind(Protocol):
    """What a kind of model provides. ``model`` is a ``ContactLocalizer``; ``cfg`` its config.

    Attributes
    ----------
    name : str
        The kind's name, as ``config_["kind"]`` and the model file's config hold it.
    config_type : type
        The kind's typed configuration: ``config_type.from_config(cfg)`` checks the kind's
        hyperparameters in ``cfg`` (a ``ValueError`` naming the parameter) and returns them.
    fitted_attrs : tuple of str
        The attributes ``fit`` sets on the model; a model with all of them is fitted.
    needs_surface_points : bool
        Whether ``fit`` needs the skin's surface points (candidates), whatever the constraint.
    train_extra : str or None
        The optional package ``fit`` needs (its import name, as ``skinloc._lazy``'s
        ``extra_installed`` takes it, e.g. ``"torch"``); None: the core install fits it.
    quick_fit : bool
        Whether a fit on a calibration takes seconds, so that callers may fit it again and
        again (the app's influence of each touch); False leaves such a model out of that.
    summary : str
        What a model of the kind is, in one phrase, for reports.
    """

    name: str
    config_type: type
    fitted_attrs: tuple[str, ...]
    needs_surface_points: bool
    train_extra: str | None
    quick_fit: bool
    summary: str

    def fit(
        self,
        model: Any,
        X: np.ndarray,
        y: np.ndarray,
        frames: tuple[np.ndarray, np.ndarray | None],
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Fit ``model`` on ``X (n, n_sensors)`` counts and ``y (n, 3)`` m.

        ``X``, ``y`` are touch means when the config trains on means and ``groups`` are given;
        ``frames`` are ``(X, groups)`` before averaging. Sets ``fitted_attrs`` (and optionally
        ``contact_rule_``).
        """
        ...

    def recalibrate(
        self,
        model: Any,
        new: Any,
        X: np.ndarray,
        y: np.ndarray,
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Adapt ``new`` (a copy of the fitted ``model``) to a new session's touches."""
        ...

    def spec(self, model: Any, common: dict[str, Any]) -> ModelSpec:
        """The fitted model as its engine's arrays; ``common`` are the ``ModelSpec`` fields."""
        ...

    def write(self, model: Any, f: Any) -> None:
        """Write the kind's arrays (and the ``description`` attribute) to the open HDF5 file."""
        ...

    def read(self, model: Any, f: Any) -> None:
        """Read what ``write`` wrote from the open HDF5 file into ``model``."""
        ...

    def onnx(self, spec: Any, include_surface: bool, opset: int) -> Any:
        """The ``onnx.ModelProto`` of ``spec``, or a ``ValueError`` saying why there is none."""
        ...

    def c_header(self, spec: Any, include_surface: bool, prefix: str) -> str:
        """The C header of ``spec``, or a ``ValueError`` saying why there is none."""
        ...


# The built-in kinds, by name: imported when a model of the kind is used.
_BUILTIN: dict[str, str] = {
    "map": "skinloc.models.map_kind:MapKind",
    "network": "skinloc.models.network_kind:NetworkKind",
}
_REGISTRY: dict[str, str | ModelKind] = dict(_BUILTIN)


def register_model_kind(kind: Any, *, replace: bool = False) -> Any:
    """Register a model kind (an instance or a class with a no-argument constructor).

    Usable as a class decorator; returns its argument. ``replace`` allows taking a name
    already registered (otherwise ``ValueError``).
    """
    obj = kind() if isinstance(kind, type) else kind
    missing = [
        a for a in ModelKind.__annotations__ if not hasattr(obj, a)
    ]  # fmt: skip
    if missing or not isinstance(obj, ModelKind):
        raise TypeError(f"{obj!r} is not a ModelKind (missing: {', '.join(missing) or 'methods'})")
    if obj.name in _REGISTRY and not replace:
        raise ValueError(f"a model kind is already registered as {obj.name!r}")
    _REGISTRY[obj.name] = obj
    return kind


def unregister_model_kind(name: str) -> None:
    """Remove a registered kind (built-ins come back as they were); a no-op when unknown."""
    _REGISTRY.pop(name, None)
    if name in _BUILTIN:
        _REGISTRY[name] = _BUILTIN[name]


def model_kinds() -> list[str]:
    """The names of every registered kind."""
    return list(_REGISTRY)


def model_kind(name: str) -> ModelKind:
    """The kind registered as ``name`` (its module imported now); ``ValueError`` when none."""
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ValueError(
            f"unknown model kind {name!r}; registered: {', '.join(_REGISTRY)} "
            "(a kind is added with skinloc.models.kinds.register_model_kind)"
        )
    if isinstance(entry, str):
        entry = resolve(entry)()
        _REGISTRY[name] = entry
    return entry
