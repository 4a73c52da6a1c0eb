"""BagIt (RFC 8493) bag of one site's published build, for deposit with a data archive.

The bag packs what was published; it never rebuilds. Its payload (``data/``):

- ``raw/`` — every raw input in its native format, at its catalog path (the record YAML, the scan
  files, the simulator spec), copied from the archive's fixity-checked objects;
- ``report/`` — the published site folder as it is: the HTML report with its figures and downloads,
  ``result.json``, ``record.json`` and ``build.json``;
- ``preservation/`` — open formats of everything derived, made from the published folder and the raw
  inputs (:mod:`cistern_archive.archive.preservation`), byte-identical to the report's downloads of
  the same tables, grid images and model;
- ``config/resolved.json`` — the record with every plugin's parameters as the build resolved them;
- ``provenance/`` — the build key and what it covers, the result's provenance, the input digests and
  the archive's events for the site (PREMIS-style: ingest, digest, build, publish, fixity).

``bag-info.txt`` carries ``External-Identifier`` = the site id and ``Bagging-Date`` from
``SOURCE_DATE_EPOCH`` (or the time the report was built), so two exports of an unchanged site are
equal. Manifests use SHA-256 and SHA-512. Checking that the published build is current, and moving the
finished bag into place, is the export service's (:mod:`cistern_archive.service.export`).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import bagit

from cistern_archive import __version__
from cistern_archive.archive.preservation import write_preservation
from cistern_archive.archive.repository import Archive
from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.core.errors import CisternError
from cistern_archive.core.files import write_json_atomic
from cistern_archive.pipeline.runner import RESULT_FILE

CHECKSUMS = ("sha256", "sha512")


@dataclass(frozen=True)
class BagExport:
    """What an export wrote (:func:`cistern_archive.service.export.export_bag`)."""

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


def bag_info(loaded: LoadedRecord, build_key: str, built_at: str | None) -> dict[str, str]:
    """The ``bag-info.txt`` fields of a site's bag."""
    record = loaded.record
    info = {
        "External-Identifier": record.id,
        "External-Description": f"{record.name}: sonar scans, maps, 3D model and report of the site.",
        "Bagging-Date": bagging_date(built_at),
        "Bag-Software-Agent": f"cistern-archive {__version__} (bagit {bagit.VERSION})",
        "Bag-Group-Identifier": "cistern-archive",
        "Internal-Sender-Identifier": build_key,
    }
    if record.expedition is not None:
        info["Internal-Sender-Description"] = record.expedition.name
    return info


def _copy_raw(store: Archive, site_id: str, wanted: set[str], raw: Path) -> list[dict[str, Any]]:
    """Copy the site's archived inputs named in ``wanted`` (fixity-checked objects) to ``raw/<path>``."""
    inputs = [dict(row) for row in store.index.site_inputs(site_id) if row["relative_path"] in wanted]
    for row in inputs:
        store.store.copy_out(row["sha256"], raw / row["relative_path"])
    return inputs


def _resolved_record(loaded: LoadedRecord, material: dict[str, Any]) -> dict[str, Any]:
    """The record with every stage's plugin and parameters as the build resolved them."""
    resolved = loaded.record.model_dump(mode="json")
    for item in material.get("plugins") or []:
        resolved["pipeline"][item["stage"]] = {"plugin": item["plugin"], "params": item["params"]}
    return resolved


def pack_bag(staged: Path, *, site_dir: Path, build_info: dict[str, Any], loaded: LoadedRecord,
             store: Archive) -> int:
    """Make the empty folder ``staged`` the BagIt bag of the published build in ``site_dir``.

    Parameters
    ----------
    staged : Path
        An empty folder (the caller moves the finished bag into place).
    site_dir : Path
        The published site folder; it is packed as it is, never rebuilt.
    build_info : dict
        Its ``build.json``: the build key, what the key covers (``key_material``) and ``built_at``.
    loaded : LoadedRecord
        The site's record.
    store : Archive
        The archive holding the site's inputs and events.

    Returns
    -------
    int
        The number of payload files.
    """
    site_id, key = loaded.record.id, build_info["build_key"]
    material = build_info.get("key_material") or {}
    wanted = {loaded.path.resolve().relative_to(loaded.root).as_posix(), *(material.get("inputs") or {})}
    inputs = _copy_raw(store, site_id, wanted, staged / "raw")
    shutil.copytree(site_dir, staged / "report")
    write_preservation(staged / "report", loaded, staged / "raw", staged / "preservation")
    result = json.loads((staged / "report" / RESULT_FILE).read_text(encoding="utf-8"))
    provenance = staged / "provenance"
    fields = ("relative_path", "role", "sha256", "size", "ingested_at")
    write_json_atomic(_resolved_record(loaded, material), staged / "config" / "resolved.json")
    write_json_atomic({"build_key": key, **material}, provenance / "build-key.json")
    write_json_atomic(result.get("provenance") or {}, provenance / "result-provenance.json")
    write_json_atomic([{k: row[k] for k in fields} for row in inputs], provenance / "inputs.json")
    write_json_atomic(_events(store, site_id, {r["sha256"] for r in inputs}), provenance / "events.json")
    made = bagit.make_bag(str(staged), bag_info=bag_info(loaded, key, build_info.get("built_at")),
                          checksums=list(CHECKSUMS))
    return len(list(made.payload_files()))
