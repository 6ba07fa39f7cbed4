"""Where the skin's sensors are: wire crossings, wire paths, footprints, gains and faults.

A TX x RX crossing responds most when the finger sits right over it, and its response falls
off with the distance to it over a width set by the silicone and the finger (the simulator's
``(1 + d^2 / w^2)^-1`` and the paper's observed ~10 mm footprints). So each sensor's position
is the peak of its response over the surface:

1. a robust fit of ``a / (1 + d^2 / w^2) + c`` to each sensor's mean response per touch,
   with the crossing searched over the surface points near its strongest touches and ``a``,
   ``c`` solved in closed form for each (no local minima, the crossing stays on the surface),
   touches weighted by their expected variance (pressure spread, probing error x slope);
2. one footprint ``w`` for all (one silicone layer, one finger), the width that best predicts
   each touch left out of its sensor's fit; it is the half-maximum radius of a response;
   then one damped pass dividing each touch by its estimated pressure, and one pass moving
   each touch from its label to where its image says the finger was (the person misses
   the target by ~5 mm per axis; ``label_error_mm``) before refitting the crossings;
3. the wires are continuous: sensor (i, j) lies on TX wire i and on RX wire j, so each
   crossing is pulled towards the smooth curves through its lines' crossings
   (``skinloc.sensors.wires``); this mostly helps sensors on weak lines, whose own peaks are noisy;
4. from there, the whole-image model (``skinloc.sensors.joint_fit``) fits every response of every
   touch at once: crossings, the touches' true positions, pressures, gains and one smoothly
   varying point-spread function; it is kept when it passes its own plausibility check
   (``SensorMap.method`` is ``joint``), else the per-crossing estimate stands;
5. the uncertainty of each position is the spread of the whole estimate over bootstrap
   resamples of the touches (mm).

Opt-in (``fields=True``): where the whole-image model is not kept, the separable line-field
model (``skinloc.sensors.line_fields``) replaces the per-crossing estimate when it
predicts held-out touches better; it fits the real cone's images better but places its
crossings less consistently, so it is off by default (docs/sensors.md).

Sensors and lines are flagged from the fitted gains and the no-touch noise by the one rule
the app uses too (``skinloc.sensors.health.classify_sensors``): ``dead``, ``weak``, ``noisy``.

Units: metres in the API, millimetres in reports (names say which).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.sensors import joint_fit as J
from skinloc.sensors.crossing_fit import LABEL_ERROR_MM, fit_per_crossing
from skinloc.sensors.health import classify_sensors
from skinloc.sensors.wires import line_path

__all__ = [
    "SensorMap",
    "estimate_sensor_map",
    "sensor_map_from_recordings",
    "truth_sensor_positions",
]


@dataclass
class SensorMap:
    """The estimated layout of one skin.

    Attributes
    ----------
    n_tx, n_rx : int
        Grid; sensor k is TX ``k // n_rx``, RX ``k % n_rx``.
    positions_m : (n_sensors, 3) float
        Estimated crossing positions on the surface, m.
    uncertainty_mm : (n_sensors,) float
        Bootstrap spread (RMS distance) of each position, mm.
    footprint_mm : (n_sensors,) float
        Response width ``w`` (distance at which the response halves), mm.
    gain : (n_sensors,) float
        Peak response relative to the median sensor (1 = typical).
    noise_counts : (n_sensors,) float
        No-touch noise std, counts (nan when unknown).
    status : (n_sensors,) str
        ``ok``, ``weak``, ``dead`` or ``noisy``.
    tx_paths_m, rx_paths_m : list of (m, 3) float
        Estimated path of each wire across the surface (through its crossings), m.
    line_status : dict
        ``{"tx": [...], "rx": [...]}`` status of each line.
    """

    n_tx: int
    n_rx: int
    positions_m: Points
    uncertainty_mm: np.ndarray
    footprint_mm: np.ndarray
    gain: np.ndarray
    noise_counts: np.ndarray
    status: np.ndarray
    tx_paths_m: list[np.ndarray]
    rx_paths_m: list[np.ndarray]
    line_status: dict[str, list[str]]
    line_gain: dict[str, list[float]] = field(default_factory=dict)
    #: ``joint`` (the whole-image model), ``fields`` (the line-field model) or
    #: ``per-crossing`` (the fallback).
    method: str = "per-crossing"
    #: Held-out misfit of the per-crossing fit and the line fields (when they were compared).
    heldout: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: ``{"sensors": [...], "lines": [...]}`` (positions m, sizes mm)."""
        sensors = []
        for k in range(self.n_tx * self.n_rx):
            sensors.append(
                {
                    "tx": k // self.n_rx,
                    "rx": k % self.n_rx,
                    "position_m": [round(float(v), 6) for v in self.positions_m[k]],
                    "uncertainty_mm": _r(self.uncertainty_mm[k]),
                    "footprint_mm": _r(self.footprint_mm[k]),
                    "gain": _r(self.gain[k], 3),
                    "noise_counts": _r(self.noise_counts[k]),
                    "status": str(self.status[k]),
                }
            )
        lines = []
        for kind, paths in (("tx", self.tx_paths_m), ("rx", self.rx_paths_m)):
            for i, path in enumerate(paths):
                idx = self.line_sensors(kind, i)
                lines.append(
                    {
                        "kind": kind,
                        "index": i,
                        "status": self.line_status[kind][i],
                        "gain": _r(self.line_gain[kind][i], 3),
                        "noise_counts": _nanmedian(self.noise_counts[idx]),
                        "uncertainty_mm": _r(float(np.median(self.uncertainty_mm[idx]))),
                        "path_m": np.round(path, 6).tolist(),
                    }
                )
        return {
            "n_tx": self.n_tx,
            "n_rx": self.n_rx,
            "method": self.method,
            **({} if self.heldout is None else {"heldout": self.heldout}),
            "sensors": sensors,
            "lines": lines,
        }

    def line_sensors(self, kind: str, index: int) -> np.ndarray:
        """Sensor indices of TX or RX line ``index``, in order along the other lines."""
        if kind == "tx":
            return index * self.n_rx + np.arange(self.n_rx)
        return np.arange(self.n_tx) * self.n_rx + index


def _r(v: float, nd: int = 2) -> float | None:
    v = float(v)
    return round(v, nd) if np.isfinite(v) else None


def _nanmedian(v: np.ndarray) -> float | None:
    return _r(float(np.nanmedian(v))) if np.isfinite(v).any() else None


def truth_sensor_positions(meta: dict[str, Any]) -> Points | None:
    """The simulated skin's true crossings from a recording's meta, ``(n_sensors, 3)`` m."""
    t = meta.get("truth_sensor_positions_m")
    return None if t is None else np.asarray(t, dtype=np.float64).reshape(-1, 3)


# -------------------------------------------------------------------------------- estimation


def _snap(points_m: Points, candidates: Points) -> tuple[Points, np.ndarray]:
    """Nearest candidate surface point of each point, and its index."""
    from scipy.spatial import cKDTree

    idx = cKDTree(candidates).query(points_m)[1]
    return candidates[idx], idx


def estimate_sensor_map(
    targets: Points,
    images: np.ndarray,
    n_tx: int,
    n_rx: int,
    candidates: Points,
    noise_counts: np.ndarray | None = None,
    n_boot: int = 8,
    random_state: int = 0,
    structure: bool = True,
    label_error_mm: float = LABEL_ERROR_MM,
    joint: bool = True,
    fields: bool = False,
) -> SensorMap:
    """Estimate the skin's layout from calibration touches.

    Parameters
    ----------
    targets : (n, 3) float
        Touch positions, m.
    images : (n, n_tx * n_rx) float
        Baseline-subtracted mean image of each touch, counts.
    n_tx, n_rx : int
        Grid.
    candidates : (P, 3) float
        Discretised skin surface, m (positions are snapped onto it).
    noise_counts : (n_tx * n_rx,) float, optional
        No-touch noise std per sensor, counts (to flag noisy sensors).
    n_boot : int
        Bootstrap resamples of the touches for the uncertainty (0: none, nan).
    random_state : int
        Seed of the bootstrap.
    structure : bool
        Use the TX x RX wire structure (step 3 of the module docstring).
    label_error_mm : float
        How far, per tangent axis, the touches may be from their labels (mm): each touch is
        moved to where its image says it was (step 2). 0: the labels are exact.
    joint : bool
        Refine with the whole-image model (step 5, ``skinloc.sensors.joint_fit``); it is kept
        only when it passes its own plausibility check (``SensorMap.method`` says which).
    fields : bool
        When the whole-image model is not kept, also try the separable line-field model
        (``skinloc.sensors.line_fields``) and use it when it predicts held-out touches better than
        the per-crossing fit (``SensorMap.heldout`` holds the scores; ``method`` "fields").
        Off by default: on the real cone and the simulator it fits the images better but
        places the crossings less consistently (docs/sensors.md).

    Returns
    -------
    SensorMap
    """
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    images = np.asarray(images, dtype=np.float64)
    n = n_tx * n_rx
    if images.ndim != 2 or images.shape != (len(targets), n):
        raise ValueError(f"images must be ({len(targets)}, {n}), got {images.shape}")
    if len(targets) < 10:
        raise ValueError(f"need at least 10 touches to locate sensors, got {len(targets)}")
    candidates = np.asarray(candidates, dtype=np.float64)
    from scipy.spatial import cKDTree

    tree = cKDTree(1e3 * candidates)
    if not (np.isfinite(label_error_mm) and label_error_mm >= 0):
        raise ValueError(f"label_error_mm must be >= 0, got {label_error_mm!r}")
    fit_args = (candidates, tree, n_tx, n_rx, structure, label_error_mm)
    fit = fit_per_crossing(targets, images, *fit_args)
    jf = None
    if joint:
        labels_mm, C_mm = 1e3 * targets, 1e3 * candidates
        w0 = float(np.median(fit.footprint_mm))
        jf = J.joint_fit(
            labels_mm, images, fit.positions_mm, C_mm, tree, n_tx, n_rx, w0, noise_counts,
            label_error_mm, init_touches_mm=fit.touches_mm,
        )  # fmt: skip
        if J.plausible(jf, labels_mm, w0, label_error_mm):
            # Gains without the skin-wide trend of the response (thicker silicone lower down
            # weakens every line there): an RX line runs at one height, so the raw peak would
            # confound a weak line near the top with a healthy one at the base.
            fit = jf.crossings()
        else:
            jf = None
    heldout, fm = None, None
    if fields and jf is None:
        from skinloc.sensors import line_fields as LF

        labels_mm, C_mm = 1e3 * targets, 1e3 * candidates
        predictor = LF.per_crossing_predictor(C_mm, tree, n_tx, n_rx, label_error_mm)
        heldout = LF.heldout_comparison(
            labels_mm, images, n_tx, n_rx, C_mm, tree, predictor, label_error_mm,
            random_state=random_state,
        )  # fmt: skip
        if heldout["fields_better"]:
            fm = LF.field_map(
                labels_mm, images, n_tx, n_rx, C_mm, tree, heldout["best_centres"],
                label_error_mm, n_boot, random_state,
            )  # fmt: skip
            fit = fm.crossings()
    pos, width, amp = fit.positions_mm, fit.footprint_mm, fit.gain
    rng = np.random.default_rng(random_state)
    boots = []
    for _ in range(n_boot if fm is None else 0):
        pick = rng.choice(len(targets), len(targets), replace=True)  # repeats act as weights
        if jf is None:
            boots.append(fit_per_crossing(targets[pick], images[pick], *fit_args).positions_mm)
        else:
            # From the full fit (one pass): the spread of the same estimator, quicker.
            b = J.joint_fit(
                labels_mm[pick], images[pick], jf.positions_mm, C_mm, tree, n_tx, n_rx,
                float(np.median(jf.width_mm)), noise_counts, label_error_mm, passes=1,
                init_touches_mm=jf.touches_mm[pick],
            )  # fmt: skip
            boots.append(b.positions_mm)
    if fm is not None:
        unc = fm.uncertainty_mm
    elif boots:
        B = np.stack(boots)
        # Positions are searched over the discrete surface points, so a few resamples can all
        # land on the same point: add the rounding error of that grid (spacing s: s^2 / 6 on
        # a surface) so an uncertainty is never reported as exactly zero.
        spacing = float(np.median(tree.query(tree.data, k=2)[0][:, 1]))
        unc = np.sqrt(((B - pos[None]) ** 2).sum(axis=2).mean(axis=0) + spacing**2 / 6.0)
    else:
        unc = np.full(n, np.nan)
    snapped, _ = _snap(1e-3 * pos, candidates)
    gain = amp / max(float(np.median(amp)), 1e-12)
    noise = np.full(n, np.nan) if noise_counts is None else np.asarray(noise_counts, float)
    health = classify_sensors(n_tx, n_rx, gain=gain, noise=noise)
    S = snapped.reshape(n_tx, n_rx, 3)
    W = np.where(np.isfinite(unc), 1.0 / np.maximum(unc, 0.3) ** 2, 1.0).reshape(n_tx, n_rx)
    tx_paths = [line_path(S[i], W[i]) for i in range(n_tx)]
    rx_paths = [line_path(S[:, j], W[:, j]) for j in range(n_rx)]
    return SensorMap(
        n_tx=n_tx,
        n_rx=n_rx,
        positions_m=snapped,
        uncertainty_mm=unc,
        footprint_mm=width,
        gain=gain,
        noise_counts=noise,
        status=health.status,
        tx_paths_m=tx_paths,
        rx_paths_m=rx_paths,
        line_status=health.lines,
        line_gain=health.line_gain or {},
        method="joint" if jf is not None else "fields" if fm is not None else "per-crossing",
        heldout=heldout,
    )


def sensor_map_from_recordings(recordings: Sequence[Any], **kw: Any) -> SensorMap:
    """``estimate_sensor_map`` on the touch means of recordings of one skin (same grid).

    The noise is the median no-touch std over the recordings; the surface is the first
    recording's discretised surface (or 14400 points sampled on its mesh).
    """
    from skinloc.evaluation.scoring import check_compatible
    from skinloc.geometry.mesh import surface_points

    check_compatible(recordings)
    first = recordings[0]
    cands = first.surface_points
    if cands is None:
        cands = surface_points(first.mesh)
    targets = np.concatenate([r.targets for r in recordings])
    images = np.concatenate([r.touch_means for r in recordings])
    noise = np.median(np.stack([r.noise for r in recordings]), axis=0)
    return estimate_sensor_map(
        targets, images, first.n_tx, first.n_rx, cands, noise_counts=noise, **kw
    )


def position_errors_mm(est: Points, truth: Points) -> np.ndarray:
    """Distance of each estimated crossing from the true one, ``(n_sensors,)`` mm."""
    return 1e3 * np.linalg.norm(np.asarray(est) - np.asarray(truth), axis=1)


def sensor_map_from_model(model: Any, stride: int = 8) -> SensorMap:
    """``estimate_sensor_map`` on a trained response-map model's own map.

    The map predicts every sensor's (pressure-normalised) response anywhere on the surface,
    so the sensors are located on its values at every ``stride``-th candidate point. A model
    keeps no touches, so there is no bootstrap (uncertainty nan) and no noise (no ``noisy``).

    Raises
    ------
    ValueError
        If the model is not a fitted response map (networks hold no map of the skin).
    """
    rmap = getattr(model, "map_", None)
    if rmap is None:
        raise ValueError(
            "locating sensors needs a response-map model (arch 'default'), or a recording"
        )
    n_tx, n_rx = _model_grid(model)
    pts = rmap.candidates[::stride]
    values = rmap.evaluate_mm(1e3 * pts)
    # The map's own values sit exactly at their points: no label error to undo.
    # The whole-image model needs touches with pressures; a map has none.
    return estimate_sensor_map(
        pts, values, n_tx, n_rx, rmap.candidates, n_boot=0, label_error_mm=0.0, joint=False
    )


def _model_grid(model: Any) -> tuple[int, int]:
    """The model's TX x RX grid, from its training meta (square grids otherwise)."""
    meta = getattr(model, "training_meta_", None) or getattr(model, "meta_", {}).get("training")
    meta = meta or {}
    if "n_tx" in meta and "n_rx" in meta:
        return int(meta["n_tx"]), int(meta["n_rx"])
    n = int(model.n_features_in_)
    side = int(round(np.sqrt(n)))
    if side * side != n:
        raise ValueError(f"cannot tell the TX x RX grid of a {n}-sensor model; use a recording")
    return side, side
