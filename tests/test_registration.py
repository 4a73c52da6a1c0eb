"""cistern_plugins.registration: the public registration API third-party matchers may use."""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import numpy as np

import cistern_plugins.alignment as alignment
import cistern_plugins.registration as registration
from cistern_archive.grid.polygon import polygon_scan
from cistern_plugins.registration import (
    ConvergenceParams,
    ReferenceModel,
    fit_covariance,
    judge,
    match_confidence,
    refine_point_to_line,
    scan_points,
)

DOCS = Path(__file__).resolve().parents[1] / "docs" / "writing-a-matcher.md"
ROOM = [np.array([[0, 0], [7.2, 0], [7.2, 3.6], [4.0, 3.6], [4.0, 5.0], [2.5, 5.0], [2.5, 3.6], [0, 3.6]], float)]


def test_every_public_name_is_documented_for_matcher_authors():
    text = DOCS.read_text(encoding="utf-8")
    for name in registration.__all__:
        obj = getattr(registration, name)
        assert inspect.getdoc(obj), f"{name} has no docstring"
        assert f"`{name}" in text, f"{name} is not in {DOCS.name}"


def test_the_documented_end_of_a_search_matcher():
    """The snippet of docs/writing-a-matcher.md: refine a pose a few centimetres off, judge it, and
    get the fit's covariance, on two scans of one room with a known offset."""
    rng = np.random.default_rng(0)
    reference = polygon_scan(ROOM, (1.5, 1.8), 0.0, rng=rng, n_beams=200, range_noise_m=0.0)
    moving = polygon_scan(ROOM, (3.1, 2.2), 0.0, rng=rng, n_beams=200, range_noise_m=0.0)
    truth = np.array([1.6, 0.4, 0.0])
    p = ConvergenceParams(calibrated=False)
    model, src = ReferenceModel(reference), scan_points(moving)
    start = truth + [0.05, -0.04, math.radians(0.5)]
    pose = refine_point_to_line(model, src, start, iterations=30, correspondence_m=0.3, trim_fraction=0.8,
                                max_shift_m=0.2)
    assert pose is not None and np.hypot(*(pose[:2] - truth[:2])) < 0.01
    quality = model.assess_pair(moving, pose, p.limits())
    assert judge(quality, p.limits()) == ""
    assert match_confidence(quality, p.limits()) is None  # fixed limits: no calibrated probability
    covariance = fit_covariance(model, src, pose, p.inlier_distance_m, quality.rms_m)
    assert covariance.shape == (3, 3) and np.all(np.linalg.eigvalsh(covariance) > 0)
    far = truth + [1.5, 1.0, 0.0]
    assert "inlier" in judge(model.assess_pair(moving, far, p.limits()), p.limits())
    assert refine_point_to_line(model, src, start, iterations=30, correspondence_m=0.3, trim_fraction=0.8,
                                max_shift_m=0.01) is None  # it would move 6 cm: refused


# A room 4 m square with a tunnel 1 m wide leaving its east wall.
ROOM_AND_TUNNEL = [np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 1.5], [12.0, 1.5], [12.0, 2.5], [4.0, 2.5], [4.0, 4.0],
                             [0.0, 4.0]])]


def test_a_fit_is_not_held_along_a_tunnel_by_walls_that_meet_across_each_other(monkeypatch):
    """A station in the room and one inside the tunnel, 3 m ranges, at their true poses. The tunnel
    station hears the tunnel's two walls, which run along it; their ends at the mouth lie on the room's
    wall beside it, which runs across. Counted as inliers, those points held the fit along the tunnel;
    only walls that run alike count, and the covariance says the tunnel leaves its length loose."""
    rng = np.random.default_rng(4)
    room = polygon_scan(ROOM_AND_TUNNEL, (3.0, 2.0), 0.0, rng=rng, n_beams=400, max_range_m=3.0)
    tunnel = polygon_scan(ROOM_AND_TUNNEL, (6.0, 2.0), 0.0, rng=rng, n_beams=400, max_range_m=3.0)
    model, points, pose = ReferenceModel(room), scan_points(tunnel), np.array([3.0, 0.0, 0.0])
    along, across = np.sqrt(np.diag(fit_covariance(model, points, pose, 0.15, 0.02))[:2])
    monkeypatch.setattr(alignment, "PARALLEL_DEG", 90.0)  # every inlier counted, whatever its wall
    along_all, across_all = np.sqrt(np.diag(fit_covariance(model, points, pose, 0.15, 0.02))[:2])
    assert along > 2 * along_all
    assert abs(across - across_all) < 0.2 * across_all
