"""Site records: schema, file:line errors, referenced files and plugin checks."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from catalog_helpers import RECORD, write_catalog
from cistern_archive.catalog.loader import load_record
from cistern_archive.catalog.models import SiteRecord
from cistern_archive.pipeline.registry import default_registry
from cistern_archive.pipeline.validate import validate_catalog
from cistern_archive.core.errors import CatalogError


def problems_for(tmp_path: Path, text: str) -> list[str]:
    write_catalog(tmp_path, text)
    report = validate_catalog(tmp_path)
    assert not report.ok
    return report.problems


def assert_problem(problems: list[str], path_name: str, line: int, field: str, message: str) -> None:
    pattern = re.compile(rf".*{re.escape(path_name)}:{line}: {re.escape(field)}: .*{message}")
    assert any(pattern.match(p) for p in problems), problems


def test_valid_record_gets_defaults(tmp_path):
    path = write_catalog(tmp_path)
    loaded = load_record(path, tmp_path)
    assert loaded.record.pipeline.matcher is None
    assert default_registry().choice(loaded.record.pipeline, "matcher").plugin == "correlative"
    assert loaded.record.location.redact is True
    assert loaded.record.station_index() == {"S1": 0, "S2": 1}


def test_malformed_yaml_names_file_and_line(tmp_path):
    problems = problems_for(tmp_path, RECORD + "pipeline: [unclosed\n")
    assert_problem(problems, "test-site.yaml", 15, "yaml", "")


def test_missing_field(tmp_path):
    problems = problems_for(tmp_path, RECORD.replace("name: Test site\n", ""))
    assert_problem(problems, "test-site.yaml", 1, "name", "Field required")


def test_wrong_type_points_at_its_line(tmp_path):
    problems = problems_for(tmp_path, RECORD.replace("    depth_m: 1.0\n  - file: data/s2", "    depth_m: deep\n  - file: data/s2", 1))
    assert_problem(problems, "test-site.yaml", 6, "scans[0].depth_m", "valid number")


def test_unknown_field_is_refused(tmp_path):
    problems = problems_for(tmp_path, RECORD + "colour: blue\n")
    assert_problem(problems, "test-site.yaml", 14, "colour", "unknown field")


def test_bad_slug(tmp_path):
    problems = problems_for(tmp_path, RECORD.replace("id: test-site", "id: Test Site"))
    assert_problem(problems, "test-site.yaml", 1, "id", "slug")


def test_unknown_plugin(tmp_path):
    text = RECORD + "pipeline:\n  matcher:\n    plugin: no-such-matcher\n"
    problems = problems_for(tmp_path, text)
    assert_problem(problems, "test-site.yaml", 16, "pipeline.matcher.plugin", "unknown matcher plugin 'no-such-matcher'")


def test_bad_plugin_params(tmp_path):
    text = RECORD + "pipeline:\n  matcher:\n    plugin: pf-pairwise\n    params:\n      no_such_param: 3\n"
    problems = problems_for(tmp_path, text)
    assert_problem(problems, "test-site.yaml", 17, "pipeline.matcher.params", "no_such_param: unknown parameter")


def test_missing_scan_file(tmp_path):
    problems = problems_for(tmp_path, RECORD.replace("data/s2.npz", "data/missing.npz"))
    assert_problem(problems, "test-site.yaml", 7, "scans[1].file", "not found")


@pytest.mark.parametrize("bad", ["../outside.npz", "data/../../outside.npz", "/etc/passwd"])
def test_paths_that_leave_the_catalog_are_refused(tmp_path, bad):
    problems = problems_for(tmp_path, RECORD.replace("data/s1.npz", bad))
    assert_problem(problems, "test-site.yaml", 4, "scans[0].file", "(leaves the catalog root|absolute)")


def test_symlink_out_of_the_catalog_is_refused(tmp_path):
    outside = tmp_path / "outside"
    catalog = tmp_path / "catalog"
    write_catalog(outside)
    write_catalog(catalog)
    (catalog / "data" / "s1.npz").unlink()
    (catalog / "data" / "s1.npz").symlink_to(outside / "data" / "s1.npz")
    problems = validate_catalog(catalog).problems
    assert_problem(problems, "test-site.yaml", 4, "scans[0].file", "outside the catalog root")


def test_duplicate_station_and_site_ids(tmp_path):
    problems = problems_for(tmp_path, RECORD.replace("station: S2", "station: S1"))
    assert any("station 'S1' appears twice" in p for p in problems)
    write_catalog(tmp_path, RECORD, name="copy.yaml")
    write_catalog(tmp_path, RECORD)
    problems = validate_catalog(tmp_path).problems
    assert any("site id 'test-site' is already used" in p for p in problems)


def test_load_record_raises_catalog_error(tmp_path):
    path = write_catalog(tmp_path, "- just\n- a list\n")
    with pytest.raises(CatalogError, match="expected a mapping"):
        load_record(path, tmp_path)


def test_record_model_round_trips_through_json():
    record = SiteRecord.model_validate({"id": "a", "name": "A", "scans": [{"file": "x.npz", "station": "S1"}]})
    assert SiteRecord.model_validate_json(record.model_dump_json()) == record


def test_the_readme_example_record_is_valid():
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    block = readme.split("A complete record, annotated")[1].split("```yaml\n", 1)[1].split("```", 1)[0]
    record = SiteRecord.model_validate(yaml.safe_load(block))
    assert record.id == "lair-pool"
    assert record.references[0].measure.repeats == 10


def test_a_record_that_is_not_utf8_is_a_clear_error(tmp_path):
    write_catalog(tmp_path)
    (tmp_path / "test-site.yaml").write_bytes(b"id: caf\xe9\n")
    problems = validate_catalog(tmp_path).problems
    assert_problem(problems, "test-site.yaml", 1, "(record)", "cannot be read")
