"""``export --bag``: the BagIt bag of a site's published build, when that build is current.

The export never builds. It archives the site's inputs and computes their build key as a rebuild
would (:func:`~cistern_archive.service.rebuild.plan_site`, with the report settings the site was
published with), and packs the published folder only when its ``build.json`` has that key and a
finished status (:func:`~cistern_archive.service.rebuild.is_current`); otherwise it refuses and names
the site, so that the bag's report, mesh and tables are always those of the current inputs.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

from cistern_archive.archive.bag import BagExport, check_bag_target, pack_bag
from cistern_archive.archive.repository import Archive, default_archive_dir
from cistern_archive.core.errors import CisternError
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.pipeline.validate import find_site
from cistern_archive.service.publish import publish
from cistern_archive.service.planning import CURRENT_STATUSES, is_current, plan_site, published_build


class NotPublished(CisternError):
    """The site has no published build of its current inputs to pack."""


def stale_reason(site_dir: Path, published: dict[str, Any] | None, key: str) -> str:
    """Why the published build in ``site_dir`` cannot be packed for the build key ``key`` ('' when it can)."""
    if published is None:
        return f"no published build in {site_dir}"
    if published.get("status") not in CURRENT_STATUSES:
        return f"the published build in {site_dir} is {published.get('status') or 'of unknown status'}"
    if published.get("build_key") != key:
        return (f"the published build in {site_dir} is stale: built from key "
                f"{str(published.get('build_key'))[:12]}, the current inputs give {key[:12]}")
    if not is_current(site_dir, key):
        return f"the published build in {site_dir} is incomplete (a file listed in its build.json is missing)"
    return ""


def place_bag(staged: Path, bag: Path, site_id: str) -> None:
    """Move the finished bag into place; a previous bag of the same site is replaced atomically."""
    if not check_bag_target(bag, site_id) and bag.is_dir():
        bag.rmdir()  # an empty folder (check_bag_target refuses any other)
    publish(staged, bag)


def export_bag(site_id: str, bag: Path, *, catalog: Path, out: Path, archive: Path | None = None,
               registry: Registry | None = None) -> BagExport:
    """Write the BagIt bag of one site's published build to the folder ``bag``.

    Parameters
    ----------
    site_id : str
        The site to export.
    bag : Path
        The bag folder to create (an existing bag of the same site is replaced).
    catalog, out : Path
        The catalog root and the rebuild output folder holding the published site ``OUT/<site_id>``.
    archive : Path, optional
        The archive (:func:`default_archive_dir` of the catalog when omitted); inputs are ingested first.

    Raises
    ------
    CatalogError
        The site is not a valid record of the catalog.
    NotPublished
        The site's published build is missing, failed, incomplete or stale: ``run rebuild first``.
    CisternError
        ``bag`` is something other than an empty folder or a bag of this site.
    """
    registry = registry or default_registry()
    catalog, out, bag = Path(catalog).resolve(), Path(out).resolve(), Path(bag).resolve()
    loaded = find_site(catalog, site_id, registry)
    check_bag_target(bag, site_id)  # refuse before any work; checked again just before the swap
    site_dir = out / site_id
    hint = f"run rebuild first (cistern-archive rebuild --catalog {catalog} --out {out} --site {site_id}" + \
        (f" --archive {archive})" if archive is not None else ")")
    published = published_build(site_dir)
    if published is None:
        raise NotPublished(f"{site_id}: {stale_reason(site_dir, None, '')}; {hint}")
    report_config = (published.get("key_material") or {}).get("report") or None
    with Archive(Path(archive) if archive is not None else default_archive_dir(catalog)) as store:
        key = plan_site(loaded, store, registry, run_id=None, report_config=report_config).key.key
        reason = stale_reason(site_dir, published, key)
        if reason:
            raise NotPublished(f"{site_id}: {reason}; {hint}")
        bag.parent.mkdir(parents=True, exist_ok=True)
        staged = Path(tempfile.mkdtemp(prefix=f".{bag.name}.tmp-", dir=bag.parent))
        try:
            payload_files = pack_bag(staged, site_dir=site_dir, build_info=published, loaded=loaded, store=store)
            place_bag(staged, bag, site_id)
        except BaseException:
            shutil.rmtree(staged, ignore_errors=True)
            raise
        store.index.add_event("publish", agent=store.agent, outcome="success", site_id=site_id,
                              detail={"bag": str(bag), "build_key": key})
    return BagExport(path=bag, site_id=site_id, build_key=key, payload_files=payload_files,
                     report_source=f"published report {site_dir}")
