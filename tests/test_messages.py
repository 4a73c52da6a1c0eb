"""Messages of the Micron conversation: worked examples of the protocol sheet, settings, fuzzing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from cistern_archive.tritech.codec import MessageType, Packet, PacketError, decode_packet
from cistern_archive.tritech.stream import StreamDecoder, iter_packets
from cistern_archive.tritech.head_data import HeadData, encode_head_data
from cistern_archive.tritech.messages import (
    Alive,
    BBUserData,
    HeadInf,
    SendData,
    VersionData,
    decode_message,
    head_data_for,
    time_of_day_ms,
)
from cistern_archive.tritech.codec import command
from cistern_archive.tritech.settings import HeadSettings, deg_to_steps, settings_from_command, steps_to_deg
from cistern_archive.tritech.head_command import GainCommand, HeadCommand, ReverseCommand

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(" ".join(line.split(":", 1)[-1] for line in text.strip().splitlines()))


# Worked examples of ../shared/protocols/tritech_micron.md §12 ------------------------------------

HEAD_COMMAND_12_3 = hexbytes("""
00: 40 30 30 33 43 3C 00 FF 02 37 13 80 02 01 07 23
16: 11 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
32: 00 00 00 64 00 60 09 A0 0F 51 08 54 54 00 00 00
48: 00 19 10 68 00 C8 00 E8 03 64 00 40 06 01 00 00
64: 00 0A
""")


def test_settings_build_the_worked_head_command_byte_for_byte():
    settings = HeadSettings(range_m=10.0, n_bins=200, gain=0.4, step=16)
    assert settings.ad_interval() == 104
    assert settings.bin_size_m() == pytest.approx(0.04992)
    assert settings.hd_ctrl() == 0x2307
    assert settings.head_command().encode() == HEAD_COMMAND_12_3


def test_head_command_decodes_back():
    cmd = decode_message(decode_packet(HEAD_COMMAND_12_3))
    assert isinstance(cmd, HeadCommand)
    assert (cmd.range_scale, cmd.left_limit, cmd.right_limit) == (100, 2400, 4000)
    assert (cmd.ad_interval, cmd.n_bins) == (104, 200)
    assert (cmd.ad_span, cmd.ad_low, cmd.igain, cmd.mo_time, cmd.step_size) == (81, 8, (84, 84), 25, 16)
    assert cmd.encode() == HEAD_COMMAND_12_3


def test_alive_example_12_6():
    raw = bytes.fromhex("40 30 30 31 30 10 00 02 FF 0B 04 80 02 00 40 E2 01 00 80 0C 8A 0A")
    alive = decode_message(decode_packet(raw))
    assert alive == Alive(0, 123456, 3200, HeadInf.CENTRED | HeadInf.MOTOR_ON | HeadInf.SENT_CFG)
    assert alive.params_loaded and alive.sent_cfg
    assert alive.encode() == raw
    just_booted = Alive(1, 0, 3200, HeadInf(0x4A))
    assert just_booted.no_params and not just_booted.sent_cfg
    # HeadInf 0x0A puts an LF right before the terminator: framing must still hold.
    lf_alive = Alive(0, 5, 3200, HeadInf(0x0A)).encode()
    assert lf_alive[-2:] == b"\n\n" and Alive.decode(decode_packet(lf_alive)).head_inf == 0x0A


def test_version_data_example_12_7():
    raw = bytes.fromhex("40 30 30 31 33 13 00 02 FF 0E 01 80 02 03 01 34 12 45 23 01 00 EF BE 02 0A")
    version = VersionData.decode(decode_packet(raw))
    assert version == VersionData(3, 1, 0x1234, 0x00012345, 0xBEEF, 2)
    assert version.encode() == raw


def test_send_data_example_12_1():
    expected = bytes.fromhex("40 30 30 30 43 0C 00 FF 02 07 19 80 02 95 2C B3 02 0A")
    assert SendData(45_296_789).encode() == expected
    assert SendData.decode(decode_packet(expected)).time_ms == 45_296_789
    assert time_of_day_ms(86400.0 * 3 + 45_296.789) == 45_296_789


@pytest.mark.parametrize("msg_type, code", [(MessageType.SEND_VERSION, 0x17), (MessageType.SEND_BB_USER, 0x18),
                                            (MessageType.REBOOT, 0x10), (MessageType.STOP_ALIVES, 0x42)])
def test_no_payload_commands_12_2(msg_type, code):
    assert command(msg_type) == bytes([0x40, 0x30, 0x30, 0x30, 0x38, 0x08, 0x00, 0xFF, 0x02, 0x03, code, 0x80,
                                       0x02, 0x0A])


def test_head_data_header_example_12_4():
    cmd = HeadSettings(range_m=10.0, n_bins=200, gain=0.4, step=16).head_command()
    line = head_data_for(cmd, 3200, np.arange(200) % 256)
    raw = encode_head_data(line)
    expected_head = hexbytes("""
00: 40 30 30 45 46 EF 00 02 FF 00 02 80 02 E7 00 11
16: 10 00 07 23 64 00 00 00 00 00 54 00 00 51 08 00
32: 00 68 00 60 09 A0 0F 10 80 0C C8 00
""")
    assert len(raw) == 245
    assert raw[:44] == expected_head
    decoded = decode_message(decode_packet(raw))
    assert isinstance(decoded, HeadData)
    assert decoded.bearing == 3200 and decoded.n_bins == 200 and decoded.adc8on
    np.testing.assert_array_equal(decoded.bins, np.arange(200) % 256)


def test_four_bit_head_data_example_12_5():
    cmd = HeadCommand(hd_ctrl=0x2306, range_scale=10, left_limit=2400, right_limit=4000, ad_span=0x26, ad_low=0x28,
                      igain=(84, 84), step_size=32, ad_interval=260, n_bins=8)
    line = head_data_for(cmd, 3232, np.array([1, 2, 3, 4, 10, 11, 15, 0]), head_status=0)
    expected = hexbytes("""
00: 40 30 30 32 42 2B 00 02 FF 00 02 80 02 23 00 11
16: 00 00 06 23 0A 00 00 00 00 00 54 00 00 26 28 00
32: 00 04 01 60 09 A0 0F 20 A0 0C 04 00 12 34 AB F0
48: 0A
""")
    assert encode_head_data(line) == expected
    decoded = decode_message(decode_packet(expected))
    np.testing.assert_array_equal(decoded.bins, [1, 2, 3, 4, 10, 11, 15, 0])
    assert decoded.full_scale == 15


# Settings -----------------------------------------------------------------------------------------

def test_ad_interval_rounds_and_clamps():
    assert HeadSettings(range_m=10, n_bins=200).ad_interval() == 104  # 104.17
    assert HeadSettings(range_m=1.0, n_bins=8, bits=4).ad_interval() == 260  # 260.4
    assert HeadSettings(range_m=0.1, n_bins=1500).ad_interval() == 5  # clamped at the practical minimum
    assert HeadSettings(range_m=50, n_bins=794).ad_interval() == round(2 * 50 / 794 / 1500 / 640e-9)


def test_hd_ctrl_bits():
    assert HeadSettings(bits=4, continuous=False, direction="left").hd_ctrl() == 0x2300
    assert HeadSettings(bits=8, continuous=False, direction="right").hd_ctrl() == 0x2305
    assert HeadSettings(inverted=True).hd_ctrl() == 0x230F


@pytest.mark.parametrize("bad", [dict(bits=4, n_bins=201), dict(step=12), dict(range_m=0), dict(gain=1.5),
                                 dict(left_limit=6400), dict(range_m=100, n_bins=10), dict(unknown=1)])
def test_invalid_settings_are_refused(bad):
    with pytest.raises(ValidationError):
        HeadSettings(**bad)


def test_settings_round_trip_through_a_command():
    original = HeadSettings(range_m=20.0, n_bins=400, gain=0.5, step=32, continuous=False, left_limit=1000,
                            right_limit=5000, direction="left", bits=4)
    again = settings_from_command(original.head_command())
    assert again.head_command() == original.head_command()
    assert again.range_m == pytest.approx(original.range_m, rel=0.01)


def test_angle_helpers():
    assert steps_to_deg(16) == pytest.approx(0.9)
    assert deg_to_steps(90) == 1600 and deg_to_steps(-0.9) == 6384


# Other variants -----------------------------------------------------------------------------------

def test_other_head_command_variants():
    gain = GainCommand(ad_span=(77, 77), ad_low=(40, 40), igain=(100, 100), slope=(90, 90))
    raw = gain.encode()
    assert len(raw) == 31 and raw[13] == 0x1E
    assert decode_message(decode_packet(raw)) == gain
    reverse = ReverseCommand().encode()
    assert len(reverse) == 15 and reverse[13] == 0x0F
    assert isinstance(decode_message(decode_packet(reverse)), ReverseCommand)
    dual = HeadCommand(hd_ctrl=0x2307, v3b_block=bytes(range(16)))
    raw = dual.encode()
    assert len(raw) == 82 and raw[1:5] == b"004C" and raw[13] == 0x1D
    assert decode_message(decode_packet(raw)) == dual


def test_bb_user_data():
    for half in (True, False):
        block = BBUserData.build(half_duplex=half)
        raw = block.encode()
        assert len(raw) == 264 and raw[1:5] == b"0102" and raw[9] == 253
        decoded = decode_message(decode_packet(raw))
        assert decoded.is_dst and decoded.half_duplex is half
        assert decoded.replies_per_request == (1 if half else 2)


def test_malformed_payloads_raise_packet_error_with_offset():
    short_alive = Packet(sid=2, did=0xFF, type=MessageType.ALIVE, seq=0x80, node=2, payload=b"\x00" * 5, offset=77)
    with pytest.raises(PacketError, match="byte offset 77"):
        decode_message(short_alive)
    bad_cmd = Packet(sid=0xFF, did=2, type=MessageType.HEAD_COMMAND, seq=0x80, node=2, payload=b"\x01\x02")
    with pytest.raises(PacketError, match="mtHeadCommand"):
        decode_message(bad_cmd)
    other = Packet(sid=2, did=0xFF, type=MessageType.FPGA_CAL_DATA, seq=0x80, node=2, payload=b"abc")
    assert decode_message(other) is other


# Fuzzing ------------------------------------------------------------------------------------------

def _conversation() -> list[bytes]:
    settings = HeadSettings(range_m=6.0, n_bins=64, step=32)
    cmd = settings.head_command()
    cmd4 = HeadSettings(range_m=6.0, n_bins=64, step=32, bits=4).head_command()
    return [
        Alive(1, 10, 3200, HeadInf(0x4A)).encode(),
        VersionData(3, 1, 7, 100, 200).encode(),
        BBUserData.build(half_duplex=False).encode(),
        cmd.encode(),
        Alive(0, 20, 3200, HeadInf(0xAA)).encode(),
        SendData(1234).encode(),
        encode_head_data(head_data_for(cmd, 3200, np.full(64, 0x40))),   # '@' inside the bins
        encode_head_data(head_data_for(cmd4, 3232, np.full(64, 0x0A) & 0x0F)),
        GainCommand((1, 1), (2, 2), (3, 3)).encode(),
        ReverseCommand().encode(),
    ]


CONVERSATION = _conversation()


def _decode_all(stream: bytes) -> list:
    """Decode a stream the way the driver does; only PacketError may come out of a message decoder."""
    out = []
    for packet in iter_packets(stream):
        try:
            out.append(decode_message(packet))
        except PacketError:
            out.append(None)
    return out


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2000))
def test_random_bytes_never_crash_the_decoders(data):
    _decode_all(data)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_mutated_conversation_never_crashes(data):
    stream = bytearray(b"".join(CONVERSATION))
    for _ in range(data.draw(st.integers(0, 20))):
        kind = data.draw(st.sampled_from(["flip", "drop", "insert"]))
        if not stream:
            break
        at = data.draw(st.integers(0, len(stream) - 1))
        if kind == "flip":
            stream[at] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "drop":
            del stream[at]
        else:
            stream[at:at] = data.draw(st.binary(min_size=1, max_size=16))
    _decode_all(bytes(stream))


@settings(max_examples=150, deadline=None)
@given(garbage=st.binary(max_size=600), index=st.integers(0, len(CONVERSATION) - 1),
       chunk=st.integers(1, 300))
def test_a_valid_message_after_garbage_is_always_recovered(garbage, index, chunk):
    message = CONVERSATION[index]
    # A false '@' in the garbage makes the decoder wait for its claimed length, then backtrack; the
    # message must come out whole however the stream is chunked.
    stream = garbage + message
    decoder = StreamDecoder()
    packets = []
    for k in range(0, len(stream), chunk):
        packets.extend(decoder.feed(stream[k:k + chunk]))
    packets.extend(decoder.finish())
    assert packets, "nothing decoded"
    last = packets[-1]
    assert last.to_bytes() == message
    expected = decode_message(decode_packet(message))
    got = decode_message(last)
    if isinstance(expected, HeadData):
        assert got.bearing == expected.bearing
        np.testing.assert_array_equal(got.bins, expected.bins)
    else:
        assert got == expected


# Real bytes ---------------------------------------------------------------------------------------

@pytest.mark.realdata
def test_real_udphub_head_data_decodes_as_typed_messages():
    path = DATA / "seanet" / "UdpHubLog_4001_2017_11_02_09_00_03.csv"
    if not path.is_file():
        pytest.skip(f"real SeaNet capture not found at {path}")
    stream = bytearray()
    for line in path.read_text().splitlines():
        parts = line.split(";")
        if len(parts) == 4 and parts[2] == "4002":
            stream += bytes.fromhex(parts[3])
    lines = [m for m in _decode_all(bytes(stream)) if isinstance(m, HeadData)]
    assert len(lines) > 700
    first = lines[0]
    assert first.n_bins == 794 and first.adc8on and first.range_scale == 50.0
    assert first.step_size == 32  # 1.8 degrees
    assert {line.n_bins for line in lines} == {794}
    settings = settings_from_command(HeadCommand(hd_ctrl=first.hd_ctrl, ad_interval=first.ad_interval,
                                                 n_bins=first.n_bins, step_size=first.step_size))
    assert settings.range_m == pytest.approx(50.0, rel=0.02)
