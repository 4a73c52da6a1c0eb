"""Reader of the interchange format (:mod:`cistern_archive.sonar.interchange`)."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar.interchange import check_npz, read_scan
from cistern_archive.sonar.readers import ReadResult, register_reader


@register_reader("npz", (".npz",), "cistern-archive interchange scan (.npz of arrays + JSON metadata)",
                 check=check_npz)
def read_npz(path: Path) -> ReadResult:
    check_npz(path)  # sizes and shapes from the headers, before testzip decompresses every member
    try:
        with zipfile.ZipFile(path) as archive:  # check the zip first: numpy leaks its handle on a broken zip
            damaged = archive.testzip()
        if damaged is not None:
            raise ReaderError(str(path), f"unreadable .npz: member {damaged!r} fails its CRC check")
        scan = read_scan(path)
    # damaged zip/npy members fail inside zipfile and numpy in many ways
    except (zipfile.BadZipFile, zlib.error, NotImplementedError, TypeError, AttributeError, KeyError,
            IndexError, ValueError, OSError, EOFError) as exc:
        raise ReaderError(str(path), f"unreadable .npz: {type(exc).__name__}: {exc}") from None
    return ReadResult(format="npz", scans=[scan], warnings=[])
