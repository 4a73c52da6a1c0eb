"""Dead reckoning, motion compensation, clock alignment, calibration, accuracy and the nav-graph localizer
on small synthetic inputs with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cistern_archive.navigation.accuracy import evaluate_track, rigid_errors, start_aligned_errors
from cistern_archive.navigation.calibration import fit_start_calibration
from cistern_archive.navigation.conventions import Convention, Revolution, best_of, peak_of
from cistern_archive.navigation.correction import corrected_positions
from cistern_archive.navigation.motion import compensate, inverse_transform_points, scan_echoes
from cistern_archive.navigation.track import dead_reckon, se2_between
from cistern_archive.pipeline.contracts import MatchGuess, MatchResult
from cistern_archive.sonar.interchange import read_scan, write_scan
from cistern_archive.core.scan import RangeScan, Scan


def _straight(speed=1.0, yaw=math.pi / 2, seconds=10.0, port=0.0):
    t = np.arange(0.0, seconds + 1e-9, 0.5)
    ht = np.arange(0.0, seconds + 1e-9, 0.1)
    return dead_reckon(t, np.column_stack([np.full(len(t), speed), np.full(len(t), port)]), ht, np.full(len(ht), yaw))


def test_dead_reckoning_integrates_body_velocity_in_the_map_frame():
    north = _straight()
    np.testing.assert_allclose(north.xy_m[-1], [0.0, 10.0], atol=1e-9)
    assert north.distance_m[-1] == pytest.approx(10.0)
    port = _straight(speed=0.0, port=1.0, yaw=0.0)  # facing east, moving to port = north
    np.testing.assert_allclose(port.xy_m[-1], [0.0, 10.0], atol=1e-9)
    t = np.array([0.0, 10.0])
    scaled = dead_reckon(t, np.array([[1.0, 0.0], [1.0, 0.0]]), t, np.zeros(2), scale=0.5,
                         yaw_offset_rad=math.pi / 2)
    np.testing.assert_allclose(scaled.xy_m[-1], [0.0, 5.0], atol=1e-9)


def test_dead_reckoning_refuses_too_little_data():
    with pytest.raises(ValueError, match="two velocity"):
        dead_reckon(np.array([0.0]), np.zeros((1, 2)), np.array([0.0, 1.0]), np.zeros(2))
    with pytest.raises(ValueError, match="no heading samples inside"):
        dead_reckon(np.array([0.0, 1.0]), np.zeros((2, 2)), np.array([5.0, 6.0]), np.zeros(2))


def test_relative_pose_and_its_covariance_grow_with_distance():
    track = _straight()
    delta, cov = track.relative(2.0, 4.0)
    np.testing.assert_allclose(delta, [2.0, 0.0, 0.0], atol=1e-9)  # 2 m straight ahead in the body frame
    _, cov_far = track.relative(2.0, 8.0)
    assert cov_far[0, 0] > cov[0, 0] and cov_far[1, 1] > cov[1, 1]
    noise = track.noise
    assert cov[1, 1] == pytest.approx(noise.sigma_v_mps ** 2 * noise.ping_interval_s * 2.0
                                      + (noise.sigma_heading_rad * 2.0) ** 2 + 1e-6)


def test_motion_compensation_puts_a_fixed_point_in_one_place():
    t = np.linspace(0.0, 10.0, 11)
    track = dead_reckon(t, np.column_stack([np.ones(11), np.zeros(11)]), t, np.linspace(0.0, 0.5, 11))
    world = np.array([10.0, 5.0])
    times = np.array([1.0, 3.0, 7.0, 9.5])
    body = np.array([inverse_transform_points(track.pose_at(tt), world[None])[0] for tt in times])
    assert np.ptp(body, axis=0).max() > 1.0  # seen from the moving body the point wanders
    compensated = compensate(body, times, track, 5.0)
    expected = inverse_transform_points(track.pose_at(5.0), world[None])[0]
    np.testing.assert_allclose(compensated, np.tile(expected, (4, 1)), atol=1e-9)
    shifted = compensate(body, times - 0.5, track, 4.5, clock_offset_s=0.5)  # a sonar clock 0.5 s behind
    np.testing.assert_allclose(shifted, compensated, atol=1e-9)


def _scan(grid: np.ndarray, times: np.ndarray | None = None) -> Scan:
    return Scan(bearings_rad=np.linspace(0.0, 1.0, grid.shape[0]), intensities=grid, full_scale=1.0, bin_size_m=0.1,
                beam_times_s=times)


def test_scan_echoes_keeps_every_separate_return_of_a_beam():
    grid = np.zeros((2, 20), dtype=np.uint8)
    grid[0, 3:6] = 1   # one run
    grid[0, 12] = 1    # a second echo behind it
    grid[1, 5] = grid[1, 7] = 1  # two bins one empty bin apart: one echo
    beam, ranges = scan_echoes(_scan(grid))
    np.testing.assert_array_equal(beam, [0, 0, 1])
    np.testing.assert_allclose(ranges, [0.35, 1.25, 0.55])
    _, centres = scan_echoes(_scan(grid), position="centre")
    np.testing.assert_allclose(centres, [0.45, 1.25, 0.65])
    assert len(scan_echoes(_scan(grid), position="bins")[0]) == 6
    assert len(scan_echoes(_scan(grid), min_range_m=1.0)[0]) == 1


def test_interchange_v2_round_trips_beam_times_and_v1_stays_v1(tmp_path):
    grid = np.zeros((3, 4), dtype=np.uint8)
    moving = _scan(grid, np.array([10.0, 10.068, 10.136]))
    back = read_scan(write_scan(moving, tmp_path / "m.npz"))
    np.testing.assert_array_equal(back.beam_times_s, moving.beam_times_s)
    still = read_scan(write_scan(_scan(grid), tmp_path / "s.npz"))
    assert still.beam_times_s is None
    with np.load(tmp_path / "s.npz") as data:
        assert b'"schema_version": 1' in data["metadata"].tobytes() and "beam_times_s" not in data.files
    with pytest.raises(ValueError, match="one time per beam"):
        _scan(grid, np.array([1.0, 2.0]))


def test_interchange_refuses_version_2_without_beam_times(tmp_path):
    import json
    import zipfile

    path = write_scan(_scan(np.zeros((3, 4), dtype=np.uint8)), tmp_path / "s.npz")
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with np.load(path) as data:
        meta = json.loads(data["metadata"].tobytes())
    meta["schema_version"] = 2
    buffer = __import__("io").BytesIO()
    np.lib.format.write_array(buffer, np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
    members["metadata.npy"] = buffer.getvalue()
    with zipfile.ZipFile(path, "w") as archive:
        for name, blob in members.items():
            archive.writestr(name, blob)
    from cistern_archive.core.errors import ReaderError

    with pytest.raises(ReaderError, match="version 2 needs the array beam_times_s"):
        read_scan(path)


def _synthetic_revolutions(true_offset_s: float):
    """Revolutions of a mirrored, CCW-turning sonar (PCD conventions) moving past four walls."""
    t = np.linspace(0.0, 60.0, 601)
    track = dead_reckon(t, np.column_stack([0.3 + 0.2 * np.sin(t / 3.0), np.zeros(601)]), t, 0.8 * np.sin(t / 4.0))
    s = np.linspace(-20.0, 20.0, 801)
    walls = np.concatenate([np.column_stack([s, np.full_like(s, 12.0)]), np.column_stack([s, np.full_like(s, -9.0)]),
                            np.column_stack([np.full_like(s, 22.0), s]), np.column_stack([np.full_like(s, -15.0), s])])
    step = 2 * math.pi / 200
    revolutions = {}
    for k in range(4):
        times = 5.0 + k * 13.6 + np.arange(200) * 0.068
        points = []
        for j, tt in enumerate(times):
            body = inverse_transform_points(track.pose_at(tt + true_offset_s), walls)
            angle = np.arctan2(body[:, 1], body[:, 0])
            hit = np.abs((angle - j * step + math.pi) % (2 * math.pi) - math.pi) < step / 2
            r = np.hypot(body[hit, 0], body[hit, 1])
            if len(r):
                nearest = np.argmin(r)
                phi = angle[hit][nearest]
                points.append((r[nearest] * math.cos(-phi), r[nearest] * math.sin(-phi)))  # mirrored cloud
        revolutions[k] = Revolution(np.array(points), times)
    return track, revolutions


def test_clock_offset_and_mirror_are_recovered_from_consecutive_overlap():
    track, revolutions = _synthetic_revolutions(true_offset_s=1.0)
    candidates = [Convention(clock_offset_s=o, mount_deg=0.0) for o in (-1.0, 0.0, 1.0, 2.0)]
    best, scored = best_of(revolutions, track, candidates, radius_m=0.2)
    assert best.clock_offset_s == 1.0, scored
    mirror, _ = best_of(revolutions, track, [Convention(mirrored=m, mount_deg=0.0, clock_offset_s=1.0)
                                             for m in (False, True)], radius_m=0.2)
    assert mirror.mirrored


def test_mount_is_recovered_from_the_overlap_of_revolutions_apart():
    track, revolutions = _synthetic_revolutions(true_offset_s=1.0)
    offsets = [-12.0, -6.0, 0.0, 6.0, 12.0]
    candidates = [Convention(clock_offset_s=1.0, mount_deg=o) for o in offsets]
    _, scored = best_of(revolutions, track, candidates, radius_m=0.2, gap=2)
    assert abs(peak_of(offsets, [score for _, score in scored])) < 3.0, scored


def test_peak_of_refines_between_samples_and_keeps_an_edge():
    xs = [-4.0, -2.0, 0.0, 2.0, 4.0]
    assert peak_of(xs, [-(x - 0.7) ** 2 for x in xs]) == pytest.approx(0.7)
    assert peak_of(xs, [1.0, 2.0, 3.0, 4.0, 5.0]) == 4.0
    assert peak_of(xs, [0.0, 1.0, 1.0, 0.5, 0.0]) == pytest.approx(-1.0)  # between two equal best samples


def test_start_calibration_recovers_offset_and_scale():
    t = np.linspace(0.0, 400.0, 4001)
    yaw = 0.3 * np.sin(t / 40.0)
    raw = dead_reckon(t, np.column_stack([np.full(len(t), 0.2), np.zeros(len(t))]), t, yaw)
    true = dead_reckon(t, np.column_stack([np.full(len(t), 0.2), np.zeros(len(t))]), t, yaw, scale=0.95,
                       yaw_offset_rad=math.radians(20.0), start_xy=(5.0, 7.0))
    fixes = np.arange(0.0, 400.0, 1.0)
    calibration = fit_start_calibration(raw, fixes, true.pose_at(fixes)[:, :2], window_s=300.0)
    assert calibration.scale == pytest.approx(0.95, abs=1e-3)
    assert math.degrees(calibration.yaw_offset_rad) == pytest.approx(20.0, abs=0.05)
    assert calibration.as_dict()["compass_offset_deg"] == pytest.approx(-20.0, abs=0.05)
    with pytest.raises(ValueError, match="two DGPS fixes"):
        fit_start_calibration(raw, np.array([1000.0]), np.zeros((1, 2)))


def test_errors_start_aligned_and_rigid():
    truth = np.column_stack([np.arange(10.0), np.zeros(10)])
    shifted = truth + [3.0, -2.0]
    np.testing.assert_allclose(start_aligned_errors(shifted, truth), 0.0, atol=1e-12)
    c, s = math.cos(0.2), math.sin(0.2)
    rotated = truth @ np.array([[c, s], [-s, c]]) + [1.0, 1.0]
    assert start_aligned_errors(rotated, truth).max() > 1.0
    np.testing.assert_allclose(rigid_errors(rotated, truth), 0.0, atol=1e-9)
    result = evaluate_track(lambda times: np.column_stack([times, np.zeros_like(times)]) + 0.5,
                            np.arange(10.0), truth, start=2.0, end=5.0)
    assert result["start_aligned"].fixes == 4 and result["start_aligned"].max_m == pytest.approx(0.0, abs=1e-12)


def test_fixes_of_the_calibration_window_are_drawn_but_not_counted():
    """The window's fixes are not independent of a calibrated estimate: the summaries and the rigid fit
    count the fixes after it only, still aligned on the fix where the track starts."""
    times = np.arange(10.0)
    truth = np.column_stack([times, np.zeros(10)])
    drifting = np.column_stack([times, 0.1 * times])  # 0.1 m off per second, none at the start
    result = evaluate_track(lambda t: np.column_stack([t, 0.1 * t]), times, truth, start=0.0, end=9.0,
                            evaluated_from=3.0)
    np.testing.assert_array_equal(result["evaluated"], times > 3.0)
    np.testing.assert_allclose(result["start_aligned_errors"], 0.1 * times)
    assert result["start_aligned"].fixes == 6
    assert result["start_aligned"].mean_m == pytest.approx(0.1 * times[4:].mean())
    fitted_after = rigid_errors(drifting[4:], truth[4:])
    np.testing.assert_allclose(result["rigid_errors"][4:], fitted_after, atol=1e-9)
    assert result["rigid"].max_m == pytest.approx(fitted_after.max(), abs=1e-9)
    with pytest.raises(ValueError, match="after the calibration window"):
        evaluate_track(lambda t: np.column_stack([t, 0.1 * t]), times, truth, start=0.0, end=9.0, evaluated_from=9.0)


def test_corrected_track_follows_the_solved_poses():
    track = _straight()  # north, 1 m/s
    node_times = np.array([2.0, 8.0])
    solved = np.array([track.pose_at(2.0) + [1.0, 0.0, 0.0], track.pose_at(8.0) + [3.0, 0.0, 0.0]])
    positions = corrected_positions(track, node_times, solved, np.array([2.0, 5.0, 8.0, 9.0]))
    np.testing.assert_allclose(positions, [[1.0, 2.0], [2.0, 5.0], [3.0, 8.0], [3.0, 9.0]], atol=1e-9)


def _nav_scans(odometry: np.ndarray) -> list[RangeScan]:
    return [RangeScan(bearings_rad=np.zeros(1), ranges_m=np.ones(1), yaw_rad=float(o[2]), depth_m=0.0, max_range_m=50.0,
                      bin_size_m=0.1, beam_width_rad=0.05, station=f"s{k}", time_s=10.0 * k, odometry=o)
            for k, o in enumerate(odometry)]


def test_nav_graph_pulls_drifting_odometry_onto_a_loop_closure():
    from cistern_plugins.nav_graph import NavGraphLocalizer, NavGraphParams, solve, calibration_of

    truth = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.0, 0.5]])
    odometry = np.column_stack([truth * 1.1, np.zeros(5)])  # DVL reads 10 % long
    scans = _nav_scans(odometry)
    loop = MatchResult(i=0, j=2, dx_m=10.0, dy_m=10.0, dyaw_rad=0.0, weight=1.0, converged=True, iterations=1,
                       seconds=0.0, covariance=np.diag([0.01, 0.01, 1e-4]))
    localizer = NavGraphLocalizer()
    params = NavGraphParams(scale_sigma=0.2, min_match_sigma_m=0.05)
    poses = localizer.localize(scans, [loop], params)
    assert poses.placed.all() and poses.reference == 0
    assert np.linalg.norm(poses.xy_m[2] - truth[2]) < 0.3 < np.linalg.norm(odometry[2, :2] - truth[2])
    _, values, kept, _ = solve(scans, [loop], params)
    assert len(kept) == 1 and calibration_of(values)["dvl_scale"] < 0.97
    assert localizer.pairs(5, NavGraphParams()) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    guided = localizer.guided_pairs(scans, [], NavGraphParams(loop_min_gap=3, loop_radius_m=5.0))
    assert [(i, j) for i, j, _ in guided] == [(0, 4)]
    assert isinstance(guided[0][2], MatchGuess) and guided[0][2].dy_m == pytest.approx(0.55, abs=1e-6)


def test_nav_graph_proposes_revisits_from_the_corrected_solution():
    """Later rounds look for revisits around the solution of the matches so far, not the odometry's."""
    from cistern_plugins.nav_graph import NavGraphLocalizer, NavGraphParams

    east = [[2.0 * k, 0.0] for k in range(10)]
    truth = np.array(east + [[18.0 - 2.0 * k, 0.5] for k in range(10)])  # out and back, 0.5 m apart
    odometry = np.column_stack([truth + np.array([[0.0, 0.4 * max(0, k - 9)] for k in range(20)]), np.zeros(20)])
    scans = _nav_scans(odometry)  # the way back drifts north by 0.4 m per scan
    params = NavGraphParams(loop_min_gap=2, loop_per_scan=1, loop_radius_m=3.0, revisit_gap=6, revisit_tries=2,
                            revisit_per_scan=1,
                            min_match_sigma_m=0.01, sigma_v_mps=0.3)
    localizer = NavGraphLocalizer()
    first = localizer.guided_pairs(scans, [], params)
    assert first and all(j - i >= 2 for i, j, _ in first)
    along = [MatchResult(i=i, j=j, dx_m=float(truth[j, 0] - truth[i, 0]), dy_m=float(truth[j, 1] - truth[i, 1]),
                         dyaw_rad=0.0, weight=1.0, converged=True, iterations=1, seconds=0.0,
                         covariance=np.diag([1e-4, 1e-4, 1e-6])) for i, j in [(q, q + 2) for q in range(18)]]
    asked = localizer.guided_pairs(scans, along, params)
    revisits = [(i, j, guess) for i, j, guess in asked if j - i >= 6]
    assert revisits and all((i, j) not in {(m.i, m.j) for m in along} for i, j, _ in revisits)
    far_end = [(i, j) for i, j, _ in revisits if j >= 16]
    assert far_end and all(abs((19 - j) - i) <= 1 for i, j in far_end)  # the same place, found despite the drift
    closed = [MatchResult(i=i, j=j, dx_m=0.0, dy_m=0.5, dyaw_rad=0.0, weight=1.0, converged=True, iterations=1,
                          seconds=0.0) for i, j, _ in revisits]
    again = localizer.guided_pairs(scans, along + closed, params)
    assert not {j for i, j, _ in again if j - i >= 6 and (i, j) not in {(m.i, m.j) for m in closed}} & {j for _, j in far_end}
    nearest_only = localizer.guided_pairs(scans, along, params.model_copy(update={"revisit_per_scan": 0}))
    assert len({j for _, j, _ in nearest_only}) == len(nearest_only) < len(asked)  # loop_per_scan 1, no revisits


def test_nav_graph_gate_drops_a_wrong_loop_and_needs_odometry():
    from cistern_plugins.nav_graph import NavGraphLocalizer, NavGraphParams, solve

    truth = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [15.0, 0.0]])
    scans = _nav_scans(np.column_stack([truth, np.zeros(4)]))
    wrong = MatchResult(i=0, j=3, dx_m=5.0, dy_m=8.0, dyaw_rad=0.0, weight=1.0, converged=True, iterations=1,
                        seconds=0.0, covariance=np.diag([0.01, 0.01, 1e-4]))
    _, values, kept, _ = solve(scans, [wrong], NavGraphParams())
    assert kept == [] and values.atPose2(3).x() == pytest.approx(15.0, abs=0.05)
    bare = [RangeScan(bearings_rad=np.zeros(1), ranges_m=np.ones(1), yaw_rad=0.0, depth_m=0.0, max_range_m=50.0,
                      bin_size_m=0.1, beam_width_rad=0.05) for _ in range(2)]
    poses = NavGraphLocalizer().localize(bare, [], NavGraphParams())
    assert not poses.placed.any() and "no odometry" in poses.reasons[0]


def test_guided_correlative_finds_the_displacement_around_a_guess():
    from cistern_plugins.guided_correlative import GuidedCorrelativeMatcher, GuidedCorrelativeParams

    rng = np.random.default_rng(1)
    s = np.linspace(-15.0, 15.0, 300)
    world = np.concatenate([np.column_stack([s, np.full_like(s, 8.0)]), np.column_stack([np.full_like(s, 12.0), s]),
                            np.column_stack([s * 0.5 - 5.0, s * 0.3 - 6.0])])
    world = world + rng.normal(0.0, 0.03, world.shape)

    def scan_from(position):
        rel = world - position
        return RangeScan(bearings_rad=np.arctan2(rel[:, 1], rel[:, 0]), ranges_m=np.hypot(rel[:, 0], rel[:, 1]),
                         yaw_rad=0.0, depth_m=0.0, max_range_m=50.0, bin_size_m=0.1, beam_width_rad=0.05)

    reference, moving = scan_from(np.zeros(2)), scan_from(np.array([2.3, -0.8]))
    matcher = GuidedCorrelativeMatcher()
    params = GuidedCorrelativeParams(sigma_m=0.03)  # 0.15 m for these 50 m scans (length unit 5)
    result = matcher.match(reference, moving, params, rng=np.random.default_rng(0),
                           guess=MatchGuess(1.5, 0.0, 0.0, 2.0))
    assert result.converged, result.reason
    assert abs(result.dx_m - 2.3) < 0.1 and abs(result.dy_m + 0.8) < 0.1
    far = matcher.match(reference, moving, params, rng=np.random.default_rng(0), guess=MatchGuess(-3.0, 0.0, 0.0, 1.0))
    assert not far.converged
    empty = RangeScan(bearings_rad=np.zeros(3), ranges_m=np.ones(3), yaw_rad=0.0, depth_m=0.0, max_range_m=50.0,
                      bin_size_m=0.1, beam_width_rad=0.05)
    assert "too few echoes" in matcher.match(reference, empty, params, rng=np.random.default_rng(0)).reason


def test_se2_between_is_the_relative_pose():
    a, b = np.array([1.0, 2.0, math.pi / 2]), np.array([1.0, 5.0, math.pi])
    np.testing.assert_allclose(se2_between(a, b), [3.0, 0.0, math.pi / 2], atol=1e-12)


def test_survey_loader_names_what_is_missing(tmp_path):
    from cistern_archive.core.errors import ReaderError
    from cistern_archive.navigation.survey import load_marina_survey

    with pytest.raises(ReaderError, match=r"no file matching '\*_DVL.log'"):
        load_marina_survey(tmp_path)


def test_compensation_refuses_a_scan_without_beam_times():
    from cistern_archive.navigation.motion import compensated_range_scan

    with pytest.raises(ValueError, match="no per-beam times"):
        compensated_range_scan(_scan(np.zeros((3, 4), dtype=np.uint8)), _straight())


def test_a_compensated_scan_says_its_echoes_were_not_heard_from_the_station():
    from cistern_archive.navigation.motion import compensated_range_scan

    grid = np.zeros((3, 40), dtype=np.uint8)
    grid[:, 20] = 1
    scan, _ = compensated_range_scan(_scan(grid, times=np.array([1.0, 2.0, 3.0])), _straight())
    assert len(scan.ranges_m) == 3 and not scan.rays_from_station  # the free-space tests know nothing of its water
