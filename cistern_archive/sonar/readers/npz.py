"""Reader of the interchange format (:mod:`cistern_archive.sonar.interchange`)."""

from __future__ import annotations

from pathlib import Path

from cistern_archive.sonar.interchange import read_scan
from cistern_archive.sonar.readers import ReadResult, register_reader


@register_reader("npz", (".npz",), "cistern-archive interchange scan (.npz of arrays + JSON metadata)")
def read_npz(path: Path) -> ReadResult:
    return ReadResult(format="npz", scans=[read_scan(path)], warnings=[])
