"""``skinloc demo`` prints the default model's error with and without the map prior."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from skinloc.evaluation.metrics import error_stats
from skinloc.experiments import demo
from skinloc.experiments.demo import NO_PRIOR, REAL_SKIN_ERROR_MM, DemoResult, SkinCurve


def test_demo_prints_both_figures_where_the_prior_was_applied(tmp_path, monkeypatch):
    from skinloc.cli.main import app

    seen = {}

    def fake_run_demo(cfg, step=None):  # the demo's models are tested in tests/experiments
        seen["sizes"] = cfg.curve_sizes
        sizes = list(cfg.curve_sizes)
        main = SkinCurve("default", sizes, [[30.0, 15.0, 10.0, 9.0, 8.0]] * 2)
        off = SkinCurve(NO_PRIOR, sizes, [[40.0, 16.0, 10.0, 9.0, 8.0]] * 2)
        stats = error_stats(np.array([5.0, 7.0]))
        return DemoResult(
            stats,
            29.0,
            {},
            tmp_path / "index.html",
            1.0,
            {"main": main, "no prior": off},
            0.5,
            [5, 10],
        )

    monkeypatch.setattr(demo, "run_demo", fake_run_demo)
    res = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "d")])
    assert res.exit_code == 0, res.output
    assert seen["sizes"] == (5, 10, 20, 40, 80)
    out = " ".join(res.output.split())
    assert "With 5 touches: 30.0 +- 0.0 mm with the map prior, 40.0 +- 0.0 mm without" in out
    real = [REAL_SKIN_ERROR_MM[a][5] for a in ("default", NO_PRIOR)]
    assert f"real skin {real[0]:.1f} / {real[1]:.1f} mm" in out
    assert "With 10 touches" in out and "With 20 touches" not in out
