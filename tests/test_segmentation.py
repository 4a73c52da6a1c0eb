"""Beam segmentation: the paper's rule (Sec. III-B) on beams with known answers, and the CFAR option."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from cistern_archive.catalog.models import Segmentation
from cistern_archive.sonar.scan import Scan
from cistern_archive.sonar.segmentation import (
    normalise_paper,
    paper_peak_bins,
    segment,
    segment_intensities,
)

PAPER = Segmentation(method="paper", threshold=50)
CFAR = Segmentation(method="cfar", threshold=50)


def make_scan(rows: list[list[int]] | np.ndarray, *, bin_size: float = 0.05, full_scale: float = 255) -> Scan:
    intensities = np.asarray(rows, dtype=np.uint8 if full_scale == 255 else np.uint16)
    bearings = np.linspace(0, 2 * math.pi, intensities.shape[0], endpoint=False)
    return Scan(bearings_rad=bearings, intensities=intensities, full_scale=full_scale, bin_size_m=bin_size,
                station="t", yaw_rad=0.3, depth_m=1.5)


def test_normalises_by_the_scan_maximum():
    values = np.array([[0.0, 10.0, 20.0], [5.0, 40.0, 0.0]])
    assert_array_equal(normalise_paper(values), [[0, 64, 128], [32, 255, 0]])
    assert_array_equal(normalise_paper(np.zeros((2, 3))), np.zeros((2, 3)))


def test_maximum_bin_with_a_neighbour_gives_its_centre():
    scan = make_scan([[0, 0, 30, 200, 40, 0, 0, 0]])
    ranges = segment(scan, PAPER)
    assert_allclose(ranges.ranges_m, [3.5 * 0.05])
    assert ranges.station == "t" and ranges.yaw_rad == 0.3 and ranges.depth_m == 1.5
    assert ranges.max_range_m == pytest.approx(8 * 0.05)


def test_isolated_spike_is_skipped_by_the_adjacency_rule():
    # The spike at bin 1 has zero neighbours; the wall at bins 5-6 is lower but kept.
    scan = make_scan([[0, 255, 0, 0, 0, 120, 90, 0, 0]])
    assert_array_equal(paper_peak_bins(normalise_paper(scan.intensities.astype(float)), 50), [5])
    assert_allclose(segment(scan, PAPER).ranges_m, [5.5 * 0.05])


def test_one_nonzero_neighbour_is_enough():
    scan = make_scan([[0, 0, 0, 1, 200, 0, 0]])
    assert_allclose(segment(scan, PAPER).ranges_m, [4.5 * 0.05])


def test_threshold_is_strict_and_on_the_normalised_scale():
    # The scan maximum (255) is on beam 0, so beam 1's 50 normalises to 50: not above 50.
    scan = make_scan([[0, 255, 255, 0], [0, 50, 50, 0], [0, 51, 51, 0]])
    ranges = segment(scan, PAPER).ranges_m
    assert np.isfinite(ranges[0]) and np.isnan(ranges[1]) and np.isfinite(ranges[2])
    # A weak scan is stretched by the normalisation: 20 -> 255.
    weak = make_scan([[0, 20, 20, 0]])
    assert np.isfinite(segment(weak, PAPER).ranges_m[0])


def test_empty_and_all_spike_beams_have_no_echo():
    scan = make_scan([[0, 0, 0, 0, 0, 0], [0, 200, 0, 0, 200, 0], [0, 100, 100, 0, 0, 0]])
    ranges = segment(scan, PAPER).ranges_m
    assert np.isnan(ranges[0]) and np.isnan(ranges[1])
    assert_allclose(ranges[2], 1.5 * 0.05)


def test_ties_go_to_the_nearest_bin():
    scan = make_scan([[0, 200, 200, 0, 200, 200, 0]])
    assert_allclose(segment(scan, PAPER).ranges_m, [1.5 * 0.05])


def test_segmented_image_marks_bin_and_neighbours():
    scan = make_scan([[0, 0, 30, 200, 40, 0, 0], [0, 0, 0, 0, 0, 0, 0], [180, 90, 0, 0, 0, 0, 0]])
    image = segment_intensities(scan, PAPER)
    assert image.dtype == np.uint8
    assert_array_equal(image[0], [0, 0, 255, 255, 255, 0, 0])
    assert_array_equal(image[1], 0)
    assert_array_equal(image[2], [255, 255, 0, 0, 0, 0, 0])
    assert_array_equal(segment_intensities(scan), image)


def test_min_range_blanks_the_self_echo_before_normalising():
    scan = make_scan([[250, 240, 0, 0, 0, 100, 110, 0]])
    assert_allclose(segment(scan, PAPER).ranges_m, [0.5 * 0.05])
    blanked = Segmentation(method="paper", min_range_m=0.1)
    assert_allclose(segment(scan, blanked).ranges_m, [6.5 * 0.05])


def test_full_scale_other_than_255():
    scan = make_scan([[0, 3, 15, 4, 0]], full_scale=15)
    assert_allclose(segment(scan, PAPER).ranges_m, [2.5 * 0.05])


def test_cfar_takes_the_first_strong_echo_not_a_stronger_ghost():
    row = np.zeros(60, dtype=np.uint8)
    row[20:23] = [150, 200, 150]  # the wall
    row[40:43] = [170, 230, 170]  # a stronger multipath ghost
    scan = make_scan([row])
    assert_allclose(segment(scan, PAPER).ranges_m, [41.5 * 0.05])
    assert_allclose(segment(scan, CFAR).ranges_m, [21.5 * 0.05], atol=1e-9)


def test_cfar_ignores_a_weak_early_echo_and_isolated_spikes():
    row = np.zeros(60, dtype=np.uint8)
    row[8] = 255  # spike
    row[15:18] = [30, 40, 30]  # weak clutter, below half of the wall
    row[30:33] = [160, 220, 160]
    scan = make_scan([row])
    assert_allclose(segment(scan, CFAR).ranges_m, [31.5 * 0.05], atol=1e-9)


def test_cfar_range_is_interpolated_within_the_bin():
    row = np.zeros(40, dtype=np.uint8)
    row[10:14] = [100, 200, 150, 20]
    scan = make_scan([row])
    offset = 0.5 * (100 - 150) / (100 - 400 + 150)  # parabola through 100, 200, 150: +1/6 bin
    assert_allclose(segment(scan, CFAR).ranges_m, [(11.5 + offset) * 0.05])
    symmetric = make_scan([np.array([0] * 10 + [100, 200, 100] + [0] * 10, dtype=np.uint8)])
    assert_allclose(segment(symmetric, CFAR).ranges_m, [11.5 * 0.05])


def test_cfar_rejects_a_step_in_a_noisy_background():
    rng = np.random.default_rng(1)
    noise = rng.integers(0, 40, size=(1, 80)).astype(np.uint8)
    noise[0, 50:53] = [180, 250, 180]
    ranges = segment(make_scan(noise), CFAR).ranges_m
    assert abs(ranges[0] - 51.5 * 0.05) < 0.05


def test_unknown_method_is_refused():
    class Odd:
        method = "magic"
        threshold = 50.0
        min_range_m = 0.0

    with pytest.raises(ValueError, match="magic"):
        segment(make_scan([[0, 1, 2]]), Odd())
