"""``summary.json``: what one rebuild did to every site, and the exit code it implies."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from cistern_archive.core.exitcodes import EXIT_OK, EXIT_SITES_FAILED, EXIT_USAGE
from cistern_archive.core.files import write_json_atomic

SUMMARY_SCHEMA_VERSION = 1


SUMMARY_NAME = "summary.json"
"""The rebuild's summary file in ``OUT``."""


class SiteOutcome(BaseModel):
    """One site of a rebuild."""

    model_config = ConfigDict(extra="forbid")

    id: str
    status: Literal["ok", "partial", "failed", "skipped"] = Field(
        description="ok: every scan placed and every dimension measured; partial: built, but not all of them; "
                    "failed: stopped or nothing placed; skipped: unchanged since its last build")
    reasons: list[str] = Field(default_factory=list, description="why the site is partial or failed")
    report_status: Literal["ok", "partial", "failed"] | None = Field(
        default=None, description="status of the report now published (of its last build when skipped)")
    error: str | None = None
    detail: str = Field(default="", description="traceback of the error (also in the run log)")
    build_key: str
    timings_s: dict[str, float] = Field(default_factory=dict)
    report: str | None = Field(default=None, description="the site's index.html, relative to OUT")
    worker: str | None = Field(default=None, description="host:pid of the process that built it")
    peak_rss_mb: float | None = Field(default=None, description="peak resident memory of that process")
    attempts: int = 0
    artifacts: dict[str, str] = Field(default_factory=dict, description="path relative to the site folder -> sha256")


class RebuildSummary(BaseModel):
    """The whole rebuild; written to ``OUT/summary.json``."""

    model_config = ConfigDict(extra="forbid")

    schema_version: int = SUMMARY_SCHEMA_VERSION
    run_id: str
    started_at: str
    finished_at: str = ""
    catalog: str
    out: str
    archive: str
    executor: str
    workers: int
    force: bool
    code_version: str
    sites: list[SiteOutcome] = Field(default_factory=list)
    catalog_problems: list[str] = Field(default_factory=list)
    recovered: list[str] = Field(default_factory=list, description="clean-up after an interrupted rebuild")
    index_sites: list[str] = Field(default_factory=list, description="the sites OUT/index.html lists")
    index_key: str | None = Field(default=None, description="digest of the published reports the index shows")
    stale_lock: dict | None = None
    interrupted: bool = False
    log: str = ""
    seconds: float = 0.0

    def counts(self) -> dict[str, int]:
        counts = {"ok": 0, "partial": 0, "failed": 0, "skipped": 0}
        for site in self.sites:
            counts[site.status] += 1
        return counts

    @property
    def failed(self) -> list[SiteOutcome]:
        return [s for s in self.sites if s.status == "failed"]

    @property
    def not_ok(self) -> list[SiteOutcome]:
        """The sites built in this run that are partial or failed."""
        return [s for s in self.sites if s.status in ("partial", "failed")]

    @property
    def exit_code(self) -> int:
        """2 when the catalog had problems, 1 when a site is partial or failed, 0 when every site is
        ok or skipped (130 is the caller's)."""
        if self.catalog_problems:
            return EXIT_USAGE
        return EXIT_SITES_FAILED if self.not_ok else EXIT_OK

    def write(self, path: Path) -> Path:
        write_json_atomic(self.model_dump(mode="json"), path)  # 0644: readable like the reports
        return path
