"""The run log: one plain-text file per rebuild, ``OUT/logs/<run-id>.log``."""

from __future__ import annotations

import datetime as dt
import secrets
from pathlib import Path

LOG_DIR = "logs"


def new_run_id() -> str:
    """``YYYYmmddTHHMMSSZ-xxxxxx``: sortable by start time, unique across concurrent hosts."""
    now = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return f"{now}-{secrets.token_hex(3)}"


class RunLog:
    """Append-only log lines ``<UTC time> <LEVEL> <message>``, flushed as they are written."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._handle = open(self.path, "a", encoding="utf-8")

    def write(self, message: str, level: str = "INFO") -> None:
        stamp = dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds")
        for k, line in enumerate(message.rstrip("\n").splitlines() or [""]):
            self._handle.write(f"{stamp} {level:<5} {'  ' if k else ''}{line}\n")
        self._handle.flush()

    def close(self) -> None:
        self._handle.close()

    def __enter__(self) -> "RunLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
