"""Figures of docs/sensors.md: how well ``skinloc sensors`` finds the crossings.

Simulated skins (one per seed, 80 even touches): error of every crossing against the
simulator's truth, over the sensors not flagged dead, and the lines flagged against the
simulator's faults. Real skin: the crossings estimated from each recording of 2023-12-10
separately, and their pairwise agreement; the lines flagged in each.

    python bench/sensor_map_eval.py --seeds 0 1 2 [--data ../shared/data/hiro-cone-skin]
        [--json bench/results/sensor-map.json] [--label-error-mm 0] [--true-contacts]
        [--fields]

``--fields`` lets ``skinloc sensors`` try the separable line-field model where the
whole-image model is not kept, and use it where it predicts held-out touches better
(``sensors.line_fields``); each result then says which method was used and the held-out scores.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import tempfile
from pathlib import Path

import numpy as np
from _day import DAY, DEFAULT_DATA, have_day, load_day

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.geometry.mesh import cone_skin
from skinloc.sensors import sensor_map as S
from skinloc.sim.skin import SimulatedSkin, SkinParams


def _median_or_nan(v: np.ndarray) -> float:
    """Median of the finite values (nan when there are none: ``--boot 0``)."""
    v = np.asarray(v, float)
    return float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")


def flagged(smap: S.SensorMap) -> list[str]:
    """Lines not ``ok``, e.g. ``["RX 3 weak"]``."""
    return [
        f"{kind.upper()} {i} {st}"
        for kind in ("tx", "rx")
        for i, st in enumerate(smap.line_status[kind])
        if st != "ok"
    ]


#: Injected faults (the simulator's own options): name -> SkinParams changes. ``weak_line_gain``
#: applies to every faulty line of a skin, so a skin has either weak or dead lines.
FAULTS: dict[str, dict] = {
    "none": {"weak_rx_lines": (), "weak_tx_lines": ()},
    "weak TX 4 + RX 3": {"weak_rx_lines": (3,), "weak_tx_lines": (4,)},
    "dead TX 2 + RX 5": {"weak_rx_lines": (5,), "weak_tx_lines": (2,), "weak_line_gain": 0.03},
}


def sim_seed(
    seed: int,
    points: int,
    boot: int,
    label_error_mm: float = S.LABEL_ERROR_MM,
    true_contacts: bool = False,
    faults: dict | None = None,
    fields: bool = False,
) -> dict:
    """Simulate a skin and an even session, locate its sensors, score against the truth.

    ``true_contacts`` locates them from where the finger really landed instead of the labels
    (a diagnostic: the figure without the person's probing error). ``faults`` replaces the
    simulator's default faulty lines (``FAULTS``).
    """
    mesh = cone_skin()
    params = dataclasses.replace(SkinParams.default(), **(faults or {}))
    skin = SimulatedSkin(mesh, params=params, random_state=seed)
    skin.reseed(seed)
    cfg = SessionConfig(n_points=points, mode="even", samples_per_touch=50, random_state=seed)
    with tempfile.TemporaryDirectory() as tmp:
        rec = simulate_session(skin, mesh, Path(tmp) / "s.h5", cfg)
    if true_contacts:
        rec = dataclasses.replace(
            rec, targets=np.asarray(rec.meta["true_contacts"], float).reshape(-1, 3)
        )
    smap = S.sensor_map_from_recordings(
        [rec], n_boot=boot, random_state=seed, label_error_mm=label_error_mm, fields=fields
    )
    truth = S.truth_sensor_positions(rec.meta)
    err = S.position_errors_mm(smap.positions_m, truth)
    alive = smap.status != "dead"
    p = skin.params
    true_faults = [f"RX {j}" for j in p.weak_rx_lines] + [f"TX {i}" for i in p.weak_tx_lines]
    found = flagged(smap)
    false_alarms = [f for f in found if " ".join(f.split()[:2]) not in true_faults]
    noisy_true = {tx * skin.layout.n_rx + rx for tx, rx in p.noisy_sensors}
    noisy_found = set(np.flatnonzero(smap.status == "noisy").tolist())
    return {
        "seed": seed,
        "method": smap.method,
        "median_mm": float(np.median(err[alive])),
        "p90_mm": float(np.percentile(err[alive], 90)),
        "errors_mm": err[alive].round(2).tolist(),
        "uncertainty_median_mm": _median_or_nan(smap.uncertainty_mm),
        "footprint_median_mm": float(np.median(smap.footprint_mm)),
        "lines_flagged": found,
        "true_faulty_lines": true_faults,
        "line_false_alarms": false_alarms,
        "missed_lines": [t for t in true_faults if not any(f.startswith(t + " ") for f in found)],
        "noisy_sensors_true": sorted(noisy_true),
        "noisy_sensors_found": sorted(noisy_found),
    }


def real(data: Path, boot: int, fields: bool = False) -> dict:
    """Crossings from each recording of 2023-12-10 alone, and their pairwise agreement."""
    recs = load_day(data)
    maps = {
        name: S.sensor_map_from_recordings([r], n_boot=boot, fields=fields)
        for name, r in recs.items()
    }
    pairs = []
    for a, b in itertools.combinations(DAY, 2):
        d = S.position_errors_mm(maps[a].positions_m, maps[b].positions_m)
        ok = (maps[a].status != "dead") & (maps[b].status != "dead")
        pairs.append(
            {
                "a": a,
                "b": b,
                "median_mm": float(np.median(d[ok])),
                "p90_mm": float(np.percentile(d[ok], 90)),
            }
        )
    return {
        "pairs": pairs,
        "median_of_pair_medians_mm": float(np.median([p["median_mm"] for p in pairs])),
        "flagged": {name: flagged(m) for name, m in maps.items()},
        "method": {name: m.method for name, m in maps.items()},
        "heldout": {name: m.heldout for name, m in maps.items()},
        "uncertainty_median_mm": {
            name: _median_or_nan(m.uncertainty_mm) for name, m in maps.items()
        },
        "rx_line_gain": {
            name: [round(g, 2) for g in m.line_gain["rx"]] for name, m in maps.items()
        },
        "tx_line_gain": {
            name: [round(g, 2) for g in m.line_gain["tx"]] for name, m in maps.items()
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--points", type=int, default=80)
    ap.add_argument("--boot", type=int, default=8)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--label-error-mm",
        type=float,
        default=S.LABEL_ERROR_MM,
        help="prior of the person's miss per axis; 0 takes the labels as exact",
    )
    ap.add_argument(
        "--true-contacts",
        action="store_true",
        help="simulated skins only: locate from the true contacts, not the labels",
    )
    ap.add_argument(
        "--fault-seeds",
        type=int,
        nargs="*",
        default=[],
        help="also simulate these seeds with each set of injected faults (FAULTS)",
    )
    ap.add_argument(
        "--fields",
        action="store_true",
        help="try the line-field model where the whole-image model is not kept",
    )
    args = ap.parse_args()
    faulty = []
    for name, change in FAULTS.items():
        for s in args.fault_seeds:
            r = sim_seed(s, args.points, 0, args.label_error_mm, faults=change, fields=args.fields)
            r.pop("errors_mm")
            r["faults"] = name
            faulty.append(r)
            print(
                f"faults '{name}', seed {s}: flagged {r['lines_flagged']}, missed"
                f" {r['missed_lines']}, false alarms {r['line_false_alarms']};"
                f" median {r['median_mm']:.2f} mm, p90 {r['p90_mm']:.2f} mm",
                flush=True,
            )
    sims = [
        sim_seed(
            s, args.points, args.boot, args.label_error_mm, args.true_contacts, fields=args.fields
        )
        for s in args.seeds
    ]
    out: dict = {"sim": sims, "faults": faulty}
    if out["sim"]:
        all_err = np.concatenate([r["errors_mm"] for r in out["sim"]])
        out["sim_pooled"] = {
            "median_mm": float(np.median(all_err)),
            "p90_mm": float(np.percentile(all_err, 90)),
            "line_false_alarms": sum(len(r["line_false_alarms"]) for r in out["sim"]),
            "missed_lines": sum(len(r["missed_lines"]) for r in out["sim"]),
        }
        for r in out["sim"]:
            print(
                f"sim seed {r['seed']}: median {r['median_mm']:.2f} mm, p90 {r['p90_mm']:.2f} mm;"
                f" flagged {r['lines_flagged']} (true {r['true_faulty_lines']}); noisy sensors"
                f" {r['noisy_sensors_found']} (true {r['noisy_sensors_true']})"
            )
        p = out["sim_pooled"]
        print(f"sim pooled: median {p['median_mm']:.2f} mm, p90 {p['p90_mm']:.2f} mm")
    if have_day(args.data):
        out["real"] = real(args.data, args.boot, args.fields)
        print("real method:", out["real"]["method"])
        for pr in out["real"]["pairs"]:
            print(f"real {pr['a']} vs {pr['b']}: median {pr['median_mm']:.2f} mm")
        print("real flagged:", out["real"]["flagged"])
    for r in out["sim"]:
        r.pop("errors_mm")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
