"""Calibrating the multi-contact count rule on the training recording alone.

There are no multi-touch calibration recordings, so the rule (``multi_contact.CountRule``) is
set by cross-validation over the training point logs: the amplitude map is fitted on all but a
fold of point logs, and the fold's touches are searched alone (touch means and single frames)
and summed in pairs and triples of touches at least ``min_separation_mm`` apart (means, and
frames summed with frames, as two fingers' images add). The rule's ``misfit`` is the median
share of a held-out touch mean's (whitened) energy that one contact leaves unexplained: the
model's own error on a touch it was not fitted to. ``tau2`` is the ``1 - false_rate``
quantile of the relative residual reduction a second contact brings to the single touches
(measured against the two-contact residual plus ``misfit`` times the image's energy),
``tau3`` the same for a third contact on the pairs: at most ``false_rate`` of the held-out
touches are counted one too many. Nothing of the recordings a model is tested on is used.
The same folds measure the skin's two-point threshold (``two_point``): pairs of held-out touch
means at every separation, counted by the calibrated rule and placed by the search.
"""

from __future__ import annotations

import itertools
from dataclasses import replace
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.models.multi_contact.contacts import N_COLS, CountRule, noise_weights
from skinloc.models.multi_contact.footprint import (
    N_FEATURES,
    PAIR_MM,
    calibrate_footprint,
    footprint_features,
)
from skinloc.models.multi_contact.landing import calibrate_landing
from skinloc.models.multi_contact.search import (
    STAT_G2,
    STAT_ROW1,
    SearchTables,
    search_into,
)
from skinloc.models.multi_contact.two_point import placed_both, threshold_from_pairs
from skinloc.models.response_map import AmplitudeMap

__all__ = [
    "calibrate_count_rule",
    "count_statistics",
    "pair_statistics",
    "rule_statistics",
    "search_statistics",
    "sensor_noise_from_frames",
    "two_point_threshold",
]

#: Fewest point logs to calibrate on; fewer keep the default rule.
MIN_POINT_LOGS = 10
#: Extra touch means per held-out touch, each of a random half of its frames.
SUB_MEANS = 4
#: Most pairs (triples: a quarter) searched per fold.
MAX_SETS = 200
#: Share of held-out touches the calibrated rule may count one too many.
FALSE_RATE = 0.02
#: Power of the weakest contact's peak signal in the calibrated rule's statistic (chosen by
#: cross-validation inside 80PL_1, bench/multitouch_diagnose.py: 1 counts 2-5 % more held-out
#: pairs than 0 at the same false rate over three fold splits; 2 about the same as 1).
Z_POWER = 1.0
#: Most pairs per fold, at every separation, the two-point threshold is measured on.
TWO_POINT_SETS = 120
#: Least strength ratio (weaker / stronger) of its pairs: two fingers of similar strength.
TWO_POINT_RATIO = 0.5
#: Weakest-contact peak signals (noise levels) the calibration chooses among.
Z_GRID = (8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0)


def sensor_noise_from_frames(X: np.ndarray, groups: np.ndarray | None) -> np.ndarray | None:
    """Noise per sensor, counts ``(k,)``: the median over touches of each touch's frame scatter.

    Most touches leave most sensors alone, so the median is the no-touch noise. ``None`` when
    no touch has two frames.
    """
    if groups is None:
        return None
    X = np.asarray(X, dtype=np.float64)
    _, inv, counts = np.unique(np.asarray(groups), return_inverse=True, return_counts=True)
    stds = [X[inv == g].std(axis=0, ddof=1) for g in np.flatnonzero(counts >= 2)]
    if not stds:
        return None
    return np.median(np.stack(stds), axis=0)


def search_statistics(
    tables: SearchTables,
    images: np.ndarray,
    max_contacts: int = 3,
    footprint: np.ndarray | None = None,
) -> np.ndarray:
    """What the search finds in each image ``(n, k)``: ``(n, 7)``.

    Columns: the gains ``g1, g2, g3`` of the best 1, 2, 3 contacts (whitened counts^2, 0 where
    none was found), ``z2, z3`` (the weakest of the m contacts' peak signal, noise levels),
    ``|xw|^2`` and the image's peak signal, noise levels. ``footprint (n, N_FEATURES)``, if
    given, receives each image's footprint features against the one-contact fit
    (``multi_contact.footprint``; nan where there are none).
    """
    out = np.zeros((3, N_COLS))
    st, xw, Ft = tables.scratch.stats, tables.scratch.xw, tables.Ft
    res = np.zeros((len(images), 7))
    X = np.ascontiguousarray(images, dtype=np.float32)
    f = np.zeros(N_FEATURES)
    for i, x in enumerate(X):
        search_into(
            x,
            max_contacts,
            tables.arrays,
            tables.prm,
            tables.scratch,
            True,
            out,
            *tables.pair.kernel_args,
        )
        res[i, :6] = st[:6]  # g1, g2, g3, z2, z3, |xw|^2: the STAT_* slots 0-5
        res[i, 6] = float(np.max(x * tables.w))
        if footprint is not None:
            # the one-contact fit's row (``max_contacts`` >= 2: it comes with the pair stage)
            ok = max_contacts >= 2 and footprint_features(xw, Ft[int(st[STAT_ROW1])], f)
            footprint[i] = f if ok else np.nan
    return res


def pair_statistics(tables: SearchTables, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``search_statistics`` of ``images (n, k)`` with two contacts at most, and their places.

    Returns ``(raw (n, 7), positions (n, 2, 3) m)``; positions are nan where no pair was found.
    """
    out = np.zeros((3, N_COLS))
    st, keep, fpos = tables.scratch.stats, tables.scratch.keep, tables.arrays.Fpos
    raw = np.zeros((len(images), 7))
    pos = np.full((len(images), 2, 3), np.nan)
    for i, x in enumerate(np.ascontiguousarray(images, dtype=np.float32)):
        search_into(
            x, 2, tables.arrays, tables.prm, tables.scratch, True, out, *tables.pair.kernel_args
        )
        raw[i, :6] = st[:6]  # the STAT_* slots 0-5
        raw[i, 6] = float(np.max(x * tables.w))
        if st[STAT_G2] > 0:  # a pair was fitted (calibration mode keeps its rows whatever the rule)
            pos[i] = fpos[keep[:2].astype(np.int64)]
    return raw, pos


def rule_statistics(raw: np.ndarray, misfit: float, z_power: float = 0.0) -> np.ndarray:
    """The statistics the count rule thresholds, from ``search_statistics``: ``(n, 5)``.

    Columns: ``rho2``, ``rho3`` (``relative_gain`` of the m-th contact with the floor
    ``misfit * |xw|^2``, times ``z_m ** z_power``; ``-inf`` where no m contacts were found),
    ``z2``, ``z3`` and the image's peak signal, noise levels.
    """
    g1, g2, g3, z2, z3, xx, zmax = raw.T
    r1, r2, r3 = (np.maximum(xx - g, 1.0) for g in (g1, g2, g3))
    floor = max(misfit, 0.0) * xx
    res = np.full((len(raw), 5), -np.inf)
    w2, w3 = (np.maximum(z, 0.0) ** max(z_power, 0.0) for z in (z2, z3))
    res[:, 0] = np.where(g2 > 0, (r1 - r2) / (r2 + floor) * w2, -np.inf)
    res[:, 1] = np.where(g3 > 0, (r2 - r3) / (r3 + floor) * w3, -np.inf)
    res[:, 2] = np.where(g2 > 0, z2, -np.inf)
    res[:, 3] = np.where(g3 > 0, z3, -np.inf)
    res[:, 4] = zmax
    return res


def count_statistics(tables: SearchTables, images: np.ndarray, max_contacts: int = 3) -> np.ndarray:
    """``rule_statistics`` of ``images (n, k)`` with the tables' own rule: ``(n, 5)``."""
    raw = search_statistics(tables, images, max_contacts)
    return rule_statistics(raw, tables.rule.misfit, tables.rule.z_power)


def single_misfit(raw: np.ndarray, z_on: float) -> float:
    """The median share of a detected single touch's energy one contact leaves, ``R1 / |xw|^2``.

    ``raw`` are ``search_statistics`` of held-out single touches; 0 when none is detected.
    """
    g1, xx, zmax = raw[:, 0], raw[:, 5], raw[:, 6]
    keep = (zmax >= z_on) & (xx > 0)
    if not keep.any():
        return 0.0
    return float(np.median(np.maximum(xx[keep] - g1[keep], 0.0) / xx[keep]))


def choose_thresholds(
    neg: list[np.ndarray], pos: np.ndarray, z_on: float, false_rate: float
) -> tuple[float, float, float, float]:
    """``(z_min, tau, detected, false)``: the rule "rho >= tau and z >= z_min" for one count.

    ``neg`` are ``(rho, z)`` arrays of images with one contact fewer (touch means, frames:
    each must keep under ``false_rate``), ``pos`` those with the count. For each ``z_min`` of
    ``Z_GRID`` the least ``tau`` that keeps every negative set under ``false_rate``; the
    ``z_min`` that detects most positives wins (the lower on ties).
    """
    best = (z_on, np.inf, -1.0, 0.0)
    for z_min in Z_GRID:
        z_min = max(z_min, z_on)
        tau = 0.0
        for v in neg:
            rho = np.where(v[:, 1] >= z_min, v[:, 0], -np.inf)
            rho = np.where(np.isfinite(rho), rho, -1.0)
            # the share at or above tau is at most false_rate: tau above that quantile
            tau = max(tau, float(np.quantile(rho, 1 - false_rate)) + 1e-9)
        det = float(np.mean((pos[:, 0] >= tau) & (pos[:, 1] >= z_min)))
        if det > best[2]:
            fal = max(float(np.mean((v[:, 0] >= tau) & (v[:, 1] >= z_min))) for v in neg)
            best = (z_min, tau, det, fal)
    return best


def _far_apart(y: Points, idx: tuple[int, ...], min_m: float) -> bool:
    return all(
        np.linalg.norm(y[a] - y[b]) >= min_m for i, a in enumerate(idx) for b in idx[i + 1 :]
    )


def calibrate_count_rule(
    X_means: np.ndarray,
    y: Points,
    candidates: Points,
    coarse: np.ndarray,
    cells: np.ndarray,
    length_scale_mm: float,
    noise: float,
    sensor_noise: np.ndarray | None,
    frames: list[np.ndarray] | None = None,
    rule: CountRule | None = None,
    n_folds: int = 5,
    random_state: int = 0,
    misfit_floor: bool = True,
    z_power: float = Z_POWER,
) -> tuple[CountRule, dict[str, Any]]:
    """The count rule calibrated by cross-validation over the training point logs.

    Parameters
    ----------
    X_means : (n, k) float
        Baseline-subtracted touch means, counts.
    y : (n, 3) float
        Their positions, m.
    candidates, coarse, cells
        The map's candidates (m) and search cells (``ResponseMap.search_cells``).
    length_scale_mm, noise : float
        The shape map's hyperparameters (the amplitude map's too).
    sensor_noise : (k,) float or None
        Noise per sensor, counts.
    frames : list of (s_i, k) float, optional
        Each touch's frames, baseline-subtracted: per-frame singles and sums too.
    rule : CountRule, optional
        The rule's other settings (default ``CountRule()``).
    misfit_floor : bool
        Measure the rule's ``misfit`` (the median share of a held-out touch mean's energy one
        contact leaves) and count against it; ``False``: the residual alone (the rule before).
    z_power : float
        The rule's ``z_power`` (0: the relative reduction alone, the rule before).

    Returns
    -------
    rule : CountRule
        With ``tau2``, ``tau3`` calibrated (unchanged, ``calibrated=False``, for fewer than
        ``MIN_POINT_LOGS`` point logs).
    report : dict
        The held-out rates the rule reaches.
    """
    rule = rule or CountRule()
    n = len(X_means)
    if n < MIN_POINT_LOGS:
        return rule, {"calibrated": False, "reason": f"{n} point logs"}
    rng = np.random.default_rng(random_state)
    folds = np.array_split(rng.permutation(n), min(n_folds, n // 2))
    min_m = 1e-3 * rule.min_separation_mm
    stats: dict[str, list[np.ndarray]] = {"mean": [], "frame": [], "pair": [], "triple": []}
    # the two-point threshold's pairs: every separation, touch means summed (raw, places, truth)
    tp_raw, tp_pos, tp_true = [], [], []
    tp_rng = np.random.default_rng(random_state + 1)  # its own draws: the rule's stay the same
    power = np.linalg.norm(np.maximum(X_means, 0.0), axis=1)
    # the footprint cue's sets: features of held-out singles, and of pairs the search cannot
    # separate (PAIR_MM apart), with their own draws
    fp: dict[str, list[np.ndarray]] = {"mean": [], "frame": [], "pair": []}
    fp_rng = np.random.default_rng(random_state + 2)
    for test in folds:
        train = np.setdiff1d(np.arange(n), test)
        amp = AmplitudeMap.fit(y[train], X_means[train], length_scale_mm, noise)
        unit, _ = amp.evaluate(candidates)
        tables = SearchTables(unit, candidates, coarse, cells, sensor_noise, rule)
        sets: dict[str, list[np.ndarray]] = {"mean": list(X_means[test]), "frame": []}
        sets["pair"], sets["triple"] = [], []
        if frames is not None:
            for i in test:
                fi = frames[i]
                pick = rng.choice(len(fi), min(5, len(fi)), replace=False)
                sets["frame"] += list(fi[pick])
                # means of half the frames: more touch means, so that the rule's share of
                # false second contacts is not decided by one or two touches
                for _ in range(SUB_MEANS if len(fi) >= 4 else 0):
                    sets["mean"].append(
                        fi[rng.choice(len(fi), len(fi) // 2, replace=False)].mean(0)
                    )
        t = list(test)
        pairs = [p for p in itertools.combinations(t, 2) if _far_apart(y, p, min_m)]
        for i in rng.permutation(len(pairs))[:MAX_SETS]:
            a, b = pairs[i]
            sets["pair"].append(X_means[a] + X_means[b])
            if frames is not None:
                fa, fb = frames[a], frames[b]
                sets["pair"].append(fa[rng.integers(len(fa))] + fb[rng.integers(len(fb))])
        for _ in range(10 * len(t) if len(t) >= 3 else 0):
            idx = tuple(rng.choice(t, 3, replace=False))
            if _far_apart(y, idx, min_m) and len(sets["triple"]) < MAX_SETS // 4:
                sets["triple"].append(X_means[list(idx)].sum(axis=0))
        similar = [
            p
            for p in itertools.combinations(t, 2)
            if min(power[list(p)]) > TWO_POINT_RATIO * max(power[list(p)])
        ]
        pick = [similar[i] for i in tp_rng.permutation(len(similar))[:TWO_POINT_SETS]]
        if pick:
            raw_p, pos_p = pair_statistics(
                tables, np.stack([X_means[list(p)].sum(0) for p in pick])
            )
            tp_raw.append(raw_p)
            tp_pos.append(pos_p)
            tp_true.append(np.stack([y[list(p)] for p in pick]))
        close = [
            p
            for p in itertools.combinations(t, 2)
            if PAIR_MM[0] <= 1e3 * np.linalg.norm(y[p[0]] - y[p[1]]) <= PAIR_MM[1]
        ]
        fp_pairs = [X_means[a] + X_means[b] for a, b in close]
        if frames is not None:
            for a, b in close:
                fa, fb = frames[a], frames[b]
                fp_pairs.append(fa[fp_rng.integers(len(fa))] + fb[fp_rng.integers(len(fb))])
        if fp_pairs:
            F = np.full((len(fp_pairs), N_FEATURES), np.nan)
            r = search_statistics(tables, np.asarray(fp_pairs), 2, F)
            fp["pair"].append(F[r[:, 6] >= rule.z_on])
        for name, imgs in sets.items():
            if imgs:
                k_max = 2 if name in ("mean", "frame") else 3  # singles need no third contact
                F = np.full((len(imgs), N_FEATURES), np.nan) if name in fp else None
                r = search_statistics(tables, np.asarray(imgs), k_max, F)
                stats[name].append(r)
                if F is not None:
                    fp[name].append(F[r[:, 6] >= rule.z_on])  # detected singles only
    raw = {k: np.concatenate(v) if v else np.zeros((0, 7)) for k, v in stats.items()}
    # the misfit of held-out touch means: what the model leaves of a touch it was not fitted to
    misfit = single_misfit(raw["mean"], rule.z_on) if misfit_floor else 0.0
    S = {k: rule_statistics(v, misfit, z_power) for k, v in raw.items()}
    # only detected singles count (the others are no contact at all)
    singles = [S[k][S[k][:, 4] >= rule.z_on] for k in ("mean", "frame")]
    singles = [v for v in singles if len(v) >= 20]
    if not singles or len(S["pair"]) < 20:
        return rule, {"calibrated": False, "reason": "too few held-out touches"}
    pair, tri = S["pair"], S["triple"]
    z2, tau2, det2, false2 = choose_thresholds(
        [v[:, [0, 2]] for v in singles], pair[:, [0, 2]], rule.z_on, FALSE_RATE
    )
    two = (pair[:, 0] >= tau2) & (pair[:, 2] >= z2)
    # too few to calibrate a third: the default threshold, at the weakest third contact allowed
    z3, det3, false3 = rule.z3_min, None, None
    tau3 = rule.tau3 * max(rule.z3_min, rule.z_on) ** z_power
    if two.sum() >= 20 and len(tri) >= 20:
        tri2 = tri[(tri[:, 0] >= tau2) & (tri[:, 2] >= z2)]
        z3, tau3, det3, false3 = choose_thresholds(
            [pair[two][:, [1, 3]]], tri2[:, [1, 3]], rule.z_on, FALSE_RATE
        )
    rule_new = replace(
        rule,
        tau2=tau2,
        tau3=tau3,
        z2_min=z2,
        z3_min=z3,
        misfit=misfit,
        z_power=z_power,
        calibrated=True,
    )
    weights, fp_two, fp_hold, fp_report = calibrate_footprint(
        [np.concatenate(fp[k]) for k in ("mean", "frame") if fp[k]],
        np.concatenate(fp["pair"]) if fp["pair"] else np.zeros((0, N_FEATURES)),
    )
    rule_new = replace(
        rule_new,
        footprint_weights=tuple(float(v) for v in weights),
        footprint_two=fp_two,
        footprint_hold=fp_hold,
    )
    report = {
        "calibrated": True,
        "folds": len(folds),
        "misfit": misfit,
        "n_single": [len(v) for v in singles],
        "n_pair": len(pair),
        "n_triple": len(tri),
        "single_called_two": false2,
        "pair_counted_two": det2,
        "pair_called_three": false3,
        "triple_counted_three_of_counted_two": det3,
        "footprint": fp_report,
    }
    if tp_raw:
        report["two_point"] = two_point_threshold(
            rule_new, np.concatenate(tp_raw), np.concatenate(tp_pos), np.concatenate(tp_true)
        )
    return rule_new, report


def two_point_threshold(
    rule: CountRule, raw: np.ndarray, positions: np.ndarray, truth: np.ndarray
) -> dict[str, Any]:
    """The two-point threshold (``two_point.threshold_from_pairs``) of held-out pairs.

    ``raw (n, 7)`` and ``positions (n, 2, 3)`` m from ``pair_statistics``, ``truth (n, 2, 3)``
    m the two touches' positions; counted two by ``rule``'s own thresholds.
    """
    S = rule_statistics(raw, rule.misfit, rule.z_power)
    two = (S[:, 0] >= rule.tau2) & (S[:, 2] >= max(rule.z2_min, rule.z_on)) & (S[:, 4] >= rule.z_on)
    placed = np.array(
        [bool(c) and placed_both(p, t) for c, p, t in zip(two, positions, truth, strict=True)]
    )
    sep = 1e3 * np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1)
    return {
        **threshold_from_pairs(sep, two, placed),
        "source": "held-out pairs of the calibration touches (touch means summed)",
    }


def fit_contact_model(
    rmap: Any,
    X_means: np.ndarray,
    y: Points,
    frames: np.ndarray | None,
    groups: np.ndarray | None,
    sensor_noise: np.ndarray | None,
    random_state: int = 0,
) -> tuple[Any, dict[str, Any]]:
    """A fitted ``ResponseMap`` with its amplitude map, and the calibrated count rule's dict.

    ``frames (m, k)`` and ``groups (m,)`` are the training frames before averaging (touch
    means ``X_means`` in the order of the sorted group labels), or ``None``.
    """
    rmap = rmap.with_amplitude(y, X_means)
    coarse, cells = rmap.search_cells()
    per_touch = None
    if frames is not None and groups is not None:
        uniq, inv = np.unique(np.asarray(groups), return_inverse=True)
        F = np.asarray(frames, dtype=np.float64)
        per_touch = [F[inv == g] for g in range(len(uniq))]
    base = rmap.layers[0]
    rule, report = calibrate_count_rule(
        np.asarray(X_means, dtype=np.float64),
        np.asarray(y, dtype=np.float64),
        rmap.candidates,
        coarse,
        cells,
        base.length_scale_mm,
        base.noise,
        sensor_noise,
        per_touch,
        random_state=random_state,
    )
    if per_touch is not None:
        # the time cue: how much a touch's image changes shape as it lands and lifts
        change, landing = calibrate_landing(
            per_touch,
            noise_weights(sensor_noise, X_means.shape[1]),
            np.asarray(y, dtype=np.float64),
            z_on=rule.z_on,
            random_state=random_state,
        )
        rule = replace(rule, landing_change=change, landing_hold=landing["hold"])
        report = {**report, "landing": landing}
    # the two-point threshold beside the rule (the rule's fields are the kernels' parameters)
    two_point = report.pop("two_point", None)
    return rmap, {**rule.as_dict(), "cv": report, "two_point": two_point}
