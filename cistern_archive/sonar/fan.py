"""Fan pictures of a scan: polar intensities resampled onto a Cartesian image, as PNG bytes.

The picture is drawn in the sonar frame seen from above, forward up (bearing 0 points up, bearings grow
counter-clockwise, i.e. to the left), so it looks like the head's own display. Rendering uses
matplotlib's Agg canvas with no wall-clock metadata, so equal scans give equal bytes.
"""

from __future__ import annotations

import io
import math

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cistern_archive.core.scan import RangeScan, Scan

PNG_METADATA = {"Software": None}


def polar_to_cartesian(
    bearings_rad: np.ndarray, values: np.ndarray, bin_size_m: float, start_range_m: float = 0.0,
    *, pixels: int = 400, beam_width_rad: float | None = None,
) -> tuple[np.ndarray, float]:
    """Resample a (beams, bins) polar image onto a square Cartesian grid (nearest beam and bin).

    Parameters
    ----------
    bearings_rad : ndarray, shape (A,)
        Beam bearings, sonar frame (CCW from forward).
    values : ndarray, shape (A, B)
    bin_size_m, start_range_m : float
    pixels : int
        Side of the output image.
    beam_width_rad : float, optional
        Pixels farther than this from every beam (the median bearing step by default, so the gap
        outside a sector scan stays empty) are left empty.

    Returns
    -------
    image : ndarray of float, shape (pixels, pixels)
        ``nan`` outside the swept fan. Row 0 is the top (forward), column 0 the left.
    extent_m : float
        Half the side of the image in metres.
    """
    n_beams, n_bins = values.shape
    extent = start_range_m + n_bins * bin_size_m
    axis = (np.arange(pixels) + 0.5) / pixels * 2 * extent - extent
    right, forward = np.meshgrid(axis, axis[::-1])
    rng = np.hypot(right, forward)
    bearing = np.arctan2(-right, forward)
    order = np.argsort(np.mod(bearings_rad, 2 * np.pi))
    sorted_b = np.mod(bearings_rad[order], 2 * np.pi)
    query = np.mod(bearing, 2 * np.pi)
    pos = np.searchsorted(sorted_b, query)
    lo = (pos - 1) % n_beams
    hi = pos % n_beams
    d_lo = np.abs(np.mod(query - sorted_b[lo] + np.pi, 2 * np.pi) - np.pi)
    d_hi = np.abs(np.mod(query - sorted_b[hi] + np.pi, 2 * np.pi) - np.pi)
    nearest = np.where(d_lo <= d_hi, lo, hi)
    gap = np.min(np.stack([d_lo, d_hi]), axis=0)
    if beam_width_rad is None:
        diffs = np.diff(np.concatenate([sorted_b, sorted_b[:1] + 2 * np.pi])) if n_beams > 1 else np.array([math.pi])
        beam_width_rad = max(float(np.median(diffs)), 1e-6)
    bins = np.floor((rng - start_range_m) / bin_size_m).astype(np.int64)
    valid = (bins >= 0) & (bins < n_bins) & (gap <= beam_width_rad)
    image = np.full(rng.shape, np.nan)
    image[valid] = np.asarray(values, dtype=np.float64)[order[nearest[valid]], bins[valid]]
    return image, extent


def display_levels(scan: Scan, contrast: str = "auto") -> np.ndarray:
    """Intensities scaled to 0..1 for display (see :func:`fan_png`)."""
    values = scan.normalised()
    if contrast == "full-scale":
        return values
    if contrast != "auto":
        raise ValueError(f"contrast must be 'auto' or 'full-scale', got {contrast!r}")
    nonzero = values[values > 0]
    top = float(np.percentile(nonzero, 99.5)) if nonzero.size else 1.0
    return np.clip(values / max(top, 1e-6), 0.0, 1.0)


def _render(images: list[tuple[str, np.ndarray]], extent: float, overlays: list[np.ndarray | None],
            suptitle: str, dpi: int) -> bytes:
    fig = Figure(figsize=(4.2 * len(images), 4.4), dpi=dpi)
    FigureCanvasAgg(fig)
    for k, ((title, image), points) in enumerate(zip(images, overlays)):
        ax = fig.add_subplot(1, len(images), k + 1)
        ax.set_facecolor("#101010")
        ax.imshow(image, cmap="inferno", vmin=0, vmax=1, extent=(-extent, extent, -extent, extent),
                  interpolation="nearest")
        if points is not None and len(points):
            ax.plot(points[:, 0], points[:, 1], ".", ms=1.5, color="#4fc3f7")
        ax.plot([0], [0], "+", color="white", ms=8)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("right (m)", fontsize=8)
        ax.set_ylabel("forward (m)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_aspect("equal")
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, metadata=PNG_METADATA)
    return buffer.getvalue()


def _ranges_to_display(ranges: RangeScan) -> np.ndarray:
    """Echo points in display coordinates (right, forward)."""
    pts = ranges.points(yaw_rad=0.0)
    return np.column_stack([-pts[:, 1], pts[:, 0]])


def fan_png(
    scan: Scan,
    *,
    segmented: np.ndarray | None = None,
    ranges: RangeScan | None = None,
    title: str | None = None,
    pixels: int = 360,
    dpi: int = 100,
    contrast: str = "auto",
) -> bytes:
    """A PNG of the scan's fan: the raw intensities, and beside them the segmented image if given.

    Parameters
    ----------
    scan : Scan
    segmented : ndarray, shape (A, B), optional
        A segmented image on the 0..255 scale, e.g. from
        :func:`cistern_archive.sonar.segmentation.segment_intensities`.
    ranges : RangeScan, optional
        Segmented ranges drawn as points over the segmented panel (or over the raw one when
        ``segmented`` is not given).
    title : str, optional
        Defaults to the station label and sonar model.
    pixels, dpi : int
    contrast : {'auto', 'full-scale'}
        ``full-scale`` maps 0..``scan.full_scale`` to the colour map; ``auto`` maps 0 .. the 99.5th
        percentile of the non-zero intensities (weak real recordings stay visible).

    Returns
    -------
    bytes
        A PNG without time or software metadata.
    """
    raw, extent = polar_to_cartesian(scan.bearings_rad, display_levels(scan, contrast), scan.bin_size_m,
                                     scan.start_range_m, pixels=pixels)
    panels = [("raw intensities", raw)]
    overlays: list[np.ndarray | None] = [None]
    points = _ranges_to_display(ranges) if ranges is not None else None
    if segmented is not None:
        seg, _ = polar_to_cartesian(scan.bearings_rad, np.asarray(segmented, dtype=np.float64) / 255.0,
                                    scan.bin_size_m, scan.start_range_m, pixels=pixels)
        panels.append(("segmented", seg))
        overlays.append(points)
    else:
        overlays[0] = points
    label = title if title is not None else f"{scan.station or 'scan'} · {scan.sonar_model}"
    return _render(panels, extent, overlays, label, dpi)
