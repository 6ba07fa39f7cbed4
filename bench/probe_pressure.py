"""Does pressing each target at several depths reduce per-frame gross errors? (docs/accuracy.md)

Simulated skins only (no real arm). Three parts:

The real recordings (``--data``-free: ``../shared/data/hiro-cone-skin``, 2023-12-10) are only
read for part 2 and skipped when absent.

1. The simulator's pressure model: for a pressure P (a probe's depth / 2 mm), the peak signal
   and the normalised image's cosine to P = 1's at the same point (the default map matches
   normalised images, so only a change of shape can move a located touch), over random points
   of skin 11.
2. How touches vary: per touch, the peak sensor's frame-to-frame spread relative to its mean
   (and beyond the noise), and the peak's touch-to-touch spread, real recordings against
   simulated fresh touches; where the gross frames (> 30 mm) fall: the share of them in light
   touches (peak under half the median), on the real skin (the 80-touch session's default
   model on the other real sessions, against their prompted targets) and in every run below.
3. The comparison, for each skin seed: ``skinloc collect --probe sim`` pressing each target at
   one depth (2 mm) or at several (``--press-depth-mm 1,2,3``), at equal targets and at equal
   presses, the default model trained on each, scored per frame on fresh human-like touches
   (``skinloc simulate --seed 100 --mode random``: pressure and finger size drawn per touch)
   against where the finger really pressed.

    python bench/probe_pressure.py [--skins 11 12] [--fresh 80] [--depths 1,2,3] [--out F]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import trimesh
from _day import DAY
from probe_accuracy import fresh_touches, skinloc, truth

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.geometry.mesh import cone_skin
from skinloc.sim.signal import sensor_image
from skinloc.sim.skin import SimulatedSkin

REAL = Path(__file__).resolve().parents[1] / "../shared/data/hiro-cone-skin"
#: The real session of 2023-12-10: its 80-touch recording trains, the others are tested.
REAL_TRAIN = "ConeSkinData80Points_RND_80PL_1.mat"
NOMINAL_DEPTH_MM = 2.0


def pressure_model(seed: int, depths_mm: list[float], n: int = 200) -> list[dict]:
    """Peak signal and image shape against P = 1, at ``n`` random points of skin ``seed``."""
    skin = SimulatedSkin(cone_skin(), random_state=seed)
    points = np.asarray(trimesh.sample.sample_surface(skin.mesh, n, seed=seed)[0], dtype=float)
    p, lay = skin.params, skin.layout
    out = []

    def image(x: np.ndarray, pressure: float) -> np.ndarray:
        radius = p.finger_radius_m * pressure**p.radius_pressure_exponent
        return sensor_image(lay, p, x, pressure, radius)

    ref = np.array([image(x, 1.0) for x in points])
    for d in depths_mm:
        pressure = d / NOMINAL_DEPTH_MM
        radius_mm = 1e3 * p.finger_radius_m * pressure**p.radius_pressure_exponent
        imgs = np.array([image(x, pressure) for x in points])
        cos = (imgs * ref).sum(1) / (np.linalg.norm(imgs, axis=1) * np.linalg.norm(ref, axis=1))
        out.append(
            {
                "depth_mm": d,
                "pressure": pressure,
                "radius_mm": round(radius_mm, 2),
                "peak_vs_p1": round(float(np.median(imgs.max(1) / ref.max(1))), 3),
                "cosine_to_p1_median": round(float(np.median(cos)), 5),
                "cosine_to_p1_min": round(float(cos.min()), 5),
                "peak_counts_median": round(float(np.median(imgs.max(1))), 1),
                "noise_counts": p.noise_std_counts,
            }
        )
    return out


def within_touch(rec) -> dict:
    """Per touch: the peak sensor's frame-to-frame spread / its mean, median over touches.

    Also that spread beyond the baseline's noise, and the touch-to-touch spread of the peak.
    """
    deltas = rec.deltas  # (n, frames, sensors) counts over the baseline
    means = deltas.mean(axis=1)
    peak = means.argmax(axis=1)
    rows = np.take_along_axis(deltas, peak[:, None, None], axis=2)[..., 0]  # (n, frames)
    cv = rows.std(axis=1) / np.maximum(rows.mean(axis=1), 1e-9)
    # the peak's frames against the noise alone: the part of the spread noise does not explain
    noise = float(np.median(rec.baseline_frames.std(axis=0)))
    excess = np.sqrt(np.maximum(rows.var(axis=1) - noise**2, 0.0)) / np.maximum(
        rows.mean(axis=1), 1e-9
    )
    # each frame's normalised image against its touch's (the shape change within a touch)
    unit = deltas / np.maximum(np.linalg.norm(deltas, axis=2, keepdims=True), 1e-9)
    mean_unit = means / np.maximum(np.linalg.norm(means, axis=1, keepdims=True), 1e-9)
    shape = np.linalg.norm(unit - mean_unit[:, None, :], axis=2)
    return {
        "touches": int(len(rows)),
        "frame_shape_change_median": round(float(np.median(shape)), 3),
        "frame_shape_change_p99": round(float(np.percentile(shape, 99)), 3),
        "peak_cv_median": round(float(np.median(cv)), 3),
        "peak_cv_p90": round(float(np.percentile(cv, 90)), 3),
        "peak_spread_beyond_noise_median": round(float(np.median(excess)), 3),
        "touch_peak_cv": round(float(means.max(1).std() / means.max(1).mean()), 3),
    }


def gross_in_light(model, test) -> dict:
    """Frames > 30 mm off, and the share of them in light touches (peak < half the median)."""
    frame = evaluate(model, [test], per_frame=True)
    gross = frame.errors_mm.reshape(test.n_point_logs, -1) > 30
    peaks = test.deltas.mean(axis=1).max(axis=1)
    light = peaks < 0.5 * np.median(peaks)
    return {
        "frames_over_30mm_pct": round(100 * float(gross.mean()), 2),
        "light_touches_pct": round(100 * float(light.mean()), 1),
        "gross_frames_in_light_touches_pct": round(
            100 * float(gross[light].sum() / max(gross.sum(), 1)), 1
        ),
    }


def score(cal: Path, test: list) -> dict:
    rec = read_recording(cal)
    model = train_localizer([rec])
    touch = evaluate(model, test).stats
    frame = evaluate(model, test, per_frame=True)
    return {
        "presses": rec.n_point_logs,
        "targets": len({tuple(np.round(t, 6)) for t in rec.planned_targets}),
        "touch_mean_mm": round(touch.mean_mm, 2),
        "frame_mean_mm": round(frame.stats.mean_mm, 2),
        "frame_median_mm": round(frame.stats.median_mm, 2),
        "frames_over_30mm_pct": round(100 * float(np.mean(frame.errors_mm > 30)), 2),
        "gross_frames_in_light_touches_pct": gross_in_light(model, test[0])[
            "gross_frames_in_light_touches_pct"
        ],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, nargs="+", default=[11, 12])
    ap.add_argument("--targets", type=int, default=80, help="targets of the one-depth plan")
    ap.add_argument("--depths", default="1,2,3", help="the several depths, mm")
    ap.add_argument("--fresh", type=int, default=80, help="fresh human-like touches per skin")
    ap.add_argument("--out", type=Path, default=None, help="write everything as JSON here")
    args = ap.parse_args()
    depths = [float(x) for x in args.depths.split(",")]
    k, n = len(depths), args.targets
    result: dict = {"depths_mm": depths, "model": pressure_model(11, [0.5, *depths, 4.0])}
    for r in result["model"]:
        print(json.dumps(r), flush=True)
    real = {name: read_recording(REAL / name) for name in DAY if (REAL / name).is_file()}
    result["within_touch_real"] = {name: within_touch(rec) for name, rec in real.items()}
    if REAL_TRAIN in real:  # the real skin's gross frames: 80PL_1's model on the day's others
        model = train_localizer([real[REAL_TRAIN]])
        result["gross_real"] = {
            name: gross_in_light(model, rec) for name, rec in real.items() if name != REAL_TRAIN
        }
    for key in ("within_touch_real", "gross_real"):
        for name, r in result.get(key, {}).items():
            print(key, name, json.dumps(r), flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for s in args.skins:
            fresh = fresh_touches(d, s, args.fresh)
            result.setdefault("within_touch_sim", {})[s] = within_touch(read_recording(fresh))
            print("within_touch_sim", s, json.dumps(result["within_touch_sim"][s]), flush=True)
            test = [truth(fresh)]
            runs = {  # name: (targets, depths)
                "one depth, n targets": (n, "2"),
                f"{k} depths, n targets": (n, args.depths),
                f"one depth, {k}n targets": (k * n, "2"),
                f"{k} depths, n/{k} targets": (round(n / k), args.depths),
            }
            for name, (targets, press) in runs.items():
                cal = d / f"cal{s}_{targets}_{press}.h5"
                skinloc(
                    "collect", "--probe", "sim", "--points", targets, "--skin-seed", s,
                    "--press-depth-mm", press, "--out", cal,
                )  # fmt: skip
                row = {"skin": s, "run": name, "depths_mm": press, **score(cal, test)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    result["runs"] = rows
    for name in dict.fromkeys(r["run"] for r in rows):
        sel = [r for r in rows if r["run"] == name]
        m = {
            key: np.mean([r[key] for r in sel])
            for key in ("presses", "touch_mean_mm", "frame_median_mm", "frames_over_30mm_pct")
        }
        print(
            f"| {name} | {m['presses']:.0f} | {m['touch_mean_mm']:.2f} | "
            f"{m['frame_median_mm']:.2f} | {m['frames_over_30mm_pct']:.2f} % |"
        )
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
