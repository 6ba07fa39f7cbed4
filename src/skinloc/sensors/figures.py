"""Figures of the skin itself: its sensors and wires, and where it localises well.

Axes in mm; files only (matplotlib's Agg backend).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skinloc._typing import Points
from skinloc.evaluation.report import draw_mesh, pyplot, save_figure
from skinloc.sensors.sensor_map import SensorMap

__all__ = ["plot_coverage", "plot_sensor_map"]

_STATUS_COLOURS = {"ok": "tab:green", "weak": "tab:orange", "dead": "k", "noisy": "tab:purple"}


def _skin_axes(mesh, title: str):
    plt = pyplot()
    fig = plt.figure(figsize=(7.5, 6))
    ax = fig.add_subplot(projection="3d")
    draw_mesh(ax, mesh)
    ax.view_init(elev=30, azim=-65)
    ax.set_title(title)
    return plt, fig, ax


def plot_sensor_map(mesh, smap: SensorMap, path: str | Path, truth: Points | None = None) -> Path:
    """Plot the skin with its estimated crossings and wires.

    Crossings are coloured by status and sized by uncertainty; TX wires blue, RX wires red;
    the true crossings (x) when known.
    """
    plt, fig, ax = _skin_axes(mesh, "Sensors: crossings, wires and their uncertainty")
    for p in smap.tx_paths_m:
        ax.plot(*(1e3 * p).T, c="tab:blue", lw=1.0, alpha=0.8)
    for p in smap.rx_paths_m:
        ax.plot(*(1e3 * p).T, c="tab:red", lw=1.0, alpha=0.8)
    pos = 1e3 * smap.positions_m
    unc = np.nan_to_num(smap.uncertainty_mm, nan=1.0)
    for status, colour in _STATUS_COLOURS.items():
        sel = smap.status == status
        if sel.any():
            ax.scatter(
                *pos[sel].T,
                s=12 + 6 * unc[sel] ** 2,
                c=colour,
                alpha=0.7,
                depthshade=False,
                label=f"{status} ({int(sel.sum())})",
            )
    if truth is not None:
        ax.scatter(*(1e3 * truth).T, marker="x", c="k", s=14, label="true", depthshade=False)
    ax.legend(loc="upper left", fontsize=8, title="marker area ~ uncertainty^2")
    return save_figure(fig, path, svg=False)


def plot_coverage(
    mesh, points: Points, expected_mm: np.ndarray, path: str | Path, blind: Points | None = None
) -> Path:
    """Expected localisation error over the skin (colour, mm) and the blind spots (x)."""
    plt, fig, ax = _skin_axes(mesh, "Coverage: expected localisation error")
    p = 1e3 * np.asarray(points)
    vmax = float(np.percentile(expected_mm, 95))  # a few far-off outliers would wash it out
    sc = ax.scatter(
        *p.T, c=expected_mm, cmap="viridis_r", vmin=0.0, vmax=vmax, s=10, depthshade=False
    )
    if blind is not None and len(blind):
        ax.scatter(*(1e3 * blind).T, marker="x", c="tab:red", s=30, label="blind spot")
        ax.legend(loc="upper left", fontsize=8)
    fig.colorbar(sc, ax=ax, shrink=0.6, label="expected error (mm)")
    return save_figure(fig, path, svg=False)
