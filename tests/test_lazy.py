"""``skinloc._lazy``: optional dependencies are imported through ``require_extra``."""

from __future__ import annotations

import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

import pytest
import typer

from skinloc import _lazy
from skinloc._lazy import EXTRAS, extra_installed, require_extra
from skinloc.errors import MissingExtraError

ROOT = Path(__file__).resolve().parents[1]


def _dist(requirement: str) -> str:
    return re.split(r"[<>=!~;\[ ]", requirement, maxsplit=1)[0].lower().replace("_", "-")


def test_the_table_of_extras_is_pyprojects():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    wanted = {(_dist(r), name) for name in ("nets", "export", "live") for r in extras[name]}
    owners = importlib.metadata.packages_distributions()  # the test venv has every extra
    table = set()
    for module, (extra, _) in EXTRAS.items():
        for dist in owners.get(module, []):
            table.add((dist.lower().replace("_", "-"), extra))
    assert wanted <= table, wanted - table
    assert {e for e, _ in EXTRAS.values()} == {"nets", "export", "live", "cluster"}


def test_a_missing_extra_is_one_line_naming_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "pylsl", None)  # as if it were not installed
    with pytest.raises(MissingExtraError) as info:
        require_extra("pylsl", "the LSL sink")
    assert str(info.value) == "the LSL sink needs pylsl: pip install 'skinloc[live]'"
    assert not extra_installed("pylsl")


def test_an_extra_that_does_not_load_says_why_in_one_line(monkeypatch):
    def broken(name: str):
        raise RuntimeError("LSL binary library file was not found.\nsee the docs")

    monkeypatch.setattr(_lazy.importlib, "import_module", broken)
    with pytest.raises(MissingExtraError) as info:
        require_extra("pylsl", "the LSL sink")
    msg = str(info.value)
    assert "\n" not in msg and "does not load (LSL binary library" in msg
    assert msg.endswith("pip install 'skinloc[live]'")


def test_only_the_extras_go_through_it():
    with pytest.raises(KeyError):
        require_extra("numpy", "this")


def test_the_cli_turns_a_stray_missing_extra_into_one_line(capsys):
    from skinloc.cli.common import friendly_errors

    @friendly_errors
    def command() -> None:
        import cyclonedds_is_not_here  # noqa: F401

    @friendly_errors
    def other() -> None:
        raise ModuleNotFoundError("No module named 'cyclonedds.idl'", name="cyclonedds.idl")

    with pytest.raises(ModuleNotFoundError):  # not an extra: a bug, with its traceback
        command()
    with pytest.raises(typer.Exit):
        other()
    err = capsys.readouterr().err.strip()
    assert err == "error: this command needs cyclonedds: pip install 'skinloc[live]'"


def test_benchmarks_leave_out_the_networks_without_pytorch(monkeypatch):
    from skinloc.cli.bench import installed_archs

    assert installed_archs(("default", "mlp")) == (("default", "mlp"), [])
    monkeypatch.setitem(sys.modules, "torch", None)
    kept, why = installed_archs(("default", "mlp", "paper"))
    assert kept == ("default",)
    assert why == [
        "training the 'mlp' and 'paper' networks needs PyTorch: pip install 'skinloc[nets]'"
    ]
