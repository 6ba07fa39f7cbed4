"""How far the simulated skin's two-finger images depart from the sum of single-finger images.

For random pairs of contacts on several simulated skins (the paper's cone, fitted defaults,
each finger's pressure and radius drawn as in a session), compares the physical two-finger
image (``sim.fingers.multi_touch_image``: shared crossing fields, line loading, body
re-transmission) with the sum of the two single images (``summed_image``). Prints the relative
L2 difference ``|phys - sum| / |sum|`` (noise-free images, counts) and the change of the
weaker finger's peak, by separation (<30, 30-60, >60 mm) and by whether the fingers sit on
the same TX line, the same RX line or no shared line (the wire passing nearest each finger).

    python bench/multitouch_sim.py --skins 4 --pairs 2000
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from skinloc.geometry.mesh import cone_skin, sample_surface
from skinloc.sim.fingers import Finger, multi_touch_image, nearest_lines, summed_image
from skinloc.sim.skin import SimulatedSkin

SEPARATIONS_MM = ((0, 30), (30, 60), (60, np.inf))
SHARING = ("same TX line", "same RX line", "no shared line")


def _sharing(a: tuple[int, int], b: tuple[int, int]) -> str | None:
    if a[0] == b[0] and a[1] == b[1]:
        return None  # the same crossing: the two fingers overlap
    if a[0] == b[0]:
        return SHARING[0]
    if a[1] == b[1]:
        return SHARING[1]
    return SHARING[2]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, default=4, help="simulated skins (skin seeds 0..N-1)")
    ap.add_argument("--pairs", type=int, default=2000, help="pairs per skin")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print the table as JSON")
    args = ap.parse_args()

    mesh = cone_skin()
    rows: dict[tuple[str, int], list[tuple[float, float]]] = {}
    for skin_seed in range(args.skins):
        skin = SimulatedSkin(mesh, random_state=skin_seed)
        rng = np.random.default_rng([args.seed, skin_seed])
        points, _ = sample_surface(mesh, 2 * args.pairs, rng)
        lines = [nearest_lines(skin.layout, p) for p in points]
        for k in range(args.pairs):
            i, j = 2 * k, 2 * k + 1
            share = _sharing(lines[i], lines[j])
            sep_mm = 1e3 * float(np.linalg.norm(points[i] - points[j]))
            if share is None or sep_mm < 15.0:  # two fingertips do not overlap
                continue
            fingers = []
            for p in (points[i], points[j]):
                pressure, radius = skin.draw_touch(rng, weak=False)
                fingers.append(Finger(p, pressure, radius))
            phys = multi_touch_image(skin.layout, skin.params, fingers)
            summ = summed_image(skin.layout, skin.params, fingers)
            rel = float(np.linalg.norm(phys - summ) / np.linalg.norm(summ))
            # the weaker finger's own peak (its single image's strongest sensor)
            singles = [summed_image(skin.layout, skin.params, [f]) for f in fingers]
            weak = int(np.argmin([s.max() for s in singles]))
            at = int(np.argmax(singles[weak]))
            peak = float(phys[at] / summ[at] - 1.0)
            b = next(n for n, (lo, hi) in enumerate(SEPARATIONS_MM) if lo <= sep_mm < hi)
            rows.setdefault((share, b), []).append((rel, peak))
    table = []
    for share in SHARING:
        for b, (lo, hi) in enumerate(SEPARATIONS_MM):
            vals = np.asarray(rows.get((share, b), []))
            if not len(vals):
                continue
            table.append(
                {
                    "sharing": share,
                    "separation_mm": f"{lo}-{hi:g}" if np.isfinite(hi) else f">{lo}",
                    "pairs": len(vals),
                    "rel_l2_median": float(np.median(vals[:, 0])),
                    "rel_l2_p90": float(np.percentile(vals[:, 0], 90)),
                    "weaker_peak_change_median": float(np.median(vals[:, 1])),
                }
            )
    if args.json:
        json.dump(table, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    print("| fingers | separation mm | pairs | rel. L2 median | rel. L2 p90 | weaker peak |")
    print("|---|---|---|---|---|---|")
    for r in table:
        print(
            f"| {r['sharing']} | {r['separation_mm']} | {r['pairs']} | "
            f"{100 * r['rel_l2_median']:.1f} % | {100 * r['rel_l2_p90']:.1f} % | "
            f"{100 * r['weaker_peak_change_median']:+.1f} % |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
