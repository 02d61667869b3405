"""Profile drawings of a vessel as SVG (written by hand) and DXF (ezdxf), atomically.

The half-section convention of archaeological drawing: the axis a vertical dash-dot line;
on its left the section cut through the wall (outer and inner profile, closed along the
rim and base) filled black; on its right the outer silhouette as seen (the largest radius
at each height, mirrored); horizontal lines at the rim and base join the halves.  A scale
bar and the measures as text.  The SVG is drawn on paper in millimetres at ``1:N``; the
DXF holds the model at 1:1 in its own unit (``$INSUNITS``), the scale written as text
(CAD applies a scale in its layouts).

Drawing contract (:class:`Drawing`): profile polylines in ``(r, z)``, scene units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import escape as xml_escape

import numpy as np

from pipeline.atomic import atomic_file

#: Millimetres per scene unit for the units a user may name.
UNIT_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
#: DXF ``$INSUNITS`` codes of those units.
_DXF_UNITS = {"mm": 4, "cm": 5, "m": 6, "in": 1}
#: Largest drawing on the paper (mm) when no scale is given: an A4 page's print area.
_PAPER_MM = 180.0


@dataclass(frozen=True)
class Drawing:
    """What a profile drawing shows.

    Attributes
    ----------
    section : (S, 2) float64
        The cut wall, closed polygon in ``(r, z)`` (drawn at ``-r``).
    others : list of (L, 2) float64
        Further cut pieces (handles), drawn filled at ``-r``.
    silhouette : (B, 2) float64
        The outer outline ``(r, z)`` (drawn at ``+r``).
    rim_z, base_z : float
        Heights of the rim and base lines.
    lines : list of str
        The measures, one text line each.
    units : str or None
        The scene unit (``mm``, ``cm``, ``m``, ``in``) or None when unknown.
    scale : int or None
        ``N`` of ``1:N``; None chooses one to fit.
    title : str
    """

    section: np.ndarray
    silhouette: np.ndarray
    rim_z: float
    base_z: float
    lines: list = field(default_factory=list)
    others: list = field(default_factory=list)
    units: str | None = None
    scale: int | None = None
    title: str = ""


def _nice(value: float) -> float:
    """The largest of 1, 2, 5 x 10^k not above ``value``."""
    exp = math.floor(math.log10(value))
    for step in (5, 2, 1):
        if step * 10 ** exp <= value:
            return step * 10 ** exp
    return 10 ** exp


def paper_scale(drawing: Drawing) -> tuple[int, float]:
    """``(N, mm of paper per scene unit)``: the given scale, or the smallest 1-2-5 step
    that fits the object on :data:`_PAPER_MM` (a unit counts as 1 mm when unknown)."""
    unit_mm = UNIT_MM.get(drawing.units or "mm", 1.0)
    pts = np.vstack([drawing.section, drawing.silhouette])
    extent = max(2 * np.abs(pts[:, 0]).max(), np.ptp(pts[:, 1])) * unit_mm
    if drawing.scale is not None:
        n = int(drawing.scale)
    else:
        n = 1
        while extent / n > _PAPER_MM:
            n = int(round(n * (2.5 if str(n)[0] == "2" else 2)))  # 1, 2, 5, 10, 20, 50 ...
    return n, unit_mm / n


def _scale_bar(drawing: Drawing) -> float:
    """Scale bar length (scene units): a round 1-2-5 length near half the width."""
    return _nice(max(np.abs(drawing.silhouette[:, 0]).max(), 1e-300))


def svg_text(drawing: Drawing) -> str:
    """The SVG document (paper millimetres) of ``drawing``."""
    n, k = paper_scale(drawing)
    pts = np.vstack([drawing.section, drawing.silhouette])
    half = np.abs(pts[:, 0]).max() * k
    zmin, zmax = pts[:, 1].min(), pts[:, 1].max()
    margin = 10.0
    text_h = 5.0 * (len(drawing.lines) + 3)
    # the measures' lines set a floor on the width (3.5 mm sans-serif: ~2 mm a character)
    width = max(2 * half, 2.0 * max(map(len, drawing.lines), default=0)) + 2 * margin
    height = (zmax - zmin) * k + 2 * margin + 15.0 + text_h
    cx, top = margin + half, margin

    def xy(rz: np.ndarray, sign: float) -> str:
        x = cx + sign * rz[:, 0] * k
        y = top + (zmax - rz[:, 1]) * k
        return " ".join(f"{a:.3f},{b:.3f}" for a, b in zip(x, y, strict=True))

    def y_of(z: float) -> float:
        return top + (zmax - z) * k

    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.2f}mm" '
           f'height="{height:.2f}mm" viewBox="0 0 {width:.3f} {height:.3f}">',
           f"<title>{xml_escape(drawing.title or 'profile')}</title>",
           '<g id="section" fill="black" stroke="black" stroke-width="0.25">',
           f'<polygon points="{xy(drawing.section, -1.0)}"/>']
    out += [f'<polygon points="{xy(p, -1.0)}"/>' for p in drawing.others if len(p) > 2]
    out.append("</g>")
    out.append(f'<polyline id="silhouette" fill="none" stroke="black" stroke-width="0.35" '
               f'points="{xy(drawing.silhouette, 1.0)}"/>')
    r_rim = np.interp(drawing.rim_z, drawing.silhouette[:, 1], drawing.silhouette[:, 0])
    r_base = np.interp(drawing.base_z, drawing.silhouette[:, 1], drawing.silhouette[:, 0])
    for z, r in ((drawing.rim_z, r_rim), (drawing.base_z, r_base)):
        out.append(f'<line class="join" x1="{cx:.3f}" y1="{y_of(z):.3f}" '
                   f'x2="{cx + r * k:.3f}" y2="{y_of(z):.3f}" stroke="black" '
                   'stroke-width="0.25"/>')
    out.append(f'<line id="axis" x1="{cx:.3f}" y1="{top - 5:.3f}" x2="{cx:.3f}" '
               f'y2="{y_of(zmin) + 5:.3f}" stroke="black" stroke-width="0.18" '
               'stroke-dasharray="6,1.5,0.8,1.5"/>')
    bar = _scale_bar(drawing)
    unit = drawing.units or "units"
    y_bar = y_of(zmin) + 12.0
    out.append(f'<g id="scalebar" stroke="black" stroke-width="0.35">'
               f'<line x1="{margin:.3f}" y1="{y_bar:.3f}" x2="{margin + bar * k:.3f}" '
               f'y2="{y_bar:.3f}"/>'
               f'<line x1="{margin:.3f}" y1="{y_bar - 1.5:.3f}" x2="{margin:.3f}" '
               f'y2="{y_bar + 1.5:.3f}"/>'
               f'<line x1="{margin + bar * k:.3f}" y1="{y_bar - 1.5:.3f}" '
               f'x2="{margin + bar * k:.3f}" y2="{y_bar + 1.5:.3f}"/></g>')
    lines = [f"{bar:g} {unit}   scale 1:{n}"] + list(drawing.lines)
    out.append('<g id="measures" font-family="sans-serif" font-size="3.5" fill="black">')
    for i, line in enumerate(lines):
        out.append(f'<text x="{margin:.3f}" y="{y_bar + 6.0 + 5.0 * i:.3f}">'
                   f"{xml_escape(line)}</text>")
    out += ["</g>", "</svg>", ""]
    return "\n".join(out)


def write_svg(path: str | Path, drawing: Drawing) -> Path:
    """Write ``drawing`` as SVG to ``path`` (write-then-rename)."""
    with atomic_file(path) as tmp:
        tmp.write_text(svg_text(drawing), encoding="utf-8")
    return Path(path)


def dxf_document(drawing: Drawing):
    """An ``ezdxf`` document of ``drawing`` at 1:1 in the scene unit.

    Layers: ``SECTION`` (the cut wall: closed polylines and a solid hatch), ``SILHOUETTE``,
    ``AXIS`` (linetype DASHDOT), ``SCALEBAR``, ``TEXT``.
    """
    import ezdxf

    doc = ezdxf.new("R2010", setup=True)
    doc.header["$INSUNITS"] = _DXF_UNITS.get(drawing.units or "", 0)
    for name, colour in (("SECTION", 7), ("SILHOUETTE", 7), ("AXIS", 1), ("SCALEBAR", 7),
                         ("TEXT", 7)):
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()
    for piece in [drawing.section] + [p for p in drawing.others if len(p) > 2]:
        left = [(-float(r), float(z)) for r, z in piece]
        msp.add_lwpolyline(left, close=True, dxfattribs={"layer": "SECTION"})
        hatch = msp.add_hatch(color=7, dxfattribs={"layer": "SECTION"})
        hatch.paths.add_polyline_path(left, is_closed=True)
    msp.add_lwpolyline([(float(r), float(z)) for r, z in drawing.silhouette],
                       dxfattribs={"layer": "SILHOUETTE"})
    sil = drawing.silhouette
    for z in (drawing.rim_z, drawing.base_z):
        msp.add_line((0.0, z), (float(np.interp(z, sil[:, 1], sil[:, 0])), z),
                     dxfattribs={"layer": "SILHOUETTE"})
    zmin, zmax = float(sil[:, 1].min()), float(sil[:, 1].max())
    pad = 0.05 * (zmax - zmin)
    msp.add_line((0.0, zmin - pad), (0.0, zmax + pad),
                 dxfattribs={"layer": "AXIS", "linetype": "DASHDOT"})
    bar = _scale_bar(drawing)
    x0 = -float(np.abs(sil[:, 0]).max())
    y_bar = zmin - 3 * pad
    msp.add_line((x0, y_bar), (x0 + bar, y_bar), dxfattribs={"layer": "SCALEBAR"})
    n, _ = paper_scale(drawing)
    lines = [f"{bar:g} {drawing.units or 'units'}   scale 1:{n}"] + list(drawing.lines)
    size = 0.03 * (zmax - zmin)
    for i, line in enumerate(lines):
        msp.add_text(line, height=size, dxfattribs={"layer": "TEXT"}).set_placement(
            (x0, y_bar - (i + 1.5) * 1.6 * size))
    return doc


def write_dxf(path: str | Path, drawing: Drawing) -> Path:
    """Write ``drawing`` as DXF to ``path`` (write-then-rename)."""
    doc = dxf_document(drawing)
    with atomic_file(path) as tmp:
        doc.saveas(tmp)
    return Path(path)
