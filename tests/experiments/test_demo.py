"""``skinloc demo`` in a reduced form: several skins, the paper's net beside, a notebook page."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc import __version__
from skinloc.experiments.demo import (
    NO_PRIOR,
    PROBING_FLOOR_MM,
    REAL_SKIN_ERROR_MM,
    DemoConfig,
    reference_curves,
    run_demo,
)

runner = CliRunner()


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("demo")
    cfg = DemoConfig(
        out_dir=out,
        n_points=12,
        n_validation=4,
        samples_per_touch=4,
        curve_sizes=(6, 12),
        random_state=7,
        n_skins=2,
        n_validation_extra=3,
    )
    return out, run_demo(cfg)


@pytest.mark.slow  # the demo: models per skin and curve size
def test_expected_error_is_over_several_skins_with_the_paper_net(demo) -> None:
    _, res = demo
    main, paper = res.skins["main"], res.skins["paper"]
    assert main.sizes == paper.sizes == [6, 12]
    assert np.asarray(main.per_skin).shape == (2, 2)
    mean, spread, n = res.headline()
    assert n == 2 and mean == pytest.approx(np.mean([r[-1] for r in main.per_skin]))
    assert spread >= 0 and np.isfinite(mean)
    # skin 1's own curve is the first row of the several-skins curve
    assert res.curve[12].mean_mm == pytest.approx(main.per_skin[0][-1])


@pytest.mark.slow  # the demo: models per skin and curve size
def test_the_default_is_drawn_with_and_without_the_map_prior(demo) -> None:
    _, res = demo
    main, off = res.skins["main"], res.skins["no prior"]
    assert off.arch == NO_PRIOR and off.sizes == main.sizes
    assert np.asarray(off.per_skin).shape == np.asarray(main.per_skin).shape
    # 6 and 12 touches: both within the prior's reach, so both fitted with and without it
    assert res.prior_sizes == [6, 12]
    lines = res.prior_lines()
    assert len(lines) == 2 and lines[0].startswith("6 touches: ")
    assert "with the map prior" in lines[0] and "without" in lines[0]


@pytest.mark.slow  # the demo: models per skin and curve size
def test_report_is_a_notebook_page_with_vector_figures(demo) -> None:
    out, _ = demo
    page = (out / "index.html").read_text(encoding="utf-8")
    for needed in (
        __version__,
        "seed",
        "7 (skins 7-8",
        "response map",
        "paper 64-32-3",
        "map prior, 6 touches",
        "probing floor",
    ):
        assert needed in page, needed
    assert "mean +- std over 2 simulated skins" in page
    for name in ("sensor_image", "predictions_3d", "error_vs_points", "uncertainty"):
        assert (out / f"{name}.png").stat().st_size > 0
        assert (out / f"{name}.svg").read_text(encoding="utf-8").lstrip().startswith("<?xml")
        assert f'href="{name}.svg"' in page
    for kept in ("calibration.h5", "validation.h5", "model.h5"):
        assert (out / kept).exists()


def test_real_skin_figures_cover_the_curve_sizes() -> None:
    for arch in ("default", NO_PRIOR, "paper"):
        assert sorted(REAL_SKIN_ERROR_MM[arch]) == list(DemoConfig().curve_sizes)


def test_reference_curves_are_the_real_skin_figures_and_the_floor() -> None:
    ref = reference_curves()
    assert ref["probing_floor_mm"] == PROBING_FLOOR_MM
    assert set(ref["curves"]) == {"default", NO_PRIOR, "paper"}
    for arch, c in ref["curves"].items():
        assert dict(zip(c["sizes"], c["mean_mm"], strict=True)) == REAL_SKIN_ERROR_MM[arch]
    assert ref["trained_on"].endswith("80PL_1.mat") and len(ref["tested_on"]) == 2


def test_cli_rejects_zero_skins(tmp_path: Path) -> None:
    from skinloc.cli.main import app

    res = runner.invoke(app, ["demo", "--out", str(tmp_path / "d"), "--skins", "0"])
    assert res.exit_code != 0 and "skins" in res.output
    assert not (tmp_path / "d").exists()


def test_without_pytorch_the_demo_leaves_the_paper_net_out_and_says_so(tmp_path, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "torch", None)  # as in a plain install
    cfg = DemoConfig(
        out_dir=tmp_path,
        n_points=8,
        n_validation=3,
        samples_per_touch=3,
        curve_sizes=(8,),
        random_state=3,
        n_skins=1,
        n_validation_extra=2,
    )
    res = run_demo(cfg)
    assert "paper" not in res.skins
    assert "skinloc[nets]" in (tmp_path / "index.html").read_text(encoding="utf-8")
