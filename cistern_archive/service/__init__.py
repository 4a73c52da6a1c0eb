"""The nightly rebuild service: build keys, the rebuild lock, executors (local processes, Dask),
atomic publication, ``summary.json`` and the run log.

Public API
----------
rebuild(catalog, out, *, sites, workers, force, scheduler, scheduler_file, archive, progress, registry,
        report_config) -> RebuildSummary
    Rebuild a catalog's reports incrementally (see :mod:`cistern_archive.service.rebuild`).
RebuildSummary, SiteOutcome
    What ``OUT/summary.json`` holds.
RebuildLocked
    Raised when another rebuild holds the output folder.
"""

from cistern_archive.service.lock import RebuildLocked
from cistern_archive.service.rebuild import rebuild
from cistern_archive.service.summary import RebuildSummary, SiteOutcome

__all__ = ["RebuildLocked", "RebuildSummary", "SiteOutcome", "rebuild"]
