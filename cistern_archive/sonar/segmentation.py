"""Beam segmentation: raw echo intensities to one wall range per beam.

Two methods, chosen by :class:`cistern_archive.catalog.models.Segmentation`:

``paper``
    McVicker et al., Sec. III-B, exactly: the intensities of the whole scan are normalised to 0..255 by
    the scan's maximum; on every beam the bin with the largest normalised intensity among the bins that
    have at least one non-zero neighbour (bin ``k - 1`` or ``k + 1`` of the same beam) is kept when its
    intensity is above the threshold (50 in the paper). Its centre is the beam's range; beams with no such
    bin have no echo (``nan``). The segmented image sets that bin and its neighbours to 255 and every
    other bin to 0 (:func:`segment_intensities`).

    Decisions where the text is silent: normalisation is ``rint(I * 255 / max)`` (an integer image,
    as the 0..255 wording suggests), "above" is strict (``> threshold``), ties go to the nearest bin,
    and a non-zero ``min_range_m`` blanks the bins whose centre is closer than it *before* the
    normalisation (with the default 0 nothing changes).

``cfar``
    A range-adaptive alternative that targets the failure modes of the paper's rule on real scans:

    1. each beam is smoothed with a 3-bin moving average, so an isolated one-bin spike loses two thirds
       of its height while a wall echo, which spans the pulse length, keeps most of it;
    2. the smoothed image is normalised to 0..255 by its maximum beyond ``min_range_m`` (robust to a
       single spike, unlike the raw maximum, and blind to the vehicle's own echo);
    3. a cell-averaging CFAR test along the beam: a bin is a detection when it exceeds both the absolute
       ``threshold`` and ``CFAR_SCALE`` times the mean of the ``CFAR_TRAIN`` leading training bins
       (before ``CFAR_GUARD`` guard bins), i.e. it stands out from the water in front of it; the
       training window is the leading one because the space in front of the first wall is water, while
       the space behind it holds multipath and reverberation;
    4. detections closer than ``min_range_m`` are dropped (the vehicle's own echo and the transducer's
       ring-down); the training cells still see those bins, so the decaying near field does not pass
       the test just beyond ``min_range_m``;
    5. among the detections of a beam the **first** one reaching ``FIRST_RATIO`` of the beam's strongest
       detection starts the wall echo (the contiguous run of detections from there; its peak is the
       run's maximum): later, possibly stronger, echoes are multipath ghosts (the direct path is the
       shortest);
    6. the range is sub-bin: the raw maximum next to the echo's peak, refined by a parabola through it and
       its neighbours (a Gaussian fit, the intensities being log-compressed).

Both return a :class:`~cistern_archive.sonar.scan.RangeScan`. The CFAR constants below were chosen on
simulated scans whose seeds are not those of the bundled catalog; ``benchmarks/segmentation.py`` compares
the two methods.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from cistern_archive.sonar.scan import RangeScan, Scan

PAPER_SCALE = 255
CFAR_TRAIN = 8
CFAR_GUARD = 2
CFAR_SCALE = 1.5
FIRST_RATIO = 0.7


class SegmentationSettings(Protocol):
    """What :func:`segment` reads from its settings (satisfied by ``catalog.models.Segmentation``)."""

    method: str
    threshold: float
    min_range_m: float


def _blank_near(scan: Scan, min_range_m: float) -> np.ndarray:
    """Intensities as float64 with the bins whose centre is closer than ``min_range_m`` set to 0."""
    values = np.asarray(scan.intensities, dtype=np.float64).copy()
    if min_range_m > 0:
        values[:, scan.bin_centres_m < min_range_m] = 0.0
    return np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0).clip(min=0.0)


def normalise_paper(values: np.ndarray) -> np.ndarray:
    """Normalise a whole scan to integers 0..255 by its maximum (paper Sec. III-B).

    Parameters
    ----------
    values : ndarray, shape (A, B)
        Non-negative intensities.

    Returns
    -------
    ndarray of int16, shape (A, B)
        ``rint(values * 255 / values.max())``; all zeros when the scan is empty.
    """
    peak = float(values.max()) if values.size else 0.0
    if peak <= 0:
        return np.zeros(values.shape, dtype=np.int16)
    return np.rint(values * (PAPER_SCALE / peak)).astype(np.int16)


def paper_peak_bins(normalised: np.ndarray, threshold: float) -> np.ndarray:
    """The bin each beam keeps under the paper's rule, or -1.

    Parameters
    ----------
    normalised : ndarray, shape (A, B)
        The output of :func:`normalise_paper`.
    threshold : float
        A kept bin must be strictly above this (50 in the paper).

    Returns
    -------
    ndarray of int64, shape (A,)
        Index of the maximum bin among those with a non-zero neighbour on the same beam, when it exceeds
        ``threshold``; -1 otherwise. Ties go to the nearest bin.
    """
    n_beams, n_bins = normalised.shape
    if n_bins == 0:
        return np.full(n_beams, -1, dtype=np.int64)
    nonzero = normalised > 0
    has_neighbour = np.zeros_like(nonzero)
    has_neighbour[:, 1:] |= nonzero[:, :-1]
    has_neighbour[:, :-1] |= nonzero[:, 1:]
    candidates = np.where(has_neighbour, normalised, -1)
    best = np.argmax(candidates, axis=1)
    best_value = candidates[np.arange(n_beams), best]
    return np.where(best_value > threshold, best, -1).astype(np.int64)


def _moving_average3(values: np.ndarray) -> np.ndarray:
    padded = np.pad(values, ((0, 0), (1, 1)))
    return (padded[:, :-2] + padded[:, 1:-1] + padded[:, 2:]) / 3.0


def _leading_noise(smooth: np.ndarray, train: int, guard: int) -> np.ndarray:
    """Mean of the ``train`` bins ending ``guard`` bins before each bin (fewer near the start)."""
    n_beams, n_bins = smooth.shape
    cumsum = np.concatenate([np.zeros((n_beams, 1)), np.cumsum(smooth, axis=1)], axis=1)
    idx = np.arange(n_bins)
    hi = np.clip(idx - guard, 0, n_bins)
    lo = np.clip(idx - guard - train, 0, n_bins)
    count = np.maximum(hi - lo, 1)
    return (cumsum[:, hi] - cumsum[:, lo]) / count


def cfar_detections(scan: Scan, threshold: float, min_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Detection mask and normalised smoothed image of the ``cfar`` method (steps 1-4).

    The training cells see the unblanked beam, so the decaying tail of the near field in front of a bin
    raises that bin's noise estimate instead of the blanked zeros lowering it.

    Returns
    -------
    detections : ndarray of bool, shape (A, B)
    smooth : ndarray of float64, shape (A, B)
        The smoothed image normalised to 0..255 by its maximum beyond ``min_range_m``.
    """
    values = _blank_near(scan, 0.0)
    smooth = _moving_average3(values)
    far = scan.bin_centres_m >= min_range_m
    peak = float(smooth[:, far].max()) if smooth[:, far].size else 0.0
    if peak <= 0:
        return np.zeros(smooth.shape, dtype=bool), np.zeros_like(smooth)
    smooth *= PAPER_SCALE / peak
    noise = _leading_noise(smooth, CFAR_TRAIN, CFAR_GUARD)
    detections = (smooth > threshold) & (smooth > CFAR_SCALE * noise) & far[None, :]
    return detections, np.where(far[None, :], smooth, 0.0)


def _first_strong_peaks(detections: np.ndarray, smooth: np.ndarray) -> np.ndarray:
    """Per beam the peak bin of the first detected echo reaching FIRST_RATIO of the strongest; -1 if none.

    The echo is the contiguous run of detections starting at its first strong bin; its peak is the run's
    largest smoothed value.
    """
    n_beams, n_bins = smooth.shape
    masked = np.where(detections, smooth, 0.0)
    strongest = masked.max(axis=1) if n_bins else np.zeros(n_beams)
    strong = detections & (masked >= FIRST_RATIO * strongest[:, None])
    has = strong.any(axis=1)
    first = np.argmax(strong, axis=1)
    peaks = np.full(n_beams, -1, dtype=np.int64)
    for beam in np.flatnonzero(has):
        start = int(first[beam])
        run = detections[beam, start:]
        length = int(np.argmin(run)) if not run.all() else run.size
        peaks[beam] = start + int(np.argmax(smooth[beam, start:start + max(length, 1)]))
    return peaks


def _interpolated_ranges(values: np.ndarray, peaks: np.ndarray, centres: np.ndarray, bin_size: float) -> np.ndarray:
    """Sub-bin echo ranges: the raw maximum next to each peak, refined by a parabola through it and its
    two neighbours (intensities are log-compressed, so this is a Gaussian fit); nan where peak is -1."""
    n_beams, n_bins = values.shape
    ranges = np.full(peaks.shape, np.nan)
    ok = peaks >= 0
    if not ok.any():
        return ranges
    beams = np.flatnonzero(ok)
    near = np.clip(peaks[ok][:, None] + np.array([-1, 0, 1])[None, :], 0, n_bins - 1)
    top = near[np.arange(beams.size), np.argmax(values[beams[:, None], near], axis=1)]
    left = values[beams, np.clip(top - 1, 0, n_bins - 1)]
    mid = values[beams, top]
    right = values[beams, np.clip(top + 1, 0, n_bins - 1)]
    curvature = left - 2 * mid + right
    inner = (top > 0) & (top < n_bins - 1) & (curvature < 0)
    offset = np.where(inner, 0.5 * (left - right) / np.where(inner, curvature, -1.0), 0.0)
    ranges[ok] = centres[top] + np.clip(offset, -0.5, 0.5) * bin_size
    return ranges


def peak_bins(scan: Scan, settings: SegmentationSettings) -> np.ndarray:
    """The echo bin of every beam (-1 for none) under ``settings.method``."""
    if settings.method == "paper":
        normalised = normalise_paper(_blank_near(scan, settings.min_range_m))
        return paper_peak_bins(normalised, settings.threshold)
    if settings.method == "cfar":
        detections, smooth = cfar_detections(scan, settings.threshold, settings.min_range_m)
        return _first_strong_peaks(detections, smooth)
    raise ValueError(f"unknown segmentation method {settings.method!r}; expected 'paper' or 'cfar'")


def segment(scan: Scan, settings: SegmentationSettings) -> RangeScan:
    """Segment every beam of ``scan`` into a wall range (paper Sec. III-B, or the CFAR alternative).

    Parameters
    ----------
    scan : Scan
        Raw intensities.
    settings : Segmentation
        ``method`` ('paper' | 'cfar'), ``threshold`` (on the 0..255 normalised scale) and
        ``min_range_m``.

    Returns
    -------
    RangeScan
        One range per beam; ``nan`` where the beam has no echo.
    """
    peaks = peak_bins(scan, settings)
    centres = scan.bin_centres_m
    if settings.method == "cfar":
        ranges = _interpolated_ranges(_blank_near(scan, settings.min_range_m), peaks, centres, scan.bin_size_m)
    else:
        ranges = np.where(peaks >= 0, centres[np.clip(peaks, 0, None)] if centres.size else np.nan, np.nan)
    return RangeScan(
        bearings_rad=scan.bearings_rad,
        ranges_m=ranges,
        yaw_rad=scan.yaw_rad,
        depth_m=scan.depth_m,
        max_range_m=scan.max_range_m,
        bin_size_m=scan.bin_size_m,
        beam_width_rad=scan.beam_width_rad,
        station=scan.station,
    )


def segment_intensities(scan: Scan, settings: SegmentationSettings | None = None) -> np.ndarray:
    """The segmented image: the echo bin of each beam and its two neighbours 255, all else 0.

    This is the paper's output image (Sec. III-B); with ``settings.method == 'cfar'`` the marked bin is
    the CFAR echo's peak. ``settings`` defaults to the paper's rule with threshold 50.

    Returns
    -------
    ndarray of uint8, shape (A, B)
    """
    if settings is None:
        from cistern_archive.catalog.models import Segmentation

        settings = Segmentation()
    peaks = peak_bins(scan, settings)
    out = np.zeros(scan.intensities.shape, dtype=np.uint8)
    n_bins = scan.n_bins
    beams = np.flatnonzero(peaks >= 0)
    for offset in (-1, 0, 1):
        idx = peaks[beams] + offset
        keep = (idx >= 0) & (idx < n_bins)
        out[beams[keep], idx[keep]] = 255
    return out
