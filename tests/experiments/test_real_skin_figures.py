"""The demo's real-skin figures (``REAL_SKIN_ERROR_MM``) recomputed from the recordings."""

from __future__ import annotations

from pathlib import Path

import pytest

from skinloc.experiments.demo import REAL_SKIN_ERROR_MM, REAL_SKIN_SPLIT, real_skin_errors

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "hiro-cone-skin"

pytestmark = [
    pytest.mark.real,
    pytest.mark.skipif(
        not all((DATA / n).is_file() for n in REAL_SKIN_SPLIT),
        reason="the real recordings are not beside the repository",
    ),
]


@pytest.mark.parametrize("arch", ["default", "default, no prior"])
def test_the_real_skin_figures_are_current(arch):
    # the paper's network (PyTorch, minutes of training) is left to bench/fit_simulator.py
    got = real_skin_errors(DATA, arch)
    want = REAL_SKIN_ERROR_MM[arch]
    assert got.keys() == want.keys()
    for n, mm in want.items():
        assert got[n] == pytest.approx(mm, abs=0.15), (n, got, want)
