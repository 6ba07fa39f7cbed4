"""The skin's two-point threshold: the bins, the words, the calibration, old model files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from skinloc.models.localizer import ContactLocalizer
from skinloc.models.multi_contact.two_point import (
    describe,
    placed_both,
    recogniser_mm,
    threshold_from_pairs,
    two_point_of,
)
from tests._live import model_path

GOLDEN_MODEL = Path(__file__).resolve().parents[2] / "golden" / "model_main_default.h5"


def _pairs(rates: dict[float, tuple[float, float]], n: int = 20):
    """Pairs ``n`` per bin at separation ``lo + 5`` mm, counted / placed at the given rates."""
    sep, two, placed = [], [], []
    for lo, (r_two, r_placed) in rates.items():
        k2, kp = round(r_two * n), round(r_placed * n)
        sep += [lo + 5.0] * n
        two += [True] * k2 + [False] * (n - k2)
        placed += [True] * kp + [False] * (n - kp)
    return np.array(sep), np.array(two), np.array(placed)


def test_the_threshold_is_the_first_bin_from_which_every_bin_reaches_the_share():
    rates = {10: (0.2, 0.1), 20: (0.95, 0.5), 30: (0.6, 0.5), 40: (0.9, 0.9), 50: (1.0, 0.95)}
    tp = threshold_from_pairs(*_pairs(rates))
    assert tp["counted_two_mm"] == 40.0  # 20-30 reaches it, but 30-40 does not
    assert tp["threshold_mm"] == 40.0
    assert tp["bins"]["10-20"]["n"] == 20 and tp["n_pairs"] == 100
    # placing both also needs counting two: a pair placed but counted one is not placed
    tp = threshold_from_pairs(*_pairs({40: (0.5, 1.0), 50: (0.95, 0.95)}))
    assert tp["bins"]["40-50"]["all_within_15mm"] == pytest.approx(0.5)
    assert tp["counted_two_mm"] == 50.0


def test_no_separation_placing_both_gives_none_and_small_bins_decide_nothing():
    tp = threshold_from_pairs(*_pairs({30: (0.95, 0.6), 40: (1.0, 0.7)}))
    assert tp["counted_two_mm"] == 30.0 and tp["threshold_mm"] is None
    few = _pairs({10: (0.0, 0.0)}, n=3)
    many = _pairs({30: (1.0, 1.0)})
    tp = threshold_from_pairs(*(np.concatenate(p) for p in zip(few, many, strict=True)))
    assert tp["bins"]["10-20"]["n"] == 3 and tp["counted_two_mm"] == 30.0
    tp = threshold_from_pairs(*_pairs({30: (0.5, 0.0), 40: (0.5, 0.0)}))
    assert tp["counted_two_mm"] is None and tp["threshold_mm"] is None


def test_placed_both_takes_the_better_assignment():
    true = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]])
    assert placed_both(true[::-1] + [0.01, 0.0, 0.0], true)
    assert not placed_both(true + [[0.02, 0, 0], [0, 0, 0]], true)
    assert not placed_both(true[:1], true)


def test_the_words_a_person_reads():
    assert "unknown" in describe(None)
    none = describe({"counted_two_mm": 50.0, "threshold_mm": None})
    assert "none" in none and "closer than 50 mm are read as one" in none
    assert describe({"counted_two_mm": 30.0, "threshold_mm": 40.0}).startswith(
        "two-point threshold: 40 mm"
    )
    assert "not counted two" in describe({"counted_two_mm": None, "threshold_mm": None})


def test_fit_measures_it_and_the_model_file_keeps_it(tmp_path):
    model = ContactLocalizer.load(model_path("map"))
    tp = two_point_of(model.contact_rule_)
    assert tp is not None and tp["n_pairs"] >= 20
    assert sum(b["n"] for b in tp["bins"].values()) <= tp["n_pairs"]
    for b in tp["bins"].values():
        assert 0.0 <= b["all_within_15mm"] <= b["counted_two"] <= 1.0
    # farther pairs are counted two more often than the closest ones
    counts = [b["counted_two"] for b in tp["bins"].values() if b["n"] >= 5]
    assert counts[-1] >= counts[0]
    if tp["counted_two_mm"] is not None and tp["threshold_mm"] is not None:
        assert tp["threshold_mm"] >= tp["counted_two_mm"]
    model.save(tmp_path / "again.h5")
    assert two_point_of(ContactLocalizer.load(tmp_path / "again.h5").contact_rule_) == tp


def test_model_files_saved_before_it_load_with_it_unknown():
    model = ContactLocalizer.load(GOLDEN_MODEL)
    assert model.contact_rule_ is None or "two_point" not in model.contact_rule_
    assert two_point_of(model.contact_rule_) is None
    assert "unknown" in describe(two_point_of(model.contact_rule_))
    assert two_point_of({"tau2": 1.0, "two_point": None}) is None


def test_the_recogniser_takes_the_full_threshold_else_the_count():
    assert recogniser_mm({"counted_two_mm": 50.0, "threshold_mm": 70.0}) == (70.0, "placed")
    assert recogniser_mm({"counted_two_mm": 50.0, "threshold_mm": None}) == (50.0, "counted")
    # measured, and no separation is counted two: two fingers are never sure by distance
    assert recogniser_mm({"counted_two_mm": None, "threshold_mm": None}) == (math.inf, "none")
    assert recogniser_mm(None) == (None, "unknown")
    # a damaged value is not a threshold
    assert recogniser_mm({"counted_two_mm": -5.0, "threshold_mm": "x"})[1] == "none"
