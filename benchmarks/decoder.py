"""Live-decoding throughput of the SeaNet stream in pure Python, against the 115200-baud line rate.

The stream is what a Micron sends while scanning: 8-bit mtHeadData lines (``--bins`` bins, 45 + bins bytes
each) with an mtAlive every 25 lines, optionally with random garbage bursts between packets
(``--garbage``, the fraction of packets preceded by 1..64 random bytes). It is fed to
:class:`cistern_archive.tritech.codec.StreamDecoder` in chunks of ``--chunk`` bytes (a serial read), and
every packet is turned into its typed message (:func:`cistern_archive.tritech.messages.decode_message`),
exactly as :class:`cistern_archive.acquisition.driver.MicronDriver` does. The line rate of 115200 baud 8N1 is
11,520 bytes/s; the target is at least 10x that.

Usage::

    .venv/bin/python benchmarks/decoder.py [--bins 200] [--chunk 256] [--garbage 0.0] [--link] [--json]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np

from cistern_archive.tritech.stream import StreamDecoder
from cistern_archive.tritech.head_data import HeadData, encode_head_data
from cistern_archive.tritech.messages import Alive, HeadInf, decode_message, head_data_for
from cistern_archive.tritech.settings import HeadSettings

LINE_RATE = 115200 / 10  # bytes/s on an 8N1 line


def make_stream(n_lines: int, n_bins: int, garbage: float, rng: np.random.Generator) -> bytes:
    cmd = HeadSettings(range_m=10.0, n_bins=n_bins, step=16).head_command()
    parts: list[bytes] = []
    for k in range(n_lines):
        if garbage and rng.random() < garbage:
            parts.append(rng.integers(0, 256, size=int(rng.integers(1, 65)), dtype=np.uint8).tobytes())
        bins = rng.integers(0, 256, size=n_bins, dtype=np.uint8)
        parts.append(encode_head_data(head_data_for(cmd, (3200 + 16 * k) % 6400, bins)))
        if k % 25 == 0:
            parts.append(Alive(0, k, 3200, HeadInf(0xAA)).encode())
    return b"".join(parts)


def decode(stream: bytes, chunk: int) -> tuple[int, int]:
    decoder = StreamDecoder()
    lines = 0
    packets = 0
    for start in range(0, len(stream), chunk):
        for packet in decoder.feed(stream[start:start + chunk]):
            packets += 1
            if isinstance(decode_message(packet), HeadData):
                lines += 1
    decoder.take_discards()
    return packets, lines


def link_rate(n_bins: int) -> dict:
    """Driver + emulated head over a real pty with no pacing: one 360-degree scan, bytes/s received.

    This bounds the whole live path (pty, pyserial, decoding, request/reply turn-arounds); the emulator
    runs in the same process, so the figure is a lower bound of the driver's own speed.
    """
    from cistern_archive.simulation.spec import EffectsSpec
    from cistern_archive.acquisition.driver import DriverConfig, MicronDriver
    from cistern_archive.acquisition.assembly import collect_scan
    from cistern_archive.acquisition.emulator import HeadTiming
    from cistern_archive.acquisition.emulator_server import build_emulator
    from cistern_archive.acquisition.echoes import SimulatedEcho

    room = np.array([[0.0, 0.0], [12.0, 0.0], [12.0, 8.0], [0.0, 8.0]])
    echo = SimulatedEcho.from_polygon(room, x_m=4.0, y_m=3.0, effects=EffectsSpec.ideal())
    settings = HeadSettings(range_m=10.0, n_bins=n_bins, step=16)
    with build_emulator(echo, timing=HeadTiming(alive_period=0.5, boot=0.1, realtime=False)) as server:
        with MicronDriver(server.url, settings, config=DriverConfig(reply_timeout_s=0.5)) as driver:
            driver.start()
            start = time.perf_counter()
            capture = collect_scan(driver, start=False)
            elapsed = time.perf_counter() - start
            received = driver.stats.bytes_received
    return {"link_lines": capture.scan.n_beams, "link_s": round(elapsed, 3),
            "link_bytes_per_s": round(received / elapsed),
            "link_times_line_rate": round(received / elapsed / LINE_RATE, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bins", type=int, default=200)
    parser.add_argument("--lines", type=int, default=4000, help="scan lines in the stream")
    parser.add_argument("--chunk", type=int, default=256, help="bytes per feed (one serial read)")
    parser.add_argument("--garbage", type=float, default=0.0, help="fraction of packets preceded by garbage")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs; the best is reported")
    parser.add_argument("--link", action="store_true", help="also time driver + emulator over a pty")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)

    stream = make_stream(args.lines, args.bins, args.garbage, np.random.default_rng(0))
    times = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        packets, lines = decode(stream, args.chunk)
        times.append(time.perf_counter() - start)
    best = min(times)
    rate = len(stream) / best
    result = {
        "benchmark": "seanet-decoder",
        "bytes": len(stream),
        "packets": packets,
        "lines": lines,
        "bins": args.bins,
        "chunk_bytes": args.chunk,
        "garbage_fraction": args.garbage,
        "best_s": round(best, 4),
        "bytes_per_s": round(rate),
        "lines_per_s": round(lines / best),
        "line_rate_bytes_per_s": LINE_RATE,
        "times_line_rate": round(rate / LINE_RATE, 1),
        "target_times_line_rate": 10,
        "meets_target": rate >= 10 * LINE_RATE,
        "python": platform.python_version(),
    }
    if args.link:
        result.update(link_rate(args.bins))
    if not args.json:
        print(f"decoded {len(stream):,} bytes ({lines} lines of {args.bins} bins) in {best * 1000:.1f} ms: "
              f"{rate / 1e6:.2f} MB/s = {rate / LINE_RATE:.0f}x the 115200-baud line rate "
              f"({'meets' if result['meets_target'] else 'misses'} the 10x target)")
        if args.link:
            print(f"driver + emulated head over a pty: {result['link_lines']} lines in {result['link_s']} s = "
                  f"{result['link_times_line_rate']}x the line rate")
    print(json.dumps(result))
    return 0 if result["meets_target"] else 1


if __name__ == "__main__":
    sys.exit(main())
