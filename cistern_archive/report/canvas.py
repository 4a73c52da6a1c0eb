"""What every figure of the report shares: its own Agg canvas with fixed margins, the record of a
written figure (:class:`FigureFile`) and the colours of converged and failed pair links."""

from __future__ import annotations

from dataclasses import dataclass

from matplotlib import rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

rcParams["svg.hashsalt"] = "cistern-archive"

LINK_OK, LINK_BAD = "#1b7837", "#c51b7d"
LINK_FIT = "#2b8cbe"
"""Joins of groups of scans fitted as wholes (:attr:`~cistern_archive.core.poses.Poses.group_links`)."""


@dataclass(frozen=True)
class FigureFile:
    """A figure written beside the page."""

    key: str
    file: str
    title: str
    alt: str
    caption: str = ""


def new_figure(width_in: float, height_in: float, dpi: int, **margins: float) -> Figure:
    """A figure on its own Agg canvas with fixed margins (fractions of the figure; a constraint
    solver would cost more than the drawing)."""
    figure = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(figure)
    figure.subplots_adjust(**{"left": 0.1, "right": 0.95, "bottom": 0.1, "top": 0.92, **margins})
    return figure
