"""Record one stationary 360° scan from a live head into the catalog, without ever risking earlier data.

Order of writes (each step leaves the catalog valid if the next never happens):

1. **Raw byte stream** — every byte received, appended to ``data/<site>/<station>.seanet`` (a new file
   per session, never overwritten) and flushed + fsynced as it arrives, so a Ctrl-C or a pulled cable
   loses nothing that came off the wire. The file is readable by the ``seanet-raw`` reader.
2. **Decoded scan** — :func:`cistern_archive.sonar.interchange.write_scan` (temporary sibling + rename).
3. **Site record** — the new scan appended to the record's ``scans:`` list by a textual insertion that
   keeps every other byte (comments included), validated with :func:`cistern_archive.catalog.loader.load_record`
   on a temporary sibling before it replaces the record.
4. **Archive** — raw stream, scan and record handed to a ``store`` (the command passes the archive's
   ingest, :func:`cistern_archive.archive.catalog_store`); acquisition itself knows no archive.

A scan cut short (interrupt, link failure, gaps that did not fill) is still written and recorded, marked
``settings["partial"] = true`` with its station label suffixed ``-partial``.
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from cistern_archive.catalog.loader import LoadedRecord, load_record, record_paths
from cistern_archive.catalog.models import SiteRecord, check_station
from cistern_archive.core.errors import CatalogError, CisternError
from cistern_archive.core.files import write_text_atomic
from cistern_archive.sonar.interchange import write_scan
from cistern_archive.core.scan import yaw_from_compass_deg
from cistern_archive.acquisition.driver import DriverConfig, MicronDriver
from cistern_archive.acquisition.assembly import ScanAssembler, ScanCapture, collect_scan
from cistern_archive.tritech.codec import STEPS_PER_REV
from cistern_archive.tritech.settings import STEP_SIZES, HeadSettings

__all__ = [
    "AcquisitionResult",
    "find_site",
    "RawRecorder",
    "acquire_scan",
    "append_scan_to_record",
    "settings_for_record",
]

PARTIAL_SUFFIX = "-partial"
RAW_SUFFIX = ".seanet"


class RawRecorder:
    """An append-only capture file: every chunk is written, flushed and fsynced before returning.

    Parameters
    ----------
    path : Path
        Opened in append mode (created when missing); existing bytes are never touched.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._handle = open(self.path, "ab", buffering=0)
        self.bytes_written = 0

    def __call__(self, data: bytes) -> None:
        self._handle.write(data)
        os.fsync(self._handle.fileno())
        self.bytes_written += len(data)

    def close(self) -> None:
        if not self._handle.closed:
            os.fsync(self._handle.fileno())
            self._handle.close()

    def __enter__(self) -> "RawRecorder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class AcquisitionResult:
    """What :func:`acquire_scan` wrote.

    Attributes
    ----------
    raw_path : Path or None
        The byte capture (kept whenever a byte arrived; None when the head sent nothing).
    scan_path : Path or None
        The interchange scan (None when no scan line arrived).
    record_path : Path or None
        The site record, when it was updated.
    station : str
        The label recorded (suffixed ``-partial`` for a partial scan).
    capture : ScanCapture
    archived : list of str
        Files added to the archive (empty when it was skipped; see ``notes``).
    notes : list of str
        Human-readable remarks (archive skipped, partial scan...).
    """

    raw_path: Path | None
    scan_path: Path | None
    record_path: Path | None
    station: str
    capture: ScanCapture
    archived: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def partial(self) -> bool:
        return not self.capture.complete


def check_new_station(station: str, loaded: LoadedRecord) -> None:
    """Refuse a station label that cannot name the capture's files inside ``data/<site>/``.

    Raises
    ------
    CatalogError
        Before anything is written, naming the label (``../../x``, ``/abs/path``, ``.hidden``, ...).
    """
    for label in (station, station + PARTIAL_SUFFIX):
        try:
            check_station(label)
        except ValueError as exc:
            raise CatalogError([f"{loaded.path}: --station: {exc}"]) from None


def find_site(catalog: Path, site_id: str) -> LoadedRecord:
    """The loaded record with id ``site_id`` (CatalogError naming the catalog when absent)."""
    for path in record_paths(catalog):
        loaded = load_record(path, catalog)
        if loaded.record.id == site_id:
            return loaded
    raise CatalogError([f"{catalog}: no site record with id {site_id!r}"])


def settings_for_record(record: SiteRecord) -> HeadSettings:
    """Head settings from the record's ``sonar:`` block (range, bins, step, gain), continuous rotation."""
    sonar = record.sonar
    values: dict = {}
    if sonar.range_m is not None:
        values["range_m"] = sonar.range_m
    if sonar.bins is not None:
        values["n_bins"] = sonar.bins
    if sonar.step_deg is not None:
        wanted = sonar.step_deg * STEPS_PER_REV / 360
        values["step"] = min(STEP_SIZES, key=lambda s: abs(s - wanted))
    if sonar.gain is not None and sonar.gain <= 1:
        values["gain"] = sonar.gain
    return HeadSettings(continuous=True, **values)


def _unique(path: Path) -> Path:
    """``path`` if free, else ``stem-2.suffix``, ``stem-3.suffix``, ... (never an existing file)."""
    if not path.exists():
        return path
    k = 2
    while True:
        candidate = path.with_name(f"{path.stem}-{k}{path.suffix}")
        if not candidate.exists():
            return candidate
        k += 1


def _entry_yaml(entry: dict, indent: int) -> str:
    """One ``- key: value`` list item at ``indent`` spaces, in block style."""
    body = yaml.safe_dump([entry], sort_keys=False, default_flow_style=False, allow_unicode=True, width=100)
    pad = " " * indent
    return "".join(pad + line if line.strip() else line for line in body.splitlines(keepends=True))


def _line_end(text: str, index: int) -> int:
    """Index just after the last line before ``index`` that is neither blank nor only a comment."""
    lines = text[:index].splitlines(keepends=True)
    while lines and (not lines[-1].strip() or lines[-1].lstrip().startswith("#")):
        lines.pop()
    return sum(len(line) for line in lines)


def insert_scan_text(text: str, entry: dict) -> str:
    """The record text with ``entry`` appended to its ``scans:`` list; every other byte is kept.

    Falls back to re-emitting the whole document only when ``scans`` is not a block sequence.
    """
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    if not isinstance(root, yaml.MappingNode):
        raise CatalogError(["record is not a mapping"])
    for key, value in root.value:
        if key.value == "scans" and isinstance(value, yaml.SequenceNode) and not value.flow_style and value.value:
            cut = _line_end(text, value.value[-1].end_mark.index)
            prefix = text[:cut] if text[:cut].endswith("\n") else text[:cut] + "\n"
            return prefix + _entry_yaml(entry, value.start_mark.column) + text[cut:]
    data = yaml.safe_load(text)
    data.setdefault("scans", []).append(entry)
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100)


def append_scan_to_record(loaded: LoadedRecord, entry: dict) -> Path:
    """Append a scan entry to the record file atomically, validated before it replaces the record.

    Raises
    ------
    CatalogError
        The updated record would not validate (e.g. the station label already exists); the record on
        disk is then unchanged.
    """
    path = loaded.path
    text = path.read_text(encoding="utf-8")
    updated = insert_scan_text(text, entry)

    def validate(tmp: Path) -> None:
        load_record(tmp, loaded.root)

    write_text_atomic(path, updated, newline="", validate=validate)
    return path


Store = Callable[[str, list[tuple[Path, str]]], list[str]]
"""Keeps a capture's files safe: called with the site id and ``(path, role)`` pairs, returns the
catalog-relative paths it stored (the archive's ingest, see :func:`cistern_archive.archive.catalog_store`)."""


def acquire_scan(catalog: str | os.PathLike, port: str, site_id: str, station: str, *, depth_m: float,
                 heading_deg: float, settings: HeadSettings | None = None, config: DriverConfig | None = None,
                 store: Store | None = None, accept_missing: int = 0,
                 on_line: Callable[[ScanAssembler], None] | None = None,
                 log: Callable[[str], None] | None = None) -> AcquisitionResult:
    """Record one stationary scan from the head on ``port`` into site ``site_id`` of ``catalog``.

    Parameters
    ----------
    catalog : path
        Catalog root.
    port : str
        ``serial_for_url`` URL of the head (device path, ``socket://host:port``).
    site_id, station : str
        The record to extend and the new station's label (must not exist yet).
    depth_m, heading_deg : float
        Head depth (m, positive down) and compass heading (degrees clockwise from north) during the scan.
    settings : HeadSettings, optional
        Default: :func:`settings_for_record`.
    store : Store, optional
        Keeps the raw stream, the scan and the record once they are written (none: they stay in the
        catalog only). A store that fails leaves a note; the catalog files are complete either way.
    accept_missing : int
        Bearings that may stay empty after one revolution (see :func:`~.driver.collect_scan`).
    on_line, log : callable, optional
        Progress and status callbacks.

    Returns
    -------
    AcquisitionResult

    Raises
    ------
    CatalogError
        Unknown site, or the station already exists (checked before anything is written).
    """
    root = Path(catalog)
    loaded = find_site(root, site_id)
    if loaded.record.survey is not None:
        raise CatalogError([f"{loaded.path}: site {site_id!r} is a moving survey, built from its dataset; "
                            "stationary scans are added to sites with a scans list"])
    check_new_station(station, loaded)
    existing = {ref.station for ref in loaded.record.scans}
    if station in existing or station + PARTIAL_SUFFIX in existing:
        raise CatalogError([f"{loaded.path}: station {station!r} is already in site {site_id!r}; "
                            "choose another label"])
    settings = settings or settings_for_record(loaded.record)
    data_dir = root / "data" / site_id
    raw_path = _unique(data_dir / f"{station}{RAW_SUFFIX}")
    yaw = yaw_from_compass_deg(heading_deg)
    notes: list[str] = []
    with RawRecorder(raw_path) as recorder:
        driver = MicronDriver(port, settings, config=config, raw_sink=recorder, log=log)
        try:
            capture = collect_scan(driver, station=station, depth_m=depth_m, yaw_rad=yaw, on_line=on_line,
                                   accept_missing=accept_missing)
        finally:
            driver.close()
    if recorder.bytes_written == 0:
        raw_path.unlink(missing_ok=True)  # an empty capture says nothing; do not leave it behind
    result = AcquisitionResult(raw_path=raw_path if recorder.bytes_written else None, scan_path=None,
                               record_path=None, station=station, capture=capture, notes=notes)
    if capture.error:
        notes.append(f"scan stopped early: {capture.error}")
    if capture.scan is None:
        notes.append(f"no scan line arrived; the raw capture is kept in {raw_path}" if result.raw_path
                     else "nothing arrived from the head")
        return result
    label = station if capture.complete else station + PARTIAL_SUFFIX
    raw_rel = raw_path.resolve().relative_to(root.resolve()).as_posix()
    scan = capture.scan.replace(station=label, settings={**capture.scan.settings, "raw_file": raw_rel,
                                                         "heading_deg": heading_deg,
                                                         "requested": settings.as_record()})
    scan_path = write_scan(scan, _unique(data_dir / f"{label}.npz"))
    os.chmod(scan_path, 0o644)
    result.scan_path, result.station = scan_path, label
    entry = {
        "file": scan_path.resolve().relative_to(root.resolve()).as_posix(),
        "format": "npz",
        "station": label,
        "yaw_deg": float(heading_deg),
        "depth_m": float(depth_m),
        "time": dt.datetime.fromtimestamp(scan.timestamp, tz=dt.timezone.utc).isoformat(timespec="seconds"),
    }
    result.record_path = append_scan_to_record(loaded, entry)
    if capture.complete and capture.missing:
        notes.append(f"{capture.missing} bearing(s) missing, accepted (--accept-gaps)")
    if not capture.complete:
        notes.append(f"partial scan ({capture.missing} of {settings.beams_per_revolution()} bearings "
                     f"missing) recorded as station {label!r}")
    if store is not None:
        try:
            result.archived = store(site_id, [(raw_path, "scan"), (scan_path, "scan"), (result.record_path, "record")])
        except (OSError, CisternError) as exc:
            notes.append(f"archive failed ({exc}); the catalog files are complete, re-run `cistern-archive "
                         "ingest` later")
    return result
