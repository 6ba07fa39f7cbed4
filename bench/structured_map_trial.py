"""Trial of a structured response map (dropped): each image as a TX profile times an RX profile.

The real touch images are close to rank one (a TX line profile times an RX line profile: 98 %
of the energy in the median touch of 80PL_1), so 16 interpolated line profiles could stand in
for the 64 interpolated sensors. This script builds the default map, replaces its table by the
structured one (raw, renormalised, or half-and-half with the default), and scores each on the
development pair of 2024-05-23 only, with all touches and with random subsets of 10 and 20.

    python bench/structured_map_trial.py --data ../shared/data/hiro-cone-skin

Result (docs/accuracy.md, "Tried and dropped"): no consistent gain.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import evaluate, train_localizer, training_arrays
from skinloc.models.response_map import fit_layer, shape_features


def structured_table(model, recs, mode: str) -> None:
    """Replace ``model.map_``'s table by the outer product of interpolated TX and RX profiles."""
    X, y, _ = training_arrays(recs)
    F = shape_features(X, True)
    tx, rx = recs[0].n_tx, recs[0].n_rx
    U, S, Vt = np.linalg.svd(F.reshape(len(F), tx, rx))
    a = U[:, :, 0] * np.sqrt(S[:, :1])
    b = Vt[:, 0, :] * np.sqrt(S[:, :1])
    sign = np.where(a.sum(axis=1, keepdims=True) < 0, -1.0, 1.0)
    ab = np.hstack([a * sign, b * sign])
    mean = ab.mean(axis=0)
    layer = fit_layer(1e3 * y, ab - mean, None, (2.0, 300.0), None)
    rmap = model.map_
    q = 1e3 * rmap.candidates
    P = np.vstack([layer(q[i : i + 4096]) for i in range(0, len(q), 4096)]) + mean
    T = np.einsum("pi,pj->pij", P[:, :tx], P[:, tx:]).reshape(len(q), -1)
    if mode == "norm":
        T = np.maximum(T, 0.0)
        T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-9)
    elif mode == "blend":
        T = 0.5 * T + 0.5 * rmap.table
    rmap._table = T.astype(np.float32)
    rmap._sq = (rmap._table**2).sum(axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    args = ap.parse_args()
    a = read_recording(args.data / "ConeSkinData_RND_40PL_1.mat")
    b = read_recording(args.data / "ConeSkinData_RND_20PL_2.mat")
    rng = np.random.default_rng(0)
    for train, test, name in [(a, b, "40PL_1 -> 20PL_2"), (b, a, "20PL_2 -> 40PL_1")]:
        for k in [None, 10, 20]:
            if k is not None and k >= train.n_point_logs:
                continue
            draws = (
                [None]
                if k is None
                else [rng.choice(train.n_point_logs, k, replace=False) for _ in range(4)]
            )
            scores: dict[str, list[float]] = {}
            for d in draws:
                tr = train if d is None else train.subset(d)
                for mode in ["default", "raw", "norm", "blend"]:
                    model = train_localizer([tr])
                    if mode != "default":
                        structured_table(model, [tr], mode)
                    scores.setdefault(mode, []).append(evaluate(model, [test]).stats.mean_mm)
            row = ", ".join(f"{m} {np.mean(v):.1f}" for m, v in scores.items())
            print(f"{name}, {k or 'all'} touches: {row} mm")  # noqa: T201


if __name__ == "__main__":
    main()
