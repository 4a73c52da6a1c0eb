"""Readers of Tritech SeaNet recordings: V4LOG files, raw packet captures and UDP-hub hex logs.

All three carry ``mtHeadData`` scan lines, decoded by the shared codec :mod:`cistern_archive.tritech.codec`.

Formats
-------
``seanet-v4log`` (``*.V4LOG``, SeaNet Pro)
    A 32-byte magic ``"SeaNetV4 Log File V1 ..."`` then eight u32 (little-endian) at byte 32: a version
    word, the offset of a registry-text block, the offset of the first record, the number of scan-line
    records, the offset of the configuration records, the offset of a u32 index of record offsets (two
    copies) and the last byte's offset; then two f64 times. Each record is a u16 record length (counting
    itself), an f64 time in days since 1899-12-30 and the SeaNet packet from its source-node byte on,
    *without* the byte-count field and the LF: SID, DID, type, sequence, node, payload.
``seanet-raw`` (``*.seanet``, ``*.bin``)
    The byte stream of the serial line exactly as received (what live acquisition writes first). No
    timestamps are stored, so scan times are ``nan``.
``seanet-udphub`` (``UdpHubLog_*.csv``)
    Lines ``YYYY.MM.DD hh.mm.ss.fff;ip;port;hex bytes``. Port 4002 lines are successive chunks of the
    SeaNet byte stream (a packet may span several lines); port 13102 lines are ASCII
    ``$ROV,heading,roll,pitch,depth,alt,lat,lon,*`` navigation sentences, used for each scan's heading
    (circular mean) and depth (median) over the scan's time span. Times are taken as UTC.

Geometry
--------
* Bearings: Tritech steps (1/16 gradian, 6400 per turn, clockwise, 3200 ahead) become sonar-frame
  radians counter-clockwise from forward with :func:`cistern_archive.tritech.codec.bearing_to_rad`:
  ``theta = -(steps - 3200) * 2 pi / 6400`` wrapped to [-pi, pi), mirrored (``-theta``) when the HdCtrl
  ``invert`` bit says the head is mounted upside-down (:meth:`HeadData.bearing_rad`, the same rule as
  the live-acquisition driver).
* Bin size from the echoed ADInterval: ``c * ADInterval * 640 ns / 2`` with c = 1500 m/s; bin 0 starts
  at range 0.
* Intensities: 8-bit lines keep 0..255 (``full_scale`` 255); 4-bit lines 0..15 (``full_scale`` 15).
"""

from __future__ import annotations

import bisect
import math
import re
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar.readers import ReadResult, header_check, read_bytes, register_reader
from cistern_archive.core.scan import yaw_from_compass_deg
from cistern_archive.sonar.sweeps import Beam, ScanTemplate, beams_to_scans
from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV, MessageType, Packet, PacketError
from cistern_archive.tritech.stream import StreamDecoder
from cistern_archive.tritech.head_data import HeadData, decode_head_data

V4LOG_MAGIC = b"SeaNetV4 Log File"
OLE_EPOCH_UNIX_DAYS = 25569.0  # 1970-01-01 in days since 1899-12-30
UDP_SONAR_PORT = 4002
UDP_NAV_PORT = 13102
MICRON_BEAM_WIDTH_RAD = math.radians(3.0)

DEVICE_NAMES = {0x11: "Tritech Micron DST", 0x02: "Tritech SeaNet imaging sonar (analogue head)"}


def sonar_model_name(device_type: int) -> str:
    """Human name of an ``mtHeadData`` DeviceType byte."""
    return DEVICE_NAMES.get(device_type, f"Tritech SeaNet head (device type 0x{device_type:02X})")


@dataclass(frozen=True)
class NavFix:
    """One ``$ROV`` navigation sentence."""

    time: float
    heading_deg: float
    depth_m: float


class _Collector:
    """Turns decoded SeaNet packets into beams, collecting warnings."""

    def __init__(self, path: Path, where: Callable[[int], str]):
        self.path = path
        self.where = where
        self.beams: list[Beam] = []
        self.heads: list[HeadData] = []
        self._notes: list[tuple[int, str]] = []

    def warn(self, offset: int, message: str) -> None:
        self.note(offset, f"{self.path}: {self.where(offset)}: {message}")

    def note(self, offset: int, text: str) -> None:
        """Record a complete warning text concerning stream offset ``offset``."""
        self._notes.append((offset, text))

    @property
    def warnings(self) -> list[str]:
        """Warnings in stream order."""
        return [text for _, text in sorted(self._notes, key=lambda item: item[0])]

    def add(self, packet: Packet, timestamp: float, offset: int) -> None:
        if packet.type != MessageType.HEAD_DATA:
            return
        try:
            head = decode_head_data(packet, offset=offset)
        except PacketError as exc:
            self.warn(offset, f"mtHeadData skipped: {str(exc).split(': ', 1)[-1]}")
            return
        if head.n_bins == 0:
            self.warn(offset, "mtHeadData skipped: empty beam (Dbytes 0)")
            return
        if head.ad_interval == 0:
            self.warn(offset, "mtHeadData skipped: ADInterval 0 gives no bin size")
            return
        if not 0 <= head.bearing < STEPS_PER_REV:
            self.warn(offset, f"mtHeadData skipped: bearing {head.bearing} outside 0..{STEPS_PER_REV - 1}")
            return
        key = (head.n_bins, head.ad_interval, head.adc8on, head.device_type)
        self.heads.append(head)
        self.beams.append(Beam(bearing_rad=head.bearing_rad(), intensities=head.bins,
                               timestamp=timestamp, key=key))


def _template(heads_by_beam: dict[int, HeadData], nav: Sequence[NavFix] = ()
              ) -> Callable[[Beam, Sequence[Beam]], ScanTemplate]:
    def make(first: Beam, sweep: Sequence[Beam]) -> ScanTemplate:
        head = heads_by_beam[id(first)]
        settings = head.settings()
        settings.update({"speed_of_sound_m_s": DEFAULT_SPEED_OF_SOUND, "bearing_zero_steps": 3200,
                         "first_bearing_steps": head.bearing,
                         "last_bearing_steps": heads_by_beam[id(sweep[-1])].bearing})
        yaw, depth = 0.0, 0.0
        if nav:
            fixes = _nav_for(nav, sweep[0].timestamp, sweep[-1].timestamp)
            if fixes:
                headings = np.radians([f.heading_deg for f in fixes])
                heading = math.degrees(math.atan2(np.sin(headings).mean(), np.cos(headings).mean())) % 360.0
                yaw = yaw_from_compass_deg(heading)
                depth = float(np.median([f.depth_m for f in fixes]))
                settings["compass_heading_deg"] = heading
        return ScanTemplate(full_scale=float(head.full_scale), bin_size_m=head.bin_size_m(), yaw_rad=yaw,
                            depth_m=depth, sonar_model=sonar_model_name(head.device_type),
                            beam_width_rad=MICRON_BEAM_WIDTH_RAD, settings=settings)

    return make


def _nav_for(nav: Sequence[NavFix], start: float, end: float) -> list[NavFix]:
    """Fixes within [start, end], or the nearest one when none falls inside."""
    if not (math.isfinite(start) and math.isfinite(end)):
        return []
    times = [f.time for f in nav]
    lo, hi = bisect.bisect_left(times, start), bisect.bisect_right(times, end)
    if hi > lo:
        return list(nav[lo:hi])
    i = min(max(lo, 0), len(nav) - 1)
    if i > 0 and abs(times[i - 1] - start) < abs(times[i] - start):
        i -= 1
    return [nav[i]]


def _finish(fmt: str, path: Path, col: _Collector, nav: Sequence[NavFix] = ()) -> ReadResult:
    if not col.beams:
        detail = f" ({len(col.warnings)} warning(s); first: {col.warnings[0]})" if col.warnings else ""
        raise ReaderError(str(path), f"no readable mtHeadData scan lines{detail}", offset=0)
    heads = {id(bm): hd for bm, hd in zip(col.beams, col.heads)}
    scans = beams_to_scans(col.beams, _template(heads, nav))
    return ReadResult(format=fmt, scans=scans, warnings=col.warnings)


def _warn_discards(col: _Collector, decoder: StreamDecoder) -> None:
    for d in decoder.take_discards():
        col.warn(d.offset, f"skipped {d.length} byte(s) that are not a valid SeaNet packet: {d.reason}")


# --------------------------------------------------------------------------------------------------
# Raw packet stream
# --------------------------------------------------------------------------------------------------

def _sniff_raw(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    dec = StreamDecoder()
    return bool(dec.feed(head))


def decode_seanet_stream(data: bytes, path: Path, where: Callable[[int], str] | None = None,
                         time_of: Callable[[int], float] | None = None) -> _Collector:
    """Decode a SeaNet byte stream into beams (used by the raw and UDP-hub readers)."""
    col = _Collector(path, where or (lambda off: f"byte offset {off}"))
    decoder = StreamDecoder()
    chunk = 1 << 16
    for start in range(0, len(data), chunk):
        for packet in decoder.feed(data[start:start + chunk]):
            col.add(packet, time_of(packet.offset) if time_of else float("nan"), packet.offset)
        _warn_discards(col, decoder)
    for packet in decoder.finish():
        col.add(packet, time_of(packet.offset) if time_of else float("nan"), packet.offset)
    _warn_discards(col, decoder)
    return col


@register_reader("seanet-raw", (".seanet", ".bin"), "raw SeaNet serial byte stream (live acquisition capture)",
                 sniff=_sniff_raw,
                 check=header_check(_sniff_raw, "a SeaNet stream: no valid packet in its first 4 KiB"))
def read_seanet_raw(path: Path) -> ReadResult:
    """Read a raw SeaNet capture: every ``mtHeadData`` of the stream, split into sweeps."""
    data = read_bytes(path)
    if not data:
        raise ReaderError(str(path), "empty file", offset=0)
    return _finish("seanet-raw", path, decode_seanet_stream(data, path))


# --------------------------------------------------------------------------------------------------
# V4LOG
# --------------------------------------------------------------------------------------------------

_V4_HEADER = struct.Struct("<8I")
_V4_RECORD_HEAD = struct.Struct("<Hd5B")
V4_MIN_RECORD = _V4_RECORD_HEAD.size  # 15 bytes: length, time, SID, DID, type, seq, node


def _v4_index(data: bytes, start: int, stop: int, limit: int) -> list[int]:
    """Record offsets from the index table (empty when it is absent or implausible)."""
    if not (0 < start <= stop <= len(data)) or (stop - start) % 4:
        return []
    offsets = np.frombuffer(data, dtype="<u4", count=(stop - start) // 4, offset=start)
    if offsets.size == 0 or np.any(offsets >= limit) or np.any(np.diff(offsets.astype(np.int64)) <= 0):
        return []
    return [int(x) for x in offsets]


def _sniff_v4log(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            return fh.read(len(V4LOG_MAGIC)) == V4LOG_MAGIC
    except OSError:
        return False


@register_reader("seanet-v4log", (".v4log",), "Tritech SeaNet Pro V4LOG", sniff=_sniff_v4log,
                 check=header_check(_sniff_v4log, f"a V4LOG file: it does not start with {V4LOG_MAGIC!r}"))
def read_v4log(path: Path) -> ReadResult:
    """Read a SeaNet Pro V4LOG file (layout in the module docstring)."""
    data = read_bytes(path)
    if not data.startswith(V4LOG_MAGIC):
        raise ReaderError(str(path), f"not a V4LOG file: expected magic {V4LOG_MAGIC!r}", offset=0)
    if len(data) < 32 + _V4_HEADER.size:
        raise ReaderError(str(path), f"truncated V4LOG header ({len(data)} bytes)", offset=len(data))
    _, _, first, n_records, _, index_at, _, _ = _V4_HEADER.unpack_from(data, 32)
    if not 32 + _V4_HEADER.size <= first < len(data):
        raise ReaderError(str(path), f"first-record offset {first} outside the file", offset=32 + 8)
    end = index_at if first < index_at <= len(data) else len(data)
    index = _v4_index(data, index_at, index_at + 4 * n_records, end) if index_at == end else []
    col = _Collector(path, lambda off: f"byte offset {off}")
    pos, record = first, 0
    while pos < end:
        problem = _v4_record(data, pos, end, col, record)
        if problem is None:
            pos += struct.unpack_from("<H", data, pos)[0]
            record += 1
            continue
        nxt = next((o for o in index if o > pos), None)
        how = "resuming at the next indexed record"
        if nxt is None:
            nxt, how = _v4_resync(data, pos, end), "resuming at the next plausible scan-line record"
        col.note(pos, f"{path}: record {record}: byte offset {pos}: {problem}; "
                 + (f"{how} (byte offset {nxt})" if nxt is not None else "stopped"))
        if nxt is None:
            break
        pos = nxt
        record += 1
    if n_records and record < n_records and not col.warnings:
        col.note(pos, f"{path}: header announces {n_records} records, found {record}")
    return _finish("seanet-v4log", path, col)


def _v4_resync(data: bytes, pos: int, end: int) -> int | None:
    """Offset of the next record after ``pos`` that looks like an mtHeadData record, or None."""
    hit = pos + 1 + 11
    while True:
        hit = data.find(b"\xff\x02\x80", hit, end)
        if hit < 0:
            return None
        q = hit - 11
        if q > pos and _v4_consistent(data, q, end):
            return q
        hit += 1


def _v4_consistent(data: bytes, pos: int, end: int) -> bool:
    """A record at ``pos`` whose length agrees with its mtHeadData TotalByteCount (others: any sane length)."""
    if end - pos < V4_MIN_RECORD:
        return False
    (length,) = struct.unpack_from("<H", data, pos)
    if length < V4_MIN_RECORD or pos + length > end:
        return False
    if data[pos + 12] == MessageType.HEAD_DATA:
        return length >= V4_MIN_RECORD + 2 and struct.unpack_from("<H", data, pos + 15)[0] == length - 15
    return True


def _v4_record(data: bytes, pos: int, end: int, col: _Collector, record: int) -> str | None:
    """Decode one V4LOG record into ``col``; return a problem description or None."""
    if end - pos < V4_MIN_RECORD:
        return f"truncated record ({end - pos} bytes left)"
    length, days, sid, did, mtype, seq, node = _V4_RECORD_HEAD.unpack_from(data, pos)
    if not _v4_consistent(data, pos, end):
        return f"record length {length} invalid ({end - pos} bytes left)"
    if not (math.isfinite(days) and 0 < days < 200_000):
        col.note(pos, f"{col.path}: record {record}: byte offset {pos + 2}: invalid time {days!r}; using nan")
        timestamp = float("nan")
    else:
        timestamp = (days - OLE_EPOCH_UNIX_DAYS) * 86400.0
    payload = data[pos + V4_MIN_RECORD:pos + length]
    packet = Packet(sid=sid, did=did, type=mtype, seq=seq, node=node, payload=payload, offset=pos)
    col.add(packet, timestamp, pos)
    return None


# --------------------------------------------------------------------------------------------------
# UDP hub hex log
# --------------------------------------------------------------------------------------------------

_UDP_LINE = re.compile(r"^(\d{4})\.(\d{2})\.(\d{2}) (\d{2})\.(\d{2})\.(\d{2})\.(\d{1,6});([^;]*);(\d+);(.*)$")


def _sniff_udphub(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            first = fh.readline(4096).decode("ascii", errors="replace").strip()
    except OSError:
        return False
    return bool(_UDP_LINE.match(first))


def _udp_time(m: re.Match) -> float:
    y, mo, d, h, mi, s = (int(m.group(i)) for i in range(1, 7))
    frac = float("0." + m.group(7))
    return datetime(y, mo, d, h, mi, s, tzinfo=timezone.utc).timestamp() + frac


def parse_rov_sentence(text: str) -> tuple[float, float] | None:
    """``(heading_deg, depth_m)`` of a ``$ROV,heading,roll,pitch,depth,...`` sentence, or None."""
    fields = text.strip().split(",")
    if len(fields) < 5 or fields[0] != "$ROV":
        return None
    try:
        heading, depth = float(fields[1]), float(fields[4])
    except ValueError:
        return None
    if not (math.isfinite(heading) and math.isfinite(depth)):
        return None
    return heading % 360.0, depth


@register_reader("seanet-udphub", (".csv",), "SeaNet UDP hub hex log (UdpHubLog_*.csv) with $ROV navigation",
                 sniff=_sniff_udphub,
                 check=header_check(_sniff_udphub, "a UDP hub log: its first line is not a timestamped hex record"))
def read_udphub(path: Path) -> ReadResult:
    """Read a ``UdpHubLog_*.csv``: port-4002 SeaNet stream plus port-13102 ``$ROV`` navigation."""
    raw = read_bytes(path)
    text = raw.decode("ascii", errors="replace")
    stream = bytearray()
    starts: list[int] = []  # stream offset where each sonar line's bytes begin
    lines: list[int] = []  # 1-based line number of each sonar line
    times: list[float] = []
    nav: list[NavFix] = []
    warnings: list[tuple[int, str]] = []  # (stream offset reached, text)
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        m = _UDP_LINE.match(line.strip())
        if m is None:
            warnings.append((len(stream), f"{path}: line {lineno}: not a 'time;ip;port;hex' line; skipped"))
            continue
        try:
            payload = bytes.fromhex(m.group(10))
            when = _udp_time(m)
        except ValueError as exc:
            warnings.append((len(stream), f"{path}: line {lineno}: {exc}; skipped"))
            continue
        port = int(m.group(9))
        if port == UDP_SONAR_PORT:
            starts.append(len(stream))
            lines.append(lineno)
            times.append(when)
            stream += payload
        elif port == UDP_NAV_PORT:
            fix = parse_rov_sentence(payload.decode("ascii", errors="replace"))
            if fix is None:
                warnings.append((len(stream), f"{path}: line {lineno}: unreadable $ROV sentence; skipped"))
            else:
                nav.append(NavFix(when, *fix))
    if not stream:
        raise ReaderError(str(path), f"no port-{UDP_SONAR_PORT} SeaNet lines", record=0)

    def line_of(offset: int) -> int:
        return max(bisect.bisect_right(starts, offset) - 1, 0)

    col = decode_seanet_stream(
        bytes(stream), path,
        where=lambda off: f"line {lines[line_of(off)]} (stream byte offset {off})",
        time_of=lambda off: times[line_of(off)],
    )
    for offset, text in warnings:
        col.note(offset - 1, text)
    nav.sort(key=lambda f: f.time)
    return _finish("seanet-udphub", path, col, nav)
