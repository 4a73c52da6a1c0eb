"""Reader and SeaNet decoder throughput on the real recordings.

Times ``read_file`` (decode + split into sweeps + build scans) on

* the UdpHubLog hex capture (``../shared/data/seanet/UdpHubLog_*.csv``, 2.3 MB),
* the V4LOG (``../shared/data/seanet/*.V4LOG``),
* a ~3 MB raw binary SeaNet capture synthesised from the real packets of the UdpHubLog (the port-4002
  stream's packets, repeated; what live acquisition writes),
* the largest Ping360 Ping Viewer log (``../shared/data/ping360``, 3.8 MB),

and the bare :class:`~cistern_archive.tritech.codec.StreamDecoder` (framing only, then framing plus
``mtHeadData`` decoding) on that capture fed in 4 KiB chunks, as a multiple of a 115200-baud line
(8N1: 11 520 bytes/s). Two harder streams bound the decoder from below: 1 MB of 22-byte ``mtAlive``
packets (per-packet overhead dominates) and 1 MB of seeded random bytes with every fourth byte an ``@``
(a false start to reject at almost every position). Each figure is the best of ``--repeat`` runs.

Usage::

    .venv/bin/python benchmarks/readers.py [--repeat 5] [--json]

``--json`` prints one JSON object as the last line.

Recorded results
----------------
``.venv/bin/python benchmarks/readers.py --repeat 7 --json`` on the shared 2-core machine (Python 3.11,
other jobs running; figures vary by about 2x between runs, the slowest of three runs is given):

==========================================  =======  =====  =====  ===========
file                                        MB       scans  beams  read+split
==========================================  =======  =====  =====  ===========
UdpHubLog_4001_2017_11_02_09_00_03.csv      2.28     10     765    89 ms
90degree_scan_target_moving_in.V4LOG        0.39     19     468    12 ms
synthetic raw capture (.seanet)             3.21     50     3825   125 ms
Sensor_Log_01__inside_base_dakhel_paygah    3.83     32     3035   43 ms
==========================================  =======  =====  =====  ===========

StreamDecoder, pure Python, as a multiple of a 115200-baud line (11.52 kB/s): framing only
125 MB/s (10 800x), framing + mtHeadData decoding 53 MB/s (4 600x), back-to-back 22-byte mtAlive
5.5 MB/s (480x), random bytes with an ``@`` every fourth byte 1.0 MB/s (90x).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cistern_archive.sonar.readers import read_file  # noqa: E402
import numpy as np  # noqa: E402

from cistern_archive.tritech.codec import MessageType, encode_packet  # noqa: E402
from cistern_archive.tritech.stream import StreamDecoder, iter_packets  # noqa: E402
from cistern_archive.tritech.head_data import decode_head_data  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
LINE_RATE_BYTES_S = 115200 / 10  # 8N1: 10 bits per byte
TARGET_CAPTURE_BYTES = 3_000_000


def best_time(func: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return min(times)


def udphub_stream(path: Path) -> bytes:
    """The port-4002 byte stream of a UdpHubLog."""
    chunks = []
    for line in path.read_text(encoding="ascii").splitlines():
        parts = line.split(";")
        if len(parts) == 4 and parts[2] == "4002":
            chunks.append(bytes.fromhex(parts[3]))
    return b"".join(chunks)


def synth_capture(udphub: Path, target: int) -> bytes:
    """Whole real packets of the UdpHubLog, repeated to about ``target`` bytes."""
    frames = [p.to_bytes() for p in iter_packets(udphub_stream(udphub))]
    one = b"".join(frames)
    return one * max(1, round(target / len(one)))


def bench_reader(path: Path, repeat: int) -> dict:
    result = read_file(path)
    seconds = best_time(lambda: read_file(path), repeat)
    size = path.stat().st_size
    return {"file": path.name, "format": result.format, "bytes": size, "scans": len(result.scans),
            "beams": sum(s.n_beams for s in result.scans), "seconds": round(seconds, 4),
            "mb_per_s": round(size / seconds / 1e6, 2)}


def alive_stream(size: int) -> bytes:
    """``size`` bytes of back-to-back mtAlive packets (sheet §12.6)."""
    alive = encode_packet(MessageType.ALIVE, bytes.fromhex("0040E20100800C8A"), sid=2, did=0xFF)
    return alive * (size // len(alive))


def garbage_stream(size: int, seed: int = 7) -> bytes:
    """Seeded random bytes with every fourth byte an ``@``."""
    data = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8)
    data[::4] = 0x40
    return data.tobytes()


def bench_decoder(stream: bytes, repeat: int, head_data: bool) -> dict:
    def run() -> int:
        dec = StreamDecoder()
        n = 0
        for i in range(0, len(stream), 4096):
            for packet in dec.feed(stream[i:i + 4096]):
                if head_data and packet.type == MessageType.HEAD_DATA:
                    decode_head_data(packet)
                n += 1
        return n

    packets = run()
    seconds = best_time(run, repeat)
    rate = len(stream) / seconds
    return {"bytes": len(stream), "packets": packets, "seconds": round(seconds, 4),
            "mb_per_s": round(rate / 1e6, 2), "x_115200_baud": round(rate / LINE_RATE_BYTES_S, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    seanet = DATA / "seanet"
    udphub = next(seanet.glob("UdpHubLog_*.csv"), None)
    v4log = next(seanet.glob("*.V4LOG"), None)
    if udphub is None or v4log is None:
        print(f"real recordings not found under {seanet}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        capture = Path(tmp) / "synthetic_capture.seanet"
        capture.write_bytes(synth_capture(udphub, TARGET_CAPTURE_BYTES))
        ping_logs = sorted((DATA / "ping360").glob("*.bin"), key=lambda p: p.stat().st_size)
        files = [udphub, v4log, capture] + ping_logs[-1:]
        readers = [bench_reader(p, args.repeat) for p in files]
        stream = capture.read_bytes()
    decoder = {"framing_only": bench_decoder(stream, args.repeat, head_data=False),
               "with_head_data": bench_decoder(stream, args.repeat, head_data=True),
               "small_packets": bench_decoder(alive_stream(1_000_000), args.repeat, head_data=False),
               "garbage": bench_decoder(garbage_stream(1_000_000), args.repeat, head_data=False),
               "line_rate_bytes_s": LINE_RATE_BYTES_S}
    report = {"benchmark": "readers", "python": sys.version.split()[0], "repeat": args.repeat,
              "readers": readers, "decoder": decoder}
    for r in readers:
        print(f"{r['format']:14s} {r['file'][:40]:40s} {r['bytes'] / 1e6:6.2f} MB  {r['scans']:3d} scans "
              f"{r['beams']:5d} beams  {r['seconds'] * 1e3:8.1f} ms  {r['mb_per_s']:6.2f} MB/s")
    for name, d in decoder.items():
        if isinstance(d, dict):
            print(f"decoder {name:15s} {d['mb_per_s']:6.2f} MB/s = {d['x_115200_baud']:7.1f} x 115200 baud "
                  f"({d['packets']} packets)")
    if args.json:
        print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
