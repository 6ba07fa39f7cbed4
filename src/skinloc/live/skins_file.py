"""Many skins from one process: the configuration file of ``skinloc run --config``.

A TOML file lists the skins of a robot; each becomes a ``SkinConfig`` of one ``Runner``::

    sinks = ["jsonl", "ws://127.0.0.1:8767"]   # receive the contacts of every skin
    params = "skinloc_params.yaml"   # optional: `ros2 param dump /skinloc` of a run, read back

    [defaults]                 # any SkinConfig field, for every skin
    model = "arm.h5"           # paths are relative to this file
    baud = 1000000
    wire_format = "binary"

    [defaults.pipeline]        # any PipelineConfig field
    touch_on_z = 8.0

    [defaults.gestures]        # any GestureConfig field (gesture thresholds, mm and s)
    tap_max_s = 0.25

    [[skin]]
    name = "left-forearm"
    source = "/dev/ttyACM0"

    [[skin]]
    name = "right-forearm"
    source = "/dev/ttyACM1"
    model = "right.h5"
    sinks = ["udp://127.0.0.1:9870"]
    pipeline = { drift_tracking = false }
    parent_frame = "fr3_link7"   # ROS 2 /tf_static: fr3_link7 -> skin/right-forearm
    translation = [0.0, 0.0, 0.107]   # m
    rpy = [0.0, 0.0, -0.785]          # rad (or rotation = [x, y, z, w])
    up = [0.0, 0.0, 1.0]              # "up" for swipe directions, mesh frame
    gestures = { swipe_min_mm = 40.0 }

Every key is checked: an unknown one is an error naming the skin, the key and the known keys,
and a value of the wrong type or range (``realtime = "no"``, ``baud = "fast"``) one naming the
file, the skin, the key and the value. Every skin names its ``source`` (or ``[defaults]`` does):
the simulated skin is ``source = "sim"``, never a silent default.
``params`` names a ``ros2 param dump`` file of the ROS 2 node (``skinloc.live.sinks.ros2.params``):
its ``pipeline`` and ``gestures`` values of each skin override the file's, checked alike.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any

from skinloc.live.core import PipelineConfig
from skinloc.live.runner import Runner, SkinConfig
from skinloc.live.sinks.ros2.params import read_param_dump
from skinloc.live.skin_config import mount_pose
from skinloc.ros2.names import ros_name

__all__ = ["load_skins", "read_skins_toml", "runner_from_config", "skin_mount", "skin_table"]

_PATH_KEYS = ("model", "baseline")


def _resolve(value: Any, base: Path) -> Any:
    if isinstance(value, str) and value and not Path(value).is_absolute():
        candidate = base / value
        return str(candidate)
    return value


def read_skins_toml(path: Path, label: str | None = None) -> dict[str, Any]:
    """The TOML of the skins file ``path`` as a dict; ``ValueError`` in one line when broken.

    ``label`` names the file in the message (default: ``skins file PATH``).
    """
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"cannot read {label or f'skins file {path}'}: {exc}") from None


def skin_table(raw: dict[str, Any], k: int, table: str) -> dict[str, Any]:
    """Skin ``k``'s table ``table`` (``pipeline``, ``gestures``) over ``[defaults.TABLE]``.

    ``raw`` is a skins file's TOML (``read_skins_toml``); a skin ``k`` it lacks has the
    defaults'. Raises ``ValueError`` when either is not a table.
    """
    skins = raw.get("skin") or [{}]
    entry = skins[k] if k < len(skins) else {}
    parts = (raw.get("defaults", {}).get(table, {}), entry.get(table, {}))
    if not all(isinstance(p, dict) for p in parts):
        name = str({**raw.get("defaults", {}), **entry}.get("name", f"skin{k}"))
        raise ValueError(f"skin {name!r}: {table} must be a table of settings")
    return {**parts[0], **parts[1]}


def load_skins(path: str | Path) -> tuple[list[SkinConfig], list[str]]:
    """Read a skins file; returns ``(skins, global sinks)``.

    Raises
    ------
    ValueError
        For a missing file, bad TOML, no skins, or an unknown or ill-typed key.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"skins file not found: {path}")
    raw = read_skins_toml(path)
    unknown = sorted(set(raw) - {"sinks", "defaults", "skin", "params"})
    if unknown:
        raise ValueError(
            f"{path}: unknown top-level key(s) {', '.join(unknown)}; use sinks, defaults, params, "
            "[[skin]]"
        )
    dumped: dict[str, dict[str, Any]] = {}
    if "params" in raw:
        if not isinstance(raw["params"], str):
            raise ValueError(f"{path}: params must be the path of a ros2 param dump file")
        dumped = read_param_dump(_resolve(raw["params"], path.parent))
    skins_raw = raw.get("skin", [])
    if not isinstance(skins_raw, list) or not skins_raw:
        raise ValueError(f"{path}: no [[skin]] entries")
    base = path.parent
    known = {f.name for f in dataclasses.fields(SkinConfig)} - {"config"} | {"pipeline"}
    defaults = dict(raw.get("defaults", {}))
    skins = []
    for k, entry in enumerate(skins_raw):
        merged = {**defaults, **entry}
        name = merged.get("name", f"skin{k}")
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"{path}: skin #{k + 1}: name must be a non-empty text, not {name!r}")
        saved = dumped.get(ros_name(name), {})
        for table in ("pipeline", "gestures"):
            try:
                merged[table] = {**skin_table(raw, k, table), **saved.get(table, {})}
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
        merged["name"] = name
        bad = sorted(set(merged) - known)
        if bad:
            raise ValueError(
                f"{path}: skin {name!r}: unknown key(s) {', '.join(bad)}; known: "
                f"{', '.join(sorted(known))}"
            )
        if "model" not in merged:
            raise ValueError(f"{path}: skin {name!r} has no model (set it or [defaults] model)")
        for key in _PATH_KEYS:
            if key in merged:
                merged[key] = _resolve(merged[key], base)
        source = merged.get("source")
        if isinstance(source, str) and Path(source).suffix.lower() in (".h5", ".hdf5", ".mat"):
            merged["source"] = _resolve(source, base)
        sinks = merged.pop("sinks", [])
        if not isinstance(sinks, list) or not all(isinstance(s, str) for s in sinks):
            raise ValueError(f"{path}: skin {name!r}: sinks must be a list of strings")
        try:
            config = PipelineConfig.from_dict(merged.pop("pipeline"), "pipeline")
            skins.append(SkinConfig(config=config, sinks=list(sinks), **merged))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: skin {name!r}: {exc}") from None
        if source is None:  # checked last: the other keys' errors come first
            raise ValueError(
                f"{path}: skin {name!r} has no source: give a serial port, a recording, or "
                'source = "sim" for the simulated skin (--source sim on the command line)'
            )
    sinks = raw.get("sinks", [])
    if not isinstance(sinks, list) or not all(isinstance(s, str) for s in sinks):
        raise ValueError(f"{path}: sinks must be a list of strings")
    return skins, list(sinks)


def runner_from_config(path: str | Path, extra_sinks: list[str] | None = None) -> Runner:
    """A ``Runner`` for every skin of a skins file (plus ``extra_sinks`` for all skins)."""
    skins, sinks = load_skins(path)
    return Runner(skins, sinks=[*sinks, *(extra_sinks or [])])


def skin_mount(
    path: str | Path, name: str | None = None
) -> tuple[str | None, tuple[float, float, float], tuple[float, float, float, float]]:
    """One skin's pose on the robot from a skins file: ``(parent_frame, translation m, xyzw)``.

    Only the pose keys are read (``parent_frame``, ``translation``, ``rotation`` or ``rpy``,
    over ``[defaults]``), so a skin not yet calibrated (no ``model``) has one. ``name`` picks
    the ``[[skin]]``; it may be left out when the file has one skin. Raises ``ValueError`` in
    one line for a missing file, an unknown name or a bad pose.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"skins file not found: {path}")
    raw = read_skins_toml(path)
    skins = raw.get("skin", [])
    if not isinstance(skins, list) or not skins:
        raise ValueError(f"{path}: no [[skin]] entries")
    defaults = raw.get("defaults", {})
    entries = [{**defaults, **e} for e in skins if isinstance(e, dict)]
    names = [str(e.get("name", f"skin{k}")) for k, e in enumerate(entries)]
    if name is None:
        if len(entries) != 1:
            raise ValueError(f"{path} has {len(entries)} skins: name one ({', '.join(names)})")
        entry = entries[0]
    elif name in names:
        entry = entries[names.index(name)]
    else:
        raise ValueError(f"{path} has no skin {name!r}; it has: {', '.join(names)}")
    try:
        translation, rotation = mount_pose(
            entry.get("parent_frame"),
            entry.get("translation", (0.0, 0.0, 0.0)),
            entry.get("rotation"),
            entry.get("rpy"),
        )
    except ValueError as exc:
        raise ValueError(f"{path}: skin {names[entries.index(entry)]!r}: {exc}") from None
    return entry.get("parent_frame"), translation, rotation
