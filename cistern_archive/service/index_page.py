"""``OUT/index.html``: the catalog's page of every published site, rendered again only when what it
shows changed (step 6 of :mod:`cistern_archive.service.rebuild`)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from cistern_archive.pipeline.results import SiteResult
from cistern_archive.report.index import IndexEntry, render_index
from cistern_archive.service.buildkey import canonical_json
from cistern_archive.service.planning import published_build
from cistern_archive.service.summary import SUMMARY_NAME


def published_sites(out: Path, site_ids: list[str]) -> list[str]:
    """The catalog's sites that have a published ``result.json``, sorted."""
    return sorted(site_id for site_id in site_ids if (out / site_id / "result.json").is_file())


def index_key(out: Path, sites: list[str], code: str) -> str:
    """A digest of what ``OUT/index.html`` shows: the code version and, per published site, its
    ``build.json`` (build key, run, build time, status)."""
    shown = []
    for site_id in sites:
        info = published_build(out / site_id) or {}
        shown.append([site_id, *(info.get(k) for k in ("build_key", "run_id", "built_at", "status"))])
    return hashlib.sha256(canonical_json({"code_version": code, "sites": shown}).encode("utf-8")).hexdigest()


def index_is_current(out: Path, key: str) -> bool:
    """Whether ``OUT/index.html`` was rendered from exactly the published reports ``key`` describes
    (recorded in the previous ``summary.json``; a crash between a publish and the index write leaves an
    older key there, so the index is rendered again)."""
    if not (out / "index.html").is_file():
        return False
    try:
        previous = json.loads((out / SUMMARY_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(previous, dict) and previous.get("index_key") == key


def index_entries(out: Path, site_ids: list[str]):
    """One :class:`~cistern_archive.report.IndexEntry` per published site, in site-id order."""
    entries = []
    for site_id in sorted(site_ids):
        site_dir = out / site_id
        try:
            result = SiteResult.model_validate_json((site_dir / "result.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        built_at = (published_build(site_dir) or {}).get("built_at") or ""
        entries.append(IndexEntry.from_result(result, build_time=built_at))
    return entries


def write_index(out: Path, site_ids: list[str]) -> Path:
    """Render ``OUT/index.html`` for every published site of the catalog and move it into place atomically.

    The page is rendered in a temporary sibling folder whose entries link to the site folders, so that
    the renderer sees the thumbnails, and then renamed over the previous index.
    """
    staging = Path(tempfile.mkdtemp(prefix=".index.tmp-", dir=out))
    try:
        for site_id in site_ids:
            if (out / site_id).is_dir():
                (staging / site_id).symlink_to(out / site_id, target_is_directory=True)
        page = render_index(index_entries(out, site_ids), staging)
        os.replace(page, out / "index.html")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out / "index.html"
