"""The package's import graph has no circle: each module depends only on modules below it.

The subpackages keep the rows of docs/architecture.md (a package imports only packages on the
rows below its own: never one above, never one beside), and no module imports another's
private name (``from skinloc.x import _y``), in ``src`` and in ``bench/``.

Every import counts, including those inside functions and under ``TYPE_CHECKING``: a lazy
import hides a circle from Python but not from a reader. The one harmless circle, a package
``__init__`` re-exporting its own children (which never import it back), is ignored.
Registries name their backends as dotted strings (``skinloc._lazy.resolve``), so they make no
edge here. The subpackages must form layers (no two import each other, even through a third):
docs/architecture.md draws them. A module is as long as its one idea needs; only one far
beyond that (``SMELL_LINES``) is flagged, as worth a look, never as a reason to split it.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import skinloc

ROOT = Path(skinloc.__file__).parent


def _modules(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` under ``root`` (a package directory)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = (root.name, *path.relative_to(root).with_suffix("").parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def import_graph(root: Path) -> tuple[dict[str, set[str]], dict[str, Path]]:
    """Edges module -> the package modules it imports (anywhere in its source)."""
    mods = _modules(root)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: climb from this module's package
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                # "from pkg import name" imports pkg, and pkg.name when that is a module
                targets = [base, *(f"{base}.{a.name}" for a in node.names)]
            else:
                continue
            for target in targets:
                while target and target not in mods:  # a name inside a module: the module
                    target = target.rpartition(".")[0]
                if target and target != mod:
                    graph[mod].add(target)
    return graph, mods


def circles(graph: dict[str, set[str]], mods: dict[str, Path]) -> list[list[str]]:
    """The strongly connected groups of more than one module, except harmless ``__init__`` ones."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in graph:
        if v not in index:
            visit(v)

    def harmless(group: list[str]) -> bool:
        inits = [m for m in group if mods[m].name == "__init__.py"]
        if len(inits) != 1:
            return False
        pkg = inits[0]
        children = [m for m in group if m != pkg]
        return all(m.startswith(pkg + ".") and pkg not in graph[m] for m in children)

    return [g for g in found if not harmless(g)]


def test_no_import_circle_in_skinloc():
    graph, mods = import_graph(ROOT)
    assert circles(graph, mods) == []


#: A module this long probably holds more than one idea (a smell to look at, not a rule to
#: split by).
SMELL_LINES = 1000


def test_no_module_is_far_longer_than_one_idea_needs():
    _, mods = import_graph(ROOT)
    sizes = sorted(((len(p.read_text().splitlines()), m) for m, p in mods.items()), reverse=True)
    print("\nlines  module\n" + "\n".join(f"{n:5d}  {m}" for n, m in sizes[:10]))  # noqa: T201
    assert [(n, m) for n, m in sizes if n > SMELL_LINES] == []


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Edges between the subpackages (and top-level modules) of skinloc."""

    def room(mod: str) -> str:
        parts = mod.split(".")
        return parts[1] if len(parts) > 1 else parts[0]

    out: dict[str, set[str]] = {}
    for a, targets in graph.items():
        for b in targets:
            if room(a) != room(b) and room(b) != "skinloc":
                out.setdefault(room(a), set()).add(room(b))
    return out


def test_subpackages_import_only_the_ones_below_them():
    """The layers of docs/architecture.md: no two subpackages import each other, even indirectly."""
    graph, _ = import_graph(ROOT)
    pg = package_graph(graph)
    rooms = {r: Path(r) for r in set(pg) | {b for bs in pg.values() for b in bs}}
    full = {r: pg.get(r, set()) for r in rooms}
    assert circles(full, {r: Path(f"{r}.py") for r in rooms}) == []


#: The layer table's place in docs/architecture.md: the code block after this sentence.
_LAYERS_SENTENCE = "Each package imports only packages on the rows below its own"
DOCS = ROOT.parents[1] / "docs" / "architecture.md"


def layer_rows(text: str) -> dict[str, int]:
    """Package (or top-level module) -> its row in the layer table of ``architecture.md``, 0 on top.

    ``live (live/sinks, live/sinks/ros2)`` puts ``live`` on its row (a subpackage is part of
    its package).
    """
    after = text[text.index(_LAYERS_SENTENCE) :]
    block = after.split("```", 2)[1]
    rows: dict[str, int] = {}
    for k, line in enumerate(ln for ln in block.splitlines() if ln.strip()):
        for word in line.replace("(", " ").replace(")", " ").replace(",", " ").split():
            rows.setdefault(word.split("/")[0], k)
    return rows


def layer_violations(pg: dict[str, set[str]], rows: dict[str, int]) -> list[str]:
    """Every edge of the package graph ``pg`` that does not go down a row, and every package
    the table does not place.

    The package itself (its ``__init__``, which resolves the public names lazily) and
    ``__main__`` (the entry point) stand above every row.
    """
    out = []
    for a, targets in sorted(pg.items()):
        for b in sorted(targets):
            if a in ("skinloc", "__main__"):
                continue
            if a not in rows or b not in rows:
                out.append(f"{a} -> {b}: {a if a not in rows else b} has no row in the table")
            elif rows[b] <= rows[a]:
                where = "beside" if rows[b] == rows[a] else "above"
                out.append(f"{a} -> {b}: {b} is {where} {a}")
    return out


def test_packages_import_only_the_rows_below_them():
    """The layer table of docs/architecture.md holds: no import up a row or beside."""
    if not DOCS.is_file():
        pytest.skip("docs/architecture.md is not beside the package (an installed copy)")
    graph, _ = import_graph(ROOT)
    assert layer_violations(package_graph(graph), layer_rows(DOCS.read_text())) == []


def test_the_layer_check_finds_imports_up_and_beside():
    table = (
        "x\n" + _LAYERS_SENTENCE + ":\n\n```\n cli\n live  (live/sinks)\n sim  calibration\n```\n"
    )
    rows = layer_rows(table)
    assert rows == {"cli": 0, "live": 1, "sim": 2, "calibration": 2}
    pg = {"cli": {"live"}, "live": {"sim", "cli"}, "calibration": {"sim"}, "sim": {"new"}}
    assert layer_violations(pg, rows) == [
        "calibration -> sim: sim is beside calibration",
        "live -> cli: cli is above live",
        "sim -> new: new has no row in the table",
    ]


def private_imports(root: Path, package: str = "skinloc") -> list[str]:
    """``from <package>.x import _y`` in the ``.py`` files under ``root``: one line each.

    A name imported under a private alias (``import subtract as _prep``) is public; dunders
    are not private names.
    """
    out = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            module = node.module or ""
            if node.level == 0 and not (module == package or module.startswith(package + ".")):
                continue
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    where = f"{path.relative_to(root)}:{node.lineno}"
                    out.append(f"{where}: from {'.' * node.level}{module} import {alias.name}")
    return out


def test_no_module_imports_another_modules_private_name():
    """Every name used across modules is public where it belongs (src and bench/)."""
    bench = ROOT.parents[1] / "bench"
    found = private_imports(ROOT) + (private_imports(bench) if bench.is_dir() else [])
    assert found == []


def test_the_private_import_check_finds_them(tmp_path):
    pkg = _write(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "from skinloc.x import _hidden, shown\nfrom skinloc.y import z as _alias\n",
            "b.py": "from .a import _other\nfrom numpy import _private_elsewhere\n",
            "c.py": "from skinloc import __version__\n",
        },
    )
    assert private_imports(pkg) == [
        "a.py:1: from skinloc.x import _hidden",
        "b.py:1: from .a import _other",
    ]


def _write(root: Path, files: dict[str, str]) -> Path:
    pkg = root / "pkg"
    for rel, text in files.items():
        path = pkg / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return pkg


@pytest.mark.parametrize(
    ("files", "expected"),
    [
        # an import inside a function still closes a circle
        (
            {
                "__init__.py": "",
                "a.py": "import pkg.b\n",
                "b.py": "def f():\n    from pkg import a\n",
            },
            [["pkg.a", "pkg.b"]],
        ),
        # so does one under TYPE_CHECKING, and a relative one
        (
            {
                "__init__.py": "",
                "a.py": (
                    "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import X\n"
                ),
                "b.py": "from pkg.a import Y\n",
            },
            [["pkg.a", "pkg.b"]],
        ),
        # a package __init__ re-exporting its children is harmless
        (
            {"__init__.py": "", "s/__init__.py": "from pkg.s.base import B\n", "s/base.py": ""},
            [],
        ),
        # unless a child imports the package back
        (
            {
                "__init__.py": "",
                "s/__init__.py": "from pkg.s.base import B\n",
                "s/base.py": "def f():\n    from pkg.s import other\n",
                "s/other.py": "",
            },
            [["pkg.s", "pkg.s.base"]],
        ),
        # a registry naming its backends by string makes no edge
        (
            {
                "__init__.py": "",
                "base.py": "BACKENDS = {'x': 'pkg.backend:X'}\n",
                "backend.py": "from pkg.base import BACKENDS\n",
            },
            [],
        ),
    ],
)
def test_the_checker_finds_circles(tmp_path, files, expected):
    graph, mods = import_graph(_write(tmp_path, files))
    assert circles(graph, mods) == expected


def test_the_public_names_resolve_and_import_skinloc_stays_light():
    """``skinloc.X`` reaches every public name; importing ``skinloc`` alone loads no subpackage."""
    code = (
        "import sys, skinloc; "
        "assert not [m for m in sys.modules if m.startswith('skinloc.')], 'eager import'; "
        "[getattr(skinloc, n) for n in skinloc.__all__]; "
        "assert 'torch' not in sys.modules"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        skinloc.nothing  # noqa: B018
