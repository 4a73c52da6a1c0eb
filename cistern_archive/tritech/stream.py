"""Incremental SeaNet stream decoding: feed byte chunks of any size, get whole validated packets.

A decoder never splits on ``@`` or LF, because both occur inside payloads; after any failure it skips
one byte past the bad ``@`` and searches again (``../shared/protocols/tritech_micron.md`` §1.3 rule 7),
so the next good packet is never lost. Skipped bytes are reported as :class:`Discard`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

from cistern_archive.tritech.codec import Packet, check_body, check_header, packet_at

__all__ = ["Discard", "StreamDecoder", "iter_packets"]


@dataclass(frozen=True)
class Discard:
    """Bytes a :class:`StreamDecoder` skipped.

    Attributes
    ----------
    offset : int
        Stream offset of the first skipped byte.
    length : int
        Number of bytes skipped.
    reason : str
        Why (the failed check of the ``@`` at ``offset``, or "no '@'" for bytes between packets).
    """

    offset: int
    length: int
    reason: str

    def __str__(self) -> str:
        return f"byte offset {self.offset}: skipped {self.length} byte(s): {self.reason}"


@dataclass
class StreamDecoder:
    """Incremental SeaNet decoder: feed byte chunks of any size, get whole validated packets.

    The decoder keeps at most one partial frame (bounded by :data:`MAX_LENGTH`). A false ``@`` whose hex
    and binary lengths happen to agree holds output back until its claimed length has arrived (at most
    ``MAX_LENGTH + 6`` bytes), then is rejected and the bytes after it are searched again, so no good
    packet is lost; :meth:`finish` does the same at the end of a stream. Skipped bytes are
    reported as :class:`Discard` records in :attr:`discards` (drain them with :meth:`take_discards`);
    contiguous skipped bytes are merged into one record, whose reason is the first failed check (or
    "no '@'" when the bytes held no ``@``).

    Parameters
    ----------
    strict_byte_count : bool
        Reject frames whose byte-count field is inconsistent (§1.3 rule 5).
    start_offset : int
        Stream offset of the first byte fed (packet offsets count from here).

    Examples
    --------
    >>> dec = StreamDecoder()
    >>> [p.type_name for p in dec.feed(b"xx" + encode_packet(MessageType.SEND_VERSION))]
    ['mtSendVersion']
    >>> dec.take_discards()
    [Discard(offset=0, length=2, reason="no '@'")]
    """

    strict_byte_count: bool = True
    start_offset: int = 0
    discards: list[Discard] = field(default_factory=list)
    packets_decoded: int = 0
    bytes_fed: int = 0

    def __post_init__(self) -> None:
        self._buf = bytearray()
        self._base = self.start_offset  # stream offset of self._buf[0]

    @property
    def pending(self) -> int:
        """Bytes buffered but not yet part of a decoded packet or a discard."""
        return len(self._buf)

    @property
    def stream_offset(self) -> int:
        """Stream offset of the next byte to be fed."""
        return self._base + len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Packet]:
        """Append ``data`` and return every packet completed by it, in stream order."""
        self._buf += data
        self.bytes_fed += len(data)
        return list(self._drain(final=False))

    def __call__(self, data: bytes | bytearray | memoryview) -> Iterator[Packet]:
        """Alias of :meth:`feed` returning an iterator."""
        return iter(self.feed(data))

    def finish(self) -> list[Packet]:
        """Signal the end of the stream.

        A candidate frame that cannot complete (the stream ended first) is abandoned one byte at a time,
        so a good packet hidden inside a false frame's claimed length is still returned. Whatever remains
        is reported as a discard ("truncated").
        """
        return list(self._drain(final=True))

    def take_discards(self) -> list[Discard]:
        """Return and clear the discard records."""
        out, self.discards = self.discards, []
        return out

    def _discard(self, start: int, stop: int, reason: str) -> None:
        if stop <= start:
            return
        offset = self._base + start
        last = self.discards[-1] if self.discards else None
        if last is not None and last.offset + last.length == offset:
            keep = reason if last.reason == "no '@'" else last.reason
            self.discards[-1] = Discard(last.offset, last.length + stop - start, keep)
        else:
            self.discards.append(Discard(offset, stop - start, reason))

    def _drain(self, final: bool) -> Iterator[Packet]:
        buf = self._buf
        pos = 0
        n = len(buf)
        try:
            while pos < n:
                at = buf.find(b"@", pos)
                if at < 0:
                    self._discard(pos, n, "no '@'")
                    pos = n
                    break
                self._discard(pos, at, "no '@'")
                pos = at
                if n - pos < 7:
                    if final:
                        self._discard(pos, pos + 1, f"truncated: stream ends {n - pos} byte(s) after '@'")
                        pos += 1
                        continue
                    break
                length, reason = check_header(buf, pos)
                if length is None:
                    self._discard(pos, pos + 1, reason)
                    pos += 1
                    continue
                if n - pos < length + 6:
                    if final:
                        self._discard(pos, pos + 1, f"truncated: {n - pos} of {length + 6} bytes of a frame")
                        pos += 1
                        continue
                    break
                reason = check_body(buf, pos, length, self.strict_byte_count)
                if reason:
                    self._discard(pos, pos + 1, reason)
                    pos += 1
                    continue
                packet = packet_at(buf, pos, length, self._base + pos)
                pos += length + 6
                self.packets_decoded += 1
                yield packet
        finally:
            del buf[:pos]
            self._base += pos


def iter_packets(data: bytes | bytearray, *, start_offset: int = 0, strict_byte_count: bool = True,
                 discards: list[Discard] | None = None) -> Iterator[Packet]:
    """Decode every packet of a complete byte string (feeds it once and finishes).

    Parameters
    ----------
    data : bytes
        The stream.
    start_offset : int
        Offset of ``data[0]``.
    strict_byte_count : bool
        See :class:`StreamDecoder`.
    discards : list, optional
        Receives the :class:`Discard` records.
    """
    dec = StreamDecoder(strict_byte_count=strict_byte_count, start_offset=start_offset)
    yield from dec.feed(data)
    yield from dec.finish()
    if discards is not None:
        discards.extend(dec.take_discards())
