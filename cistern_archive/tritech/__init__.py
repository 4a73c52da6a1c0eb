"""Tritech SeaNet protocol: the packet codec (:mod:`.codec`) shared by file readers and live acquisition."""

from cistern_archive.tritech.codec import (
    Discard,
    HeadData,
    MessageType,
    Packet,
    PacketError,
    StreamDecoder,
    bearing_to_rad,
    decode_head_data,
    decode_packet,
    encode_head_data,
    encode_packet,
    iter_packets,
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
