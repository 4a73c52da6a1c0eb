"""The site plan for CAD and for print: the wall outline at every mapped depth as DXF and SVG.

The outline of a depth is the horizontal section of the pipeline's wall surface
(:mod:`cistern_archive.grid.surface`) at that depth: where the walls were seen, an open polyline
where they were not. Coordinates are the map frame in metres (x east, y north; the reference scan at
the origin).

* ``plan.dxf`` (``ezdxf``, AutoCAD 2010 format, units metres): one layer per depth, ``DEPTH_1_60M``,
  with one ``LWPOLYLINE`` per outline piece; fixed header metadata so that the same plan gives the
  same bytes;
* ``plan.svg``: the outlines north up, one colour per depth with a legend, a scale bar of a round
  length and a north arrow; 1 SVG user unit = 1 cm, y flipped so that north is up.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from cistern_archive.report.maps import DIMENSION_COLOURS
from cistern_archive.report.model3d import nice_length


SVG_WIDTH_PX = 1000


@dataclass(frozen=True)
class Outline:
    """The wall outline at one depth: polylines of map-frame points (m), closed ones repeating no point."""

    depth_m: float
    polylines: tuple[np.ndarray, ...]
    closed: tuple[bool, ...]


def section_depths(surface) -> list[float]:
    """The depths a plan shows: every slice the surface was made from, inside the surface's span."""
    top, bottom = surface.depth_range_m
    inward = min(0.05, (bottom - top) / 4)  # the surface's own top and bottom edges are ragged
    return [float(np.clip(d, top + inward, bottom - inward)) for d in surface.slice_depths_m]


def outlines(surface) -> list[Outline]:
    """The horizontal sections of a :class:`~cistern_archive.grid.surface.SurfaceMesh` at
    :func:`section_depths`, each as joined polylines."""
    mesh = surface.to_pyvista()
    out = []
    for depth in section_depths(surface):
        cut = mesh.slice(normal=(0.0, 0.0, 1.0), origin=(0.0, 0.0, -depth))
        if cut.n_points == 0:
            continue
        stripped = cut.strip(join=True)
        points = np.asarray(stripped.points)[:, :2]
        lines = np.asarray(stripped.lines)
        polylines, closed = [], []
        k = 0
        while k < len(lines):
            n = int(lines[k])
            ids = lines[k + 1:k + 1 + n]
            k += n + 1
            if n < 2:
                continue
            ring = ids[0] == ids[-1] and n > 3
            polylines.append(points[ids[:-1] if ring else ids].round(4))
            closed.append(bool(ring))
        order = sorted(range(len(polylines)), key=lambda i: (-len(polylines[i]), tuple(polylines[i][0])))
        out.append(Outline(depth, tuple(polylines[i] for i in order), tuple(closed[i] for i in order)))
    return out


def layer_name(depth_m: float) -> str:
    """``DEPTH_1_60M``: a DXF layer name (letters, digits and underscores) for a depth."""
    return "DEPTH_" + f"{depth_m:.2f}".replace(".", "_") + "M"


def write_dxf(path: Path, plan: Sequence[Outline]) -> Path:
    """``plan.dxf``: one layer per depth, one LWPOLYLINE per outline piece (metres)."""
    import ezdxf

    previous = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True  # no clock, no random GUIDs: same plan, same bytes
    try:
        doc = ezdxf.new("R2010", setup=False)
        doc.units = ezdxf.units.M
        doc.header["$INSUNITS"] = ezdxf.units.M
        space = doc.modelspace()
        for k, outline in enumerate(plan):
            name = layer_name(outline.depth_m)
            doc.layers.add(name, color=1 + k % 6)
            for line, closed in zip(outline.polylines, outline.closed):
                space.add_lwpolyline([(float(x), float(y)) for x, y in line], close=closed,
                                     dxfattribs={"layer": name})
        doc.saveas(path)
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = previous
    return path


def svg_text(plan: Sequence[Outline], *, title: str) -> str:
    """The SVG document of the plan (see the module docstring)."""
    points = np.concatenate([line for o in plan for line in o.polylines]) if plan else np.zeros((1, 2))
    x0, y0 = points.min(axis=0)
    x1, y1 = points.max(axis=0)
    span = max(x1 - x0, y1 - y0, 1.0)
    margin = 0.08 * span
    legend_w = 0.35 * span
    scale = 100.0  # SVG units (cm) per metre
    width = (x1 - x0 + 2 * margin + legend_w) * scale
    height = (y1 - y0 + 3 * margin) * scale

    def sx(x: float) -> float:
        return (x - x0 + margin) * scale

    def sy(y: float) -> float:
        return (y1 - y + margin) * scale

    stroke = 0.004 * span * scale
    font = 0.03 * span * scale
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width:.1f} {height:.1f}" '
             f'width="{SVG_WIDTH_PX}" height="{SVG_WIDTH_PX * height / width:.0f}" font-family="sans-serif">',
             f"<title>{escape(title)}</title>",
             f'<rect width="{width:.1f}" height="{height:.1f}" fill="white"/>']
    for k, outline in enumerate(plan):
        colour = DIMENSION_COLOURS[k % len(DIMENSION_COLOURS)]
        parts.append(f'<g id="{layer_name(outline.depth_m)}" stroke="{colour}" stroke-width="{stroke:.1f}" '
                     f'fill="none" stroke-linejoin="round">')
        for line, closed in zip(outline.polylines, outline.closed):
            coords = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in line)
            parts.append(f'<{"polygon" if closed else "polyline"} points="{coords}"/>')
        parts.append("</g>")
        ly = margin * scale + (k + 1) * 1.6 * font
        lx = (x1 - x0 + 1.5 * margin) * scale
        parts.append(f'<line x1="{lx:.1f}" y1="{ly - font / 3:.1f}" x2="{lx + 1.5 * font:.1f}" y2="{ly - font / 3:.1f}" '
                     f'stroke="{colour}" stroke-width="{stroke:.1f}"/>')
        parts.append(f'<text x="{lx + 2 * font:.1f}" y="{ly:.1f}" font-size="{font:.1f}">depth '
                     f"{outline.depth_m:.2f} m</text>")
    length = nice_length(x1 - x0 if x1 > x0 else span)
    bx, by = sx(x0), (y1 - y0 + 2.2 * margin) * scale
    parts.append(f'<g id="scale-bar"><line x1="{bx:.1f}" y1="{by:.1f}" x2="{bx + length * scale:.1f}" y2="{by:.1f}" '
                 f'stroke="black" stroke-width="{2 * stroke:.1f}"/>'
                 f'<text x="{bx + length * scale / 2:.1f}" y="{by + 1.3 * font:.1f}" font-size="{font:.1f}" '
                 f'text-anchor="middle">{length:g} m</text></g>')
    ax, ay = (x1 - x0 + 1.5 * margin + 0.5 * legend_w) * scale, (y1 - y0 + 1.6 * margin) * scale
    arrow = 2.5 * font
    parts.append(f'<g id="north-arrow"><path d="M {ax:.1f} {ay - arrow:.1f} L {ax - arrow / 3:.1f} {ay:.1f} '
                 f'L {ax:.1f} {ay - arrow / 4:.1f} L {ax + arrow / 3:.1f} {ay:.1f} Z" fill="black"/>'
                 f'<text x="{ax:.1f}" y="{ay - arrow - font / 3:.1f}" font-size="{font:.1f}" '
                 f'text-anchor="middle">N</text></g>')
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def write_svg(path: Path, plan: Sequence[Outline], *, title: str) -> Path:
    """``plan.svg`` (see :func:`svg_text`)."""
    path.write_text(svg_text(plan, title=title), encoding="utf-8")
    return path
