"""``prior_curve``: one skin's error against calibration touches with and without the prior."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.evaluation.scoring import evaluate, prior_curve, train_localizer


@pytest.mark.slow  # maps fitted at four sizes, with and without the prior
def test_the_curve_fits_with_and_without_the_prior_where_it_applies(recording_factory):
    train, test = recording_factory(24, 3, random_state=1), recording_factory(5, 3, random_state=2)
    curve = prior_curve(train, [test], sizes=(5, 10, 20, 40))
    # sizes past the recording are dropped; all of its touches are always the last size
    assert curve["sizes"] == [5, 10, 20, 24]
    assert len(curve["prior_mm"]) == len(curve["no_prior_mm"]) == 4
    assert all(np.isfinite(curve["prior_mm"])) and all(np.isfinite(curve["no_prior_mm"]))
    # the package's prior helps up to 15 touches: beyond, one model and one figure
    assert curve["prior_applied"] == [True, True, False, False]
    assert curve["prior_mm"][2:] == curve["no_prior_mm"][2:]
    # the "no prior" point is today's --no-prior model on the same touches
    plain = train_localizer([train], prior="none")
    assert curve["no_prior_mm"][-1] == round(float(evaluate(plain, [test]).stats.mean_mm), 1)
