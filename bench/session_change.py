"""What changes between two sessions of the real skin, and what a touch-free capture can see.

The recordings of 2023-12-10 and 2024-05-23 (the same cone skin, five months apart). A
reference is built from 2023-12-10's 80PL_1 and 50PL_1 (130 touches); it is compared with the
same day's 20PL_1 and 30PL_1 (50 touches: what changes within a session, and the estimation
noise at that size) and with 2024-05-23's 20PL_2 and 40PL_1 (60 touches: what changes between
sessions). Per sensor, from the one sensor map (``skinloc sensors``'s ``SensorMap``: each
crossing's position, gain and footprint, the no-touch noise, the health classifier's flags):

- touch-free (a baseline capture alone measures it): baseline shift (counts), noise ratio,
  dead / weak / noisy sensors and lines;
- touches only: gain ratio per sensor and per line, footprint ratio, crossing displacement
  (mm) and the rigid part of it (the best rotation and translation, Kabsch, over the crossings).

    python bench/session_change.py --data ../shared/data/hiro-cone-skin --out change.json

``--simulated CHANGE`` measures a simulated pair the same way instead (``skinloc.sim.
session_change``; skin seed 0: 130 touches, then 60 of the same session and 60 of a later one,
20 frames a touch): what the simulated change looks like through the real figures' lens.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from skinloc.bench.paper import REAL_MAY
from skinloc.data.recording import read_recording
from skinloc.sensors.sensor_map import sensor_map_from_recordings

REFERENCE = ("ConeSkinData80Points_RND_80PL_1.mat", "ConeSkinData50Points_RND_50PL_1.mat")
SAME_DAY = ("ConeSkinData_RND_20PL_1.mat", "ConeSkinData30Points_RND_30PL_1.mat")


def rigid_fit(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """Best rotation (deg) and translation (mm) taking points ``a`` onto ``b`` ``(n, 3)`` m, and
    the residual (median mm) once removed (Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))
    moved = (a - ca) @ r.T + cb
    residual = float(np.median(np.linalg.norm(moved - b, axis=1)) * 1e3)
    return angle, float(np.linalg.norm(cb - ca) * 1e3), residual


def compare(ref_recs, ref_map, recs, smap, n_tx: int, n_rx: int) -> dict:
    """The figures of one comparison with the reference."""
    base_ref = np.median(np.stack([r.baseline for r in ref_recs]), axis=0)
    base = np.median(np.stack([r.baseline for r in recs]), axis=0)
    noise_ratio = smap.noise_counts / np.maximum(ref_map.noise_counts, 1e-9)
    ok = (ref_map.gain > 0) & (smap.gain > 0) & np.isfinite(ref_map.gain) & np.isfinite(smap.gain)
    gain_ratio = np.where(ok, smap.gain / np.where(ok, ref_map.gain, 1.0), np.nan)
    grid = gain_ratio.reshape(n_tx, n_rx)
    tx_line = np.nanmedian(grid, axis=1)
    rx_line = np.nanmedian(grid, axis=0)
    foot = smap.footprint_mm / np.maximum(ref_map.footprint_mm, 1e-9)
    disp = np.linalg.norm(smap.positions_m - ref_map.positions_m, axis=1) * 1e3
    angle, shift, residual = rigid_fit(ref_map.positions_m[ok], smap.positions_m[ok])
    lg = np.log(gain_ratio[ok])

    def flagged(m) -> dict:
        return {
            "sensors": {s: int((m.status == s).sum()) for s in ("dead", "weak", "noisy")},
            "lines": {
                k: [i for i, st in enumerate(v) if st != "ok"] for k, v in m.line_status.items()
            },
        }

    return {
        "n_touches": int(sum(r.n_point_logs for r in recs)),
        "baseline_shift_counts_median_abs": float(np.median(np.abs(base - base_ref))),
        "baseline_shift_counts_max_abs": float(np.max(np.abs(base - base_ref))),
        "noise_ratio_median": float(np.median(noise_ratio)),
        "noise_ratio_p5_p95": [float(v) for v in np.percentile(noise_ratio, [5, 95])],
        "gain_ratio_median": float(np.exp(np.median(lg))),
        "gain_ratio_p5_p95": [float(v) for v in np.exp(np.percentile(lg, [5, 95]))],
        "gain_ratio_outside_0.67_1.5": float(np.mean((lg < np.log(0.67)) | (lg > np.log(1.5)))),
        "gain_spread_log_std": float(np.std(lg)),
        "tx_line_gain_ratio": [round(float(v), 2) for v in tx_line],
        "rx_line_gain_ratio": [round(float(v), 2) for v in rx_line],
        "footprint_ratio_median": float(np.nanmedian(foot)),
        "crossing_displacement_mm_median": float(np.median(disp)),
        "rigid_rotation_deg": angle,
        "rigid_translation_mm": shift,
        "rigid_residual_mm_median": residual,
        "flags": flagged(smap),
    }


def simulated_groups(change: str, skin_seed: int = 0, change_seed: int = 3) -> dict:
    """Recordings of a simulated pair: the reference, the same day, and a later session."""
    import tempfile

    from skinloc.calibration.session import SessionConfig, simulate_session
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sim.session_change import later_session
    from skinloc.sim.skin import SimulatedSkin

    mesh, tmp = cone_skin(), Path(tempfile.mkdtemp())
    skin = SimulatedSkin(mesh, random_state=skin_seed)

    def session(s: SimulatedSkin, n: int, seed: int, name: str):
        s.reseed(seed)
        cfg = SessionConfig(n_points=n, mode="random", samples_per_touch=20, random_state=seed)
        return [simulate_session(s, mesh, tmp / f"{name}.h5", cfg)]

    return {
        "reference": session(skin, 130, 1, "reference"),
        "same_day": session(skin, 60, 2, "same"),
        "later": session(later_session(skin, change, change_seed), 60, 4, "later"),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--simulated", choices=["real", "mild"], help="a simulated pair instead")
    args = ap.parse_args(argv)
    if args.simulated:
        groups = simulated_groups(args.simulated)
    else:
        names = (*REFERENCE, *SAME_DAY, *REAL_MAY)
        missing = [n for n in names if not (args.data / n).is_file()]
        if missing:
            raise SystemExit(f"error: {args.data} lacks {', '.join(missing)} (give --data)")
        load = {n: read_recording(args.data / n) for n in names}
        groups = {
            "reference": [load[n] for n in REFERENCE],
            "same_day": [load[n] for n in SAME_DAY],
            "five_months": [load[n] for n in REAL_MAY],
        }
    maps = {k: sensor_map_from_recordings(v, n_boot=0) for k, v in groups.items()}
    first = groups["reference"][0]
    out = {
        "reference": {"n_touches": int(sum(r.n_point_logs for r in groups["reference"]))},
        "reference_flags": compare(
            groups["reference"], maps["reference"], groups["reference"], maps["reference"],
            first.n_tx, first.n_rx,
        )["flags"],
    }  # fmt: skip
    for k in [g for g in groups if g != "reference"]:
        out[k] = compare(
            groups["reference"], maps["reference"], groups[k], maps[k], first.n_tx, first.n_rx
        )
    print(json.dumps(out, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
