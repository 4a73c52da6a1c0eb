"""Beam segmentation: raw echo intensities to one wall range per beam.

Three methods, chosen by :class:`cistern_archive.catalog.models.Segmentation`:

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

``shadow``
    Tests of what tells a wall from what fills the water in front of it and from the ghosts behind it:

    1. each beam is smoothed over 0.12 m (3 bins of 4 cm) and the image normalised to 0..255 by its
       maximum beyond ``min_range_m``, as in ``cfar``;
    2. **a wall rises above the water in front of it**: a detection exceeds the threshold and the mean of
       its leading training window (``CFAR_TRAIN`` x 4 cm, before ``CFAR_GUARD`` x 4 cm of guard) by
       ``SHADOW_LEAD_MARGIN``. Intensities are log-compressed (a count is a fixed number of dB), so the
       test is a difference, not ``cfar``'s ratio, which inside strong floor reverberation (100+ counts)
       asks a wall for 8 dB more than the reverberation and loses it. The decaying ring-down and near
       field never rise above what precedes them, so they fail this test beyond the blanking;
    3. **a wall casts a shadow**: it is opaque, so behind its echo the beam holds only noise and the
       occasional multipath ghost, while floor and surface reverberation entering through the 35° vertical
       lobe, the water column and the near field go on. A detection must exceed the **median** of the
       ``SHADOW_TRAIL_M`` behind it (beyond ``SHADOW_GUARD_M``, the pulse's tail) by ``SHADOW_MARGIN``;
       the median ignores a ghost in that window. Where less than half the window is left before the last
       bin, the shadow cannot be seen and nothing is detected: the last
       ``SHADOW_GUARD_M + SHADOW_TRAIL_M / 2`` of the range setting (0.38 m) hold no walls, where the
       receiver noise, amplified most by the time-varying gain, would otherwise pass the test.
       A **faint** wall cannot cast a shadow deeper than it stands above the converter's floor: a head
       whose time-varying gain rises more slowly than the spreading loss (20 log R against 40 log R)
       returns distant walls 50-80 counts high, over water that is already dark. With ``faint_walls``
       ``on``, on a full turn such an echo counts when the water behind it is darker by ``SHADOW_SHARE``
       of its height and both neighbouring beams hold a detection within ``SHADOW_ECHO_M`` of its range
       (a wall answers in the overlapping cones of neighbouring beams, a speckle peak in the water does
       not; as in step 5). Through a 20 log R gain this finds a fifth of the walls the rule missed;
       through the simulator's 35 log R it adds few echoes, but those few narrowed fits of groups across
       openings that lay 0.37-0.38 m off until they passed for sure (``benchmarks/RESULTS.md``,
       "2026-12-06 (session 13)"). So ``auto`` (the default) turns it on only for a site whose wall
       echoes fall off with range as through a weak gain (:func:`site_segmentation`,
       :func:`echo_falloff`); a scan segmented on its own takes ``auto`` as ``off``;
    4. **in the near field, a wall stands out from what every beam holds at its range**: on a full turn
       of the head (:func:`full_turn`), from the blanking range on as long as the across-beam median of
       the smoothed image falls off with range (by ``COMMON_DECAY`` over the shadow's window:
       :func:`near_field`), a detection must also exceed that median by ``COMMON_MARGIN``
       (:func:`common_clutter`). The near field and the ring-down are common to all beams, a wall
       belongs to a few: under fully developed speckle (one look, exponential intensities) the near
       field's peaks 0.5-1 m out pass the two tests above on about one beam in ten, because the near
       field decays behind them as it would behind a wall; this test removes most of them. Beyond the
       near field (floor reverberation in shallow water, the water column) the test is not made: a wall
       need only rise above what is in front of it, as before. Where the median itself rises and casts
       a shadow (a round well seen from its centre, every beam meeting the wall at one range) it is a
       wall, and those ranges are not tested; nor is a sector scan, whose few beams may all meet one
       wall;
    5. **where the receiver's noise passes the threshold by itself, a wall answers on the neighbouring
       beams**: the time-varying gain lifts the noise with range, and on a full turn, from the range at
       which the across-beam median of the smoothed image rises above ``threshold`` for good
       (:func:`noise_limited`: beyond the walls of a closed site every beam holds only noise), a
       detection must have detections within ``SHADOW_ECHO_M`` of its range on both neighbouring beams
       (:func:`beside_both_neighbours`). At 0.9° steps a 3° beam's cone overlaps two neighbours on each side,
       so a wall meets three or more beams at nearly one range; noise meets one. With the range set to
       20 m in cisterns of 10 m (4 cm bins) the rule's first three tests had taken that noise for walls on
       a few beams per scan, metres behind the rock, most of them just before the end of the range
       (``benchmarks/RESULTS.md``, "2026-12-06 (session 12)"); one neighbour was not witness enough, two
       neighbours' noise meeting by chance that often. The range where this begins, or the end of the
       range less the shadow's half window (step 3) where that comes first, is the scan's
       ``detection_range_m``: beyond it a beam's silence says nothing;
    6. the **first** detection beyond ``min_range_m`` (not the strongest: multipath ghosts arrive later
       and may be stronger; a ghost casts no shadow over the wall in front of it) starts the echo, which
       lasts while the smoothed beam stays above the threshold, for at most ``SHADOW_ECHO_M``; its
       largest smoothed value is the echo's peak. A wall met obliquely returns first from the edge of the
       3° beam nearest to it, so the peak, where the beam's axis meets the wall, can lie a few bins after
       the first detection;
    7. the range is sub-bin, as in ``cfar`` (step 6).

    Windows are in metres (at least one bin), so heads with 2 mm bins and heads with 6 cm bins see the
    same physical extents, as long as their echoes are as long as the tuning sites' (``ECHO_WIDTH_M``);
    where the echoes are longer and the bins coarser, the windows grow with the echoes up to their bin
    counts at the tuning bins (:func:`window_unit`). Two uses of the beams' overlap (3° wide at 0.9°
    steps) were tried on the tuning set and dropped: smoothing across 3 or 5 beams, and keeping only
    detections that an adjacent beam confirms within 0.08-0.16 m, at every range; both missed more walls
    (grazing ones, whose range changes fast from beam to beam) than they removed false ones where the
    noise stays under the threshold (step 5 asks for neighbours only where it does not). So was looking
    for the shadow behind the end of a long (grazing) echo rather than behind its leading edge: it
    accepted leading edges decimetres before the wall on the beam's axis.

Every method returns a :class:`~cistern_archive.core.scan.RangeScan`. The CFAR and shadow constants below
were chosen on simulated scans whose seeds are not those of the bundled catalog, and reported on others;
``benchmarks/segmentation.py`` compares the three methods.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from scipy import ndimage, optimize

from cistern_archive.catalog.models import Segmentation
from cistern_archive.core.scan import RangeScan, Scan

PAPER_SCALE = 255
CFAR_TRAIN = 8
CFAR_GUARD = 2
CFAR_SCALE = 1.5
FIRST_RATIO = 0.7
SHADOW_TRAIL_M = 0.6
SHADOW_GUARD_M = 0.08
SHADOW_MARGIN = 65.0
SHADOW_SHARE = 0.7
FAINT_FALLOFF = -105.0
"""Normalised counts per decade of range: a site whose wall echoes fall off faster than this, their
incidence allowed for (:func:`echo_falloff`), takes faint walls under ``faint_walls: auto``. At the
simulator's 35 log R gain 24 sites fell off by 53-90 counts a decade (12 random cisterns, the six demo
sites; the bell-shaped cistern 90), through 20 log R by 117-191 (12 random cisterns, the demo sites
148-190): about 27 log R (``benchmarks/RESULTS.md``, "2026-12-06 (session 13)")."""
INCIDENCE_BEAMS = 3
"""Echoes of this many beams either side, within ``INCIDENCE_REACH_M``, give a wall's direction at an echo."""
INCIDENCE_REACH_M = 0.4
"""How near an echo another must lie to count towards its wall's direction."""
SHADOW_LEAD_MARGIN = 20.0
SHADOW_ECHO_M = 0.3
TUNED_BIN_M = 0.04
SHADOW_SMOOTH_M = 3 * TUNED_BIN_M
ECHO_WIDTH_M = 0.25
"""The tuning sites' echo length (:func:`echo_width_m`): 0.21-0.28 m, median 0.25, over two scans of each
of random cisterns 3-8 at 0.04 m bins; the same sites give 0.24-0.31 m at 0.05 m bins, 0.30-0.39 at
0.08 m (the bins widen the echo), 0.41-0.57 and 0.61-0.85 drawn two and three times as large
(:func:`window_unit`)."""
ECHO_STAND = 0.15
"""A beam's strongest bin is an echo to measure when it stands this share of full scale above the beam's
median (40 of 255 counts)."""
ECHO_MIN_BEAMS = 10
COMMON_MARGIN = 60.0
COMMON_DECAY = 10.0
FULL_TURN_GAPS = 10
METHODS = ("paper", "cfar", "shadow")


class SegmentationSettings(Protocol):
    """What :func:`segment` reads from its settings (satisfied by ``catalog.models.Segmentation``)."""

    method: str
    threshold: float
    min_range_m: float
    faint_walls: str


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
    """Mean of the ``train`` bins ending ``guard`` bins before each bin (fewer near the start).

    The first ``guard + 1`` bins have no training bins in front of them: their noise is ``inf``, so no
    test can find them standing out.
    """
    n_beams, n_bins = smooth.shape
    cumsum = np.concatenate([np.zeros((n_beams, 1)), np.cumsum(smooth, axis=1)], axis=1)
    idx = np.arange(n_bins)
    hi = np.clip(idx - guard, 0, n_bins)
    lo = np.clip(idx - guard - train, 0, n_bins)
    count = hi - lo
    mean = (cumsum[:, hi] - cumsum[:, lo]) / np.maximum(count, 1)
    return np.where(count > 0, mean, np.inf)


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


def _bins(length_m: float, bin_size_m: float) -> int:
    """A physical length as a whole number of bins, at least one."""
    return max(1, int(round(length_m / bin_size_m)))


def echo_width_m(scan: Scan, min_range_m: float) -> float:
    """How long a wall's echo is along the beam: the median over the beams of the width at half height
    (above the beam's median) of each beam's strongest bin beyond ``min_range_m``, over the beams where it
    stands ``ECHO_STAND`` of full scale above that median; ``nan`` with fewer than ``ECHO_MIN_BEAMS``."""
    values = np.asarray(scan.intensities, dtype=np.float64)
    far = scan.bin_centres_m >= min_range_m
    if values.size == 0 or not far.any():
        return float("nan")
    values = np.where(far[None, :], values, -np.inf)
    floor = np.median(values[:, far], axis=1)
    peak = np.argmax(values, axis=1)
    top = values[np.arange(len(values)), peak]
    strong = top - floor >= ECHO_STAND * scan.full_scale
    if strong.sum() < ECHO_MIN_BEAMS:
        return float("nan")
    rows, half = values[strong], (0.5 * (floor + top))[strong]
    below = rows < half[:, None]
    index = np.arange(values.shape[1])[None, :]
    first = peak[strong, None]
    before = np.where(below & (index < first), index, -1).max(axis=1)
    after = np.where(below & (index > first), index, values.shape[1]).min(axis=1)
    width = (after - before - 1).astype(np.float64)
    for inside, outer, inner in ((before >= 0, before, before + 1), (after < values.shape[1], after, after - 1)):
        width[inside] += _share_above(rows[inside], inner[inside], outer[inside], half[inside])
    return float(np.median(width) * scan.bin_size_m)


def _share_above(rows: np.ndarray, inner: np.ndarray, outer: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Per row, how much of the step from bin ``outer`` (below ``half``) to its neighbour ``inner`` (at or
    above it) lies above ``half``, the intensity taken as linear between them: the part of a bin beyond
    the half-height crossing."""
    at = np.arange(len(rows))
    high, low = rows[at, inner], rows[at, outer]
    return (high - half) / (high - low)


def window_unit(scan: Scan, min_range_m: float) -> float:
    """Metres of this scan per metre of the shadow rule's windows: its echoes' length
    (:func:`echo_width_m`) over ``ECHO_WIDTH_M``, at least 1 and at most the bins' ratio
    ``bin_size_m / TUNED_BIN_M`` (1 when the echoes cannot be measured).

    The windows were tuned on echoes ``ECHO_WIDTH_M`` long: a pulse of one 0.04 m bin smeared by the
    beam's footprint on walls a few metres off. Where the echoes are longer — a longer pulse with the
    coarser bins of a longer range setting (Ping Viewer sets a Ping360's transmit duration from the range
    resolution), walls farther off — a window in metres covers less of the echo and of the shadow behind
    it; bins coarser than the echo only quantise it. Random cisterns drawn three times as large
    (``benchmarks/sites.py --random 20 --seed 2 --generator '{"scale": 3.0}'``: echoes 0.61-0.85 m long
    at 0.12 m bins) placed 98 of 170 scans with the windows in metres and 163 with this unit; at 0.08 m
    bins and the usual pulse (echoes 0.30-0.39 m) the windows' bin counts matched fewer pairs than metres
    and put a scan 0.89 m off, this unit as many as metres (``benchmarks/RESULTS.md``, "2026-12-07
    (session 24)")."""
    ceiling = max(1.0, scan.bin_size_m / TUNED_BIN_M)
    width = echo_width_m(scan, min_range_m)
    if ceiling == 1.0 or not math.isfinite(width):
        return 1.0
    return float(min(ceiling, max(1.0, width / ECHO_WIDTH_M)))


def _moving_average(values: np.ndarray, width: int, axis: int) -> np.ndarray:
    """Centred moving average of odd ``width`` along ``axis``; the ends repeat the edge values."""
    half = width // 2
    if half == 0 or values.shape[axis] == 0:
        return values.copy()
    pad = [(0, 0), (0, 0)]
    pad[axis] = (half + 1, half)
    cumsum = np.cumsum(np.pad(values, pad, mode="edge"), axis=axis)
    n = values.shape[axis]
    upper = np.take(cumsum, np.arange(width, width + n), axis=axis)
    lower = np.take(cumsum, np.arange(0, n), axis=axis)
    return (upper - lower) / width


def _trailing_median(smooth: np.ndarray, beams: np.ndarray, bins: np.ndarray, guard: int, trail: int) -> np.ndarray:
    """Median of the ``trail`` bins starting ``guard + 1`` bins after each (beam, bin) candidate.

    Windows are cut at the last bin; a candidate with less than half a window behind it gets ``inf`` (its
    shadow cannot be seen, so it cannot pass the test). Long windows (fine bins) are sampled at most 16
    times, evenly, which keeps the cost bounded on heads with over a thousand bins.
    """
    n_bins = smooth.shape[1]
    offsets = _trail_offsets(guard, trail)
    idx = bins[:, None] + offsets[None, :]
    inside = idx < n_bins
    samples = np.where(inside, smooth[beams[:, None], np.minimum(idx, n_bins - 1)], np.nan)
    out = np.full(bins.size, np.inf)
    enough = inside.sum(axis=1) * 2 >= offsets.size
    if enough.any():
        out[enough] = np.nanmedian(samples[enough], axis=1)
    return out


def _trail_offsets(guard: int, trail: int) -> np.ndarray:
    """The bins, after a candidate's, whose median is the water behind it (:func:`_trailing_median`)."""
    return np.arange(guard + 1, guard + 1 + trail, max(1, trail // 16))


def last_testable_bin(n_bins: int, guard: int, trail: int) -> int:
    """The last bin with at least half of its trailing window inside the range (:func:`_trailing_median`):
    beyond it no shadow can be seen, so no wall is detected (-1 when no bin has one)."""
    offsets = _trail_offsets(guard, trail)
    return max(-1, n_bins - 1 - int(offsets[(offsets.size + 1) // 2 - 1]))


def shadow_detections(scan: Scan, threshold: float, min_range_m: float, faint_walls: bool = False,
                      unit: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Detection mask, normalised smoothed image and detection range of the ``shadow`` method (steps 1-5).

    Returns
    -------
    detections : ndarray of bool, shape (A, B)
        Bins beyond ``min_range_m`` above ``threshold``, ``SHADOW_LEAD_MARGIN`` above their leading
        training mean, ``SHADOW_MARGIN`` above the median of the water behind them (with ``faint_walls``, a
        faint echo on a full turn: ``SHADOW_SHARE`` of its height, beside detections on both neighbouring
        beams) and, on a full turn, ``COMMON_MARGIN`` above the level every beam holds at their range in
        the near field, and beside detections on both neighbouring beams where the receiver noise passes
        ``threshold`` by itself.
    smooth : ndarray of float64, shape (A, B)
        The image smoothed over 0.12 m along each beam, normalised to 0..255 by its maximum beyond
        ``min_range_m``.
    detection_range_m : float
        Where the receiver noise begins to pass ``threshold`` by itself (:func:`noise_limited`, on a full
        turn), and no farther than the last bin that has a shadow's window behind it
        (:func:`last_testable_bin`: the last ``SHADOW_GUARD_M + SHADOW_TRAIL_M / 2`` of the range hold
        no walls).

    Every window is taken ``unit`` times as long (:func:`window_unit`).
    """
    bin_m = scan.bin_size_m / unit  # each window's length over this is its number of bins
    values = _blank_near(scan, 0.0)
    width = 2 * (_bins(SHADOW_SMOOTH_M, bin_m) // 2) + 1
    smooth = _moving_average(values, width, axis=1)
    far = scan.bin_centres_m >= min_range_m
    peak = float(smooth[:, far].max()) if smooth[:, far].size else 0.0
    if peak <= 0:
        return np.zeros(smooth.shape, dtype=bool), np.zeros_like(smooth), float("inf")
    smooth *= PAPER_SCALE / peak
    windows = _shadow_windows(bin_m)
    candidates = _rising(smooth, threshold, far, windows)
    turn = full_turn(scan.bearings_rad)
    common = np.median(smooth, axis=0) if turn else None
    if turn:
        candidates &= smooth - common_clutter(common, threshold, far, bin_m)[None, :] >= COMMON_MARGIN
    beams, bins = np.nonzero(candidates)
    _, _, guard, trail = windows
    behind = _trailing_median(smooth, beams, bins, guard, trail)
    depth = smooth[beams, bins] - behind
    detections = np.zeros_like(candidates)
    detections[beams, bins] = depth >= SHADOW_MARGIN
    last = last_testable_bin(smooth.shape[1], guard, trail)
    reach = float(scan.bin_centres_m[last]) if last >= 0 else 0.0
    echo_bins = _bins(SHADOW_ECHO_M, bin_m)
    if turn:
        if faint_walls:
            faint = np.zeros_like(candidates)
            faint[beams, bins] = (depth < SHADOW_MARGIN) & (depth >= SHADOW_SHARE * smooth[beams, bins])
            detections |= faint & beside_both_neighbours(detections | faint, scan.bearings_rad, echo_bins)
        noisy = noise_limited(common, threshold, far)
        if noisy.any():
            confirmed = beside_both_neighbours(detections, scan.bearings_rad, echo_bins)
            detections[:, noisy] &= confirmed[:, noisy]
            reach = min(reach, float(scan.bin_centres_m[int(np.argmax(noisy))]))
    return detections, np.where(far[None, :], smooth, 0.0), reach


def noise_limited(common: np.ndarray, threshold: float, far: np.ndarray) -> np.ndarray:
    """Mask of the ranges where the receiver noise alone passes ``threshold`` (step 5): from the first
    bin beyond the blanking (``far``) whose across-beam level (``common``) stays above ``threshold`` to
    the last bin. Beyond the walls of a closed site every beam holds only the receiver's noise, which the
    time-varying gain lifts with range; a wall that most beams meet at one range (a round well) lifts the
    level only over its echo, and the water behind it lets it fall again."""
    below = np.flatnonzero(~(common > threshold) | ~far)
    start = int(below[-1]) + 1 if below.size else 0
    mask = np.zeros(common.shape, dtype=bool)
    mask[start:] = True
    return mask


def beside_both_neighbours(detections: np.ndarray, bearings_rad: np.ndarray, reach_bins: int) -> np.ndarray:
    """Mask of the detections with a detection on both neighbouring beams (the next bearing either way
    round the turn) within ``reach_bins`` along the range: a wall answers in the overlapping cones of
    neighbouring beams (3° wide at 0.9° steps) at nearly one range; receiver noise does not, though at
    the end of a long range two neighbours' noise does often enough that one is not a witness."""
    order = np.argsort(np.mod(bearings_rad, 2 * np.pi), kind="stable")
    spread = ndimage.maximum_filter1d(detections[order].astype(np.uint8), size=2 * reach_bins + 1, axis=1) > 0
    confirmed = np.empty_like(detections)
    confirmed[order] = np.roll(spread, 1, axis=0) & np.roll(spread, -1, axis=0)
    return detections & confirmed


def full_turn(bearings_rad: np.ndarray) -> bool:
    """Whether the beams cover a whole turn: no gap between neighbouring bearings wider than
    ``FULL_TURN_GAPS`` times the median step (a sector scan's beams may all meet one wall at one range)."""
    if bearings_rad.size < 8:
        return False
    ordered = np.sort(np.mod(bearings_rad, 2 * np.pi))
    gaps = np.diff(np.concatenate([ordered, ordered[:1] + 2 * np.pi]))
    return bool(gaps.max() <= FULL_TURN_GAPS * np.median(gaps))


def common_clutter(common: np.ndarray, threshold: float, far: np.ndarray, bin_m: float) -> np.ndarray:
    """The level every beam holds at each range (``common``: the across-beam median of the smoothed
    image) over the near field: from ``far``'s first bin as long as that level falls off by
    ``COMMON_DECAY`` or more over the shadow's window behind (:func:`near_field`); ``-inf`` elsewhere,
    and over a wall that most beams see at one range (a round well seen from its centre: the median
    passes the rule's own two tests, it rises above what precedes it and casts a shadow) and its echo's
    length."""
    windows = _shadow_windows(bin_m)
    _, _, guard, trail = windows
    every = np.arange(common.size)
    decay = common - _trailing_median(common[None, :], np.zeros_like(every), every, guard, trail)
    walls = np.flatnonzero(_rising(common[None, :], threshold, far, windows)[0] & (decay >= SHADOW_MARGIN))
    out = np.where(near_field(decay, far), common, -np.inf)
    for start in walls:
        out[start:start + _bins(SHADOW_ECHO_M, bin_m) + 1] = -np.inf
    return out


def _shadow_windows(bin_m: float) -> tuple[int, int, int, int]:
    """The shadow rule's windows in bins of ``bin_m``: the leading training window and its guard, the
    trailing guard and the trailing window."""
    return (_bins(CFAR_TRAIN * TUNED_BIN_M, bin_m), _bins(CFAR_GUARD * TUNED_BIN_M, bin_m),
            _bins(SHADOW_GUARD_M, bin_m), _bins(SHADOW_TRAIL_M, bin_m))


def _rising(smooth: np.ndarray, threshold: float, far: np.ndarray, windows: tuple[int, int, int, int]) -> np.ndarray:
    """Bins beyond the blanking (``far``) above ``threshold`` and ``SHADOW_LEAD_MARGIN`` above the mean of
    the water in front of them (step 2)."""
    train, lead_guard, _, _ = windows
    noise = _leading_noise(smooth, train, lead_guard)
    return (smooth > threshold) & (smooth - noise >= SHADOW_LEAD_MARGIN) & far[None, :]


def near_field(decay: np.ndarray, far: np.ndarray) -> np.ndarray:
    """Mask of the near field: the bins from ``far``'s first on while the common level falls off
    (``decay`` >= ``COMMON_DECAY``). It ends where the level stops falling: floor reverberation in
    shallow water, the water column, a wall every beam meets."""
    mask = np.zeros(decay.shape, dtype=bool)
    if not far.any():
        return mask
    start = int(np.argmax(far))
    ends = np.flatnonzero(decay[start:] < COMMON_DECAY)
    mask[start:start + int(ends[0]) if ends.size else decay.size] = True
    return mask


def _echo_peaks(detections: np.ndarray, smooth: np.ndarray, threshold: float, longest: int) -> np.ndarray:
    """Per beam the peak of the echo that starts at the first detection: the largest smoothed value over
    the bins from there on that stay above ``threshold``, at most ``longest`` of them; -1 if none."""
    n_beams, n_bins = smooth.shape
    has = detections.any(axis=1)
    first = np.argmax(detections, axis=1)
    positions = np.where(smooth <= threshold, np.arange(n_bins)[None, :], n_bins)
    run_end = np.minimum.accumulate(positions[:, ::-1], axis=1)[:, ::-1]
    peaks = np.full(n_beams, -1, dtype=np.int64)
    for beam in np.flatnonzero(has):
        start = int(first[beam])
        stop = min(int(run_end[beam, start]), start + longest, n_bins)
        peaks[beam] = start + int(np.argmax(smooth[beam, start:max(stop, start + 1)]))
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
    return _peaks_and_reach(scan, settings)[0]


def _peaks_and_reach(scan: Scan, settings: SegmentationSettings) -> tuple[np.ndarray, float]:
    """:func:`peak_bins` and the scan's detection range (``inf`` but for the ``shadow`` method's)."""
    if settings.method not in METHODS:
        raise ValueError(f"unknown segmentation method {settings.method!r}; expected one of {', '.join(METHODS)}")
    if scan.n_bins == 0 or scan.n_beams == 0:
        return np.full(scan.n_beams, -1, dtype=np.int64), float("inf")
    if settings.method == "paper":
        normalised = normalise_paper(_blank_near(scan, settings.min_range_m))
        return paper_peak_bins(normalised, settings.threshold), float("inf")
    if settings.method == "cfar":
        detections, smooth = cfar_detections(scan, settings.threshold, settings.min_range_m)
        return _first_strong_peaks(detections, smooth), float("inf")
    peaks, _, reach = shadow_peaks(scan, settings.threshold, settings.min_range_m, settings.faint_walls == "on")
    return peaks, reach


def shadow_peaks(scan: Scan, threshold: float, min_range_m: float, faint_walls: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``shadow`` method's echo peak bin per beam (-1 for none), with its smoothed image and detection
    range (:func:`shadow_detections`, its windows scaled to the scan's echoes by :func:`window_unit`)."""
    unit = window_unit(scan, min_range_m)
    detections, smooth, reach = shadow_detections(scan, threshold, min_range_m, faint_walls, unit)
    return _echo_peaks(detections, smooth, threshold, _bins(SHADOW_ECHO_M, scan.bin_size_m / unit)), smooth, reach


def segment(scan: Scan, settings: SegmentationSettings) -> RangeScan:
    """Segment every beam of ``scan`` into a wall range (paper Sec. III-B, or the CFAR or shadow rule).

    Parameters
    ----------
    scan : Scan
        Raw intensities.
    settings : Segmentation
        ``method`` ('paper' | 'cfar' | 'shadow'), ``threshold`` (on the 0..255 normalised scale),
        ``min_range_m`` and ``faint_walls`` (shadow only; ``auto`` is ``off`` here: a site decides it,
        :func:`site_segmentation`).

    Returns
    -------
    RangeScan
        One range per beam; ``nan`` where the beam has no echo.
    """
    peaks, reach = _peaks_and_reach(scan, settings)
    centres = scan.bin_centres_m
    if settings.method in ("cfar", "shadow"):
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
        vertical_beam_width_rad=scan.vertical_beam_width_rad,
        time_s=scan.timestamp,
        detection_range_m=reach,
    )


def echo_incidence(ranges_m: np.ndarray, bearings_rad: np.ndarray) -> np.ndarray:
    """``cos`` of the angle between each beam and the normal of the wall its echo lies on, the wall's
    direction taken from the echoes of ``INCIDENCE_BEAMS`` beams either side within ``INCIDENCE_REACH_M``
    (their principal axis); ``nan`` without an echo or with fewer than four such echoes."""
    order = np.argsort(np.mod(bearings_rad, 2 * np.pi), kind="stable")
    r, b = ranges_m[order], bearings_rad[order]
    x, y = r * np.sin(b), r * np.cos(b)
    shifts = np.arange(-INCIDENCE_BEAMS, INCIDENCE_BEAMS + 1)
    nx = np.stack([np.roll(x, -k) for k in shifts], axis=1)
    ny = np.stack([np.roll(y, -k) for k in shifts], axis=1)
    near = np.isfinite(nx) & (np.hypot(nx - x[:, None], ny - y[:, None]) < INCIDENCE_REACH_M)
    count = near.sum(axis=1)
    mx = np.where(near, nx, 0.0).sum(axis=1) / np.maximum(count, 1)
    my = np.where(near, ny, 0.0).sum(axis=1) / np.maximum(count, 1)
    dx, dy = np.where(near, nx - mx[:, None], 0.0), np.where(near, ny - my[:, None], 0.0)
    sxx, syy, sxy = (dx * dx).sum(axis=1), (dy * dy).sum(axis=1), (dx * dy).sum(axis=1)
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # the wall's direction (principal axis)
    cos_incidence = np.abs(-np.sin(angle) * np.sin(b) + np.cos(angle) * np.cos(b))  # normal · beam
    out = np.full(r.shape, np.nan)
    out[order] = np.where(np.isfinite(r) & (count >= 4), cos_incidence, np.nan)
    return out


def echo_falloff(scans: Sequence[Scan], threshold: float, min_range_m: float) -> float:
    """How fast the wall echoes of ``scans`` fall off with range, their incidence allowed for: ``b`` of
    ``h = a + b log10 r + c log10 cos i`` fitted to the ``shadow`` rule's echo peaks ``h`` (normalised
    counts; log-compressed, so counts are decibels) at ranges ``r`` and incidences ``i``
    (:func:`echo_incidence`), pooled over the scans, by least squares with a soft-L1 loss (ghosts and
    corners). A wall's echo weakens as it is met more obliquely, and far walls are met more obliquely
    than near ones, so range alone would read a long gallery as a weak gain. Counts per decade; ``nan``
    with fewer than 20 such echoes or no spread in range."""
    ranges, heights, incidences = [], [], []
    for scan in scans:
        if scan.n_beams == 0 or scan.n_bins == 0:
            continue
        peaks, smooth, _ = shadow_peaks(scan, threshold, min_range_m)
        has = peaks >= 0
        r = np.where(has, scan.bin_centres_m[np.clip(peaks, 0, None)], np.nan)
        cos_i = echo_incidence(r, scan.bearings_rad)
        keep = np.isfinite(cos_i) & (cos_i > 0.05) & (r > 0)
        ranges.append(r[keep])
        heights.append(smooth[np.flatnonzero(keep), peaks[keep]])
        incidences.append(cos_i[keep])
    if not ranges:
        return float("nan")
    r, h, c = np.concatenate(ranges), np.concatenate(heights), np.concatenate(incidences)
    if r.size < 20 or np.ptp(np.log10(r)) <= 0:
        return float("nan")
    design = np.column_stack([np.ones_like(r), np.log10(r), np.log10(c)])
    fit = optimize.least_squares(lambda p: design @ p - h, np.zeros(3), loss="soft_l1", f_scale=20.0)
    return float(fit.x[1])


def site_segmentation(scans: Sequence[Scan], settings: Segmentation) -> Segmentation:
    """``settings`` for the scans of one site, ``faint_walls: auto`` decided: ``on`` where their wall echoes
    fall off faster than ``FAINT_FALLOFF`` (:func:`echo_falloff`), ``off`` elsewhere and for other methods."""
    if settings.faint_walls != "auto":
        return settings
    falloff = echo_falloff(scans, settings.threshold, settings.min_range_m) if settings.method == "shadow" else np.nan
    return settings.model_copy(update={"faint_walls": "on" if falloff < FAINT_FALLOFF else "off"})


def segment_intensities(scan: Scan, settings: SegmentationSettings | None = None) -> np.ndarray:
    """The segmented image: the echo bin of each beam and its two neighbours 255, all else 0.

    This is the paper's output image (Sec. III-B); with ``cfar`` or ``shadow`` the marked bin is the
    echo's peak. ``settings`` defaults to the paper's rule with threshold 50.

    Returns
    -------
    ndarray of uint8, shape (A, B)
    """
    if settings is None:
        settings = Segmentation(method="paper")
    peaks = peak_bins(scan, settings)
    out = np.zeros(scan.intensities.shape, dtype=np.uint8)
    n_bins = scan.n_bins
    beams = np.flatnonzero(peaks >= 0)
    for offset in (-1, 0, 1):
        idx = peaks[beams] + offset
        keep = (idx >= 0) & (idx < n_bins)
        out[beams[keep], idx[keep]] = 255
    return out
