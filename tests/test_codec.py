"""SeaNet codec: the protocol sheet's worked examples, framing checks, resync and property tests."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cistern_archive.tritech.codec import MessageType, PacketError, decode_packet, encode_packet
from cistern_archive.tritech.stream import StreamDecoder, iter_packets
from cistern_archive.tritech.head_data import (
    HeadData,
    ad_interval_for,
    bearing_to_rad,
    decode_head_data,
    encode_head_data,
    rad_to_bearing,
)

SEND_DATA = bytes.fromhex("40 30 30 30 43 0C 00 FF 02 07 19 80 02 95 2C B3 02 0A")  # sheet §12.1
TINY_4BIT = bytes.fromhex(  # sheet §12.5
    "40 30 30 32 42 2B 00 02 FF 00 02 80 02 23 00 11"
    "00 00 06 23 0A 00 00 00 00 00 54 00 00 26 28 00"
    "00 04 01 60 09 A0 0F 20 A0 0C 04 00 12 34 AB F0 0A")
ALIVE = bytes.fromhex("40 30 30 31 30 10 00 02 FF 0B 04 80 02 00 40 E2 01 00 80 0C 8A 0A")  # §12.6
VERSION = bytes.fromhex("40 30 30 31 33 13 00 02 FF 0E 01 80 02 03 01 34 12 45 23 01 00 EF BE 02 0A")  # §12.7


def _head(bins: np.ndarray, *, adc8on: bool = True, bearing: int = 3200) -> HeadData:
    return HeadData(total_byte_count=0, device_type=0x11, head_status=0x10 if adc8on else 0, sweep_code=0,
                    hd_ctrl=0x2307 if adc8on else 0x2306, range_scale_raw=100, txn=0, gain=84, slope=0,
                    ad_span=0x51, ad_low=0x08, heading_offset=0, ad_interval=104, left_limit=2400,
                    right_limit=4000, step_size=16, bearing=bearing, dbytes=0, bins=np.asarray(bins, np.uint8))


def test_sheet_send_data_example_round_trips():
    packet = decode_packet(SEND_DATA)
    assert (packet.sid, packet.did, packet.type, packet.seq, packet.node) == (0xFF, 2, 25, 0x80, 2)
    assert packet.payload == bytes.fromhex("95 2C B3 02") and packet.byte_count == 7
    assert encode_packet(MessageType.SEND_DATA, packet.payload) == SEND_DATA
    assert packet.to_bytes() == SEND_DATA and packet.total_length == 18


@pytest.mark.parametrize("mtype,tt", [(MessageType.SEND_VERSION, 0x17), (MessageType.SEND_BB_USER, 0x18),
                                      (MessageType.REBOOT, 0x10), (MessageType.STOP_ALIVES, 0x42)])
def test_no_payload_commands_match_sheet(mtype, tt):
    assert encode_packet(mtype) == bytes([0x40, 0x30, 0x30, 0x30, 0x38, 8, 0, 0xFF, 2, 3, tt, 0x80, 2, 0x0A])


def test_alive_and_version_examples_decode():
    alive = decode_packet(ALIVE)
    assert alive.type == MessageType.ALIVE and alive.type_name == "mtAlive" and len(alive.payload) == 8
    version = decode_packet(VERSION)
    assert version.type == MessageType.VERSION_DATA and version.length == 19


def test_tiny_4bit_head_data_example():
    head = decode_head_data(decode_packet(TINY_4BIT))
    assert head.bins.tolist() == [1, 2, 3, 4, 10, 11, 15, 0]
    assert decode_head_data(decode_packet(TINY_4BIT), high_nibble_first=False).bins.tolist() == [
        2, 1, 4, 3, 11, 10, 0, 15]
    assert (head.bearing, head.ad_interval, head.range_scale, head.range_unit) == (3232, 260, 1.0, "m")
    assert (head.step_size, head.left_limit, head.right_limit, head.gain) == (32, 2400, 4000, 84)
    assert not head.adc8on and head.full_scale == 15 and head.continuous and head.scan_right
    assert head.bin_size_m() == pytest.approx(1500 * 260 * 640e-9 / 2)
    assert head.bin_size_m(1480.0) == pytest.approx(1480 * 260 * 640e-9 / 2)
    assert encode_head_data(head) == TINY_4BIT


def test_8bit_head_data_round_trip_and_sheet_geometry():
    bins = np.arange(200, dtype=np.uint8)
    frame = encode_head_data(_head(bins))
    assert len(frame) == 245 and frame[1:5] == b"00EF" and frame[9] == 0  # sheet §12.4
    head = decode_head_data(decode_packet(frame))
    assert head.adc8on and head.full_scale == 255 and head.n_bins == 200 and head.total_byte_count == 231
    np.testing.assert_array_equal(head.bins, bins)
    assert head.bin_size_m() == pytest.approx(0.04992) and head.span_m() == pytest.approx(9.984)
    assert ad_interval_for(10.0, 200) == 104


def test_lowercase_hex_length_is_accepted():
    frame = bytearray(encode_packet(MessageType.SEND_DATA, b"\x00\x00\x00\x0a"))
    frame[1:5] = b"000c"
    assert decode_packet(bytes(frame)).payload == b"\x00\x00\x00\x0a"


@pytest.mark.parametrize("mutate,message", [
    (lambda f: f.__setitem__(5, 0x0D), "hex length"),
    (lambda f: f.__setitem__(len(f) - 1, 0x0B), "no LF"),
    (lambda f: f.__setitem__(9, 9), "byte count"),
    (lambda f: f.__setitem__(2, ord("G")), "hex digits"),
])
def test_decode_packet_rejects_bad_frames(mutate, message):
    frame = bytearray(SEND_DATA)
    mutate(frame)
    with pytest.raises(PacketError, match=message):
        decode_packet(bytes(frame), offset=7)


def test_decode_packet_rejects_truncation_and_oversize():
    with pytest.raises(PacketError, match="truncated"):
        decode_packet(SEND_DATA[:-1])
    with pytest.raises(PacketError, match="outside"):
        decode_packet(b"@FFFF\xff\xff" + bytes(20))
    with pytest.raises(ValueError):
        encode_packet(MessageType.HEAD_DATA, bytes(5000))


def test_head_data_byte_count_exception_only_for_head_data():
    frame = bytearray(encode_packet(MessageType.SEND_DATA, bytes(4)))
    frame[9] = 0
    with pytest.raises(PacketError, match="byte count"):
        decode_packet(bytes(frame))
    assert decode_packet(bytes(frame), strict_byte_count=False).type == MessageType.SEND_DATA


def test_decode_head_data_rejects_inconsistent_counts():
    payload = bytearray(decode_packet(TINY_4BIT).payload)
    payload[29] = 9  # Dbytes larger than the data present
    with pytest.raises(PacketError, match="Dbytes"):
        decode_head_data(bytes(payload))
    with pytest.raises(PacketError, match="shorter"):
        decode_head_data(bytes(10))
    with pytest.raises(PacketError, match="expected mtHeadData"):
        decode_head_data(decode_packet(ALIVE))


def test_stream_decoder_byte_by_byte_with_garbage_and_offsets():
    stream = b"\x00@@0x" + ALIVE + b"@000C\x0c" + TINY_4BIT + VERSION + b"\n@"
    dec = StreamDecoder()
    packets = []
    for i in range(len(stream)):
        packets += dec.feed(stream[i:i + 1])
    packets += dec.finish()
    assert [p.type for p in packets] == [MessageType.ALIVE, MessageType.HEAD_DATA, MessageType.VERSION_DATA]
    assert [p.offset for p in packets] == [5, 5 + len(ALIVE) + 6, 5 + len(ALIVE) + 6 + len(TINY_4BIT)]
    discards = dec.take_discards()
    assert sum(d.length for d in discards) == len(stream) - len(ALIVE) - len(TINY_4BIT) - len(VERSION)
    assert discards[0].offset == 0 and dec.pending == 0


def test_false_frame_hiding_a_good_packet_is_abandoned_at_end_of_stream():
    # "@0100" + matching binary length claims 262 bytes; the good packet inside must still come out.
    stream = b"@0100\x00\x01" + SEND_DATA
    dec = StreamDecoder()
    assert dec.feed(stream) == []
    assert [p.payload for p in dec.finish()] == [SEND_DATA[13:-1]]


def test_real_lf_and_at_bytes_inside_payload_do_not_split():
    payload = b"@\n@000C\x0c\x00\n\n"
    frame = encode_packet(MessageType.AUX_DATA, payload, sid=2, did=0xFF)
    assert [p.payload for p in iter_packets(frame * 3)] == [payload] * 3


def test_bearing_conversion_convention():
    assert bearing_to_rad(3200) == pytest.approx(0.0)
    assert bearing_to_rad(1600) == pytest.approx(math.pi / 2)
    assert bearing_to_rad(4800) == pytest.approx(-math.pi / 2)
    assert bearing_to_rad(0) == pytest.approx(-math.pi)
    upside_down = HeadData(**{**_head(np.zeros(4), bearing=1600).__dict__, "hd_ctrl": 0x230F})
    inverted = decode_head_data(decode_packet(encode_head_data(upside_down)))
    assert inverted.inverted and inverted.bearing_rad() == pytest.approx(-math.pi / 2)
    assert _head(np.zeros(4), bearing=1600).bearing_rad() == pytest.approx(math.pi / 2)
    steps = np.arange(0, 6400, 7)
    np.testing.assert_array_equal(rad_to_bearing(bearing_to_rad(steps)), steps)


packets_strategy = st.lists(
    st.tuples(st.sampled_from([MessageType.ALIVE, MessageType.HEAD_DATA, MessageType.VERSION_DATA,
                               MessageType.AUX_DATA]), st.binary(max_size=80)), min_size=1, max_size=4)


@settings(max_examples=150, deadline=None)
@given(garbage=st.binary(max_size=300), tail=st.binary(max_size=40), items=packets_strategy,
       chunk=st.integers(1, 64))
def test_valid_packets_after_garbage_are_recovered(garbage, tail, items, chunk):
    frames = [encode_packet(t, p, sid=2, did=0xFF) for t, p in items]
    stream = garbage + b"".join(frames) + tail
    dec = StreamDecoder()
    got = []
    for i in range(0, len(stream), chunk):
        got += dec.feed(stream[i:i + chunk])
    got += dec.finish()
    decoded = [(p.type, p.payload) for p in got]
    expected = [(int(t), bytes(p)) for t, p in items]
    it = iter(decoded)  # every sent packet appears, in order (garbage may add frames of its own)
    assert all(any(e == d for d in it) for e in expected)
    assert sum(d.length for d in dec.take_discards()) + sum(p.total_length for p in got) == len(stream)


@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=2000))
def test_random_bytes_never_crash_the_decoder(data):
    for packet in iter_packets(data):
        assert packet.to_bytes() == data[packet.offset:packet.offset + packet.total_length]
        if packet.type == MessageType.HEAD_DATA:
            try:
                decode_head_data(packet)
            except PacketError:
                pass


@settings(max_examples=100, deadline=None)
@given(flips=st.lists(st.tuples(st.integers(0, 244), st.integers(0, 255)), max_size=6))
def test_mutated_head_data_never_crashes(flips):
    frame = bytearray(encode_head_data(_head(np.arange(200, dtype=np.uint8))))
    for index, value in flips:
        frame[index] = value
    for packet in iter_packets(bytes(frame) + SEND_DATA):
        if packet.type == MessageType.HEAD_DATA:
            try:
                decode_head_data(packet)
            except PacketError:
                pass
    assert any(p.payload == SEND_DATA[13:-1] for p in iter_packets(bytes(frame) + SEND_DATA))
