"""``cistern-archive config SITE``: the resolved record, every default filled in, as record.json holds it."""

from __future__ import annotations

import json
import subprocess
import sys

import yaml

from catalog_helpers import RECORD, write_catalog
from cistern_archive.catalog.loader import load_record
from cistern_archive.pipeline.contracts import STAGES
from cistern_archive.pipeline.registry import Registry
from cistern_archive.pipeline.runner import build_site, write_site_result

PF_RECORD = RECORD + """\
pipeline:
  matcher:
    plugin: icp
    params:
      max_iterations: 7
"""


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cistern_archive", *args], capture_output=True, text=True,
                          timeout=300)


def test_config_prints_every_stage_with_its_defaults_as_record_json_holds_it(tmp_path):
    write_catalog(tmp_path, PF_RECORD)
    out = run_cli("config", "test-site", "--catalog", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    shown = json.loads(out.stdout)
    registry = Registry()
    for stage in STAGES:
        choice = shown["pipeline"][stage]
        model = registry.load(stage, choice["plugin"]).params_model
        expected = model().model_dump(mode="json")
        if stage == "matcher":
            assert choice["plugin"] == "icp"
            expected["max_iterations"] = 7
        else:
            assert choice["plugin"] == registry.default(stage)
        assert choice["params"] == expected, stage
    loaded = load_record(tmp_path / "test-site.yaml", tmp_path)
    write_site_result(build_site(loaded, registry=registry), tmp_path / "built")
    built = json.loads((tmp_path / "built" / "record.json").read_text())
    # what a record leaves to the site is decided when it is built, and record.json says what was decided
    assert shown["segmentation"]["faint_walls"] == "auto" and built["segmentation"]["faint_walls"] in ("on", "off")
    built["segmentation"]["faint_walls"] = "auto"
    assert built == shown

    readable = run_cli("config", "test-site", "--catalog", str(tmp_path))
    assert readable.returncode == 0, readable.stderr
    assert yaml.safe_load(readable.stdout) == shown
    assert readable.stdout.index("id: test-site") < readable.stdout.index("pipeline:")


def test_config_of_the_bundled_catalog(bundled_catalog):
    out = run_cli("config", "lair-pool", "--catalog", str(bundled_catalog), "--json")
    assert out.returncode == 0, out.stderr
    assert set(json.loads(out.stdout)["pipeline"]) == set(STAGES)


def test_config_refuses_an_unknown_site_and_an_invalid_record(tmp_path):
    write_catalog(tmp_path, PF_RECORD)
    unknown = run_cli("config", "nowhere", "--catalog", str(tmp_path))
    assert unknown.returncode == 2
    assert "no valid site record with id 'nowhere' (valid: test-site)" in unknown.stderr
    assert "Traceback" not in unknown.stderr and not unknown.stdout

    (tmp_path / "test-site.yaml").write_text(PF_RECORD.replace("max_iterations: 7", "max_iterations: -1"))
    invalid = run_cli("config", "test-site", "--catalog", str(tmp_path))
    assert invalid.returncode == 2
    assert "test-site.yaml:" in invalid.stderr and "pipeline.matcher.params" in invalid.stderr
    assert "max_iterations" in invalid.stderr
    assert "the record of site 'test-site' is invalid" in invalid.stderr
    assert "Traceback" not in invalid.stderr and not invalid.stdout
