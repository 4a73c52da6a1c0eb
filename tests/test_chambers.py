"""The random multi-chamber cisterns (cistern_archive.simulation.chambers) and the Wilson interval."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.evaluation import wilson_interval
from cistern_archive.sonar.geometry import contains, ray_cast
from cistern_archive.simulation.simulator import simulate_site, station_poses
from cistern_archive.simulation.spec import SimulationSpec, load_spec
from cistern_archive.simulation.chambers import (
    OPENING_INSET_M,
    ROOM_M,
    STATIONS,
    TUNNEL_WIDTH_M,
    GeneratorSettings,
    random_cistern,
    random_cisterns,
    simulate_into,
    wall_distance,
    write_specs,
)

ROOT = Path(__file__).resolve().parents[1]
CISTERNS = random_cisterns(30, seed=7)


def _segments_cross(p1, p2, q1, q2) -> bool:
    def side(a, b, c):
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    return side(p1, p2, q1) * side(p1, p2, q2) < 0 and side(q1, q2, p1) * side(q1, q2, p2) < 0


def test_equal_seeds_give_equal_specs_and_other_seeds_other_sites():
    again = random_cisterns(30, seed=7)
    assert [c.spec for c in again] == [c.spec for c in CISTERNS]
    other = random_cisterns(30, seed=8)
    assert [c.spec.site for c in other] != [c.spec.site for c in CISTERNS]


def test_specs_are_valid_and_round_trip_through_yaml(tmp_path: Path):
    paths = write_specs(CISTERNS[:5], tmp_path)
    for cistern, path in zip(CISTERNS[:5], paths):
        assert load_spec(path) == cistern.spec
        SimulationSpec.model_validate(cistern.spec.model_dump())
        assert len(station_poses(cistern.spec)) == len(cistern.spec.stations)  # every station is in the water


def test_one_to_three_chambers_of_2_5_to_8_m_not_only_rectangles():
    counts = {c.chambers for c in CISTERNS}
    assert counts == {1, 2, 3}
    kinds = set()
    for cistern in CISTERNS:
        for chamber in cistern.layout.chambers:
            kinds.add(chamber.kind)
            assert all(ROOM_M[0] <= e <= ROOM_M[1] for e in chamber.extent_m())
    assert kinds == {"polygon", "round"}
    assert any(len(c.ring()) > 4 for cistern in CISTERNS for c in cistern.layout.chambers)


def test_one_closed_simple_counter_clockwise_outline():
    for cistern in CISTERNS:
        level = cistern.spec.site.levels
        assert len(level) == 1 and not level[0].islands
        ring = np.asarray(level[0].walls.polygon)
        x, y = ring[:, 0], ring[:, 1]
        assert 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) > 0
        edges = list(zip(ring, np.roll(ring, -1, axis=0)))
        for (a, b), (c, d) in combinations(edges, 2):
            assert not _segments_cross(a, b, c, d), cistern.spec.id


def test_tunnels_are_0_8_to_1_2_m_wide_wall_to_wall():
    tunnels = 0
    for cistern in CISTERNS:
        assert len(cistern.layout.tunnels) == cistern.chambers - 1
        ring = [np.asarray(cistern.spec.site.levels[0].walls.polygon)]
        for t in cistern.layout.tunnels:
            assert TUNNEL_WIDTH_M[0] <= t.width_m <= TUNNEL_WIDTH_M[1]
            assert 1.0 <= t.x1 - t.x0 <= 2.5
            middle = cistern.layout.to_map(np.array([[0.5 * (t.x0 + t.x1), t.y]]))[0]
            across = cistern.layout.rotation_rad + math.pi / 2
            ranges, _ = ray_cast(middle, np.array([across, across + math.pi]), ring)
            assert ranges.sum() == pytest.approx(t.width_m, abs=2e-3)  # measured on the written walls
            tunnels += 1
    assert tunnels >= 15


def test_six_to_twelve_stations_in_visiting_order_some_in_tunnels_or_openings_some_near_walls():
    places = set()
    for cistern in CISTERNS:
        spec = cistern.spec
        assert STATIONS[0] <= len(spec.stations) <= STATIONS[1]
        ring = np.asarray(spec.site.levels[0].walls.polygon)
        xy = np.array([[s.x_m, s.y_m] for s in spec.stations])
        assert contains([ring], xy).all()
        assert (wall_distance(xy, ring) >= 0.39).all()
        names = [s.name for s in spec.stations]
        prefixes = [n[0] for n in names]
        chamber_order = [p for p in prefixes if p in "abc"]
        assert chamber_order == sorted(chamber_order)  # one chamber after another
        connectors = [k for k, p in enumerate(prefixes) if p in "to"]
        assert len(connectors) == cistern.chambers - 1
        for k in connectors:  # each tunnel's station lies between the chambers it joins
            assert prefixes[k - 1] < prefixes[k + 1]
        places |= {s.place for s in cistern.stations}
        assert [s.name for s in cistern.stations] == names
    assert places == {"chamber", "near-wall", "tunnel", "opening"}


def test_micron_like_echoes_and_two_degree_compass():
    for cistern in CISTERNS:
        e = cistern.spec.effects
        assert e.speckle_looks > 0 and e.multipath_fraction > 0 and e.spike_rate > 0 and e.self_echo_db > -100
        assert abs(e.compass_bias_deg) <= 2.0 and e.compass_sigma_deg == pytest.approx(2.0)


def test_default_settings_draw_the_same_sites_as_none():
    again = random_cisterns(30, seed=7, settings=GeneratorSettings())
    assert [c.spec for c in again] == [c.spec for c in CISTERNS]


def test_settings_reach_the_sonar_and_the_segmentation_of_every_site():
    settings = GeneratorSettings(sonar={"tvg_exponent": 20.0}, segmentation={"faint_walls": "on"})
    for plain, cistern in zip(CISTERNS[:6], random_cisterns(6, seed=7, settings=settings)):
        assert cistern.spec.sonar.tvg_exponent == 20.0 and cistern.spec.segmentation.faint_walls == "on"
        assert cistern.spec.segmentation.min_range_m == plain.spec.segmentation.min_range_m
        assert plain.spec.segmentation.faint_walls == "auto" and plain.spec.sonar.tvg_exponent == 35.0


def test_settings_give_longer_tunnels_surveyed_along_their_length():
    settings = GeneratorSettings(tunnel_length_m=(2.0, 4.0), tunnel_width_m=(0.7, 1.0), tunnel_station_spacing_m=1.5)
    tunnels = 0
    for cistern in random_cisterns(12, seed=7, settings=settings):
        names = [s.name for s in cistern.spec.stations]
        for k, t in enumerate(cistern.layout.tunnels):
            assert 2.0 <= t.x1 - t.x0 <= 4.0 and 0.7 <= t.width_m <= 1.0
            survey = [s for s in cistern.stations if s.name[0] in "otp" and s.name[1] == str(k + 1)]
            xs = [s.xy[0] for s in survey]  # in the site's frame, west to east
            assert xs[0] == pytest.approx(t.x0 - OPENING_INSET_M) and xs[-1] == pytest.approx(t.x1 + OPENING_INSET_M)
            assert [s.place for s in survey] == ["opening"] + ["tunnel"] * (len(survey) - 2) + ["opening"]
            assert np.diff([t.x0, *xs[1:-1], t.x1]).max() <= 1.5 + 1e-9 and len(survey) >= 3
            first = names.index(survey[0].name)  # visited in a row, between the chambers they join
            assert names[first:first + len(survey)] == [s.name for s in survey]
            tunnels += 1
    assert tunnels >= 5


def test_settings_put_stations_on_an_uneven_floor():
    for cistern in random_cisterns(10, seed=7, settings=GeneratorSettings(station_depth_jitter_m=0.6)):
        depths = [s.depth_m for s in cistern.spec.stations]
        water = cistern.spec.site.water_depth_m
        assert 0.3 <= min(depths) and max(depths) <= water - 0.3 + 1e-9
    spans = [np.ptp([s.depth_m for s in c.spec.stations])
             for c in random_cisterns(10, seed=7, settings=GeneratorSettings(station_depth_jitter_m=0.6))]
    assert max(spans) > 0.8 and max(np.ptp([s.depth_m for s in c.spec.stations]) for c in CISTERNS) <= 0.1


def test_settings_list_the_stations_by_label_or_shuffled_at_the_same_places():
    visited = random_cisterns(6, seed=7)
    for order in ("label", "shuffled"):
        listed = random_cisterns(6, seed=7, settings=GeneratorSettings(station_order=order))
        for a, b in zip(visited, listed):
            where = {s.name: (s.x_m, s.y_m, s.yaw_deg) for s in a.spec.stations}
            assert {s.name: (s.x_m, s.y_m, s.yaw_deg) for s in b.spec.stations} == where
            assert [s.name for s in b.stations] == [s.name for s in b.spec.stations]
            visits = [s.name for s in sorted(b.spec.stations, key=lambda s: s.visit)]
            assert visits == [s.name for s in a.spec.stations]  # the scans' times keep the visits' order
            assert b.spec.references[0].measure.frame == a.spec.stations[0].name == a.spec.references[0].measure.frame
        names = [[s.name for s in c.spec.stations] for c in listed]
        if order == "label":
            assert all(n == sorted(n) for n in names)
        else:
            assert any(n != [s.name for s in c.spec.stations] for n, c in zip(names, visited))


def test_settings_stand_pillars_in_the_chambers_clear_of_walls_tunnels_and_stations():
    settings = GeneratorSettings(pillars=(1, 2))
    plain = random_cisterns(8, seed=7)
    pillared = random_cisterns(8, seed=7, settings=settings)
    assert sum(len(c.spec.site.levels[0].islands) for c in pillared) >= 8
    assert pillared[0].spec.site.levels[0].walls == plain[0].spec.site.levels[0].walls  # pillars added to its rooms
    for b in pillared:
        outer, *pillars = b.spec.site.levels[0].rings()
        stations = np.array([[s.x_m, s.y_m] for s in b.spec.stations])
        for pillar in pillars:
            assert contains([outer], pillar).all()
            assert wall_distance(pillar, outer).min() >= 0.8 - 1e-6  # the vehicle passes round it
            assert not contains([pillar], stations).any()
            assert wall_distance(stations, pillar).min() >= 0.45 - 1e-3
    assert all(not c.spec.site.levels[0].islands for c in plain)
    with pytest.raises(ValueError, match="pillars"):
        GeneratorSettings(pillars=(2, 1))


def test_settings_bring_the_vehicle_back_to_the_first_chamber_for_a_last_station():
    plain = random_cisterns(6, seed=7)
    back = random_cisterns(6, seed=7, settings=GeneratorSettings(return_to_start=True))
    for a, b in zip(plain, back):
        assert [s.name for s in b.spec.stations] == [s.name for s in a.spec.stations] + ["r1"]
        assert b.spec.stations[:-1] == a.spec.stations and b.spec.site == a.spec.site  # the same site, one more station
        first = b.layout.to_map(b.layout.chambers[0].ring())
        last = b.spec.stations[-1]
        assert contains([first], np.array([[last.x_m, last.y_m]]))[0]
        others = np.array([[s.x_m, s.y_m] for s in b.spec.stations[:-1]])
        assert np.hypot(*(others - [last.x_m, last.y_m]).T).min() > 0.3


def test_a_return_station_finds_room_in_a_small_chamber_full_of_stations():
    """Seed 35's 40 sites hold a 4.4 m x 3.2 m first chamber with no place 0.8 m from all of its
    stations: the return station stands as far from them as they stand from each other, and the other
    sites draw the same stations as they would have (the seeds measured before keep their sites)."""
    sites = random_cisterns(40, seed=35, settings=GeneratorSettings(return_to_start=True))
    plain = random_cisterns(40, seed=35)
    crowded = 0
    for a, b in zip(plain, sites):
        assert b.spec.stations[:-1] == a.spec.stations
        first = b.layout.to_map(b.layout.chambers[0].ring())
        last = b.spec.stations[-1]
        assert last.name == "r1" and contains([first], np.array([[last.x_m, last.y_m]]))[0]
        others = np.array([[s.x_m, s.y_m] for s in b.spec.stations[:-1]])
        nearest = np.hypot(*(others - [last.x_m, last.y_m]).T).min()
        assert nearest > 0.3
        crowded += nearest < 0.8
    assert crowded >= 1


def test_settings_set_the_sonar_and_its_other_effects():
    settings = GeneratorSettings(bin_m=0.08, step_deg=1.8, sonar={"beam_width_deg": 4.0}, effects={"speckle_looks": 1.0})
    for cistern in random_cisterns(10, seed=7, settings=settings):
        sonar, effects = cistern.spec.sonar, cistern.spec.effects
        assert sonar.step_deg == 1.8 and sonar.beam_width_deg == 4.0 and effects.speckle_looks == 1.0
        assert sonar.range_m / sonar.bins == pytest.approx(0.08)


def test_a_scaled_site_is_the_same_site_larger_and_heard_as_well():
    small, large = (random_cistern(np.random.default_rng(3), settings=GeneratorSettings(scale=k)) for k in (1.0, 3.0))
    walls = [np.array(c.spec.site.levels[0].walls.polygon) for c in (small, large)]
    assert np.allclose(walls[1], 3.0 * walls[0], atol=0.003)
    places = [np.array([[s.x_m, s.y_m, s.depth_m] for s in c.spec.stations]) for c in (small, large)]
    assert np.allclose(places[1], 3.0 * places[0], atol=0.003)
    assert large.spec.site.water_depth_m == pytest.approx(3.0 * small.spec.site.water_depth_m, abs=0.01)
    assert large.spec.sonar.range_m == pytest.approx(3.0 * small.spec.sonar.range_m)
    assert large.spec.sonar.bins == small.spec.sonar.bins
    # the same draws at places three times as far give the same counts, walls among them, beyond the
    # vehicle's own echoes and near-field reverberation, which keep their ranges (2.6 m of the small site)
    scans = [simulate_site(c.spec).scans[0].scan for c in (small, large)]
    counts = [np.asarray(s.intensities, dtype=np.int64)[:, 65:] for s in scans]
    assert (counts[0] > 100).sum() > 500
    assert np.mean(np.abs(counts[1] - counts[0]) <= 2) > 0.99


def test_settings_set_the_compass_and_the_clutter_and_refuse_bad_ranges():
    settings = GeneratorSettings(compass_bias_deg=4.0, compass_sigma_deg=4.0, multipath_fraction=(0.2, 0.2),
                                 spike_rate=0.02)
    effects = [c.spec.effects for c in random_cisterns(20, seed=7, settings=settings)]
    assert all(abs(e.compass_bias_deg) <= 4.0 and e.compass_sigma_deg == 4.0 for e in effects)
    assert max(abs(e.compass_bias_deg) for e in effects) > 2.0
    assert all(e.multipath_fraction == 0.2 and e.spike_rate == 0.02 for e in effects)
    with pytest.raises(ValueError, match="tunnel_length_m"):
        GeneratorSettings(tunnel_length_m=(3.0, 2.0))
    with pytest.raises(ValueError, match="beam_widht_deg"):  # the simulator's spec refuses what it does not know
        random_cisterns(1, seed=7, settings=GeneratorSettings(sonar={"beam_widht_deg": 4.0}))
    with pytest.raises(ValueError):
        GeneratorSettings(tunnel_lenght_m=(1.0, 2.0))  # a misspelt setting is an error, not a default


def test_fixed_counts_and_bad_counts():
    rng = np.random.default_rng(3)
    cistern = random_cistern(rng, 4, chambers=3, stations=6)
    assert cistern.chambers == 3 and len(cistern.spec.stations) == 6 and cistern.spec.id == "cistern-004"
    with pytest.raises(ValueError, match="chambers must be 1-3"):
        random_cistern(rng, chambers=4)


def test_simulated_into_a_catalog_with_truth(tmp_path: Path):
    from cistern_archive.catalog.loader import load_record

    cistern = random_cistern(np.random.default_rng(11), 0, chambers=2, stations=6)
    record_path = simulate_into(write_specs([cistern], tmp_path)[0], tmp_path)
    record = load_record(record_path, tmp_path).record
    assert [t.station for t in record.truth] == [s.name for s in cistern.spec.stations]
    assert record.simulation == "specs/cistern-000.yaml"
    assert len(list((tmp_path / "data" / "cistern-000").glob("*.npz"))) == 6


@pytest.mark.parametrize(("k", "n", "low", "high"), [
    (5, 10, 0.2366, 0.7634),     # Wilson (1927); Newcombe (1998), Table I
    (0, 10, 0.0, 0.2775),
    (10, 10, 0.7225, 1.0),
    (81, 263, 0.2553, 0.3662),   # Newcombe (1998), example of Table I
])
def test_wilson_interval_known_values(k: int, n: int, low: float, high: float):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(low, abs=1e-4) and hi == pytest.approx(high, abs=1e-4)


def test_wilson_interval_edges():
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="within 0..3"):
        wilson_interval(4, 3)
    lo, hi = wilson_interval(40, 40)
    assert lo < 1.0 and hi == 1.0


@pytest.mark.slow
def test_sites_random_json_interface():
    """``benchmarks/sites.py --random 1`` through the real runner: the last line is the interface."""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sites.py"), "--random", "1", "--seed", "3",
                          "--far-pairs", "2", "--json"], capture_output=True, text=True, timeout=600, check=True)
    last = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(last) == ["sites", "scans", "placed", "pairs_ge50", "pairs_ge50_ok", "far_pairs",
                          "far_pairs_converged", "median_aligned_error_m", "max_aligned_error_m",
                          "silent_wrong_sites"]
    expected = random_cisterns(1, 3)[0]
    assert last["sites"] == 1 and last["scans"] == len(expected.spec.stations)
    assert 0 <= last["placed"] <= last["scans"] and 0 <= last["pairs_ge50_ok"] <= last["pairs_ge50"]
    assert last["far_pairs"] <= 2 and last["far_pairs_converged"] <= last["far_pairs"]
    assert last["silent_wrong_sites"] in (0, 1)
    if last["placed"] >= 2:
        assert 0 <= last["median_aligned_error_m"] <= last["max_aligned_error_m"]
    assert "scans placed" in out.stdout and "[" in out.stdout  # the table with Wilson intervals


def test_sites_benchmark_refuses_generator_settings_it_cannot_draw_from():
    """A tunnel wider than any chamber's end wall, or settings that are not valid: one line naming the
    settings and the cause, exit 2, no traceback."""
    for settings, cause in (('{"tunnel_width_m": [2.5, 3.0]}', "cannot hold a"),
                            ('{"tunnel_length_m": [3, 2]}', "tunnel_length_m must be")):
        out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sites.py"), "--random", "3",
                              "--generator", settings], capture_output=True, text=True, timeout=120)
        assert out.returncode == 2, out.stderr
        assert cause in out.stderr and "Traceback" not in out.stderr, out.stderr


def test_sites_benchmark_builds_with_the_matcher_it_is_given():
    """``score_site(..., matcher=(name, params))`` (``--matcher``, ``--matcher-params``): the pool built
    with its own matcher converges on its pairs; with ``icp`` allowed one iteration, no pair settles
    (what still places its scans is ``site-graph``'s fit of the scans as wholes)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from sites import score_site

    catalog = ROOT / "catalog"
    own = score_site(catalog / "sites" / "lair-pool.yaml", catalog)
    assert own["pairs_converged"] == own["pairs"] > 0
    starved = score_site(catalog / "sites" / "lair-pool.yaml", catalog, matcher=("icp", {"max_iterations": 1}))
    assert starved["pairs"] > 0 and starved["pairs_converged"] == 0


def test_sites_benchmark_scores_a_join_against_its_interval():
    """``join_errors``: a join's stations, how far the second lies from where it belongs relative to the
    first after the rigid alignment, and its 95 % half-width; a join 0.2 m off with a sigma of 0.05 m
    lies outside its interval."""
    from types import SimpleNamespace

    from cistern_archive.core.poses import Poses

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from sites import join_errors

    truth_xy = np.array([[0.0, 0.0], [2.0, 0.0], [6.0, 0.0], [8.0, 1.0]])
    estimated = truth_xy.copy()
    estimated[2:] += [0.2, 0.0]  # the second group, joined at (1, 2), laid 0.2 m along the tunnel
    turn = math.radians(30.0)
    rotation = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    poses = Poses(xy_m=estimated @ rotation.T + [3.0, -1.0], yaw_rad=np.zeros(4), placed=np.ones(4, bool),
                  reasons=("",) * 4, reference=0, covariance=np.tile(np.eye(3), (4, 1, 1)),
                  group_links=((1, 2),), group_link_radius95_m=(0.1,))
    truth = SimpleNamespace(xy=truth_xy, scans=[SimpleNamespace(station=s) for s in ("a1", "a2", "b1", "b2")])
    (join,) = join_errors(poses, truth)
    assert join["stations"] == ["a2", "b1"]
    assert join["error_m"] == pytest.approx(0.2, abs=0.005)  # the alignment turns the whole a little
    assert join["ci95_m"] == pytest.approx(0.1) and join["error_m"] > join["ci95_m"]
    assert join_errors(None, truth) == []
