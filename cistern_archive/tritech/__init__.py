"""Tritech SeaNet protocol, shared by the file readers and live acquisition: packet framing
(:mod:`.codec`), stream decoding (:mod:`.stream`), sonar lines (:mod:`.head_data`), the other messages
(:mod:`.messages`, :mod:`.head_command`) and head settings (:mod:`.settings`)."""

from cistern_archive.tritech.codec import MessageType, Packet, PacketError, decode_packet, encode_packet
from cistern_archive.tritech.stream import Discard, StreamDecoder, iter_packets
from cistern_archive.tritech.head_data import (
    HeadData,
    bearing_to_rad,
    decode_head_data,
    encode_head_data,
    rad_to_bearing,
)

__all__ = [
    "Discard",
    "HeadData",
    "MessageType",
    "Packet",
    "PacketError",
    "StreamDecoder",
    "bearing_to_rad",
    "decode_head_data",
    "decode_packet",
    "encode_head_data",
    "encode_packet",
    "iter_packets",
    "rad_to_bearing",
]
