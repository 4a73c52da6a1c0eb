"""The main job end to end: rebuild the bundled catalog, read every page in a real browser, rebuild
again and get the same bytes, and skip every unchanged site on a third run."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from browser_helpers import BROKEN_IMAGES, broken_links, launch_browser, open_page
from cistern_archive.service.rebuild import rebuild

pytestmark = [pytest.mark.slow, pytest.mark.browser]

# Files whose content holds wall-clock measurements or run ids by design.
VOLATILE = {"result.json", "summary.json", "build.json"}


@pytest.fixture(scope="module")
def demo(bundled_catalog, tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("demo")
    out, archive = root / "site", root / "archive"
    summary = rebuild(bundled_catalog, out, archive=archive, workers=2)
    assert all(s.status in ("ok", "partial") for s in summary.sites), [(s.id, s.error) for s in summary.sites]
    assert summary.exit_code == (0 if all(s.status == "ok" for s in summary.sites) else 1)
    return out, archive


def published_files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name not in VOLATILE and "logs" not in p.parts}


def test_every_site_builds_and_summary_lists_them(demo, bundled_catalog):
    out, _ = demo
    summary = json.loads((out / "summary.json").read_text())
    ids = {path.stem for path in (bundled_catalog / "sites").glob("*.yaml")}
    assert {s["id"] for s in summary["sites"]} == ids
    for site in summary["sites"]:
        result = json.loads((out / site["id"] / "result.json").read_text())
        assert site["status"] == result["status"]
        complete = all(scan["placed"] for scan in result["scans"]) and \
            all(d["map_m"] is not None for d in result["dimensions"])
        assert result["status"] == ("ok" if complete else "partial"), (site["id"], result["status_reasons"])
        assert bool(result["status_reasons"]) == (not complete)
        assert any(scan["placed"] for scan in result["scans"])
        assert result["dimensions"], site["id"]


def test_every_page_reads_cleanly_in_chromium(demo):
    out, _ = demo
    pages = [out / "index.html"] + sorted(out.glob("*/index.html"))
    shots = Path(os.environ.get("CISTERN_TEST_OUTPUT", out.parent / "shots")) / "demo"
    shots.mkdir(parents=True, exist_ok=True)
    with launch_browser() as browser:
        for path in pages:
            context, page, problems = open_page(browser, path.as_uri())
            try:
                assert page.evaluate(BROKEN_IMAGES) == [], path
                assert broken_links(page, path) == [], path
                if path.parent != out:
                    assert page.locator("#dimension-table tbody tr").count() >= 1, path
                else:
                    assert page.locator("#difference-table").is_visible()
                if path.parent.name in ("site", "lair-pool"):
                    page.screenshot(path=str(shots / f"{path.parent.name}.png"), full_page=True)
                assert problems == [], (path, problems)
            finally:
                context.close()


def test_forced_rebuild_gives_the_same_bytes_and_unchanged_sites_are_skipped(demo, bundled_catalog):
    out, archive = demo
    first = published_files(out)
    again = rebuild(bundled_catalog, out, archive=archive, workers=2, force=True)
    assert again.exit_code == (0 if all(s.status == "ok" for s in again.sites) else 1)
    second = published_files(out)
    assert sorted(first) == sorted(second)
    differing = [name for name in first if first[name] != second[name]]
    assert differing == []
    skipped = rebuild(bundled_catalog, out, archive=archive, workers=1)
    assert skipped.counts()["skipped"] == len(skipped.sites)
