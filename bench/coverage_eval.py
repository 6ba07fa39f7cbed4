"""Check the coverage map against real errors per region (docs/accuracy.md, "Coverage").

Leave one 2023-12-10 recording out: train the default map on the other three, compute the
expected error (temperature calibrated by cross-validation on the training touches only) at
each test target, and compare with the real error there: rank correlation, and the mean real
error in the thirds of the test touches the map expects to be best, middle and worst.

    python bench/coverage_eval.py [--data ../shared/data/hiro-cone-skin]
"""

from __future__ import annotations

import numpy as np
from _day import DAY, day_parser, load_day
from scipy.stats import spearmanr

from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.geometry.mesh import farthest_point_sampling
from skinloc.models.response_map import shape_features
from skinloc.sensors.coverage import calibrate_temperature, expected_error_mm, gp_state


def main() -> None:
    args = day_parser(__doc__).parse_args()
    recs = list(load_day(args.data).values())
    exp_all, real_all = [], []
    for t, name in enumerate(DAY):
        train = [r for i, r in enumerate(recs) if i != t]
        model = train_localizer(train)
        rmap = model.map_
        F = shape_features(np.concatenate([r.touch_means for r in train]))
        y = np.concatenate([r.targets for r in train])
        temp = calibrate_temperature(y, F, rmap.candidates)
        gp = gp_state(rmap, F)
        grid = rmap.candidates[farthest_point_sampling(rmap.candidates, 400)]
        q = recs[t].targets
        mu_g, mu_q = rmap.evaluate_mm(1e3 * grid), rmap.evaluate_mm(1e3 * q)
        s2_g = temp * (gp.noise + gp.posterior_var(1e3 * grid))
        s2_q = temp * (gp.noise + gp.posterior_var(1e3 * q))
        expected = expected_error_mm(grid, mu_g, s2_g, (q, mu_q, s2_q))
        real = evaluate(model, [recs[t]]).errors_mm
        rho = spearmanr(expected, real).statistic
        print(
            f"{name}: temperature {temp:.0f}; expected mean {expected.mean():.1f} mm, "
            f"real mean {real.mean():.1f} mm, Spearman {rho:.2f}"
        )
        exp_all.append(expected)
        real_all.append(real)
    e, r = np.concatenate(exp_all), np.concatenate(real_all)
    order = np.argsort(e)
    thirds = np.array_split(order, 3)
    print(f"all {len(e)} touches: Spearman {spearmanr(e, r).statistic:.2f}")
    for label, idx in zip(("best", "middle", "worst"), thirds, strict=True):
        print(
            f"  {label} third by expected error: expected {e[idx].mean():.1f} mm, "
            f"real {r[idx].mean():.1f} mm"
        )


if __name__ == "__main__":
    main()
