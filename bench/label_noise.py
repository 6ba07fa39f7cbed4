"""The label-noise floor on the real recordings of 2023-12-10 (docs/accuracy.md).

Targets were reused between the sessions of that day. For every pair of recordings, the
shared targets' two touches are localised by a default map trained on the other recordings
of the day (neither touch in training); the per-touch repeatability is RMS(d) / sqrt(2).

    python bench/label_noise.py [--data ../shared/data/hiro-cone-skin]
"""

from __future__ import annotations

import itertools

import numpy as np
from _day import DAY, day_parser, load_day

from skinloc.evaluation.repeatability import probing_repeatability_mm, repeated_pairs
from skinloc.evaluation.scoring import train_localizer


def main() -> None:
    args = day_parser(__doc__).parse_args()
    recs = list(load_day(args.data).values())
    pa, pb = [], []
    for a, b in itertools.combinations(range(len(recs)), 2):
        shared = [p for p in repeated_pairs([recs[a], recs[b]]) if p[0] == 0 and p[2] == 1]
        if not shared:
            continue
        model = train_localizer([r for i, r in enumerate(recs) if i not in (a, b)])
        ia = [p[1] for p in shared]
        ib = [p[3] for p in shared]
        xa = model.predict(recs[a].touch_means[ia])
        xb = model.predict(recs[b].touch_means[ib])
        r = probing_repeatability_mm(xa, xb)
        print(f"{DAY[a]} x {DAY[b]}: {r['n_pairs']} shared targets, floor {r['rms_mm']:.1f} mm")
        pa.append(xa)
        pb.append(xb)
    r = probing_repeatability_mm(np.concatenate(pa), np.concatenate(pb))
    print(
        f"all: {r['n_pairs']} pairs; probing repeatability {r['rms_mm']:.1f} mm per touch "
        f"(median pair distance {r['median_pair_mm']:.1f} mm)"
    )


if __name__ == "__main__":
    main()
