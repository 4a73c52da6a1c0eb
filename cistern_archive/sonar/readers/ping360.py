"""Reader of Blue Robotics Ping Viewer binary logs of a Ping360 scanning sonar.

File layout (Qt ``QDataStream``, big-endian)
--------------------------------------------
* Header: ``QString`` magic ``"PingViewer sensor log file"``, u32 format version (1), then five
  ``QString`` (git hash, build date, version tag, OS name, OS version) and two u32 (sensor family and
  type). A ``QString`` is a u32 byte length (``0xFFFFFFFF`` = null) followed by UTF-16BE text.
* Then records until the end: a ``QString`` elapsed time ``hh:mm:ss.zzz`` since the log started
  (digits may be in any Unicode script, e.g. Persian ``۰۰:۰۰:۰۲.۸۴۵``) and a ``QByteArray`` (u32 length +
  bytes) holding **one chunk of the serial byte stream as read**, not one message: a Ping message may
  span two records.

The chunks are concatenated and decoded as Ping protocol messages (little-endian): ``"BR"``, u16 payload
length, u16 message id, u8 source and destination ids, the payload, and a u16 checksum equal to the sum
of all previous bytes. A message whose checksum fails is skipped one byte at a time (the decoder resyncs
on the next ``"BR"``), with a warning naming its file offset. Messages used:

* 2300 ``device_data``: mode u8, gain u8, angle u16, transmit duration u16, sample period u16,
  transmit frequency u16, number of samples u16, data length u16, data (u8 per sample);
* 2301 ``auto_device_data``: as 2300 but with start/stop angle u16, step count u8 and delay u8 between the
  frequency and the number of samples.

Geometry
--------
* Angle: gradians 0..399 increasing clockwise seen from above. Ping Viewer shows raw angle 200 straight
  ahead (it adds a default offset of 200 gradians to the device angle, and its sectors are centred
  there), so the sonar frame (CCW from forward, radians) is
  ``theta = -(angle - 200) * 2 pi / 400`` wrapped to [-pi, pi).
* Bin size: ``c * sample_period * 25 ns / 2`` with c = 1500 m/s; bin 0 starts at range 0.
* Intensities are 8-bit (``full_scale`` 255).
* Time: the file name's ``YYYYMMDD-hhmmssmmm`` (taken as UTC) plus each record's elapsed time; ``nan``
  when the name carries no time.
"""

from __future__ import annotations

import bisect
import math
import re
import struct
import unicodedata
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar.readers import ReadResult, read_bytes, register_reader
from cistern_archive.core.scan import wrap_angle
from cistern_archive.sonar.sweeps import Beam, ScanTemplate, beams_to_scans

MAGIC = "PingViewer sensor log file"
MAGIC_BYTES = struct.pack(">I", 2 * len(MAGIC)) + MAGIC.encode("utf-16-be")
SAMPLE_TICK_S = 25e-9
SPEED_OF_SOUND = 1500.0
GRADIANS = 400
ANGLE_AHEAD = 200
PING360_BEAM_WIDTH_RAD = math.radians(2.2)
MAX_PAYLOAD = 8192
MAX_TIME_STRING = 128
MSG_DEVICE_DATA = 2300
MSG_AUTO_DEVICE_DATA = 2301

_DEVICE_DATA = struct.Struct("<BBHHHHHH")
_AUTO_DEVICE_DATA = struct.Struct("<BBHHHHHHBBHH")
_TIME = re.compile(r"^(\d+):(\d{2}):(\d{2})(?:\.(\d+))?$")
_NAME_TIME = re.compile(r"(\d{8})-(\d{6})(\d{3})")


@dataclass
class _Chunks:
    """The concatenated serial stream and where each chunk came from."""

    stream: bytearray
    stream_starts: list[int]
    file_offsets: list[int]
    elapsed: list[float]

    def locate(self, offset: int) -> tuple[int, int]:
        """``(record index, file offset)`` of stream byte ``offset``."""
        k = max(bisect.bisect_right(self.stream_starts, offset) - 1, 0)
        return k, self.file_offsets[k] + offset - self.stream_starts[k]


def _ascii_digits(text: str) -> str:
    return "".join(str(unicodedata.decimal(ch)) if unicodedata.decimal(ch, None) is not None else ch
                   for ch in text)


def parse_elapsed(text: str) -> float | None:
    """Seconds of an ``hh:mm:ss.zzz`` string in any digit script, or None."""
    m = _TIME.match(_ascii_digits(text.strip()))
    if m is None:
        return None
    frac = float("0." + m.group(4)) if m.group(4) else 0.0
    return int(m.group(1)) * 3600 + int(m.group(2)) * 60 + int(m.group(3)) + frac


def start_time_from_name(path: Path) -> float:
    """Unix time encoded in a Ping Viewer file name (``..._YYYYMMDD-hhmmssmmm...``), or ``nan``."""
    m = _NAME_TIME.search(path.name)
    if m is None:
        return float("nan")
    try:
        stamp = datetime.strptime(m.group(1) + m.group(2), "%Y%m%d%H%M%S").replace(tzinfo=timezone.utc)
    except ValueError:
        return float("nan")
    return stamp.timestamp() + int(m.group(3)) / 1000.0


def _qstring(data: bytes, pos: int, limit: int) -> tuple[str | None, int]:
    """Decode a QString at ``pos``; raises ValueError when it is malformed or longer than ``limit``."""
    if pos + 4 > len(data):
        raise ValueError("truncated string length")
    (n,) = struct.unpack_from(">I", data, pos)
    if n == 0xFFFFFFFF:
        return None, pos + 4
    if n % 2 or n > limit or pos + 4 + n > len(data):
        raise ValueError(f"implausible string length {n}")
    return data[pos + 4:pos + 4 + n].decode("utf-16-be"), pos + 4 + n


def _parse_header(data: bytes, path: Path) -> tuple[int, dict[str, object]]:
    if not data.startswith(MAGIC_BYTES):
        raise ReaderError(str(path), f"not a Ping Viewer log: expected the {MAGIC!r} header", offset=0)
    pos = len(MAGIC_BYTES)
    try:
        (version,) = struct.unpack_from(">I", data, pos)
        pos += 4
        texts = []
        for _ in range(5):
            text, pos = _qstring(data, pos, 1024)
            texts.append(text)
        family, sensor = struct.unpack_from(">II", data, pos)
        pos += 8
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        raise ReaderError(str(path), f"malformed Ping Viewer header: {exc}", offset=pos) from exc
    info = {"log_version": version, "ping_viewer_hash": texts[0], "ping_viewer_date": texts[1],
            "ping_viewer_version": texts[2], "os": texts[3], "os_version": texts[4],
            "sensor_family": family, "sensor_type": sensor}
    return pos, info


def _record_at(data: bytes, pos: int) -> tuple[float, int, int] | None:
    """``(elapsed, chunk start, chunk length)`` of a plausible record at ``pos`` (length may overrun)."""
    try:
        text, p = _qstring(data, pos, MAX_TIME_STRING)
    except (ValueError, UnicodeDecodeError):
        return None
    elapsed = parse_elapsed(text) if text is not None else None
    if elapsed is None or p + 4 > len(data):
        return None
    (n,) = struct.unpack_from(">I", data, p)
    return elapsed, p + 4, n


def _resync(data: bytes, pos: int) -> int | None:
    """Offset of the next plausible record after ``pos``."""
    q = pos + 1
    while True:
        q = data.find(b"\x00\x00\x00", q)
        if q < 0 or q + 8 > len(data):
            return None
        rec = _record_at(data, q)
        if rec is not None and rec[1] + rec[2] <= len(data):
            return q
        q += 1


def _read_chunks(data: bytes, pos: int, path: Path, warnings: list[tuple[int, str]]) -> _Chunks:
    chunks = _Chunks(bytearray(), [], [], [])
    record = 0
    while pos < len(data):
        rec = _record_at(data, pos)
        if rec is None or rec[1] + rec[2] > len(data):
            nxt = _resync(data, pos)
            if rec is not None and nxt is None:  # the last chunk is cut short: keep what is there
                warnings.append((pos, f"{path}: record {record}: byte offset {pos}: truncated: chunk of {rec[2]} "
                                      f"bytes has {len(data) - rec[1]}; kept what is there"))
                chunks.stream_starts.append(len(chunks.stream))
                chunks.file_offsets.append(rec[1])
                chunks.elapsed.append(rec[0])
                chunks.stream += data[rec[1]:]
                break
            problem = "not a (time, bytes) record" if rec is None else f"chunk length {rec[2]} overruns the file"
            warnings.append((pos, f"{path}: record {record}: byte offset {pos}: {problem}; "
                             + (f"skipped {nxt - pos} bytes to the next record" if nxt is not None
                                else f"ignored the last {len(data) - pos} bytes")))
            if nxt is None:
                break
            pos = nxt
            record += 1
            continue
        elapsed, start, n = rec
        chunks.stream_starts.append(len(chunks.stream))
        chunks.file_offsets.append(start)
        chunks.elapsed.append(elapsed)
        chunks.stream += data[start:start + n]
        pos = start + n
        record += 1
    return chunks


@dataclass(frozen=True)
class PingMessage:
    """One checksummed Ping protocol message."""

    message_id: int
    payload: bytes
    offset: int  # stream offset of "BR"


def decode_ping_stream(stream: bytes | bytearray) -> tuple[list[PingMessage], list[tuple[int, int, str]]]:
    """All valid messages of a Ping byte stream and the ``(offset, length, reason)`` of skipped bytes."""
    messages: list[PingMessage] = []
    skipped: list[tuple[int, int, str]] = []

    def skip(start: int, stop: int, reason: str) -> None:
        if stop <= start:
            return
        if skipped and skipped[-1][0] + skipped[-1][1] == start and reason == "no 'BR'":
            o, n, r = skipped[-1]
            skipped[-1] = (o, n + stop - start, r)
        else:
            skipped.append((start, stop - start, reason))

    pos, n = 0, len(stream)
    while pos < n:
        at = stream.find(b"BR", pos)
        if at < 0:
            skip(pos, n, "no 'BR'")
            break
        skip(pos, at, "no 'BR'")
        if n - at < 8:
            skip(at, n, f"truncated message header ({n - at} bytes)")
            break
        length, mid = struct.unpack_from("<HH", stream, at + 2)
        end = at + 8 + length + 2
        if length > MAX_PAYLOAD:
            skip(at, at + 1, f"payload length {length} exceeds {MAX_PAYLOAD}")
            pos = at + 1
            continue
        if end > n:
            skip(at, at + 1, f"truncated message {mid}: {n - at} of {end - at} bytes")
            pos = at + 1
            continue
        (check,) = struct.unpack_from("<H", stream, end - 2)
        if int(np.frombuffer(stream, dtype=np.uint8, count=end - 2 - at, offset=at).sum()) & 0xFFFF != check:
            skip(at, at + 1, f"checksum mismatch in message {mid}")
            pos = at + 1
            continue
        messages.append(PingMessage(mid, bytes(stream[at + 8:end - 2]), at))
        pos = end
    return messages, skipped


def _beam(msg: PingMessage) -> tuple[dict[str, int], np.ndarray] | str:
    """Fields and samples of a device_data message, or a problem description."""
    fmt = _DEVICE_DATA if msg.message_id == MSG_DEVICE_DATA else _AUTO_DEVICE_DATA
    if len(msg.payload) < fmt.size:
        return f"message {msg.message_id} payload of {len(msg.payload)} bytes is too short"
    values = fmt.unpack_from(msg.payload)
    if msg.message_id == MSG_DEVICE_DATA:
        mode, gain, angle, tx, period, freq, n_samples, n_data = values
        extra = {}
    else:
        mode, gain, angle, tx, period, freq, start, stop, steps, delay, n_samples, n_data = values
        extra = {"start_angle": start, "stop_angle": stop, "num_steps": steps, "delay": delay}
    if n_data > len(msg.payload) - fmt.size:
        return f"data length {n_data} exceeds the {len(msg.payload) - fmt.size} bytes present"
    if n_data == 0:
        return "empty beam (no samples)"
    if angle >= GRADIANS:
        return f"angle {angle} outside 0..{GRADIANS - 1} gradians"
    if period == 0:
        return "sample period 0 gives no bin size"
    samples = np.frombuffer(msg.payload, dtype=np.uint8, count=n_data, offset=fmt.size).copy()
    fields = {"mode": mode, "gain_setting": gain, "angle": angle, "transmit_duration": tx,
              "sample_period": period, "transmit_frequency": freq, "number_of_samples": n_samples, **extra}
    return fields, samples


def _sniff(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            return fh.read(len(MAGIC_BYTES)) == MAGIC_BYTES
    except OSError:
        return False


def _check(path: Path) -> None:
    if not _sniff(path):
        raise ReaderError(str(path), f"not a Ping Viewer log: it does not start with {MAGIC_BYTES!r}")


@register_reader("ping360", (".bin",), "Blue Robotics Ping Viewer log of a Ping360", sniff=_sniff, check=_check)
def read_ping360(path: Path) -> ReadResult:
    """Read a Ping Viewer log; every device_data beam, split into sweeps (layout in the module docstring)."""
    data = read_bytes(path)
    pos, info = _parse_header(data, path)
    warnings: list[tuple[int, str]] = []  # (file offset, text)
    chunks = _read_chunks(data, pos, path, warnings)
    messages, skipped = decode_ping_stream(chunks.stream)
    for offset, length, reason in skipped:
        record, file_offset = chunks.locate(offset)
        warnings.append((file_offset, f"{path}: record {record}: byte offset {file_offset}: skipped {length} "
                                      f"byte(s) of the serial stream: {reason}"))
    t0 = start_time_from_name(path)
    beams: list[Beam] = []
    fields_of: dict[int, dict[str, int]] = {}
    for msg in messages:
        if msg.message_id not in (MSG_DEVICE_DATA, MSG_AUTO_DEVICE_DATA):
            continue
        result = _beam(msg)
        record, file_offset = chunks.locate(msg.offset)
        if isinstance(result, str):
            warnings.append((file_offset, f"{path}: record {record}: byte offset {file_offset}: beam skipped: "
                                          f"{result}"))
            continue
        fields, samples = result
        theta = wrap_angle(-(fields["angle"] - ANGLE_AHEAD) * 2.0 * math.pi / GRADIANS)
        key = (samples.size, fields["sample_period"], fields["gain_setting"], fields["transmit_frequency"])
        beam = Beam(bearing_rad=theta, intensities=samples, timestamp=t0 + chunks.elapsed[record], key=key)
        fields_of[id(beam)] = fields
        beams.append(beam)
    if not beams:
        raise ReaderError(str(path), f"no readable Ping360 device_data beams ({len(warnings)} warning(s))",
                          offset=pos)

    def template(first: Beam, sweep) -> ScanTemplate:
        fields = fields_of[id(first)]
        settings = {**info, **fields, "speed_of_sound_m_s": SPEED_OF_SOUND, "angle_ahead": ANGLE_AHEAD,
                    "last_angle": fields_of[id(sweep[-1])]["angle"]}
        bin_size = SPEED_OF_SOUND * fields["sample_period"] * SAMPLE_TICK_S / 2
        return ScanTemplate(full_scale=255.0, bin_size_m=bin_size, sonar_model="Blue Robotics Ping360",
                            beam_width_rad=PING360_BEAM_WIDTH_RAD, settings=settings)

    ordered = [text for _, text in sorted(warnings, key=lambda item: item[0])]
    return ReadResult(format="ping360", scans=beams_to_scans(beams, template), warnings=ordered)
