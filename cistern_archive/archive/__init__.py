"""Preservation: content-addressed store of raw inputs, SQLite index with provenance events, fixity
checks and BagIt export."""

from cistern_archive.archive.fixity import FixityProblem, FixityReport, verify_archive
from cistern_archive.archive.repository import Archive, IngestedInput, agent, catalog_store, default_archive_dir

__all__ = ["Archive", "FixityProblem", "FixityReport", "IngestedInput", "agent", "catalog_store", "default_archive_dir",
           "verify_archive"]
