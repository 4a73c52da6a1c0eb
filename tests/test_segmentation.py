"""Beam segmentation: the paper's rule (Sec. III-B) on beams with known answers, and the CFAR option."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from cistern_archive.catalog.models import Segmentation
from cistern_archive.core.scan import Scan
from cistern_archive.simulation.simulator import TruePose, simulate_scan
from cistern_archive.simulation.spec import EffectsSpec, SonarSpec
from cistern_archive.sonar.readers import read_file
from cistern_archive.sonar import segmentation
from cistern_archive.sonar.segmentation import (
    METHODS,
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


# --- the shadow method -----------------------------------------------------------------------------

SHADOW = Segmentation(method="shadow", threshold=50)
BIN = 0.04  # the shadow method's windows are physical; 4 cm bins make them 8 + 2 leading, 2 + 15 trailing


NEAR_WALL = np.zeros(100, dtype=np.uint8)
NEAR_WALL[20:23] = [200, 250, 200]  # another beam's strong wall, which sets the scan's normalisation


def reverberation_row(n: int, start: int, stop: int, seed: int = 0) -> np.ndarray:
    """Zeros, with a speckled reverberation plateau (90-140) over ``start:stop``."""
    row = np.zeros(n, dtype=np.uint8)
    row[start:stop] = np.random.default_rng(seed).integers(90, 141, size=stop - start)
    return row


def test_default_method_is_shadow():
    assert Segmentation().method == "shadow"
    assert set(METHODS) == {"paper", "cfar", "shadow"}


def test_shadow_finds_the_wall_behind_floor_reverberation():
    # Reverberation from 0.6 m up to the wall at 2.4 m, with a one-bin speckle peak brighter than the
    # wall; behind the wall only its shadow.
    row = reverberation_row(100, 15, 60)
    row[30] = 210
    row[60:63] = [170, 190, 170]
    scan = make_scan([row, NEAR_WALL], bin_size=BIN)
    assert_allclose(segment(scan, PAPER).ranges_m[0], 30.5 * BIN)  # the paper's maximum: the speckle
    assert_allclose(segment(scan, SHADOW).ranges_m[0], 61.5 * BIN, atol=1e-9)


def test_shadow_sees_no_wall_in_reverberation_that_goes_on():
    # The same plateau with no wall: every bump is followed by more reverberation, none by a shadow.
    row = reverberation_row(100, 15, 100, seed=1)
    row[40:43] = [150, 175, 150]
    scan = make_scan([row, NEAR_WALL], bin_size=BIN)
    assert np.isfinite(segment(scan, PAPER).ranges_m[0])
    assert np.isnan(segment(scan, SHADOW).ranges_m[0])
    assert_allclose(segment(scan, SHADOW).ranges_m[1], 21.5 * BIN, atol=1e-9)


def test_shadow_takes_the_wall_not_a_stronger_ghost():
    row = np.zeros(80, dtype=np.uint8)
    row[20:23] = [150, 200, 150]  # the wall
    row[30:33] = [170, 240, 170]  # a stronger multipath ghost 0.4 m behind it
    scan = make_scan([row], bin_size=BIN)
    assert_allclose(segment(scan, PAPER).ranges_m, [31.5 * BIN])
    assert_allclose(segment(scan, SHADOW).ranges_m, [21.5 * BIN], atol=1e-9)


def test_shadow_ignores_the_ring_down_beyond_the_blanking():
    # The transducer rings at full scale to 0.48 m and decays; blanking at 0.4 m leaves its tail.
    k = np.arange(80)
    row = np.where(k < 12, 250, 250 * np.exp(-(k - 12) / 4.0)).astype(np.uint8)
    row[40:43] = [150, 200, 150]
    scan = make_scan([row], bin_size=BIN)
    blanked = {"min_range_m": 0.4}
    assert_allclose(segment(scan, PAPER.model_copy(update=blanked)).ranges_m, [10.5 * BIN])  # the blanking edge
    assert_allclose(segment(scan, SHADOW.model_copy(update=blanked)).ranges_m, [41.5 * BIN], atol=1e-9)


def test_shadow_needs_room_behind_a_wall_to_see_its_shadow():
    # The last SHADOW_GUARD_M + SHADOW_TRAIL_M / 2 (0.38 m, 9.5 bins) of the range hold no walls.
    row = np.zeros(50, dtype=np.uint8)
    row[42:45] = [150, 200, 150]
    assert np.isnan(segment(make_scan([row], bin_size=BIN), SHADOW).ranges_m[0])
    row = np.zeros(50, dtype=np.uint8)
    row[34:37] = [150, 200, 150]
    assert_allclose(segment(make_scan([row], bin_size=BIN), SHADOW).ranges_m, [35.5 * BIN], atol=1e-9)


def test_shadow_windows_are_physical_lengths():
    # The reverberation case sampled four times finer gives the same wall.
    coarse = reverberation_row(100, 15, 60)
    coarse[30] = 210
    coarse[60:63] = [170, 190, 170]
    fine = np.repeat(coarse, 4)
    ranges = segment(make_scan([fine], bin_size=BIN / 4), SHADOW).ranges_m
    assert abs(ranges[0] - 61.5 * BIN) < BIN


@pytest.mark.parametrize("method", METHODS)
def test_degenerate_scans_give_no_wall_and_no_error(method):
    settings = Segmentation(method=method, min_range_m=0.1)
    empty = segment(make_scan([[0] * 20, [0] * 20]), settings)
    assert empty.ranges_m.shape == (2,) and np.all(np.isnan(empty.ranges_m))
    one_bin = segment(make_scan([[200], [0]]), settings)
    assert one_bin.ranges_m.shape == (2,) and np.all(np.isnan(one_bin.ranges_m))
    no_beams = Scan(bearings_rad=np.zeros(0), intensities=np.zeros((0, 20), dtype=np.uint8), full_scale=255,
                    bin_size_m=0.05)
    assert segment(no_beams, settings).ranges_m.shape == (0,)
    no_bins = Scan(bearings_rad=np.zeros(3), intensities=np.zeros((3, 0), dtype=np.uint8), full_scale=255,
                   bin_size_m=0.05)
    assert np.all(np.isnan(segment(no_bins, settings).ranges_m))


def test_saturated_scan_has_no_wall_except_under_the_paper_rule():
    scan = make_scan(np.full((3, 40), 255))
    # Every bin ties at 255: the paper's rule keeps the nearest beyond the blanking.
    assert_allclose(segment(scan, Segmentation(method="paper", min_range_m=0.1)).ranges_m, [0.125] * 3)
    # Nothing rises above what precedes it (bins with no training cells in front are never detections).
    for method in ("cfar", "shadow"):
        for min_range_m in (0.0, 0.1):
            ranges = segment(scan, Segmentation(method=method, min_range_m=min_range_m)).ranges_m
            assert np.all(np.isnan(ranges)), (method, min_range_m)


@pytest.mark.parametrize("seed", [3, 4])
def test_shadow_beats_the_paper_on_a_simulated_shallow_site(seed):
    """A box 4 m x 3 m in 1 m of water, the head 0.25 m above the floor (the 35° lobe meets it 0.8 m out),
    floor reverberation 8 dB above the default and ghosts on a fifth of the beams."""
    sim = simulate_scan([np.array([[0, 0], [4.0, 0], [4.0, 3.0], [0, 3.0]])], TruePose("t", 1.4, 1.1, 0.3, 0.75),
                        SonarSpec(range_m=6.0, bins=150), EffectsSpec(floor_db=-16.0, multipath_fraction=0.2),
                        np.random.default_rng(seed), water_depth_m=1.0)
    scores = {}
    for method in ("paper", "shadow"):
        ranges = segment(sim.scan, Segmentation(method=method, min_range_m=0.4)).ranges_m
        hit = np.abs(ranges - sim.truth_ranges_m) <= 2 * sim.scan.bin_size_m
        scores[method] = (hit.mean(), (np.isfinite(ranges) & ~hit).mean())
    assert scores["shadow"][0] >= scores["paper"][0]
    assert scores["shadow"][1] < 0.85 * scores["paper"][1]
    assert scores["shadow"][1] < 0.09


@pytest.mark.realdata
def test_real_ping360_ring_down_is_a_wall_for_the_paper_rule_only(shared_data):
    """A Ping360 revolution (10 m, 8 mm bins): the paper's maximum sits on the blanking edge on almost
    every beam, the shadow rule's echoes almost never."""
    scans = [s for s in read_file(shared_data / "ping360" / "Sensor_Log_01__inside_base_dakhel_paygah.bin").scans
             if s.n_beams >= 390 and s.bin_size_m > 0.005]
    assert scans
    for method, low, high in (("paper", 0.9, 1.0), ("shadow", 0.0, 0.05)):
        ranges = segment(scans[0], Segmentation(method=method, min_range_m=0.5))
        at_edge = np.mean(ranges.ranges_m[ranges.valid] <= 0.6)
        assert low <= at_edge <= high, (method, at_edge)


# --- what every beam holds at one range ------------------------------------------------------------

def _box_scan(seed: int, looks: float):
    """A box 4 m x 3 m in 3 m of water, the head at 1.5 m depth, under fully developed speckle (one look)."""
    return simulate_scan([np.array([[0, 0], [4.0, 0], [4.0, 3.0], [0, 3.0]])], TruePose("t", 1.4, 1.1, 0.3, 1.5),
                         SonarSpec(range_m=6.0, bins=150), EffectsSpec(speckle_looks=looks),
                         np.random.default_rng(seed), water_depth_m=3.0)


def _outcomes(sim, settings: Segmentation) -> tuple[float, float]:
    """Share of beams on the wall (within two bins), share with an echo more than two bins before it."""
    ranges = segment(sim.scan, settings).ranges_m
    error = ranges - sim.truth_ranges_m
    tol = 2 * sim.scan.bin_size_m
    return float(np.mean(np.abs(error) <= tol)), float(np.mean(error < -tol))


@pytest.mark.parametrize("seed", [1, 2])
def test_shadow_drops_near_field_speckle_that_every_beam_holds(seed, monkeypatch):
    settings = Segmentation(method="shadow", min_range_m=0.4)
    sim = _box_scan(seed, looks=1.0)
    with_test = _outcomes(sim, settings)
    monkeypatch.setattr(segmentation, "COMMON_MARGIN", -np.inf)  # no common-level test
    without = _outcomes(sim, settings)
    assert without[1] > 0.04  # the near field's speckle peaks pass the lead and shadow tests
    assert with_test[1] < 0.4 * without[1]
    assert with_test[0] >= without[0]


@pytest.mark.parametrize("seed", [1, 2])
def test_shadow_keeps_walls_inside_shallow_water_reverberation(seed, monkeypatch):
    """The head 0.25 m above the floor in 1 m of water: reverberation fills most of every beam beyond the
    near field, where the common level is not tested."""
    sim = simulate_scan([np.array([[0, 0], [4.0, 0], [4.0, 3.0], [0, 3.0]])], TruePose("t", 1.4, 1.1, 0.3, 0.75),
                        SonarSpec(range_m=6.0, bins=150), EffectsSpec(floor_db=-16.0), np.random.default_rng(seed),
                        water_depth_m=1.0)
    settings = Segmentation(method="shadow", min_range_m=0.4)
    hit = _outcomes(sim, settings)[0]
    monkeypatch.setattr(segmentation, "COMMON_DECAY", -np.inf)  # the common level tested everywhere
    everywhere = _outcomes(sim, settings)[0]
    monkeypatch.setattr(segmentation, "COMMON_MARGIN", -np.inf)  # no common-level test
    untested = _outcomes(sim, settings)[0]
    assert hit > everywhere + 0.01
    assert hit >= untested - 0.04


@pytest.mark.parametrize("offset_m", [0.0, 0.3])
def test_a_round_well_seen_from_its_centre_keeps_its_wall(offset_m):
    # Every beam meets the wall at one range, so the across-beam median there is the wall, not clutter.
    ring = np.array([[2.0 * math.cos(t), 2.0 * math.sin(t)] for t in np.linspace(0, 2 * math.pi, 72, endpoint=False)])
    sim = simulate_scan([ring], TruePose("c", offset_m, 0.0, 0.0, 1.5), SonarSpec(range_m=6.0, bins=150),
                        EffectsSpec(), np.random.default_rng(5), water_depth_m=3.0)
    hit, before = _outcomes(sim, Segmentation(method="shadow", min_range_m=0.4))
    assert hit > 0.95 and before < 0.02


def test_full_turn_is_told_from_a_sector():
    step = math.radians(0.9)
    turn = np.arange(400) * step
    assert segmentation.full_turn(turn)
    assert segmentation.full_turn(np.delete(turn, [10, 11, 12]))  # a few beams lost
    assert not segmentation.full_turn(turn[:100])  # a 90° sector
    assert not segmentation.full_turn(turn[:5])


# --- the end of a long range: receiver noise lifted by the time-varying gain ---------------------------

def _gallery_at_long_range(seed: int):
    """A plastered gallery 12 m x 3 m with the head's range set to 20 m (500 bins of 4 cm): beams that
    graze its long walls hear them too faintly, and beyond every wall a beam holds only the receiver's
    noise, which the time-varying gain lifts above the threshold towards the end of the range."""
    return simulate_scan([np.array([[0, 0], [12.0, 0], [12.0, 3.0], [0, 3.0]])], TruePose("t", 1.5, 1.2, 0.3, 1.5),
                         SonarSpec(range_m=20.0, bins=500), EffectsSpec(wall_roughness=0.03),
                         np.random.default_rng(seed), water_depth_m=3.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_shadow_takes_little_noise_beyond_the_walls_at_a_long_range(seed, monkeypatch):
    settings = Segmentation(method="shadow", min_range_m=0.4)
    sim = _gallery_at_long_range(seed)
    tol = 2 * sim.scan.bin_size_m

    def outcome(scan):
        """Echoes more than 0.5 m behind the wall; share of beams on it (within two bins)."""
        error = scan.ranges_m - sim.truth_ranges_m
        return int(np.sum(error > 0.5)), float(np.mean(np.abs(error) <= tol))

    scan = segment(sim.scan, settings)
    monkeypatch.setattr(segmentation, "noise_limited", lambda common, threshold, far: np.zeros(common.shape, bool))
    unchecked = segment(sim.scan, settings)
    (behind, hit), (behind_unchecked, hit_unchecked) = outcome(scan), outcome(unchecked)
    assert behind_unchecked >= 9  # noise taken for walls, metres behind them
    assert behind <= 1
    assert hit >= hit_unchecked - 0.015
    # where the noise passes the threshold by itself, silence says nothing: well short of the 20 m range
    assert 6.0 < scan.detection_range_m < 12.0
    # without the noise's limit, only the end of the range, where no shadow can be seen behind a wall
    assert 19.0 < unchecked.detection_range_m < sim.scan.max_range_m


def test_the_last_bins_of_the_range_hold_no_wall_and_set_the_detection_range():
    """A wall whose shadow window would run past the last bin is never detected: the scan's
    ``detection_range_m`` ends before it, so a beam that heard nothing there says nothing of walls."""
    guard, trail = 2, 15
    last = segmentation.last_testable_bin(100, guard, trail)
    offsets = np.arange(guard + 1, guard + 1 + trail)
    assert 2 * np.sum(last + offsets < 100) >= offsets.size
    assert 2 * np.sum(last + 1 + offsets < 100) < offsets.size
    settings = Segmentation(method="shadow", min_range_m=0.4)
    for half_m, heard in ((5.0, True), (5.8, False)):  # walls face-on at 5.0 m, or 5.8 m of a 6 m range
        room = [np.array([[-half_m, -half_m], [half_m, -half_m], [half_m, half_m], [-half_m, half_m]])]
        sim = simulate_scan(room, TruePose("s", 0.0, 0.0, 0.0, 1.0), SonarSpec(range_m=6.0, bins=300),
                            EffectsSpec(), np.random.default_rng(1), water_depth_m=2.0)
        scan = segment(sim.scan, settings)
        assert scan.detection_range_m < 5.7  # never beyond the last bin with a shadow's window behind it
        face_on = np.abs(np.sin(2 * np.asarray(scan.bearings_rad))) < 0.3  # within about 9° of a wall's normal
        assert np.mean(np.isfinite(scan.ranges_m[face_on])) > 0.9 if heard else not np.isfinite(scan.ranges_m[face_on]).any()


def test_noise_limited_starts_where_the_level_stays_above_the_threshold_to_the_end():
    far = np.arange(10) >= 1
    common = np.array([90, 10, 80, 20, 30, 60, 70, 55, 65, 80], dtype=float)  # a wall at bin 2, noise from 5 on
    assert_array_equal(np.flatnonzero(segmentation.noise_limited(common, 50.0, far)), [5, 6, 7, 8, 9])
    assert not segmentation.noise_limited(common[:5], 50.0, far[:5]).any()


def test_a_detection_needs_both_neighbouring_beams_near_its_range():
    detections = np.zeros((6, 20), dtype=bool)
    detections[[0, 1, 2], [10, 11, 12]] = True  # a wall over three beams
    detections[4, 15] = True  # noise on one beam
    detections[[5, 0], [3, 18]] = True  # noise on beams 5 and 0, far apart in range
    bearings = np.linspace(0, 2 * math.pi, 6, endpoint=False)[[3, 4, 5, 0, 1, 2]]  # a turn begun mid-way
    kept = segmentation.beside_both_neighbours(detections[[3, 4, 5, 0, 1, 2]], bearings, 2)
    assert_array_equal(np.argwhere(kept[[3, 4, 5, 0, 1, 2]]), [[1, 11]])


# --- faint walls: a time-varying gain that rises more slowly than the spreading loss ------------------

def _room_through_weak_tvg(seed: int, tvg_exponent: float, pose: TruePose = TruePose("t", 1.5, 1.2, 0.3, 1.5)):
    """A room 9 m x 6 m seen from ``pose`` (by default near one corner) with the range at 10 m: through a
    20 log R gain its far walls come back 50-80 counts above the converter's floor, too faint to cast a
    65-count shadow."""
    return simulate_scan([np.array([[0, 0], [9.0, 0], [9.0, 6.0], [0, 6.0]])], pose,
                         SonarSpec(range_m=10.0, bins=250, tvg_exponent=tvg_exponent), EffectsSpec(),
                         np.random.default_rng(seed), water_depth_m=3.0)


def _hit_and_false(sim, settings: Segmentation) -> tuple[float, float]:
    """Share of beams on the wall (within two bins), share with an echo elsewhere."""
    ranges = segment(sim.scan, settings).ranges_m
    on_wall = np.abs(ranges - sim.truth_ranges_m) <= 2 * sim.scan.bin_size_m
    return float(np.mean(on_wall)), float(np.mean(np.isfinite(ranges) & ~on_wall))


@pytest.mark.parametrize("seed", [1, 2])
def test_faint_walls_beside_their_neighbours_count_through_a_weak_gain(seed):
    plain = Segmentation(method="shadow", min_range_m=0.4, faint_walls="off")
    faint = plain.model_copy(update={"faint_walls": "on"})
    weak = _room_through_weak_tvg(seed, 20.0)
    usual = _room_through_weak_tvg(seed, 35.0)
    with_faint = _hit_and_false(weak, faint), _hit_and_false(usual, faint)
    without = _hit_and_false(weak, plain), _hit_and_false(usual, plain)
    assert with_faint[0][0] >= without[0][0] + 0.02  # more of the far walls through the weak gain
    assert with_faint[0][1] <= without[0][1] + 0.02
    assert abs(with_faint[1][0] - without[1][0]) <= 0.01  # through the usual gain hardly anything changes
    assert with_faint[1][1] <= without[1][1] + 0.01


def test_a_faint_echo_counts_only_beside_detections_on_both_neighbouring_beams():
    bearings = np.radians(np.arange(400) * 0.9)
    rows = np.zeros((400, 150))
    rows[:, 60:63] = 200.0  # a wall every beam hears strongly at 2.4 m (255 once normalised)
    opening = np.arange(96, 105)
    rows[opening, 60:63] = 0.0  # an opening nine beams wide ...
    rows[opening, 100:103] = 45.0  # ... with a faint wall behind it: 57 normalised, over dark water
    rows[[300], 60:63] = 0.0
    rows[[300], 100:103] = 45.0  # the same faint echo on a single beam: a speckle peak, not a wall
    scan = Scan(bearings_rad=bearings, intensities=rows.astype(np.uint8), full_scale=255, bin_size_m=BIN)
    ranges = segment(scan, SHADOW.model_copy(update={"min_range_m": 0.4, "faint_walls": "on"})).ranges_m
    assert_allclose(ranges[opening[1:-1]], 101 * BIN + BIN / 2, atol=BIN)  # its edge beams have one witness
    assert np.isnan(ranges[300])
    assert_allclose(ranges[0], 61 * BIN + BIN / 2, atol=BIN)
    for alone in ("off", "auto"):  # a scan segmented on its own takes auto as off
        blanked = {"min_range_m": 0.4, "faint_walls": alone}
        assert np.isnan(segment(scan, SHADOW.model_copy(update=blanked)).ranges_m[opening]).all()


def _site_through(tvg_exponent: float) -> list:
    """Three stations of the weak-gain room: a site's worth of echoes at every range."""
    return [_room_through_weak_tvg(k, tvg_exponent, TruePose(f"s{k}", x, y, 0.3 * k, 1.5)).scan
            for k, (x, y) in enumerate([(1.5, 1.2), (4.5, 3.0), (7.5, 4.8)])]


def test_a_site_whose_echoes_fall_off_like_a_weak_gain_takes_faint_walls():
    weak, usual = _site_through(20.0), _site_through(35.0)
    falloff = {name: segmentation.echo_falloff(scans, 50.0, 0.4) for name, scans in (("weak", weak), ("usual", usual))}
    assert falloff["weak"] < segmentation.FAINT_FALLOFF < falloff["usual"], falloff
    auto = Segmentation(method="shadow", min_range_m=0.4)
    assert auto.faint_walls == "auto"
    assert segmentation.site_segmentation(weak, auto).faint_walls == "on"
    assert segmentation.site_segmentation(usual, auto).faint_walls == "off"
    assert segmentation.site_segmentation(weak, auto.model_copy(update={"method": "cfar"})).faint_walls == "off"
    chosen = auto.model_copy(update={"faint_walls": "off"})
    assert segmentation.site_segmentation(weak, chosen) is chosen  # a choice made in the record stands
    silent = weak[0].replace(intensities=np.zeros_like(weak[0].intensities))
    assert math.isnan(segmentation.echo_falloff([silent], 50.0, 0.4))  # no echoes: nothing to decide on
    assert segmentation.site_segmentation([silent], auto).faint_walls == "off"


def test_echo_incidence_reads_the_wall_a_beam_meets():
    # A straight wall 2 m east of the head: a beam at bearing b meets it at incidence b - 90°.
    bearings = np.radians(np.arange(30.0, 150.0, 0.9))
    ranges = 2.0 / np.sin(bearings)
    cos_i = segmentation.echo_incidence(ranges, bearings)
    inner = slice(5, -5)
    assert_allclose(cos_i[inner], np.abs(np.sin(bearings[inner])), atol=1e-6)
    ranges[10] = np.nan
    assert np.isnan(segmentation.echo_incidence(ranges, bearings)[10])


def _first_scan(**settings):
    from cistern_archive.simulation.chambers import GeneratorSettings, random_cistern
    from cistern_archive.simulation.simulator import simulate_site

    site = random_cistern(np.random.default_rng(3), settings=GeneratorSettings(**settings))
    return simulate_site(site.spec).scans[0].scan


def test_the_windows_follow_the_echoes_not_the_bins():
    """At the tuning bins the windows are the metres they were tuned in; coarser bins at the usual pulse
    lengthen them a little (the bins widen the echo); a site three times as large, its pulse and bins
    three times as long, three times."""
    assert segmentation.window_unit(_first_scan(), 0.4) == 1.0
    assert 1.0 <= segmentation.window_unit(_first_scan(bin_m=0.08), 0.4) < 1.6
    assert segmentation.window_unit(_first_scan(scale=3.0), 0.4) == pytest.approx(3.0, abs=0.2)
    assert segmentation.echo_width_m(_first_scan(scale=3.0), 0.4) == pytest.approx(
        3 * segmentation.echo_width_m(_first_scan(), 0.4), rel=0.1)


def test_a_site_three_times_as_large_is_segmented_at_three_times_the_ranges():
    """A random cistern drawn three times as large (0.12 m bins, the pulse three times as long, every
    count drawn as at the original place): the shadow rule's windows follow its echoes, three times as
    long, so nearly every beam's echo lies at three times the range (with the windows in metres 87 % of
    the beams did: the trailing window covered a third of the echo's smear)."""
    small, large = (segment(scan, Segmentation(min_range_m=0.4)) for scan in (_first_scan(), _first_scan(scale=3.0)))
    ra, rb = np.asarray(small.ranges_m), np.asarray(large.ranges_m)
    heard = np.isfinite(ra) | np.isfinite(rb)
    same = np.isfinite(ra) & np.isfinite(rb) & (np.abs(rb - 3.0 * ra) <= 2 * large.bin_size_m)
    assert heard.sum() > 300 and same.sum() >= 0.98 * heard.sum()
