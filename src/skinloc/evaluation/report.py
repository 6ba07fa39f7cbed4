"""Figures and HTML reports: sensor images, predictions on the 3D skin, error curves."""

from __future__ import annotations

import html
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

__all__ = [
    "plot_error_curve",
    "plot_error_curves",
    "plot_paper_fig3",
    "plot_predictions_3d",
    "plot_sensor_image",
    "plot_uncertainty",
    "pyplot",
    "write_html",
]


def pyplot():
    """``matplotlib.pyplot`` on the file-only Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")  # files only; never needs a display
    import matplotlib.pyplot as plt

    return plt


def draw_mesh(ax, mesh, alpha: float = 0.3, edgecolor: str = "0.7") -> None:
    """Draw the skin on 3D axes ``ax``: a light translucent surface, axes in mm, true scale."""
    v = np.asarray(mesh.vertices) * 1e3
    ax.plot_trisurf(
        v[:, 0],
        v[:, 1],
        v[:, 2],
        triangles=mesh.faces,
        color="0.9",
        alpha=alpha,
        edgecolor=edgecolor,
        linewidth=0.2,
    )
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_box_aspect(np.ptp(v, axis=0))


def save_figure(fig, path: str | Path, *, svg: bool = True, **kw) -> Path:
    """Write ``fig`` to ``path`` (150 dpi) and close it; returns the path.

    Laid out tight first (unless ``bbox_inches`` is given); with ``svg``, a PNG also gets the
    same figure beside it as SVG. ``kw`` goes to ``savefig``.
    """
    from matplotlib import pyplot as plt

    path = Path(path)
    if "bbox_inches" not in kw:
        fig.tight_layout()
    fig.savefig(path, dpi=150, **kw)
    if svg and path.suffix.lower() == ".png":
        fig.savefig(path.with_suffix(".svg"), **kw)
    plt.close(fig)
    return path


def plot_sensor_image(
    image: np.ndarray, n_tx: int, n_rx: int, path: str | Path, title: str = "Sensor image"
) -> Path:
    """Heat map of one baseline-subtracted image ``(n_tx * n_rx,)`` counts, TX rows x RX columns."""
    plt = pyplot()
    grid = np.asarray(image, dtype=float).reshape(n_tx, n_rx)
    fig, ax = plt.subplots(figsize=(4.6, 4))
    lim = max(abs(grid).max(), 1.0)
    im = ax.imshow(grid, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax.set_xlabel("RX line")
    ax.set_ylabel("TX line")
    ax.set_xticks(range(n_rx))
    ax.set_yticks(range(n_tx))
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label="counts above baseline")
    return save_figure(fig, path)


def plot_predictions_3d(
    mesh,
    true: np.ndarray,
    predicted: np.ndarray,
    path: str | Path,
    title: str = "Prompted targets (o) and predictions (x)",
) -> Path:
    """The skin in 3D with each target joined to its prediction, coloured by error (mm axes).

    Two views (from above and from the side) so that no segment hides behind the surface.
    """
    plt = pyplot()
    from matplotlib import cm, colors

    t, p = np.asarray(true) * 1e3, np.asarray(predicted) * 1e3
    err = np.linalg.norm(p - t, axis=1)
    norm = colors.Normalize(0.0, max(float(np.percentile(err, 95)) if len(err) else 1.0, 1.0))
    cmap = plt.get_cmap("plasma")
    fig = plt.figure(figsize=(12, 5.8))
    for k, (elev, azim) in enumerate(((60, -70), (15, -100))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        draw_mesh(ax, mesh, alpha=0.25, edgecolor="0.75")
        for a, b, e in zip(t, p, err, strict=True):
            ax.plot(*np.stack([a, b]).T, color=cmap(norm(e)), lw=3.0, solid_capstyle="round")
        # Small markers, so that the segments (a few mm long) stay visible between them.
        ax.scatter(*t.T, facecolors="none", edgecolors="k", s=12, lw=0.7, label="target")
        ax.scatter(*p.T, c="k", marker="x", s=12, lw=0.7, label="prediction")
        ax.view_init(elev=elev, azim=azim)
        if k == 0:
            ax.legend(loc="upper left")
    sm = cm.ScalarMappable(norm=norm, cmap=cmap)
    sm.set_array([])
    fig.subplots_adjust(left=0.0, right=0.9, wspace=0.0)
    fig.colorbar(sm, cax=fig.add_axes((0.92, 0.2, 0.012, 0.6)), label="error (mm)")
    fig.suptitle(title)
    return save_figure(fig, path, bbox_inches="tight")


def plot_error_curves(
    simulated: dict[str, tuple[Sequence[int], Sequence[float], Sequence[float]]],
    real: dict[str, tuple[Sequence[int], Sequence[float]]],
    path: str | Path,
    floor_mm: float | None = None,
) -> Path:
    """Error against point logs: simulated curves with error bars, real-skin points beside.

    ``simulated[label] = (sizes, mean_mm, std_mm)`` and ``real[label] = (sizes, mean_mm)``;
    the i-th real curve takes the i-th simulated one's colour. ``floor_mm`` draws the probing
    floor (how far a person's touch lands from the prompt) as a dotted line.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:purple"]
    for i, (label, (xs, ys, es)) in enumerate(simulated.items()):
        ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, color=colours[i % 4], label=label)
    for i, (label, (xs, ys)) in enumerate(real.items()):
        ax.plot(xs, ys, marker="s", ls="--", mfc="none", color=colours[i % 4], label=label)
    if floor_mm is not None:
        ax.axhline(floor_mm, color="0.4", ls=":", label=f"probing floor ({floor_mm:.1f} mm)")
    ax.set_xlabel("calibration point logs")
    ax.set_ylabel("mean localisation error (mm)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_uncertainty(uncertainty_mm: np.ndarray, error_mm: np.ndarray, path: str | Path) -> Path:
    """The model's predicted uncertainty against its actual error, one point per touch (mm)."""
    plt = pyplot()
    u, e = np.asarray(uncertainty_mm, dtype=float), np.asarray(error_mm, dtype=float)
    fig, ax = plt.subplots(figsize=(4.8, 4.2))
    ok = np.isfinite(u)
    ax.scatter(u[ok], e[ok], s=20, color="tab:blue")
    top = max(float(np.nanmax(np.r_[u[ok], e, 1.0])), 1.0) * 1.05
    ax.plot([0, top], [0, top], color="0.6", ls=":", label="error = uncertainty")
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.set_xlabel("model uncertainty (mm)")
    ax.set_ylabel("actual error (mm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_error_curve(
    n_points: Sequence[int],
    mean_mm: Sequence[float],
    std_mm: Sequence[float],
    path: str | Path,
    label: str = "skinloc",
    extra: dict[str, tuple[Sequence[int], Sequence[float]]] | None = None,
) -> Path:
    """Mean +- std localisation error against the number of calibration point logs."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.errorbar(n_points, mean_mm, yerr=std_mm, marker="o", capsize=3, label=label)
    for name, (xs, ys) in (extra or {}).items():
        ax.plot(xs, ys, marker="s", ls="--", label=name)
    ax.set_xlabel("calibration point logs")
    ax.set_ylabel("localisation error (mm)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend()
    return save_figure(fig, path)


def plot_paper_fig3(
    n_points: Sequence[int],
    snr_mean: Sequence[float],
    snr_std: Sequence[float],
    err_mean: Sequence[float],
    err_std: Sequence[float],
    path: str | Path,
    title: str = "",
) -> Path:
    """The paper's Fig. 3: (a) mean SNR and (b) error against point logs."""
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    a.errorbar(n_points, snr_mean, yerr=snr_std, marker="o", capsize=3)
    a.set_xlabel("calibration point logs")
    a.set_ylabel("mean SNR (dB)")
    a.set_title("(a) SNR")
    b.errorbar(n_points, err_mean, yerr=err_std, marker="o", capsize=3, color="tab:red")
    b.set_xlabel("calibration point logs")
    b.set_ylabel("localisation error (mm)")
    b.set_ylim(bottom=0)
    b.set_title("(b) validation error")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def write_html(
    path: str | Path,
    title: str,
    summary: dict[str, str],
    figures: Sequence[tuple[str, str]],
    notes: str = "",
) -> Path:
    """A self-contained page: a summary table and the figures (paths relative to the page)."""
    rows = "\n".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in summary.items()
    )
    figs = "\n".join(
        f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}">'
        f"<figcaption>{html.escape(cap)}{_vector_link(path, src)}</figcaption></figure>"
        for src, cap in figures
    )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
body {{ font-family: system-ui, sans-serif; max-width: 1000px; margin: 2em auto; color: #222; }}
table {{ border-collapse: collapse; margin: 1em 0; }}
th, td {{ border: 1px solid #ccc; padding: 4px 10px; text-align: left; }}
figure {{ display: block; margin: 1em 0; }}
img {{ max-width: 100%; }} figure {{ max-width: 960px; }}
figcaption {{ font-size: 0.9em; color: #555; }}
</style></head><body>
<h1>{html.escape(title)}</h1>
<table>{rows}</table>
{figs}
<p>{html.escape(notes)}</p>
</body></html>
"""
    path = Path(path)
    path.write_text(page, encoding="utf-8")
    return path


def _vector_link(page: str | Path, src: str) -> str:
    """`` (SVG)`` link when the figure's SVG sits beside its PNG, else nothing."""
    svg = Path(src).with_suffix(".svg")
    if Path(src).suffix.lower() == ".png" and (Path(page).parent / svg).exists():
        return f' <a href="{html.escape(str(svg))}">(SVG)</a>'
    return ""
