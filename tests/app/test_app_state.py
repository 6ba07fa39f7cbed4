"""The workspace's state is declared (issue 31.5): what a part of ``Workspace`` may touch.

Each part (``skinloc.app.workspace.*``) is a subclass of ``WorkspaceState``; every attribute it
uses through ``self`` must be a method or property of the workspace, declared (annotated) in
``WorkspaceState`` or in the part's own class, or a public attribute another part declares.
Another part's private state is off limits, and no attribute is declared twice.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

pytest.importorskip("fastapi")

from skinloc.app.hub import Hub  # noqa: E402
from skinloc.app.workspace import AppConfig, Workspace  # noqa: E402
from skinloc.app.workspace.state import WorkspaceState  # noqa: E402

PARTS = [c for c in Workspace.__mro__ if c is not object]


def declared(cls: type) -> set[str]:
    """The attributes ``cls`` itself annotates."""
    return set(inspect.get_annotations(cls))


def is_behaviour(name: str) -> bool:
    """Whether ``name`` is a method or property of the workspace (not state)."""
    attr = inspect.getattr_static(Workspace, name, None)
    return isinstance(attr, (property, staticmethod, classmethod)) or inspect.isfunction(attr)


def self_attributes(cls: type) -> dict[str, int]:
    """``{attribute: first line}`` of each ``self.X`` in the class body of ``cls``."""
    path = Path(inspect.getsourcefile(cls))
    tree = ast.parse(path.read_text(encoding="utf-8"))
    (node,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls.__name__]
    out: dict[str, int] = {}
    for n in ast.walk(node):
        if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "self":
            out.setdefault(n.attr, n.lineno)
    return out


def test_every_part_is_a_workspace_state():
    for part in PARTS:
        if part is not Workspace and part is not WorkspaceState:
            assert issubclass(part, WorkspaceState), part.__name__


def test_no_attribute_is_declared_twice():
    owner: dict[str, str] = {}
    for part in PARTS:
        for name in declared(part):
            assert name not in owner, f"{name} declared by {owner.get(name)} and {part.__name__}"
            owner[name] = part.__name__


def test_each_part_touches_only_declared_state():
    shared = declared(WorkspaceState)
    public = {n for p in PARTS for n in declared(p) if not n.startswith("_")}
    problems = []
    for part in PARTS:
        own = declared(part)
        for name, line in self_attributes(part).items():
            if is_behaviour(name) or name in shared or name in own or name in public:
                continue
            where = f"{inspect.getsourcefile(part)}:{line} ({part.__name__})"
            declarer = [p.__name__ for p in PARTS if name in declared(p)]
            problems.append(
                f"{where}: self.{name} is "
                + (f"private to {declarer[0]}" if declarer else "declared nowhere")
            )
    assert not problems, "\n".join(problems)


def test_a_new_workspace_holds_only_declared_state(tmp_path):
    ws = Workspace(AppConfig(data_dir=tmp_path), Hub())
    everything = set().union(*(declared(p) for p in PARTS))
    assert set(vars(ws)) <= everything, set(vars(ws)) - everything
    # each part set up its own state
    assert ws.live_sink is not None and ws.record_tee is not None and ws._quiet == []
    assert ws.mode.value == "idle" and ws.lease is None and ws.page_states == {}


def test_taking_a_touch_back_takes_its_probe_and_truth_entries_too(recording_factory):
    from skinloc.app.workspace.state import pop_point_log

    rec = recording_factory(3, 2)
    rec.meta["probe_tips_m"] = [[0.0, 0.0, float(i)] for i in range(3)]
    rec.meta["true_contacts"] = [[float(i), 0.0, 0.0] for i in range(3)]
    removed = pop_point_log(rec, 1)
    assert rec.n_point_logs == 2
    assert [t[2] for t in rec.meta["probe_tips_m"]] == [0.0, 2.0]
    assert [c[0] for c in rec.meta["true_contacts"]] == [0.0, 2.0]
    assert removed["meta"]["probe_tips_m"] == [0.0, 0.0, 1.0]
