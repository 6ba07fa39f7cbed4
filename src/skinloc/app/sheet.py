"""Printable target sheets: the calibration targets laid out on the flattened skin, SVG and PDF.

The sheet is printed at actual size, cut along the outline and laid on the skin (the paper's
proposed remedy: a grid drawn on the skin), so a person finds each target without guessing.
``layout_sheet`` does the geometry once; ``render_svg`` and ``render_pdf`` draw the same layout.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from xml.sax.saxutils import escape

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.geometry.flatten import flatten

log = logging.getLogger(__name__)

__all__ = ["TargetSheet", "layout_sheet", "render_pdf", "render_svg"]

#: Paper sizes tried in order, (name, width mm, height mm).
PAGES = [
    ("A4 landscape", 297.0, 210.0),
    ("A4 portrait", 210.0, 297.0),
    ("A3 landscape", 420.0, 297.0),
    ("A3 portrait", 297.0, 420.0),
]
MARGIN_MM = 8.0
HEADER_MM = 14.0
FOOTER_MM = 12.0
SCALE_BAR_MM = 50.0


@dataclass
class TargetSheet:
    """A laid-out sheet; every coordinate in mm on the page, y downwards from the top left.

    Attributes
    ----------
    page : str
        Paper size and orientation.
    width_mm, height_mm : float
        Page size.
    scale : float
        Sheet mm per skin mm: 1 means actual size.
    outline : list of (k, 2) float
        Closed polylines of the flat skin's edge.
    targets : (n, 2) float
        Target centres.
    labels : list of str
        Label of each target (its number in the session).
    done : (n,) bool
        Targets already touched (drawn filled).
    title, subtitle : str
        Header lines.
    notes : list of str
        Lines printed at the bottom.
    """

    page: str
    width_mm: float
    height_mm: float
    scale: float
    outline: list[np.ndarray]
    targets: np.ndarray
    labels: list[str]
    done: np.ndarray
    title: str
    subtitle: str
    notes: list[str] = field(default_factory=list)

    @property
    def scale_bar(self) -> tuple[float, float, float]:
        """Left x, y and length (mm on the page) of a bar that is 50 mm on the skin."""
        return MARGIN_MM, self.height_mm - MARGIN_MM - 2.0, SCALE_BAR_MM * self.scale


def layout_sheet(
    mesh: trimesh.Trimesh,
    targets: Points,
    *,
    title: str = "skinloc calibration targets",
    done: np.ndarray | None = None,
) -> TargetSheet:
    """Flatten the skin and place its targets on the smallest page that holds them at 1:1.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Skin surface, m.
    targets : (n, 3) float
        Targets on the surface, m, numbered from 1 in this order.
    title : str
        First header line.
    done : (n,) bool, optional
        Targets already touched.

    Returns
    -------
    TargetSheet
        Falls back to the largest page, scaled down (and says so), when none holds the skin at
        actual size.
    """
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    flat = flatten(mesh)
    outline_m = flat.boundary or [flat.vertices_2d]
    pts = np.concatenate(outline_m + [flat.map_points(targets)]) * 1e3
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = np.maximum(hi - lo, 1e-6)
    chosen, scale = None, 1.0
    for name, w, h in PAGES:
        if size[0] <= w - 2 * MARGIN_MM and size[1] <= h - 2 * MARGIN_MM - HEADER_MM - FOOTER_MM:
            chosen = (name, w, h)
            break
    if chosen is None:
        chosen = PAGES[2]
        _, w, h = chosen
        scale = float(
            min(
                (w - 2 * MARGIN_MM) / size[0], (h - 2 * MARGIN_MM - HEADER_MM - FOOTER_MM) / size[1]
            )
        )
    name, w, h = chosen
    # Centre the content between the header and the footer; flip y (page y runs downwards).
    centre_page = np.array(
        [w / 2, HEADER_MM + MARGIN_MM + (h - 2 * MARGIN_MM - HEADER_MM - FOOTER_MM) / 2]
    )
    centre_skin = (lo + hi) / 2

    def place(p_m: np.ndarray) -> np.ndarray:
        q = (np.asarray(p_m) * 1e3 - centre_skin) * scale
        return centre_page + q * [1.0, -1.0]

    how = {
        "cone": "the cone unrolled exactly",
        "cylinder": "the cylinder unrolled exactly",
        "unwrap": f"a surface unwrapping (lengths kept within {100 * flat.stretch:.1f} %)",
    }[flat.kind]
    size_note = (
        "Print at 100 % (actual size, no 'fit to page'): the scale bar must measure 50 mm."
        if scale == 1.0
        else f"SCALED TO {100 * scale:.0f} %: the skin does not fit on {name} at actual size."
    )
    n = len(targets)
    return TargetSheet(
        page=name,
        width_mm=w,
        height_mm=h,
        scale=scale,
        outline=[place(loop) for loop in outline_m],
        targets=place(flat.map_points(targets)) if n else np.zeros((0, 2)),
        labels=[str(i + 1) for i in range(n)],
        done=np.zeros(n, dtype=bool) if done is None else np.asarray(done, dtype=bool),
        title=title,
        subtitle=f"{n} targets on {how}; seen from the outside of the skin.",
        notes=[size_note, "Cut along the outline, lay it on the skin and mark each cross."],
    )


def _fmt(x: float) -> str:
    return f"{x:.2f}".rstrip("0").rstrip(".")


def render_svg(sheet: TargetSheet) -> str:
    """The sheet as an SVG document sized in millimetres (prints at actual size)."""
    w, h = sheet.width_mm, sheet.height_mm
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{_fmt(w)}mm" height="{_fmt(h)}mm" '
        f'viewBox="0 0 {_fmt(w)} {_fmt(h)}" font-family="Helvetica, Arial, sans-serif">',
        f"<title>{escape(sheet.title)}</title>",
        f'<rect x="0" y="0" width="{_fmt(w)}" height="{_fmt(h)}" fill="white"/>',
        f'<text x="{_fmt(MARGIN_MM)}" y="{_fmt(MARGIN_MM + 4)}" font-size="5" '
        f'font-weight="bold">{escape(sheet.title)}</text>',
        f'<text x="{_fmt(MARGIN_MM)}" y="{_fmt(MARGIN_MM + 10)}" font-size="3.2">'
        f"{escape(sheet.subtitle)}</text>",
    ]
    for loop in sheet.outline:
        pts = " ".join(f"{_fmt(x)},{_fmt(y)}" for x, y in loop)
        out.append(
            f'<polygon points="{pts}" fill="none" stroke="black" stroke-width="0.35" '
            'stroke-dasharray="3 1.5"/>'
        )
    r = 3.0 * sheet.scale
    for (x, y), label, done in zip(sheet.targets, sheet.labels, sheet.done, strict=True):
        fill = "#bbbbbb" if done else "none"
        out.append(
            f'<g><circle cx="{_fmt(x)}" cy="{_fmt(y)}" r="{_fmt(r)}" fill="{fill}" '
            'stroke="#c0392b" stroke-width="0.3"/>'
            f'<path d="M{_fmt(x - 2 * r)} {_fmt(y)}H{_fmt(x + 2 * r)}M{_fmt(x)} {_fmt(y - 2 * r)}'
            f'V{_fmt(y + 2 * r)}" stroke="#c0392b" stroke-width="0.2"/>'
            f'<text x="{_fmt(x + 1.1 * r)}" y="{_fmt(y - 1.1 * r)}" font-size="3.5">'
            f"{escape(label)}</text></g>"
        )
    bx, by, blen = sheet.scale_bar
    out.append(
        f'<path d="M{_fmt(bx)} {_fmt(by)}h{_fmt(blen)}M{_fmt(bx)} {_fmt(by - 1.5)}v3'
        f'M{_fmt(bx + blen)} {_fmt(by - 1.5)}v3" stroke="black" stroke-width="0.4"/>'
    )
    out.append(
        f'<text x="{_fmt(bx + blen + 3)}" y="{_fmt(by + 1.2)}" font-size="3.2">50 mm on the skin'
        "</text>"
    )
    for k, note in enumerate(sheet.notes):
        out.append(
            f'<text x="{_fmt(w - MARGIN_MM)}" y="{_fmt(h - MARGIN_MM - 6 + 5 * k)}" '
            f'font-size="3" text-anchor="end">{escape(note)}</text>'
        )
    out.append("</svg>")
    return "\n".join(out) + "\n"


def render_pdf(sheet: TargetSheet) -> bytes:
    """The sheet as a one-page PDF at actual size."""
    from fpdf import FPDF

    orientation = "L" if sheet.width_mm > sheet.height_mm else "P"
    pdf = FPDF(
        orientation=orientation,
        unit="mm",
        format=(min(sheet.width_mm, sheet.height_mm), max(sheet.width_mm, sheet.height_mm)),
    )
    pdf.set_auto_page_break(False)
    pdf.set_title(sheet.title)
    pdf.set_creator("skinloc")
    pdf.add_page()
    pdf.set_font("Helvetica", "B", 14)
    pdf.text(MARGIN_MM, MARGIN_MM + 4, sheet.title)
    pdf.set_font("Helvetica", "", 9)
    pdf.text(MARGIN_MM, MARGIN_MM + 10, sheet.subtitle)
    pdf.set_draw_color(0, 0, 0)
    pdf.set_line_width(0.35)
    with pdf.local_context(dash_pattern={"dash": 3, "gap": 1.5}):
        for loop in sheet.outline:
            pdf.polygon([tuple(p) for p in loop.tolist()], style="D")
    r = 3.0 * sheet.scale
    pdf.set_draw_color(192, 57, 43)
    pdf.set_fill_color(187, 187, 187)
    pdf.set_font("Helvetica", "", 10)
    for (x, y), label, done in zip(sheet.targets.tolist(), sheet.labels, sheet.done, strict=True):
        pdf.set_line_width(0.3)
        pdf.circle(x, y, r, style="DF" if done else "D")
        pdf.set_line_width(0.2)
        pdf.line(x - 2 * r, y, x + 2 * r, y)
        pdf.line(x, y - 2 * r, x, y + 2 * r)
        pdf.text(x + 1.1 * r, y - 1.1 * r, label)
    bx, by, blen = sheet.scale_bar
    pdf.set_draw_color(0, 0, 0)
    pdf.set_line_width(0.4)
    pdf.line(bx, by, bx + blen, by)
    pdf.line(bx, by - 1.5, bx, by + 1.5)
    pdf.line(bx + blen, by - 1.5, bx + blen, by + 1.5)
    pdf.set_font("Helvetica", "", 9)
    pdf.text(bx + blen + 3, by + 1.2, "50 mm on the skin")
    for k, note in enumerate(sheet.notes):
        pdf.text(sheet.width_mm - MARGIN_MM - pdf.get_string_width(note), by - 6 + 5 * k, note)
    return bytes(pdf.output())
