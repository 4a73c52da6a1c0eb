"""``report.pdf``: the site page printed by headless Chromium with the page's print stylesheet.

Chromium (Debian's ``chromium``; ``$CISTERN_CHROMIUM`` points elsewhere) prints the page from the file
system with no network and a throw-away profile. Its PDF differs between two prints of the same page
only in the creation and modification dates of the document information dictionary; both are set to
the report's build time (``SOURCE_DATE_EPOCH``, else the Unix epoch), keeping their length and so every
byte offset, so that the same page gives the same bytes.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from urllib.parse import unquote, urlsplit

CHROMIUM_ENV = "CISTERN_CHROMIUM"
CHROMIUM_ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--no-pdf-header-footer", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--run-all-compositor-stages-before-draw", "--virtual-time-budget=10000")
"""``--virtual-time-budget``: print once the page and every image it shows have loaded, however busy
the machine."""
PRINT_TIMEOUT_S = 120.0
_PDF_DATE = re.compile(rb"/(CreationDate|ModDate) \(D:\d{14}[^)]*\)")


def chromium_path() -> Path | None:
    """The Chromium executable, or ``None`` when there is none."""
    given = os.environ.get(CHROMIUM_ENV)
    for candidate in ([given] if given else []) + ["/usr/bin/chromium", shutil.which("chromium") or ""]:
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return Path(candidate)
    return None


def pin_dates(data: bytes, when: dt.datetime | None) -> bytes:
    """The PDF with its creation and modification dates set to ``when`` (UTC; the epoch if ``None``),
    written in the same number of bytes."""
    stamp = (when or dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)).astimezone(dt.timezone.utc)
    text = stamp.strftime("%Y%m%d%H%M%S")

    def replace(match: re.Match) -> bytes:
        old = match.group(0)
        new = b"/" + match.group(1) + b" (D:" + text.encode() + b"+00'00')"
        return new if len(new) == len(old) else old

    return _PDF_DATE.sub(replace, data)


_URI = re.compile(rb"/URI \((file://[^)]*)\)")
_OBJECT = re.compile(rb"(?m)^(\d+) 0 obj\b")
_XREF = re.compile(rb"xref\n0 (\d+)\n")


def relative_links(data: bytes, folder: Path) -> bytes:
    """The PDF with its ``file://`` links made relative to ``folder`` (the page's folder), so that they
    work wherever the report is copied (and do not name the folder the page was printed from), and
    its cross-reference table rewritten for the new object offsets."""
    def relative(match: re.Match) -> bytes:
        target = unquote(urlsplit(match.group(1).decode("utf-8", "replace")).path)
        link = Path(os.path.relpath(target, folder)).as_posix()
        fragment = urlsplit(match.group(1).decode("utf-8", "replace")).fragment
        link += f"#{fragment}" if fragment else ""
        return b"/URI (" + link.encode("utf-8").replace(b"(", b"\\(").replace(b")", b"\\)") + b")"

    data = _URI.sub(relative, data)
    xref = data.rfind(b"\nxref\n") + 1  # the table, not the "startxref" after it
    table = _XREF.match(data, xref) if xref > 0 else None
    if table is None:
        return data
    size = int(table.group(1))
    offsets = {int(m.group(1)): m.start() for m in _OBJECT.finditer(data, 0, xref)}
    rows = [b"0000000000 65535 f \n"] + [
        (b"%010d 00000 n \n" % offsets[k]) if k in offsets else b"0000000000 65535 f \n" for k in range(1, size)]
    rest = data.index(b"trailer", xref)
    body = data[:xref] + b"xref\n0 %d\n" % size + b"".join(rows)
    tail = re.sub(rb"startxref\n\d+", b"startxref\n%d" % xref, data[rest:], count=1)
    return body + tail


def print_pdf(page: Path, out: Path, *, when: dt.datetime | None = None) -> str:
    """Print ``page`` to ``out``; returns ``""`` on success, else why there is no PDF."""
    chromium = chromium_path()
    if chromium is None:
        return f"Chromium not found (set ${CHROMIUM_ENV}, or Debian: apt-get install chromium)"
    with tempfile.TemporaryDirectory(prefix="cistern-pdf-") as profile:
        target = Path(profile) / "report.pdf"
        try:
            run = subprocess.run([str(chromium), *CHROMIUM_ARGS, f"--user-data-dir={profile}",
                                  f"--print-to-pdf={target}", page.resolve().as_uri()],
                                 capture_output=True, timeout=PRINT_TIMEOUT_S, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"Chromium could not print the page: {type(exc).__name__}: {exc}"
        if run.returncode != 0 or not target.is_file() or target.stat().st_size == 0:
            tail = run.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or [""]
            return f"Chromium could not print the page (exit {run.returncode}): {tail[0]}"
        out.write_bytes(relative_links(pin_dates(target.read_bytes(), when), page.resolve().parent))
    return ""
