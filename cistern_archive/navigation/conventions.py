"""Measure the frame conventions of a moving sonar from its own data: consecutive-scan overlap.

A wrong mirror, beam order, mount angle or clock offset smears the revolutions differently, so the
scans stop agreeing with each other. Placing the echoes of consecutive revolutions ``k`` and ``k+1`` in
the map by dead reckoning (each echo at the pose of its own beam time, or all at the revolution's mid
time), the fraction of echoes of ``k+1`` within ``radius_m`` of an echo of ``k`` measures that
agreement. It uses no ground truth, and a constant compass offset does not change it (it turns the
whole dead-reckoned track rigidly), so it fixes the sonar's frame relative to the DVL's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cistern_archive.navigation.motion import body_points, transform_points
from cistern_archive.navigation.track import Track
from cistern_archive.sonar import marina
from cistern_archive.sonar.readers.pcd import cloud_beams


@dataclass(frozen=True)
class Convention:
    """One hypothesis of the cloud's frame and timing (defaults: the measured ones)."""

    mirrored: bool = marina.PCD_MIRRORED
    first_beam_deg: float = marina.PCD_FIRST_BEAM_DEG
    clockwise: bool = False
    mount_deg: float = marina.SONAR_MOUNT_DEG
    clock_offset_s: float = marina.SONAR_CLOCK_OFFSET_S
    per_beam_time: bool = True


@dataclass(frozen=True, eq=False)
class Revolution:
    """Raw cloud points of one revolution with its 200 beam times (sonar clock)."""

    points: np.ndarray
    beam_times_s: np.ndarray


def place_revolution(rev: Revolution, track: Track, conv: Convention) -> np.ndarray:
    """Map-frame positions of the revolution's points under convention ``conv``."""
    beam, angle, ranges = cloud_beams(rev.points, mirrored=conv.mirrored, first_beam_deg=conv.first_beam_deg,
                                      clockwise=conv.clockwise)
    times = rev.beam_times_s[beam] if conv.per_beam_time else np.full(len(beam), rev.beam_times_s.mean())
    points = body_points(angle + math.radians(conv.mount_deg), ranges)
    return transform_points(track.pose_at(times + conv.clock_offset_s), points)


def consecutive_overlap(revolutions: dict[int, Revolution], track: Track, conv: Convention, *,
                        radius_m: float = 0.4, gap: int = 1) -> float:
    """Mean over key frames ``k`` with ``k+gap`` present of the overlap fraction (module docstring).

    ``gap`` > 1 compares revolutions farther apart: a wrong mount angle ``e`` misplaces the echoes of
    two revolutions seen from positions ``d`` apart by about ``e * d`` relative to each other, so a
    longer baseline measures the mount more sharply (dead reckoning must still hold over it).
    """
    scores = []
    for k in sorted(revolutions):
        if k + gap not in revolutions:
            continue
        a = place_revolution(revolutions[k], track, conv)
        b = place_revolution(revolutions[k + gap], track, conv)
        distance, _ = cKDTree(a).query(b, distance_upper_bound=radius_m)
        scores.append(float(np.mean(distance < radius_m)))
    if not scores:
        raise ValueError("no two consecutive revolutions to compare")
    return float(np.mean(scores))


def best_of(revolutions: dict[int, Revolution], track: Track, candidates: list[Convention], *,
            radius_m: float = 0.4, gap: int = 1) -> tuple[Convention, list[tuple[Convention, float]]]:
    """The candidate with the highest :func:`consecutive_overlap`, and every candidate's score."""
    scored = [(c, consecutive_overlap(revolutions, track, c, radius_m=radius_m, gap=gap)) for c in candidates]
    best = max(scored, key=lambda cs: cs[1])[0]
    return best, scored


def peak_of(values: list[float], scores: list[float]) -> float:
    """The maximum of a score sampled on an evenly spaced grid, refined by the parabola through the
    best sample and its two neighbours (the best sample itself when it lies on the grid's edge or the
    three are not concave)."""
    k = int(np.argmax(scores))
    if k == 0 or k == len(values) - 1:
        return float(values[k])
    left, mid, right = scores[k - 1], scores[k], scores[k + 1]
    curvature = left - 2.0 * mid + right
    if curvature >= 0:
        return float(values[k])
    step = 0.5 * (values[k + 1] - values[k - 1])
    return float(values[k] + 0.5 * step * (left - right) / curvature)
