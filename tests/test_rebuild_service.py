"""The incremental rebuild: build keys, skipping, failures, summary, run log, archive records, CLI."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from cistern_archive.archive import Archive, verify_archive
from cistern_archive.core.errors import CatalogError
from cistern_archive.service.rebuild import rebuild
from service_helpers import (CLI, FAST_REPORT, comparable_result, copy_built, copy_catalog, make_catalog,
                             report_is_complete)

SITES = ["cistern-000", "cistern-001"]


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    return make_catalog(tmp_path_factory.mktemp("template") / "catalog")


@pytest.fixture()
def catalog(template, tmp_path) -> Path:
    return copy_catalog(template, tmp_path / "catalog")


@pytest.fixture(scope="module")
def built_once(template, tmp_path_factory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("built") / "site"
    summary = _rebuild(template, out)
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    return template, out


@pytest.fixture()
def built(built_once, tmp_path) -> tuple[Path, Path]:
    """A catalog and its published reports, copied for one test."""
    return copy_built(built_once, tmp_path)


def _rebuild(catalog: Path, out: Path, **kwargs):
    return rebuild(catalog, out, workers=kwargs.pop("workers", 2), report_config=FAST_REPORT, **kwargs)


def _files(root: Path) -> dict[str, tuple[bytes, int, int]]:
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mode, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_rebuild_publishes_every_site_then_skips_the_unchanged(catalog, tmp_path):
    out = tmp_path / "site"
    raw_before = _files(catalog)
    first = _rebuild(catalog, out)
    assert _files(catalog) == raw_before, "raw inputs are never modified"
    assert [(s.id, s.status) for s in first.sites] == [(site, "ok") for site in SITES], first.sites
    assert first.exit_code == 0
    for site in SITES:
        assert (out / site / "index.html").is_file() and (out / site / "result.json").is_file()
        assert report_is_complete(out / site)
        # result.json is written once, after the report, and lists every file of the site but the
        # record and the build information beside it
        listed = json.loads((out / site / "result.json").read_text())["artifacts"]
        written = {p.relative_to(out / site).as_posix() for p in (out / site).rglob("*") if p.is_file()}
        assert listed["result"] == "result.json" and set(listed.values()) <= written
        assert written - set(listed.values()) == {"build.json", "record.json"}
    assert (out / "index.html").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert [s["id"] for s in summary["sites"]] == SITES
    assert {"id", "status", "error", "timings_s", "build_key"} <= set(summary["sites"][0])
    assert (out / summary["log"]).is_file()
    assert "site cistern-000: ok" in (out / summary["log"]).read_text()
    assert sorted(p.name for p in out.iterdir()) == [".rebuild.lock", *SITES, "index.html", "logs",
                                                      "summary.json"][1:]
    stamp = {site: (out / site / "index.html").stat().st_mtime_ns for site in SITES}

    second = _rebuild(catalog, out)
    assert [s.status for s in second.sites] == ["skipped", "skipped"]
    assert [s.build_key for s in second.sites] == [s.build_key for s in first.sites]
    assert second.exit_code == 0
    assert {site: (out / site / "index.html").stat().st_mtime_ns for site in SITES} == stamp
    assert len(list((out / "logs").iterdir())) == 2

    with Archive(tmp_path / ".archive") as archive:  # the default: beside the catalog
        assert [r["status"] for r in archive.index.runs()] == ["ok", "ok"]
        builds = archive.index.events(type="build")
        assert sorted(e["site_id"] for e in builds) == SITES
        assert len(archive.index.events(type="publish")) == 2
        assert len(archive.index.events(type="ingest")) == len(archive.index.objects())
        assert {row["role"] for row in archive.index.site_inputs("cistern-000")} == {"record", "scan", "simulation"}
        assert archive.index.artifacts("cistern-000")
        assert verify_archive(archive).ok


@pytest.mark.slow
def test_a_changed_record_rebuilds_only_its_site_and_force_rebuilds_all(built):
    catalog, out = built
    first = _rebuild(catalog, out)
    assert [s.status for s in first.sites] == ["skipped", "skipped"]
    record = catalog / "sites" / "cistern-001.yaml"
    record.chmod(0o644)
    record.write_text(record.read_text().replace("description: ", "description: Edited. ", 1))
    second = _rebuild(catalog, out)
    assert [s.status for s in second.sites] == ["skipped", "ok"]
    assert second.sites[1].build_key != first.sites[1].build_key
    comment_only = record.read_text() + "\n# a comment does not change the record\n"
    record.write_text(comment_only)
    assert [s.status for s in _rebuild(catalog, out).sites] == ["skipped", "skipped"]
    forced = _rebuild(catalog, out, force=True, workers=1)
    assert [s.status for s in forced.sites] == ["ok", "ok"]
    assert comparable_result(out / "cistern-000" / "result.json")["site_id"] == "cistern-000"


def test_a_failing_site_never_stops_the_others(built):
    catalog, out = built
    before = (out / "cistern-000" / "result.json").read_text()
    scan = catalog / "data" / "cistern-000" / "s1.npz"
    scan.chmod(0o644)
    scan.write_bytes(b"not a zip file at all")
    summary = _rebuild(catalog, out)
    assert [(s.id, s.status) for s in summary.sites] == [("cistern-000", "failed"), ("cistern-001", "skipped")]
    assert summary.exit_code == 1
    assert "load" in summary.sites[0].error and "s1.npz" in summary.sites[0].error
    failed = json.loads((out / "cistern-000" / "result.json").read_text())
    assert failed["status"] == "failed" and failed["failure"]["stage"] == "load"
    assert (out / "cistern-000" / "result.json").read_text() != before
    again = _rebuild(catalog, out)  # a failed site is retried, not skipped
    assert again.sites[0].status == "failed"


def test_catalog_problems_exit_2_while_the_valid_sites_build(catalog, tmp_path):
    (catalog / "sites" / "broken.yaml").write_text("id: Broken Site\nname: x\nscans: []\n")
    summary = _rebuild(catalog, tmp_path / "site")
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    assert summary.catalog_problems and "broken.yaml" in summary.catalog_problems[0]
    assert summary.exit_code == 2


def test_site_selection(catalog, tmp_path):
    summary = _rebuild(catalog, tmp_path / "site", sites=["cistern-001"], workers=1)
    assert [s.id for s in summary.sites] == ["cistern-001"]
    assert not (tmp_path / "site" / "cistern-000").exists()
    with pytest.raises(CatalogError, match="--site nowhere"):
        _rebuild(catalog, tmp_path / "site", sites=["nowhere"])


@pytest.mark.slow
def test_rebuild_command_plain_output_and_exit_codes(catalog, tmp_path):
    out, archive = tmp_path / "site", tmp_path / "vault"
    args = [*CLI, "rebuild", "--catalog", str(catalog), "--out", str(out), "--archive", str(archive),
            "--site", "cistern-001"]
    run = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "[1/1] cistern-001: ok" in run.stdout
    assert str((out / "index.html").resolve()) in run.stdout
    assert (archive / "index.sqlite").is_file()
    first_code = json.loads((out / "summary.json").read_text())["code_version"]
    again = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    if json.loads((out / "summary.json").read_text())["code_version"] == first_code:  # sources not edited meanwhile
        assert "1 unchanged" in again.stdout
    bad = subprocess.run([*CLI, "rebuild", "--catalog", str(catalog), "--out", str(out), "--site", "nowhere"],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "--site nowhere" in bad.stderr
