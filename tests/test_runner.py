"""The pipeline runner on the bundled pool, and its failure capture."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.pipeline.registry import default_registry
from cistern_archive.pipeline.validate import validate_catalog, validate_record
from cistern_archive.evaluation import align_rigid_2d, position_errors
from cistern_archive.pipeline.runner import build_site, write_site_result


@pytest.fixture(scope="module")
def pool_build(bundled_catalog):
    loaded = validate_record(bundled_catalog / "sites" / "lair-pool.yaml", bundled_catalog)
    return build_site(loaded)


def test_pool_builds_and_places_every_scan_near_truth(pool_build):
    result = pool_build.result
    assert result.status == "ok", result.failure
    assert [s.placed for s in result.scans] == [True] * 4
    errors = position_errors(result)
    assert errors.shape == (4,)
    assert errors.max() < 0.10, errors


def test_rigid_alignment_recovers_a_rotated_translated_copy():
    rng = np.random.default_rng(1)
    points = rng.uniform(-5, 5, (6, 2))
    angle = np.radians(7.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = points @ rotation.T + [1.5, -2.0]
    r, t = align_rigid_2d(points, moved)
    np.testing.assert_allclose(r, rotation, atol=1e-12)
    np.testing.assert_allclose(t, [1.5, -2.0], atol=1e-12)


def test_pool_result_has_the_documented_fields(pool_build, tmp_path):
    path = write_site_result(pool_build, tmp_path)
    data = json.loads(path.read_text())
    for key in ("site_id", "status", "scans", "pairs", "dimensions", "provenance", "timings_s"):
        assert key in data
    assert {"id", "x_m", "y_m", "yaw_rad", "depth_m", "placed"} <= set(data["scans"][0])
    assert {"i", "j", "dx_m", "dy_m", "weight", "converged", "iterations"} <= set(data["pairs"][0])
    assert {"name", "map_m", "reference_m", "reference_kind", "diff_m"} <= set(data["dimensions"][0])
    plugins = {p["stage"]: p for p in data["provenance"]["plugins"]}
    assert plugins["matcher"]["plugin"] == default_registry().default("matcher")
    assert plugins["matcher"]["distribution"] == "cistern-plugins"
    assert plugins["matcher"]["params"]  # every parameter, defaults included
    assert data["provenance"]["seeds"]["site"] == pool_build.record.seed
    assert set(data["timings_s"]) >= {"load", "segment", "match", "localize", "map", "compare", "total"}
    assert (tmp_path / "record.json").is_file()
    widths = [d for d in data["dimensions"] if d["name"] == "width" and d["reference_kind"] == "truth"]
    assert abs(widths[0]["diff_m"]) < 0.15


def test_the_same_record_builds_the_same_result(pool_build, bundled_catalog):
    loaded = validate_record(bundled_catalog / "sites" / "lair-pool.yaml", bundled_catalog)
    again = build_site(loaded).result
    strip = lambda r: r.model_dump(exclude={"timings_s", "pairs"})  # noqa: E731  (times differ)
    assert strip(again) == strip(pool_build.result)
    assert [(p.dx_m, p.dy_m, p.converged) for p in again.pairs] == [
        (p.dx_m, p.dy_m, p.converged) for p in pool_build.result.pairs
    ]


def copy_pool(bundled_catalog: Path, root: Path) -> Path:
    shutil.copytree(bundled_catalog / "data" / "lair-pool", root / "data" / "lair-pool")
    (root / "sites").mkdir(parents=True)
    shutil.copy(bundled_catalog / "sites" / "lair-pool.yaml", root / "sites" / "lair-pool.yaml")
    (root / "specs").mkdir()
    shutil.copy(bundled_catalog / "specs" / "lair-pool.yaml", root / "specs" / "lair-pool.yaml")
    return root / "sites" / "lair-pool.yaml"


def test_a_corrupt_scan_fails_its_site_with_stage_and_input(bundled_catalog, tmp_path):
    record_path = copy_pool(bundled_catalog, tmp_path)
    (tmp_path / "data" / "lair-pool" / "s3.npz").write_bytes(b"PK\x03\x04 this is not a zip")
    loaded = validate_record(record_path, tmp_path)
    result = build_site(loaded).result
    assert result.status == "failed"
    assert result.failure.stage == "load"
    assert result.failure.input == "data/lair-pool/s3.npz"
    assert "s3.npz" in result.failure.error
    assert [s.placed for s in result.scans] == [False] * 4


def test_validate_finds_the_bundled_catalog_clean(bundled_catalog):
    report = validate_catalog(bundled_catalog)
    assert report.ok, report.problems
    assert {r.record.id for r in report.records} >= {"lair-pool"}


def test_guided_round_passes_guesses_to_matchers_that_take_them(bundled_catalog, tmp_path):
    """``match_rounds``: the localizer's pairs, then its guided pairs, round after round until it asks for
    no new pair (a pair asked for again is not matched twice); the guess reaches a matcher that declares
    ``GuidedMatcher`` and is recorded on the result; any other matcher is matched globally."""
    from cistern_archive.pipeline.contracts import GuidedLocalizer, GuidedMatcher, MatchGuess, MatchResult
    from cistern_archive.pipeline.runner import Stage, match_pair, match_rounds
    from cistern_plugins.pf_pairwise import PFPairwiseMatcher
    from cistern_plugins.wls import WLSLocalizer
    from tests.stage_plugins import CompassOnlyMatcher

    seen = []
    rounds = []

    class Localizer(WLSLocalizer, GuidedLocalizer):
        def pairs(self, n, params):
            return [(0, 1)]

        def guided_pairs(self, scans, matches, params, *, ties=()):
            rounds.append([(m.i, m.j) for m in matches])
            return [(0, 2, MatchGuess(1.0, 2.0, 0.1, 0.5)), (1, 2, None)]

    class GuessingMatcher(CompassOnlyMatcher, GuidedMatcher):
        def match(self, reference, moving, params, *, rng, guess=None):
            seen.append(guess)
            return super().match(reference, moving, params, rng=rng)

    guided = Stage.of("matcher", GuessingMatcher())
    assert guided.plugin.has(GuidedMatcher)
    assert Stage.of("matcher", PFPairwiseMatcher()).plugin.has(GuidedMatcher)  # structurally: match takes guess
    assert not Stage.of("matcher", CompassOnlyMatcher()).plugin.has(GuidedMatcher)
    localizer = Stage.of("localizer", Localizer())
    assert localizer.plugin.has(GuidedLocalizer)
    assert not Stage.of("localizer", WLSLocalizer()).plugin.has(GuidedLocalizer)
    scans = pool_scans(bundled_catalog)
    for matcher, expect in ((guided, MatchGuess(1.0, 2.0, 0.1, 0.5)), (Stage.of("matcher", CompassOnlyMatcher()), None)):
        seen.clear()
        rounds.clear()
        matches = match_rounds(scans, localizer, lambda i, j, g: match_pair(matcher, scans, 1, i, j, g))
        assert [(m.i, m.j) for m in matches] == [(0, 1), (0, 2), (1, 2)]
        assert rounds == [[(0, 1)], [(0, 1), (0, 2), (1, 2)]]  # the third round asked for nothing new
        assert all(isinstance(m, MatchResult) for m in matches)
        assert matches[1].guess == expect and matches[2].guess is None
        assert seen == ([None, expect, None] if expect else [])
    plain = match_rounds(scans, Stage.of("localizer", WLSLocalizer()), lambda i, j, g: match_pair(
        guided, scans, 1, i, j, g))
    assert [(m.i, m.j) for m in plain] == WLSLocalizer().pairs(len(scans), WLSLocalizer.Params())


def pool_scans(catalog: Path):
    from cistern_archive.pipeline.runner import range_scans

    return range_scans(validate_record(catalog / "sites" / "lair-pool.yaml", catalog))


def test_a_pair_matched_globally_is_matched_again_when_asked_with_a_guess(bundled_catalog):
    """``match_rounds``: a pair matched globally is matched once more when asked with a guess, and never
    again after that, whatever guess it is asked with."""
    from cistern_archive.pipeline.contracts import GuidedLocalizer, GuidedMatcher, MatchGuess
    from cistern_archive.pipeline.runner import Stage, match_pair, match_rounds
    from cistern_plugins.wls import WLSLocalizer
    from tests.stage_plugins import CompassOnlyMatcher

    guess = MatchGuess(1.0, 2.0, 0.1, 0.5)

    class Localizer(WLSLocalizer, GuidedLocalizer):
        def pairs(self, n, params):
            return [(0, 1)]

        def guided_pairs(self, scans, matches, params, *, ties=()):
            return [(0, 1, None), (0, 1, guess), (0, 1, MatchGuess(1.1, 2.0, 0.1, 0.5))]

    class GuessingMatcher(CompassOnlyMatcher, GuidedMatcher):
        def match(self, reference, moving, params, *, rng, guess=None):
            return super().match(reference, moving, params, rng=rng)

    scans = pool_scans(bundled_catalog)
    matcher = Stage.of("matcher", GuessingMatcher())
    matches = match_rounds(scans, Stage.of("localizer", Localizer()), lambda i, j, g: match_pair(matcher, scans, 1, i, j, g))
    assert [(m.i, m.j, m.guess) for m in matches] == [(0, 1, None), (0, 1, guess)]


def echo_scale_run(pool_build, bundled_catalog, scale):
    """A run of the pool's localize step whose mapper tells every scan's echoes fall short by ``scale``."""
    import dataclasses

    from cistern_archive.pipeline.runner import SiteRun, Stage, resolve_stages
    from cistern_plugins.evidence_grid import EvidenceGridMapper

    class ShortEchoMapper(EvidenceGridMapper):
        def echo_scale(self, scans, poses, params):
            return np.full(len(scans), scale)

    loaded = validate_record(bundled_catalog / "sites" / "lair-pool.yaml", bundled_catalog)
    stages = resolve_stages(loaded.record, default_registry()) | {"mapper": Stage.of("mapper", ShortEchoMapper())}
    build = dataclasses.replace(pool_build, matches=list(pool_build.matches), poses=None, echo_scale=None)
    return SiteRun(loaded=loaded, registry=default_registry(), build=build, stages=stages)


def test_matches_are_lengthened_by_the_echo_scale_the_mapper_tells(pool_build, bundled_catalog):
    """``localize_step``: a mapper that tells the placed scans' echoes fall short by 2 % (an
    ``EchoScaleMapper``) has every match lengthened by 1 / 0.98 and the scans placed again from them; the
    pool, at one depth, is built without it (the evidence-grid mapper reads no lean there)."""
    from cistern_archive.pipeline.runner import localize_step

    assert pool_build.echo_scale is None and all(s.echo_scale is None for s in pool_build.result.scans)
    run = echo_scale_run(pool_build, bundled_catalog, 0.98)
    localize_step(run)
    lengthened = [(m.dx_m / 0.98, m.dy_m / 0.98) for m in pool_build.matches]
    np.testing.assert_allclose([(m.dx_m, m.dy_m) for m in run.build.matches], lengthened)
    np.testing.assert_allclose(run.build.echo_scale, 0.98)
    before, after = pool_build.poses, run.build.poses
    assert after.placed.all()
    ref = before.reference
    np.testing.assert_allclose(after.xy_m - after.xy_m[ref], (before.xy_m - before.xy_m[ref]) / 0.98, atol=0.01)


def test_an_echo_scale_that_is_not_a_share_fails_the_map_stage(pool_build, bundled_catalog):
    from cistern_archive.core.errors import StageError
    from cistern_archive.pipeline.runner import localize_step

    with pytest.raises(StageError, match="echo scale must be finite") as caught:
        localize_step(echo_scale_run(pool_build, bundled_catalog, float("nan")))
    assert caught.value.stage == "map"
