"""BagIt (RFC 8493) export of one site, for deposit with a data archive.

The bag's payload (``data/``):

- ``raw/`` — every raw input in its native format, at its catalog path (the record YAML, the scan
  files, the simulator spec), copied from the archive's fixity-checked objects;
- ``preservation/`` — open formats of everything derived (:mod:`cistern_archive.archive.preservation`);
- ``report/`` — the HTML report with its figures, ``result.json`` and ``record.json``: the published
  one when its build key is current (with the report settings it was built with), otherwise one
  rendered for the export;
- ``config/resolved.json`` — the record with every plugin's parameters resolved to their defaults;
- ``provenance/`` — the build key and what it covers, the result's provenance, the input digests and
  the archive's events for the site (PREMIS-style: ingest, digest, build, publish, fixity).

``bag-info.txt`` carries ``External-Identifier`` = the site id and ``Bagging-Date`` from
``SOURCE_DATE_EPOCH`` (or the time the report was built), so two exports of an unchanged site are
equal apart from nothing. Manifests use SHA-256 and SHA-512.
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cistern_archive.archive.repository import Archive, default_archive_dir
from cistern_archive.core.errors import CatalogError, CisternError

CHECKSUMS = ("sha256", "sha512")


@dataclass(frozen=True)
class BagExport:
    """What :func:`export_bag` wrote."""

    path: Path
    site_id: str
    build_key: str
    payload_files: int
    report_source: str


def bagging_date(built_at: str | None) -> str:
    """``YYYY-MM-DD`` from ``SOURCE_DATE_EPOCH`` when set, else from the report's build time, else today."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if epoch:
        return dt.datetime.fromtimestamp(int(epoch), tz=dt.timezone.utc).strftime("%Y-%m-%d")
    if built_at:
        built = dt.datetime.fromisoformat(built_at.replace("Z", "+00:00"))
        return built.astimezone(dt.timezone.utc).strftime("%Y-%m-%d")
    return dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d")


def _find_record(catalog: Path, site_id: str, registry):
    from cistern_archive.pipeline.validate import validate_catalog

    report = validate_catalog(catalog, registry)
    for loaded in report.records:
        if loaded.record.id == site_id:
            return loaded
    known = ", ".join(sorted(r.record.id for r in report.records)) or "none"
    raise CatalogError(report.problems + [f"{catalog}: no valid site record with id {site_id!r} (valid: {known})"])


def _events(archive: Archive, site_id: str, digests: set[str]) -> list[dict[str, Any]]:
    rows = [dict(r) for r in archive.index.events(site_id=site_id)]
    rows += [dict(r) for r in archive.index.events(type="fixity") if r["sha256"] in digests]
    return sorted(rows, key=lambda r: r["id"])


def bag_identifiers(bag: Path) -> list[str]:
    """The ``External-Identifier`` values of a bag's ``bag-info.txt`` (none when it is not a bag)."""
    info = bag / "bag-info.txt"
    if not ((bag / "bagit.txt").is_file() and info.is_file()):
        return []
    try:
        text = info.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return []
    found = []
    for line in text.splitlines():
        label, sep, value = line.partition(":")
        if sep and label.strip() == "External-Identifier":
            found.append(value.strip())
    return found


def check_bag_target(bag: Path, site_id: str) -> bool:
    """Whether ``bag`` is free for this site's bag: absent, an empty folder, or provably this site's bag
    (a BagIt folder whose only ``External-Identifier`` is exactly ``site_id``); True when it is such a bag.

    Raises
    ------
    CisternError
        Anything else (another site's bag, a folder of other files, a file): it is never replaced.
    """
    if not bag.exists() and not bag.is_symlink():
        return False
    if bag.is_dir() and not bag.is_symlink():
        if bag_identifiers(bag) == [site_id]:
            return True
        if not any(bag.iterdir()):
            return False
    raise CisternError(f"{bag}: exists and is not a bag of site {site_id!r} "
                       f"(External-Identifier: {', '.join(bag_identifiers(bag)) or 'none'}); "
                       "it is never replaced; choose an empty or new folder")


def _place(staged: Path, bag: Path, site_id: str) -> None:
    """Move the finished bag into place; a previous bag of the same site is replaced atomically."""
    from cistern_archive.service.publish import publish

    if not check_bag_target(bag, site_id) and bag.is_dir():
        bag.rmdir()  # an empty folder (check_bag_target refuses any other)
    publish(staged, bag)


def export_bag(site_id: str, bag: Path, *, catalog: Path, out: Path, archive: Path | None = None,
               registry=None) -> BagExport:
    """Write the BagIt bag of one site to the folder ``bag``.

    Parameters
    ----------
    site_id : str
        The site to export.
    bag : Path
        The bag folder to create (an existing bag of the same site is replaced).
    catalog, out : Path
        The catalog root and the rebuild output folder (its report is reused when current).
    archive : Path, optional
        The archive (:func:`default_archive_dir` of the catalog when omitted); inputs are ingested first.

    Raises
    ------
    CatalogError
        The site is not a valid record of the catalog.
    """
    import bagit

    from cistern_archive import __version__
    from cistern_archive.archive.preservation import write_preservation
    from cistern_archive.pipeline.registry import default_registry
    from cistern_archive.core.files import write_json_atomic
    from cistern_archive.pipeline.runner import build_site, write_site_result
    from cistern_archive.report.config import ReportConfig
    from cistern_archive.report.site import render_site
    from cistern_archive.service.rebuild import is_current, plan_site, published_build

    registry = registry or default_registry()
    catalog, out, bag = Path(catalog).resolve(), Path(out).resolve(), Path(bag).resolve()
    loaded = _find_record(catalog, site_id, registry)
    check_bag_target(bag, site_id)  # refuse before any work; checked again just before the swap
    bag.parent.mkdir(parents=True, exist_ok=True)
    staged = Path(tempfile.mkdtemp(prefix=f".{bag.name}.tmp-", dir=bag.parent))
    try:
        site_dir = out / site_id
        published = published_build(site_dir) or {}
        report_config = (published.get("key_material") or {}).get("report") or None
        with Archive(Path(archive) if archive is not None else default_archive_dir(catalog)) as store:
            plan = plan_site(loaded, store, registry, run_id=None, report_config=report_config)
            inputs = [dict(row) for row in store.index.site_inputs(site_id)]
            wanted = {loaded.path.resolve().relative_to(loaded.root).as_posix(), *plan.key.material["inputs"]}
            inputs = [row for row in inputs if row["relative_path"] in wanted]
            for row in inputs:
                store.store.copy_out(row["sha256"], staged / "raw" / row["relative_path"])
            build = build_site(loaded, registry=registry)
            if is_current(site_dir, plan.key.key):
                shutil.copytree(site_dir, staged / "report")
                report_source, built_at = f"published report {site_dir}", published.get("built_at")
            else:
                (staged / "report").mkdir()
                write_site_result(build, staged / "report")
                render_site(build, staged / "report", config=ReportConfig(**(report_config or {})))
                report_source, built_at = "rendered for this export (no current published report)", None
            write_preservation(build, staged / "preservation")
            resolved = loaded.record.model_dump(mode="json")
            for item in plan.key.material["plugins"]:
                resolved["pipeline"][item["stage"]] = {"plugin": item["plugin"], "params": item["params"]}
            provenance = staged / "provenance"
            fields = ("relative_path", "role", "sha256", "size", "ingested_at")
            write_json_atomic(resolved, staged / "config" / "resolved.json")
            write_json_atomic({"build_key": plan.key.key, **plan.key.material}, provenance / "build-key.json")
            write_json_atomic(build.result.provenance.model_dump(mode="json") if build.result.provenance else {},
                              provenance / "result-provenance.json")
            write_json_atomic([{k: row[k] for k in fields} for row in inputs], provenance / "inputs.json")
            write_json_atomic(_events(store, site_id, {r["sha256"] for r in inputs}), provenance / "events.json")
            store.index.add_event("publish", agent=store.agent, outcome="success", site_id=site_id,
                                  detail={"bag": str(bag), "build_key": plan.key.key})
        record = loaded.record
        info = {
            "External-Identifier": site_id,
            "External-Description": f"{record.name}: sonar scans, maps, 3D model and report of the site.",
            "Bagging-Date": bagging_date(built_at),
            "Bag-Software-Agent": f"cistern-archive {__version__} (bagit {bagit.VERSION})",
            "Bag-Group-Identifier": "cistern-archive",
            "Internal-Sender-Identifier": plan.key.key,
        }
        if record.expedition is not None:
            info["Internal-Sender-Description"] = record.expedition.name
        made = bagit.make_bag(str(staged), bag_info=info, checksums=list(CHECKSUMS))
        payload_files = len(list(made.payload_files()))
        _place(staged, bag, site_id)
    except BaseException:
        shutil.rmtree(staged, ignore_errors=True)
        raise
    return BagExport(path=bag, site_id=site_id, build_key=plan.key.key, payload_files=payload_files,
                     report_source=report_source)
