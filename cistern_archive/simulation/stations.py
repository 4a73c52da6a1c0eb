"""Where a simulated vehicle scans: explicit stations and stations planned along routes.

A route's stations are placed along a polyline so that consecutive stations share at least the route's
``overlap`` of what they see (:func:`cistern_archive.sonar.geometry.overlap_fraction`) and are at most
``max_spacing_m`` apart along it. Yaws follow the route (or a fixed heading) with seeded jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.sonar.geometry import contains, interpolate_slice, overlap_fraction
from cistern_archive.core.scan import wrap_angle
from cistern_archive.simulation.spec import RouteSpec, SimulationSpec


@dataclass(frozen=True)
class TruePose:
    """Where a scan really was: map-frame position (m), yaw (rad, CCW from east), depth (m)."""

    station: str
    x_m: float
    y_m: float
    yaw_rad: float
    depth_m: float


def station_rng(seed: int, purpose: int, index: int) -> np.random.Generator:
    """The generator for one purpose (0 route planning, 1 scans, 2 references) and index."""
    return np.random.default_rng([int(seed), int(purpose), int(index)])


def _route_yaw(route: RouteSpec, heading: float, rng: np.random.Generator) -> float:
    base = heading if route.yaw == "along" else math.radians(route.yaw_deg)
    return float(wrap_angle(base + math.radians(route.yaw_jitter_deg) * rng.standard_normal()))


def _polyline_points(waypoints: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a polyline (ends included) and the heading at each."""
    seg = np.diff(waypoints, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    s = np.arange(0.0, cumulative[-1], step)
    s = np.append(s, cumulative[-1]) if cumulative[-1] - s[-1] > 1e-9 else s
    idx = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(seg) - 1)
    t = (s - cumulative[idx]) / np.where(lengths[idx] > 0, lengths[idx], 1.0)
    points = waypoints[idx] + t[:, None] * seg[idx]
    # math.atan2 (the C library's, correctly rounded) rather than numpy's, whose vectorised kernels differ
    # in the last bit between CPUs (AVX-512 or not): a station's heading is written into its scan file.
    headings = np.array([math.atan2(dy, dx) for dx, dy in seg[idx]], dtype=np.float64)
    return points, headings


def plan_route(route: RouteSpec, spec: SimulationSpec, rng: np.random.Generator) -> list[TruePose]:
    """Stations along ``route``: each the farthest route point (within ``max_spacing_m`` along the route)
    whose overlap with the previous station is still at least ``route.overlap`` (see :class:`RouteSpec`).
    """
    points, headings = _polyline_points(np.asarray(route.waypoints, dtype=np.float64), route.step_m)
    max_hop = len(points) if route.max_spacing_m is None else max(1, int(route.max_spacing_m / route.step_m + 1e-9))
    poses: list[TruePose] = []
    for level, depth in enumerate(route.depths):
        rings = interpolate_slice(spec.site.slices(), depth)
        inside = contains(rings, points)
        if not inside.all():
            bad = points[~inside][0]
            raise ValueError(f"route of {spec.id!r} leaves the water at depth {depth} m near {bad.tolist()}")
        chosen = [0]
        while chosen[-1] < len(points) - 1:
            last = chosen[-1]
            nxt = last + 1
            while nxt + 1 < len(points) and nxt + 1 - last <= max_hop and overlap_fraction(
                points[last], points[nxt + 1], rings, spec.sonar.range_m
            ) >= route.overlap:
                nxt += 1
            chosen.append(nxt)
        for k, index in enumerate(chosen):
            name = f"{route.prefix}{k + 1:02d}" if len(route.depths) == 1 else f"{route.prefix}{level + 1}-{k + 1:02d}"
            poses.append(TruePose(name, float(points[index, 0]), float(points[index, 1]),
                                  _route_yaw(route, float(headings[index]), rng), float(depth)))
    return poses


def station_poses(spec: SimulationSpec) -> list[TruePose]:
    """Explicit stations first, then every route's stations, in order; names must be unique."""
    poses = [TruePose(s.name, s.x_m, s.y_m, math.radians(s.yaw_deg), s.depth_m) for s in spec.stations]
    for k, route in enumerate(spec.routes):
        poses.extend(plan_route(route, spec, station_rng(spec.seed, 0, k)))
    names = [p.station for p in poses]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"spec {spec.id!r}: station names {duplicates} appear twice")
    slices = spec.site.slices()
    for pose in poses:
        rings = interpolate_slice(slices, pose.depth_m)
        if not contains(rings, np.array([[pose.x_m, pose.y_m]]))[0]:
            raise ValueError(f"spec {spec.id!r}: station {pose.station!r} is not in the water")
    return poses
