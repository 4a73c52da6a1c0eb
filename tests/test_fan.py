"""Fan pictures: deterministic PNG bytes, geometry of the polar-to-Cartesian resampling."""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from cistern_archive.catalog.models import Segmentation
from cistern_archive.sonar.fan import display_levels, fan_png, polar_to_cartesian
from cistern_archive.core.scan import Scan
from cistern_archive.sonar.segmentation import segment, segment_intensities
from cistern_archive.simulation.simulator import TruePose, simulate_scan
from cistern_archive.simulation.spec import EffectsSpec, SonarSpec

BOX = [np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 3.0], [0.0, 3.0]])]


def png_chunks(data: bytes) -> list[bytes]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, kinds = 8, []
    while pos < len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + length]
        assert zlib.crc32(kind + body) == int.from_bytes(data[pos + 8 + length:pos + 12 + length], "big")
        kinds.append(kind)
        pos += 12 + length
    return kinds


@pytest.fixture(scope="module")
def sim():
    return simulate_scan(BOX, TruePose("f1", 1.5, 1.2, 0.2, 1.0), SonarSpec(range_m=6.0, bins=150, step_deg=1.8),
                         EffectsSpec(), np.random.default_rng(2))


def test_png_is_deterministic_without_metadata(sim):
    settings = Segmentation(min_range_m=0.4)
    one = fan_png(sim.scan, segmented=segment_intensities(sim.scan, settings), ranges=segment(sim.scan, settings))
    two = fan_png(sim.scan, segmented=segment_intensities(sim.scan, settings), ranges=segment(sim.scan, settings))
    assert one == two
    kinds = png_chunks(one)
    assert b"tEXt" not in kinds and b"tIME" not in kinds and b"iTXt" not in kinds
    assert kinds[0] == b"IHDR" and kinds[-1] == b"IEND"
    assert fan_png(sim.scan) != one


def test_polar_to_cartesian_places_bins_forward_up_and_left_ccw():
    bearings = np.radians([0.0, 90.0, 180.0, 270.0])
    values = np.zeros((4, 10))
    values[0, 5] = 1.0  # forward, 0.5..0.6 m
    values[1, 8] = 2.0  # bearing +90 deg (counter-clockwise): to the left
    image, extent = polar_to_cartesian(bearings, values, 0.1, pixels=201, beam_width_rad=math.radians(10))
    assert extent == pytest.approx(1.0)
    centre = 100
    assert image[centre - 55, centre] == 1.0  # 0.55 m forward = up
    assert image[centre, centre - 85] == 2.0  # 0.85 m left
    assert np.isnan(image[0, 0])  # the corners are outside the fan


def test_display_levels():
    scan = Scan(bearings_rad=np.zeros(1), intensities=np.array([[0, 10, 20, 200]], dtype=np.uint8),
                full_scale=255, bin_size_m=0.1)
    np.testing.assert_allclose(display_levels(scan, "full-scale"), [[0, 10 / 255, 20 / 255, 200 / 255]], rtol=1e-6)
    auto = display_levels(scan, "auto")
    assert auto.max() == 1.0 and auto[0, 0] == 0
    with pytest.raises(ValueError, match="contrast"):
        display_levels(scan, "loud")
