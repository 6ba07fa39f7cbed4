"""The live settings of each skin as ROS 2 parameters: names, descriptions, ranges, dump files.

One node serves every skin, so each skin's settings are the parameters ``<skin>.pipeline.<key>``
(the skins file's ``pipeline`` keys, ``PipelineConfig``) and ``<skin>.gestures.<key>`` (its
``gestures`` keys, ``GestureConfig``): the skins file's own tables, ``<skin>`` spelt as in the
topic names (``skinloc.ros2.names.ros_name``). The descriptions are the fields' own
docstrings; the ranges describe, the check of a new value is the settings' own
(``PipelineConfig.__post_init__``, ``GestureConfig.__post_init__``), run by the skin's process
(``skinloc.live.control``).

``ros2 param dump /skinloc`` writes YAML of this shape, which ``read_param_dump`` reads back
(``skinloc run --params FILE``)::

    /skinloc:
      ros__parameters:
        arm:
          pipeline:
            touch_on_z: 8.0
          gestures:
            tap_max_s: 0.3
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skinloc.live.config import PipelineConfig
from skinloc.live.gestures import GestureConfig
from skinloc.ros2.names import ros_name

__all__ = [
    "FIXED",
    "ParamSpec",
    "apply_values",
    "param_specs",
    "read_param_dump",
    "settings_of",
    "skin_key",
]

#: settings fixed at start (what they change is built once): read-only parameters
FIXED = ("gestures", "footprint_gestures")

# ranges (inclusive) of the numeric settings; the settings' own check has the exact rule
_INT_MIN = {"track_miss_frames": 0}
_FLOAT_RANGE = {"release_fraction": (0.0, 1.0)}
_FLOAT_MAX = 1e9


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its name under the skin, kind, default, description and range.

    Attributes
    ----------
    key : str
        ``pipeline.touch_on_z`` (a ``PipelineConfig`` field) or ``gestures.tap_max_s``.
    kind : {"bool", "int", "float", "str"}
    default : bool, int, float or str
    description : str
    low, high : float or None
        The range of a number.
    choices : tuple of str
        The allowed values of a string.
    read_only : bool
        Fixed at start.
    """

    key: str
    kind: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False


def _descriptions(cls: type) -> dict[str, str]:
    """The ``Attributes`` section of a numpy docstring: field -> its description, one line."""
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    names: list[str] = []
    for line in doc.split("Attributes\n----------\n", 1)[-1].splitlines():
        m = re.match(r"^(\w+(?:, \w+)*) : ", line)
        if m:
            names = m.group(1).split(", ")
            for n in names:
                out[n] = ""
        elif line.startswith("    ") and names:
            for n in names:
                out[n] = (out[n] + " " + line.strip()).strip()
    return out


def _spec(f: dataclasses.Field, default: Any, doc: str, prefix: str) -> ParamSpec:
    key = prefix + f.name
    if isinstance(default, bool):
        read_only = f.name in FIXED and prefix == "pipeline."
        return ParamSpec(key, "bool", default, doc, read_only=read_only)
    if isinstance(default, int):
        return ParamSpec(key, "int", default, doc, float(_INT_MIN.get(f.name, 1)), 1e9)
    if isinstance(default, float):
        lo, hi = _FLOAT_RANGE.get(f.name, (0.0, _FLOAT_MAX))
        return ParamSpec(key, "float", default, doc, lo, hi)
    choices = ("one-euro", "none") if f.name == "filter" else ()
    return ParamSpec(key, "str", default, doc, choices=choices)


def param_specs() -> list[ParamSpec]:
    """Every parameter of one skin, in the settings' order (pipeline, then gestures)."""
    out = []
    for cls, prefix in ((PipelineConfig, "pipeline."), (GestureConfig, "gestures.")):
        docs = _descriptions(cls)
        defaults = cls()
        for f in dataclasses.fields(cls):
            out.append(_spec(f, getattr(defaults, f.name), docs.get(f.name, ""), prefix))
    return out


def settings_of(
    config: PipelineConfig, gestures: GestureConfig | None
) -> dict[str, bool | int | float | str]:
    """One skin's settings as parameter values, ``key -> value``."""
    out: dict[str, Any] = {f"pipeline.{k}": v for k, v in dataclasses.asdict(config).items()}
    g = GestureConfig() if gestures is None else gestures
    out.update({f"gestures.{k}": v for k, v in dataclasses.asdict(g).items()})
    return out


def apply_values(
    config: PipelineConfig, gestures: GestureConfig | None, values: dict[str, Any]
) -> tuple[PipelineConfig, GestureConfig]:
    """New settings with ``values`` (``key -> value``) applied, checked by the settings' own rule.

    Raises
    ------
    ValueError
        For an unknown key or a value the settings refuse (the message names it).
    """
    pipe, gest = {}, {}
    for key, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{key} must be finite, got {value!r}")
        table, _, name = key.partition(".")
        if table == "gestures":
            gest[name] = value
        elif table == "pipeline":
            pipe[name] = value
        else:
            raise ValueError(f"unknown setting {key}; use pipeline.KEY or gestures.KEY")
    base = dataclasses.asdict(config)
    unknown = sorted(set(pipe) - set(base))
    if unknown:
        raise ValueError(f"unknown setting(s) {', '.join(unknown)}")
    for k, v in pipe.items():
        # a ROS parameter of a float setting may arrive as an integer ("8"): keep the type
        if isinstance(base[k], float) and isinstance(v, int) and not isinstance(v, bool):
            pipe[k] = float(v)
    new = PipelineConfig.from_dict({**base, **pipe}, "the new settings")
    g_base = dataclasses.asdict(GestureConfig() if gestures is None else gestures)
    g_new = dataclasses.replace(GestureConfig(**g_base), **gest) if gest else None
    if g_new is None:
        g_new = GestureConfig(**g_base)
    return new, g_new


def read_param_dump(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per skin (``ros_name`` spelling), the settings of a ``ros2 param dump`` YAML file.

    Returns
    -------
    dict
        ``{skin: {"pipeline": {...}, "gestures": {...}}}``, the tables a skins file's skin
        takes (checked where they are used, as a skins file's); node-wide parameters
        (``use_sim_time``...) are left out.

    Raises
    ------
    ValueError
        For a missing or unreadable file, or a file without a node's ``ros__parameters``.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"parameter file not found: {path}")
    data = _read_yaml(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a ros2 param dump (a YAML mapping of nodes)")
    # every node of the file: the dumps of ``run --workers``'s nodes (skinloc_0, skinloc_1...)
    # appended into one file give every skin's settings
    params: dict[str, Any] | None = None
    for value in data.values():
        if isinstance(value, dict) and isinstance(value.get("ros__parameters"), dict):
            params = {**(params or {}), **value["ros__parameters"]}
    if params is None:
        raise ValueError(f"{path}: no ros__parameters (write it with ros2 param dump)")
    out: dict[str, dict[str, Any]] = {}
    for skin, table in params.items():
        if not isinstance(table, dict):
            continue  # a node-wide parameter (use_sim_time)
        out[str(skin)] = {
            name: dict(table[name])
            for name in ("pipeline", "gestures")
            if isinstance(table.get(name), dict)
        }
    return out


def _read_yaml(path: Path) -> Any:
    """The YAML of ``path``: PyYAML when installed, else the subset ``ros2 param dump`` writes.

    The subset: indented mappings of scalars (PyYAML comes with the ROS 2 wheels).
    """
    text = path.read_text(encoding="utf-8")
    try:
        import yaml
    except ImportError:
        return _dump_subset(text, path)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"cannot read {path}: {exc}") from None


def _scalar(text: str) -> Any:
    t = text.strip()
    if t in ("true", "True"):
        return True
    if t in ("false", "False"):
        return False
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "'\"":
        return t[1:-1]
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    return t


def _dump_subset(text: str, path: Path) -> Any:
    root: dict[str, Any] = {}
    stack: list[tuple[int, dict[str, Any]]] = [(-1, root)]
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        indent = len(line) - len(line.lstrip(" "))
        key, sep, rest = line.strip().partition(":")
        if not sep:
            raise ValueError(f"cannot read {path}: line {n} is not 'key: value'")
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1]
        if rest.strip():
            parent[key] = _scalar(rest)
        else:
            parent[key] = {}
            stack.append((indent, parent[key]))
    return root


def skin_key(skin: str) -> str:
    """A skin's name as it prefixes its parameters (``ros_name``)."""
    return ros_name(skin)
