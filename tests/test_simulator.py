"""The sonar simulator: determinism, geometry against the truth, the effects it models."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.catalog.models import Segmentation
from cistern_archive.sonar.geometry import contains, interpolate_slice, overlap_fraction, ray_cast, shared_wall_fraction
from cistern_archive.sonar.segmentation import segment
from cistern_archive.simulation.output import probe_lengths
from cistern_archive.simulation.simulator import TruePose, beam_bearings, simulate_scan, simulate_site
from cistern_archive.simulation.spec import (
    EffectsSpec,
    LevelSpec,
    RingSpec,
    RouteSpec,
    SimulationSpec,
    SiteSpec,
    SonarSpec,
    StationSpec,
    load_spec,
)

CATALOG = Path(__file__).resolve().parents[1] / "catalog"
BOX = [np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])]
SONAR = SonarSpec(range_m=8.0, bins=200, step_deg=1.8)


def fraction_within_one_bin(sim, settings: Segmentation) -> float:
    ranges = segment(sim.scan, settings).ranges_m
    truth = sim.truth_ranges_m
    seen = np.isfinite(truth)
    return float(np.mean(np.abs(ranges[seen] - truth[seen]) <= sim.scan.bin_size_m))


def test_ray_cast_box():
    ranges, cosines = ray_cast(np.array([2.0, 1.0]), np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]), BOX)
    np.testing.assert_allclose(ranges, [4.0, 3.0, 2.0, 1.0])
    np.testing.assert_allclose(cosines, 1.0)
    r, c = ray_cast(np.array([2.0, 1.0]), np.array([math.pi / 4]), BOX)
    np.testing.assert_allclose(r, [3.0 * math.sqrt(2)])
    np.testing.assert_allclose(c, [math.cos(math.pi / 4)])


def test_same_seed_same_bytes_other_seed_differs():
    pose = TruePose("a", 2.0, 1.5, 0.4, 1.0)
    one = simulate_scan(BOX, pose, SONAR, EffectsSpec(), np.random.default_rng(7))
    two = simulate_scan(BOX, pose, SONAR, EffectsSpec(), np.random.default_rng(7))
    three = simulate_scan(BOX, pose, SONAR, EffectsSpec(), np.random.default_rng(8))
    assert one.scan.intensities.tobytes() == two.scan.intensities.tobytes()
    assert one.scan.yaw_rad == two.scan.yaw_rad
    assert one.scan.intensities.tobytes() != three.scan.intensities.tobytes()


def test_scan_shape_and_micron_like_settings():
    sim = simulate_scan(BOX, TruePose("a", 2.0, 1.5, 0.0, 1.0), SONAR, EffectsSpec(), np.random.default_rng(0))
    scan = sim.scan
    assert scan.intensities.dtype == np.uint8 and scan.full_scale == 255
    assert scan.intensities.shape == (200, 200)
    assert scan.bin_size_m == pytest.approx(0.04)
    assert scan.station == "a" and scan.settings["simulated"] is True
    # Clockwise head: bearings decrease in the counter-clockwise sonar frame.
    assert np.all(np.diff(np.unwrap(scan.bearings_rad)) < 0)
    assert beam_bearings(SonarSpec(step_deg=0.9)).size == 400
    # Much of the water is exact zeros after the AD mapping, as on a Tritech head; the rest is low.
    assert np.mean(scan.intensities == 0) > 0.2
    assert np.median(scan.intensities) < 40


def test_noise_free_sim_segments_to_the_walls():
    pose = TruePose("a", 2.2, 1.4, 0.3, 1.0)
    sim = simulate_scan(BOX, pose, SONAR, EffectsSpec.ideal(), np.random.default_rng(0))
    assert math.isclose(sim.scan.yaw_rad, 0.3) and sim.scan.depth_m == 1.0
    assert fraction_within_one_bin(sim, Segmentation(method="paper")) > 0.95
    assert fraction_within_one_bin(sim, Segmentation(method="cfar")) > 0.95


def test_effects_are_present():
    pose = TruePose("a", 2.0, 2.0, 0.0, 1.0)
    effects = EffectsSpec(multipath_fraction=0.5, spike_rate=0.2, compass_bias_deg=3.0, compass_sigma_deg=0.0)
    sim = simulate_scan(BOX, pose, SONAR, effects, np.random.default_rng(3), water_depth_m=2.0)
    scan = sim.scan
    assert math.degrees(scan.yaw_rad) == pytest.approx(3.0)
    # Own echo in the first bins, ghosts beyond the walls.
    assert scan.intensities[:, 0].mean() > 50
    beyond = scan.bin_centres_m[None, :] > sim.truth_ranges_m[:, None] + 0.3
    assert np.mean(scan.intensities[beyond] > 100) > 0.001


def test_every_segmentation_on_the_pool_site():
    """The pool's simulated scans segment to the walls by the spec's rule (shadow) and the two others."""
    spec = load_spec(CATALOG / "specs" / "lair-pool.yaml")
    site = simulate_site(spec)
    assert len(site.scans) == 4
    assert spec.segmentation.method == "shadow" and spec.segmentation.min_range_m == pytest.approx(0.4)
    for sim in site.scans:
        assert fraction_within_one_bin(sim, spec.segmentation) > 0.7
        assert fraction_within_one_bin(sim, spec.segmentation.model_copy(update={"method": "paper"})) > 0.7
        assert fraction_within_one_bin(sim, spec.segmentation.model_copy(update={"method": "cfar"})) > 0.75


def test_near_field_defeats_the_paper_rule_without_blanking():
    spec = load_spec(CATALOG / "specs" / "lair-pool.yaml")
    sim = simulate_site(spec).scans[0]
    assert fraction_within_one_bin(sim, Segmentation(method="paper", min_range_m=0.0)) < 0.6


def test_route_respects_overlap_and_stays_in_the_water():
    spec = SimulationSpec(
        id="corridor", name="corridor",
        site=SiteSpec(levels=[LevelSpec(depth_m=0.0, walls=RingSpec(rectangle=(0, 0, 20, 2)))]),
        sonar=SonarSpec(range_m=6.0, bins=120, step_deg=3.6),
        routes=[RouteSpec(waypoints=[(0.5, 1.0), (19.5, 1.0)], overlap=0.5, depths=[1.0])],
        seed=4,
    )
    site = simulate_site(spec)
    poses = [s.pose for s in site.scans]
    assert len(poses) >= 3
    rings = spec.site.slices()[0][1]
    for a, b in zip(poses, poses[1:]):
        assert overlap_fraction(np.array([a.x_m, a.y_m]), np.array([b.x_m, b.y_m]), rings, 6.0) >= 0.5
    assert contains(rings, np.array([[p.x_m, p.y_m] for p in poses])).all()


def test_station_outside_the_walls_is_refused():
    spec = SimulationSpec(
        id="bad", name="bad",
        site=SiteSpec(levels=[LevelSpec(depth_m=0.0, walls=RingSpec(rectangle=(0, 0, 2, 2)))]),
        stations=[StationSpec(name="out", x_m=5.0, y_m=1.0)],
    )
    with pytest.raises(ValueError, match="not in the water"):
        simulate_site(spec)


def test_a_station_listed_out_of_the_visits_order_is_recorded_at_its_visit():
    spec = SimulationSpec(
        id="order", name="order", sonar=SONAR,
        site=SiteSpec(levels=[LevelSpec(depth_m=0.0, walls=RingSpec(rectangle=(0, 0, 6, 4)))]),
        stations=[StationSpec(name="s2", x_m=3.0, y_m=2.0, visit=1), StationSpec(name="s1", x_m=1.5, y_m=2.0, visit=0),
                  StationSpec(name="s3", x_m=4.5, y_m=2.0)],  # no visit: its place in the list
    )
    scans = [sim.scan for sim in simulate_site(spec).scans]
    assert [scan.timestamp - spec.start_time.timestamp() for scan in scans] == [spec.seconds_per_station, 0.0,
                                                                                 2 * spec.seconds_per_station]
    assert segment(scans[0], Segmentation()).time_s == scans[0].timestamp  # the localizer sees the time


def test_depth_slices_interpolate():
    levels = [(0.0, [np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)]),
              (2.0, [np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)])]
    mid = interpolate_slice(levels, 1.0)[0]
    np.testing.assert_allclose(mid[2], [3.0, 3.0])
    np.testing.assert_allclose(interpolate_slice(levels, 5.0)[0][2], [4.0, 4.0])


def test_probe_lengths_of_a_rectangle():
    lengths = probe_lengths(BOX, (3.0, 2.0), 90.0, 5, 0.5)
    np.testing.assert_allclose(lengths, 4.0)


def test_vertical_lobe_on_a_vertical_wall_gives_slant_range():
    from cistern_archive.simulation.simulator import lobe_hits

    angles = np.array([0.0, math.pi / 2])
    slant, cos_inc = lobe_hits(BOX, None, np.array([2.0, 1.0]), angles, 1.0, math.radians(10.0), None)
    np.testing.assert_allclose(slant, np.array([4.0, 3.0]) / math.cos(math.radians(10.0)))
    np.testing.assert_allclose(cos_inc, math.cos(math.radians(10.0)))
    # Looking down at 30 deg from 1 m depth in 2 m of water: the floor comes first beyond 1.73 m.
    slant, _ = lobe_hits(BOX, None, np.array([2.0, 1.0]), angles, 1.0, math.radians(30.0), 2.0)
    assert np.all(np.isinf(slant))


def test_sloping_walls_are_found_at_the_depth_the_ray_reaches():
    from cistern_archive.simulation.simulator import lobe_hits

    narrow = [np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])]
    wide = [np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])]
    levels = [(0.0, narrow), (4.0, wide)]  # half-width 1 + depth / 2
    mid = interpolate_slice(levels, 2.0)
    down = math.radians(20.0)
    slant, _ = lobe_hits(mid, levels, np.zeros(2), np.array([0.0]), 2.0, down, None, iterations=8)
    # Solve h = 1 + (2 + h tan e) / 2 for the horizontal distance h.
    h = 2.0 / (1.0 - math.tan(down) / 2.0)
    assert slant[0] == pytest.approx(h / math.cos(down), abs=0.05)


def test_bell_echoes_smear_around_the_wall():
    spec = load_spec(CATALOG / "specs" / "bell-cistern.yaml")
    sim = simulate_site(spec).scans[4]
    truth = sim.truth_ranges_m
    centres = sim.scan.bin_centres_m
    bright = sim.scan.intensities >= 100
    before = bright & (centres[None, :] < truth[:, None] - 0.2)
    after = bright & (centres[None, :] > truth[:, None] + 0.2) & (centres[None, :] < truth[:, None] + 1.0)
    # The inward-leaning walls above and the outward-leaning walls below both return.
    assert before.any(axis=1).mean() > 0.5 and after.any(axis=1).mean() > 0.3


def test_corridor_ring_has_constant_width():
    ring = RingSpec(corridor=[(0.0, 0.0), (10.0, 0.0), (10.0, 8.0)], width_m=1.4).vertices()
    lengths = probe_lengths([ring], (5.0, 0.0), 90.0, 5, 0.5)
    np.testing.assert_allclose(lengths, 1.4)
    np.testing.assert_allclose(probe_lengths([ring], (10.0, 4.0), 0.0, 3, 0.5), 1.4)


def test_spec_validation_names_the_problem(tmp_path: Path):
    from pydantic import ValidationError

    from cistern_archive.core.errors import CatalogError

    with pytest.raises(ValidationError, match="exactly one of"):
        RingSpec(rectangle=(0, 0, 1, 1), ellipse=(0, 0, 1, 1))
    with pytest.raises(ValidationError, match="x_max > x_min"):
        RingSpec(rectangle=(1, 0, 0, 1))
    with pytest.raises(ValidationError, match="stations, routes"):
        SimulationSpec(id="x", name="x", site=SiteSpec(levels=[LevelSpec(depth_m=0, walls=RingSpec(rectangle=(0, 0, 1, 1)))]))
    bad = tmp_path / "bad.yaml"
    bad.write_text("id: x\nname: x\nsite:\n  levels: []\nstations: [{name: a, x_m: 0, y_m: 0}]\nsurprise: 1\n")
    with pytest.raises(CatalogError) as info:
        load_spec(bad)
    text = str(info.value)
    assert f"{bad}:4: site.levels" in text and f"{bad}:6: surprise: unknown field" in text


def test_visibility_and_overlap_in_a_box():
    from cistern_archive.sonar.geometry import ring_area, visibility_polygon

    assert ring_area(visibility_polygon(np.array([2.0, 1.0]), BOX, 10.0)) == pytest.approx(24.0, rel=1e-3)
    assert ring_area(visibility_polygon(np.array([2.0, 1.0]), BOX, 0.5)) == pytest.approx(math.pi / 4, rel=1e-3)
    a, b = np.array([1.0, 1.0]), np.array([5.0, 3.0])
    assert overlap_fraction(a, b, BOX, 10.0) == pytest.approx(1.0, abs=0.01)
    assert overlap_fraction(a, b, BOX, 1.0) == 0.0


def test_gallery_ring_steps_in_width_and_cuts_recesses():
    spec = RingSpec(
        corridor=[(0.0, 0.0), (5.0, 0.0), (9.0, 0.0), (9.0, 6.0)], widths=[1.4, 1.8, 1.4],
        recesses=[{"reach": 0, "side": "left", "at_m": 1.0, "length_m": 0.8, "depth_m": 0.5},
                  {"reach": 1, "side": "right", "at_m": 1.0, "length_m": 1.0, "depth_m": 3.0}],
    )
    ring = [spec.vertices()]
    for point in ([1.4, 1.0], [6.5, -3.5], [7.0, 0.85], [9.0, 3.0]):  # niche, branch, wide reach, after the bend
        assert contains(ring, np.array([point]))[0], point
    for point in ([3.0, 1.0], [3.0, 0.85], [8.3, -3.5]):  # wall beside the niche, narrow reach, beside the branch
        assert not contains(ring, np.array([point]))[0], point
    plain = RingSpec(corridor=[(0.0, 0.0), (10.0, 0.0), (10.0, 8.0)], width_m=1.4, widths=[1.4, 1.4]).vertices()
    mitred = RingSpec(corridor=[(0.0, 0.0), (10.0, 0.0), (10.0, 8.0)], width_m=1.4).vertices()
    assert np.allclose(plain, mitred)


def test_gallery_ring_refuses_misfits():
    with pytest.raises(ValueError, match="one positive width per reach"):
        RingSpec(corridor=[(0.0, 0.0), (5.0, 0.0)], widths=[1.0, 2.0])
    with pytest.raises(ValueError, match="does not fit"):
        RingSpec(corridor=[(0.0, 0.0), (5.0, 0.0)], recesses=[
            {"reach": 0, "side": "left", "at_m": 4.5, "length_m": 1.0, "depth_m": 0.3}])
    with pytest.raises(ValueError, match="belong to a corridor"):
        RingSpec(rectangle=(0.0, 0.0, 1.0, 1.0), widths=[1.0])


def _gallery_spec(roughness: float | None) -> SimulationSpec:
    return SimulationSpec(
        id="gallery", name="gallery", seed=5, sonar=SonarSpec(range_m=6.0, bins=150, step_deg=1.8),
        site=SiteSpec(levels=[LevelSpec(depth_m=0.0, wall_roughness=roughness,
                                         walls=RingSpec(corridor=[(0.0, 0.0), (12.0, 0.0)], width_m=1.4))]),
        stations=[StationSpec(name="g1", x_m=6.0, y_m=0.0, depth_m=1.0)],
    )


def test_rough_walls_echo_at_grazing_incidence():
    """Beams meeting the side walls of a 1.4 m gallery 2-5 m away: on smooth walls most echoes come from
    near the head (the grazing wall echo is too weak); on rough walls most come from the far wall."""
    far, on_wall = {}, {}
    for roughness in (None, 0.3):
        sim = simulate_site(_gallery_spec(roughness)).scans[0]  # default (noisy) effects
        ranges = segment(sim.scan, Segmentation(method="paper", threshold=50, min_range_m=0.4)).ranges_m
        grazing = np.isfinite(sim.truth_ranges_m) & (sim.truth_ranges_m > 2.0) & (sim.truth_ranges_m < 5.0)
        far[roughness] = float(np.mean(ranges[grazing] > 1.5))
        on_wall[roughness] = float(np.mean(np.abs(ranges[grazing] - sim.truth_ranges_m[grazing]) < 0.15))
    assert far[None] < 0.4 and far[0.3] > 0.7
    assert on_wall[0.3] > on_wall[None] + 0.3


def test_level_roughness_interpolates_in_depth():
    site = SiteSpec(levels=[LevelSpec(depth_m=0.0, wall_roughness=0.1, walls=RingSpec(rectangle=(0, 0, 1, 1))),
                            LevelSpec(depth_m=2.0, wall_roughness=0.5, walls=RingSpec(rectangle=(0, 0, 1, 1)))])
    assert site.wall_roughness(1.0, 0.03) == pytest.approx(0.3)
    assert site.wall_roughness(5.0, 0.03) == pytest.approx(0.5)
    assert _gallery_spec(None).site.wall_roughness(1.0, 0.03) == 0.03


def test_station_below_must_name_an_earlier_station():
    site = SiteSpec(levels=[LevelSpec(depth_m=0.0, walls=RingSpec(rectangle=(0, 0, 4, 4)))])
    SimulationSpec(id="s", name="s", site=site, stations=[
        StationSpec(name="a", x_m=1, y_m=1), StationSpec(name="b", x_m=1.02, y_m=1, depth_m=2.0, below="a")])
    with pytest.raises(ValueError, match="not an earlier station"):
        SimulationSpec(id="s", name="s", site=site, stations=[
            StationSpec(name="a", x_m=1, y_m=1, below="b"), StationSpec(name="b", x_m=1, y_m=1)])


def test_chambers_looking_through_a_tunnel_share_water_but_little_wall():
    """Two 4 m rooms joined by a 0.4 m tunnel: a station in each sees a fifth or more of the other's water
    through the tunnel but almost none of its walls; two stations in one room share nearly everything."""
    rooms = [np.array([[0, 0], [4, 0], [4, 1.8], [6, 1.8], [6, 0], [10, 0], [10, 4], [6, 4], [6, 2.2], [4, 2.2],
                       [4, 4], [0, 4]], dtype=float)]
    west, west_too, east = (1.5, 2.0), (3.0, 2.0), (7.0, 2.0)
    assert overlap_fraction(west, east, rooms, 8.0) > 0.2 and shared_wall_fraction(west, east, rooms, 8.0) < 0.1
    assert shared_wall_fraction(west, west_too, rooms, 8.0) > 0.95
    assert shared_wall_fraction(west, east, rooms, 8.0) == shared_wall_fraction(east, west, rooms, 8.0)
