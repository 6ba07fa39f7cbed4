"""The live view's settings: the live pipeline's thresholds and filter, in the session's skins file.

The settings live where ``skinloc run`` reads them: ``skins.toml`` in the session's folder, a
skins file (``skinloc.live.skins_file``) with one ``[[skin]]`` (the session's model and the
connected skin) whose ``pipeline`` table holds the ``PipelineConfig`` fields. The live view
builds its pipeline from that file, and ``skinloc run --config skins.toml`` runs the same
pipeline outside the app. A skins file edited by hand keeps its other keys when the page saves
(comments are not kept).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from skinloc.app.workspace.state import WorkspaceState
from skinloc.files import atomic_write
from skinloc.live.config import PipelineConfig
from skinloc.live.skins_file import read_skins_toml, skin_table

__all__ = ["EDITABLE", "LiveSettings", "toml_text"]

#: The ``PipelineConfig`` fields the page shows and edits, with what each is (unit).
EDITABLE: dict[str, str] = {
    "touch_on_z": "a touch starts above this signal, noise std",
    "touch_off_z": "and ends below this, noise std",
    "debounce_on_frames": "frames above the start threshold before a touch starts",
    "debounce_off_frames": "frames below the end threshold before it ends",
    "release_fraction": "a touch also ends below this fraction of its level",
    "drift_tracking": "let the baseline follow slow drift while nothing touches",
    "drift_time_constant_s": "time constant of the drift tracking, s",
    "filter": "position filter: one-euro or none",
    "min_cutoff_hz": "One-Euro cutoff at rest, Hz (lower: steadier, slower)",
    "beta": "One-Euro speed coefficient, s/m (higher: follows fast moves sooner)",
    "d_cutoff_hz": "One-Euro cutoff of the speed, Hz",
    "max_contacts": "fingers tracked at once at most",
    "gestures": "recognise gestures",
}
#: Name of the skins file in a session's folder.
SKINS_FILE = "skins.toml"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"a skins file holds finite numbers only, not {v}")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a TOML basic string
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise ValueError(f"a skins file cannot hold {type(v).__name__} values")


def _toml_key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def toml_text(doc: dict[str, Any], header: str = "") -> str:
    """``doc`` as TOML: plain keys, then ``[tables]``, then ``[[arrays of tables]]``.

    Enough for skins files: tables nested inside those become inline tables.
    """
    lines = [f"# {line}" for line in header.splitlines()]
    tables = {k: v for k, v in doc.items() if isinstance(v, dict)}
    arrays = {
        k: v
        for k, v in doc.items()
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v)
    }
    for k, v in doc.items():
        if k not in tables and k not in arrays:
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for name, table in tables.items():
        lines += ["", f"[{_toml_key(name)}]"]
        lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in table.items()]
    for name, entries in arrays.items():
        for entry in entries:
            lines += ["", f"[[{_toml_key(name)}]]"]
            lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"


class LiveSettings(WorkspaceState):
    """Part of ``Workspace``: the live pipeline's settings, shown and saved."""

    def _skins_path(self) -> Path:
        return self._need_session().folder.path / SKINS_FILE

    def _read_skins(self, path: Path) -> dict[str, Any]:
        """The session's skins file as a dict (none: ``{}``); a broken one is a one-line error."""
        if not path.is_file():
            return {}
        return read_skins_toml(path, path.name)

    def _live_config(self) -> PipelineConfig:
        """The pipeline settings of the open session: its skins file's, else the defaults."""
        with self._lock:
            path = self._skins_path()
            raw = self._read_skins(path)
        try:
            table = skin_table(raw, 0, "pipeline")
            return PipelineConfig.from_dict(table, f"{path.name} pipeline")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path.name}: {exc}") from None

    def live_settings(self) -> dict[str, Any]:
        """The editable settings (value, default, what each is) and where they are kept."""
        cfg = self._live_config()
        with self._lock:
            path = self._skins_path()
        defaults = PipelineConfig()
        return {
            "fields": [
                {
                    "name": name,
                    "value": getattr(cfg, name),
                    "default": getattr(defaults, name),
                    "kind": type(getattr(defaults, name)).__name__,  # bool, int, float, str
                    "help": text,
                }
                for name, text in EDITABLE.items()
            ],
            "file": path.name,
            "saved": path.is_file(),
            # from the sessions folder (the data folder the app shows on its first page)
            "command": f"skinloc run --config {path.parent.name}/{path.name}",
        }

    def skins_text(self, values: dict[str, Any] | None = None, model: str | None = None) -> str:
        """The session's skins file with ``values`` set (checked), as TOML text.

        The file as saved (other keys kept) or, when none is, the one saving would write: the
        session's model and the connected skin. ``model`` names the model file in it instead of
        the session's ``model.h5`` (the Export page's download name). Call with the lock held.
        """
        a = self._need_session()
        raw = self._read_skins(self._skins_path())
        current = dataclasses.asdict(self._live_config())
        new = PipelineConfig(**{**current, **(values or {})})  # checks every field
        skins = raw.get("skin") or [{}]
        entry = dict(skins[0])
        entry.setdefault("name", "skin")
        entry.setdefault("model", a.folder.model.name)
        if model is not None and entry["model"] == a.folder.model.name:
            entry["model"] = model
        if self.device is not None:
            entry.setdefault("source", self.device.options.source)
            entry.setdefault("n_tx", self.device.source.n_tx)
            entry.setdefault("n_rx", self.device.source.n_rx)
        table = dict(entry.get("pipeline", {}))
        table.update({k: getattr(new, k) for k in EDITABLE})
        entry["pipeline"] = table
        raw["skin"] = [entry, *skins[1:]]
        name = SKINS_FILE if model is None else f"{a.folder.id}-{SKINS_FILE}"
        return toml_text(
            raw,
            header=f"The live pipeline of session {a.folder.id}, saved by skinloc app.\n"
            f"Run it outside the app with: skinloc run --config {name}",
        )

    def set_live_settings(self, values: dict[str, Any]) -> dict[str, Any]:
        """Check ``values`` (``EDITABLE`` fields), write them to the skins file, apply them.

        The live view, if it runs, starts again with them (a fresh baseline). A value that
        ``PipelineConfig`` refuses changes nothing and is said in one line.
        """
        bad = sorted(set(values) - set(EDITABLE))
        if bad:
            raise ValueError(f"unknown setting(s) {', '.join(bad)}; known: {', '.join(EDITABLE)}")
        with self._lock:
            path = self._skins_path()
            text = self.skins_text(values)
            atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
            live = self.live_running
            if live:
                self._stop_live()
        if live:
            self.start_live()  # the new settings, on a fresh baseline
        return self.live_settings()
