"""Readers of SeaNet, Ping360 and marina recordings: real-file counts, bad input, fuzzing, sweep splitting."""

from __future__ import annotations

import math
import re
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar.readers import READERS, detect_format, read_file
from cistern_archive.sonar.sweeps import split_sweeps
from cistern_archive.tritech.codec import encode_packet, MessageType
from cistern_archive.tritech.head_data import HeadData, encode_head_data

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _data(*parts: str) -> Path:
    path = DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real recording {path} not found (../shared/data beside the repository)")
    return path


# (format, scans, beams, bins, max ranges (m, 2 decimals), warnings) measured on the real files
REAL = {
    ("ping360", "BIN__20240814-102337673.bin"): (
        "ping360", 29, 2436, [1200], [1.98, 14.98, 19.98, 29.99, 39.98, 49.99, 59.98], 1),
    ("ping360", "BIN__20240814-102841366.bin"): ("ping360", 18, 1325, [1200], [1.98, 14.98, 39.98, 59.98], 0),
    ("ping360", "Corrupted__20210619-213338492.bin"): (
        "ping360", 22, 2131, [666, 1200], [1.0, 1.98, 14.98, 39.98, 59.98], 1),
    ("ping360", "Sensor_Log_01__20200926-120409929.bin"): ("ping360", 43, 2810, [1200], [1.98, 19.98, 29.99], 0),
    ("ping360", "Sensor_Log_01__inside_base_dakhel_paygah.bin"): (
        "ping360", 32, 3035, [1200], [1.98, 9.99, 19.98], 1),
    ("ping360", "scenario__20210829-000220346-1.bin"): ("ping360", 6, 164, [1200], [1.98, 59.98], 0),
    ("seanet", "90degree_scan_target_moving_in.V4LOG"): ("seanet-v4log", 19, 468, [642], [10.17], 0),
    ("seanet", "UdpHubLog_4001_2017_11_02_09_00_03.csv"): ("seanet-udphub", 10, 765, [794], [50.69], 2),
}


@pytest.mark.realdata
@pytest.mark.parametrize("key", sorted(REAL), ids=lambda k: k[1])
def test_real_files_read_with_pinned_counts(key):
    path = _data(*key)
    result = read_file(path)
    fmt, n_scans, n_beams, bins, ranges, n_warnings = REAL[key]
    assert result.format == fmt
    assert len(result.scans) == n_scans
    assert sum(s.n_beams for s in result.scans) == n_beams
    assert sorted({s.n_bins for s in result.scans}) == bins
    assert sorted({round(s.max_range_m, 2) for s in result.scans}) == ranges
    assert len(result.warnings) == n_warnings
    for scan in result.scans:
        assert np.all(np.abs(scan.bearings_rad) <= math.pi)
        assert scan.intensities.max() <= scan.full_scale and scan.full_scale == 255


@pytest.mark.realdata
def test_v4log_geometry_and_time():
    scans = read_file(_data("seanet", "90degree_scan_target_moving_in.V4LOG")).scans
    full = scans[1]
    assert full.n_beams == 26 and full.bin_size_m == pytest.approx(1500 * 33 * 640e-9 / 2)
    span = math.degrees(full.bearings_rad.max() - full.bearings_rad.min())
    assert span == pytest.approx(86.4)  # a 90° sector in 3.6° steps
    steps = np.abs(np.diff(np.degrees(full.bearings_rad)))
    assert np.all(steps[steps > 0] == pytest.approx(3.6))  # the head pings twice at a sector limit
    assert 1116720000 < full.timestamp < 1116806400  # 2005-05-22 UTC
    assert full.settings["step_size"] == 64 and full.settings["ad_interval"] == 33


@pytest.mark.realdata
def test_udphub_sector_heading_and_depth():
    result = read_file(_data("seanet", "UdpHubLog_4001_2017_11_02_09_00_03.csv"))
    scan = result.scans[1]
    assert scan.n_beams == 89 and scan.sonar_model == "Tritech Micron DST"
    # limits 1778..4622 steps (100°..260° clockwise, 3200 ahead) -> +80°..-80° counter-clockwise,
    # mirrored because this head reports HdCtrl invert (mounted upside-down)
    assert scan.settings["inverted"]
    assert math.degrees(scan.bearings_rad.min()) == pytest.approx(-79.99, abs=0.01)
    assert math.degrees(scan.bearings_rad.max()) == pytest.approx(78.19, abs=0.01)
    assert scan.settings["compass_heading_deg"] == pytest.approx(72.4)
    assert scan.yaw_rad == pytest.approx(math.radians(90 - 72.4)) and scan.depth_m == pytest.approx(341.6)
    assert scan.bin_size_m == pytest.approx(1500 * 133 * 640e-9 / 2)
    assert "line 1 " in result.warnings[0] and "line 6760" in result.warnings[1]


@pytest.mark.realdata
def test_corrupted_ping360_names_the_damage_and_keeps_the_rest():
    result = read_file(_data("ping360", "Corrupted__20210619-213338492.bin"))
    assert sum(s.n_beams for s in result.scans) == 2131
    (warning,) = result.warnings
    assert "record 2488" in warning and "byte offset 2283784" in warning and "truncated" in warning


@pytest.mark.realdata
def test_ping360_sector_is_centred_ahead():
    scans = read_file(_data("ping360", "BIN__20240814-102841366.bin")).scans
    sweep = scans[7]  # a 90° sector in 0.9° (1 gradian) steps, raw angles 150..250
    assert sweep.n_beams == 100 and sweep.bin_size_m == pytest.approx(1500 * 2666 * 25e-9 / 2)
    assert math.degrees(sweep.bearings_rad.min()) == pytest.approx(-45.0)
    assert math.degrees(sweep.bearings_rad.max()) == pytest.approx(44.1)


@pytest.mark.realdata
def test_ping360_checksum_damage_mid_file_keeps_neighbours():
    path = _data("ping360", "BIN__20240814-102337673.bin")
    result = read_file(path)
    assert "byte offset 489388" in result.warnings[0] and "checksum" in result.warnings[0]
    assert result.scans[0].timestamp == pytest.approx(1723631017.673 + 2.574)


@pytest.mark.realdata
def test_marina_pcd_with_navigation():
    from cistern_archive.sonar import marina

    path = _data("marina", "derived_tim_pcd", "pclKeyFrame5.pcd")
    (scan,) = read_file(path).scans
    assert scan.n_beams == 200 and scan.n_bins == 500 and scan.bin_size_m == 0.1 and scan.full_scale == 1
    assert int(scan.intensities.sum()) == 3771
    assert scan.timestamp == pytest.approx(1093455289.85463)
    assert scan.settings["compass_heading_deg"] == pytest.approx(233.7, abs=0.1)
    # body heading = MTi compass - 22°; 200 beam times of 68 ms from the IS log, the first at the key frame's begin
    assert scan.yaw_rad == pytest.approx(math.radians(90.0 - (233.7 - 22.0)), abs=2e-3)
    assert scan.beam_times_s.shape == (200,) and scan.beam_times_s[0] == pytest.approx(scan.timestamp, abs=1e-3)
    assert np.median(np.diff(scan.beam_times_s)) == pytest.approx(0.068, abs=2e-3)
    # row j is the j-th beam, at -j * 1.8° in the (mirrored) cloud, +j * 1.8° + 240° in the body frame
    assert math.degrees(scan.bearings_rad[0]) == pytest.approx(240.0 - 360.0)
    assert math.degrees(scan.bearings_rad[1] - scan.bearings_rad[0]) == pytest.approx(1.8)
    frames = marina.load_keyframe_times(path.parent / "keyFrameTimeStamps.csv")
    assert len(frames) == 230
    dgps = marina.load_dgps(_data("marina", "_040825_1735_DGPS.log"))
    assert len(dgps) == 3342 and dgps["lat_deg"][0] == pytest.approx(42 + 12.225 / 60)
    gt = marina.load_gt(path.parent / "GTData.csv")
    assert len(gt) == 3342
    dvl = marina.load_dvl(_data("marina", "_040825_1735_DVL.log"))
    assert dvl["bottom_vx"][0] == pytest.approx(0.061)
    assert len(marina.load_dvl(path.parent / "dvlData.csv")) == 4961
    local = marina.load_dgps_local(_data("marina", "dgps_local_EN_m.csv"))
    assert local["east_m"][2] == pytest.approx(0.137)


# ---------------------------------------------------------------- synthetic files and bad input


def _head(bearing: int, bins: int = 50, *, ad_interval: int = 104, adc8on: bool = True) -> bytes:
    data = (np.arange(bins) % (256 if adc8on else 16)).astype(np.uint8)
    return encode_head_data(HeadData(0, 0x11, 0x10, 0, 0x2307 if adc8on else 0x2306, 100, 0, 84, 0, 81, 8, 0,
                                     ad_interval, 0, 0, 32, bearing, 0, data))


def _raw_stream(n_beams: int, step: int = 32, **kw) -> bytes:
    return b"".join(_head((i * step) % 6400, **kw) for i in range(n_beams))


def test_raw_capture_splits_revolutions(tmp_path):
    path = tmp_path / "scan.seanet"
    path.write_bytes(_raw_stream(450))
    result = read_file(path)
    assert result.format == "seanet-raw" and [s.n_beams for s in result.scans] == [200, 200, 50]
    assert result.scans[0].full_scale == 255 and math.isnan(result.scans[0].timestamp)


def test_raw_capture_4bit_full_scale(tmp_path):
    path = tmp_path / "scan.seanet"
    path.write_bytes(_raw_stream(10, adc8on=False))
    scan = read_file(path).scans[0]
    assert scan.full_scale == 15 and scan.n_bins == 50 and scan.intensities.max() == 15


@pytest.mark.realdata
def test_raw_bin_file_is_told_apart_from_ping360(tmp_path):
    path = tmp_path / "capture.bin"
    path.write_bytes(_raw_stream(5))
    assert detect_format(path) == "seanet-raw"
    ping = _data("ping360", "scenario__20210829-000220346-1.bin")
    assert detect_format(ping) == "ping360"


def test_raw_capture_bad_records_are_warned_and_skipped(tmp_path):
    good = [_head(i * 32) for i in range(6)]
    out_of_range = _head(7000)
    empty = encode_packet(MessageType.HEAD_DATA, struct.pack("<HBBBHHIBHBBHHHHBHH", 31, 0x11, 0x10, 0, 0x2307,
                                                            100, 0, 84, 0, 81, 8, 0, 104, 0, 0, 32, 3200, 0),
                          sid=2, did=0xFF)
    no_interval = _head(3300, ad_interval=0)
    stream = good[0] + b"garbage@@" + good[1] + out_of_range + good[2] + empty + good[3] + no_interval
    stream += good[4] + good[5][:-7] + b"\x00" * 7 + good[5][:30]
    path = tmp_path / "bad.seanet"
    path.write_bytes(stream)
    result = read_file(path)
    assert sum(s.n_beams for s in result.scans) == 5
    text = "\n".join(result.warnings)
    assert f"byte offset {len(good[0])}: skipped 9 byte(s)" in result.warnings[0]
    assert "bearing 7000" in text and "empty beam" in text and "ADInterval 0" in text and "truncated" in text


@pytest.mark.realdata
def test_v4log_truncated_and_corrupted_records(tmp_path):
    real = _data("seanet", "90degree_scan_target_moving_in.V4LOG").read_bytes()
    cut = tmp_path / "cut.V4LOG"
    cut.write_bytes(real[:61435 + 688 * 10 + 100])
    result = read_file(cut)
    assert sum(s.n_beams for s in result.scans) == 10
    assert "record 10: byte offset 68315" in result.warnings[0]
    broken = bytearray(real)
    broken[61435 + 688 * 3:61435 + 688 * 3 + 2] = b"\xff\xff"  # record 3's length
    path = tmp_path / "broken.V4LOG"
    path.write_bytes(bytes(broken))
    result = read_file(path)
    assert sum(s.n_beams for s in result.scans) == 467
    assert "record 3: byte offset 63499: record length 65535" in result.warnings[0]
    wrong = tmp_path / "wrong.V4LOG"
    wrong.write_bytes(b"SeaNetV3" + real[8:])
    with pytest.raises(ReaderError, match="byte offset 0: not a V4LOG"):
        read_file(wrong)


@pytest.mark.realdata
def test_ping360_mid_file_damage_keeps_records_before_and_after(tmp_path):
    real = _data("ping360", "scenario__20210829-000220346-1.bin").read_bytes()
    records = [m.start() for m in re.finditer(b"\x00\x00\x00\x18\x06\xf0", real)]  # time QStrings
    damaged = bytearray(real)
    damaged[100_000:100_040] = b"\xAA" * 40  # inside a chunk: breaks one message's checksum
    length_at = records[150] + 4 + 24  # record 150's chunk length
    damaged[length_at:length_at + 4] = b"\x7f\xff\xff\x00"
    path = tmp_path / "damaged.bin"
    path.write_bytes(bytes(damaged))
    result = read_file(path, "ping360")
    beams = sum(s.n_beams for s in result.scans)
    assert 160 <= beams < 164
    assert any("checksum" in w and "byte offset" in w for w in result.warnings)
    assert any(f"record 150: byte offset {records[150]}: chunk length" in w for w in result.warnings)
    assert all("record" in w and "byte offset" in w for w in result.warnings)


def test_ping360_wrong_magic(tmp_path):
    path = tmp_path / "x.bin"
    path.write_bytes(b"\x00\x00\x00\x04\x00A\x00B" + bytes(100))
    with pytest.raises(ReaderError, match="byte offset 0"):
        read_file(path, "ping360")


def test_pcd_nan_inf_and_garbage_rows(tmp_path):
    path = tmp_path / "cloud.pcd"
    rows = ["1.0 0.0 0", "nan 1 0", "2 inf 0", "x y z", "0.0 -3.05 0", "60 0 0"]
    path.write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 6\nHEIGHT 1\n"
                    "POINTS 6\nDATA ascii\n" + "\n".join(rows) + "\n")
    result = read_file(path)
    (scan,) = result.scans
    assert int(scan.intensities.sum()) == 2
    # the cloud is mirrored: its -90° is the sonar's +90°, the 50th beam of a revolution
    assert scan.intensities[0, 10] == 1 and scan.intensities[50, 30] == 1
    text = "\n".join(result.warnings)
    assert "line 11: NaN" in text and "line 12: NaN" in text and "line 13" in text and "beyond 50.0 m" in text


def test_udphub_bad_lines(tmp_path):
    good = _raw_stream(3)
    hexes = [good[i:i + 100].hex(" ").upper() for i in range(0, len(good), 100)]
    lines = [f"2020.01.01 00.00.0{i}.000;1.2.3.4;4002;{h}" for i, h in enumerate(hexes)]
    lines.insert(2, "not a line")
    lines.append("2020.01.01 00.00.09.000;1.2.3.4;13102;" + b"$ROV,abc,0,0,5,*\r\n".hex(" "))
    path = tmp_path / "UdpHubLog_x.csv"
    path.write_text("\n".join(lines) + "\n")
    result = read_file(path)
    assert sum(s.n_beams for s in result.scans) == 3
    assert "line 3: not a" in result.warnings[0] and "$ROV" in result.warnings[1]
    assert result.scans[0].timestamp == pytest.approx(1577836800.0)


# ---------------------------------------------------------------- sweeps


def test_split_sweeps_revolutions_reversals_keys_and_jumps():
    rev = np.radians(np.arange(0, 720, 10.0))
    assert [s.stop - s.start for s in split_sweeps(rev)] == [36, 36]
    sector = np.radians(np.r_[np.arange(-40, 41, 4), np.arange(36, -41, -4)])
    assert [s.stop - s.start for s in split_sweeps(sector)] == [21, 20]
    keys = [0] * 5 + [1] * 5
    assert [s.stop - s.start for s in split_sweeps(np.zeros(10), keys)] == [5, 5]
    jump = np.radians([0, 1, 2, 90, 91])
    assert [s.stop - s.start for s in split_sweeps(jump)] == [3, 2]
    assert split_sweeps([]) == []


# ---------------------------------------------------------------- fuzzing: only ReaderError escapes

FUZZ_SUFFIX = {"seanet-raw": ".seanet", "seanet-v4log": ".V4LOG", "seanet-udphub": ".csv", "ping360": ".bin",
               "marina-pcd": ".pcd", "npz": ".npz"}


def _seed(fmt: str) -> bytes:
    if fmt == "seanet-raw":
        return _raw_stream(4, bins=16)
    if fmt == "seanet-v4log":
        head = _head(3200, bins=8)
        rec = struct.pack("<Hd", 15 + len(head) - 14, 38494.6) + head[7:9] + head[10:13] + head[13:-1]
        header = b"SeaNetV4 Log File V1".ljust(31) + b"\x1a" + struct.pack("<8I", 16, 64, 64, 1, 0, 0, 0, 0)
        return header + rec
    if fmt == "seanet-udphub":
        return ("2020.01.01 00.00.00.000;1.2.3.4;4002;" + _raw_stream(2, bins=8).hex(" ") + "\n").encode()
    if fmt == "ping360":
        magic = "PingViewer sensor log file".encode("utf-16-be")
        head = struct.pack(">I", len(magic)) + magic + struct.pack(">I", 1) + struct.pack(">I", 0) * 5
        head += struct.pack(">II", 1, 2)
        body = struct.pack("<BBHHHHHH", 1, 0, 10, 5, 80, 750, 4, 4) + bytes([1, 2, 3, 4])
        msg = b"BR" + struct.pack("<HHBB", len(body), 2300, 0, 0) + body
        msg += struct.pack("<H", sum(msg) & 0xFFFF)
        t = "00:00:01.000".encode("utf-16-be")
        return head + struct.pack(">I", len(t)) + t + struct.pack(">I", len(msg)) + msg
    if fmt == "marina-pcd":
        return b"VERSION 0.7\nFIELDS x y z\nPOINTS 2\nDATA ascii\n1 2 0\n-3 4 0\n"
    from cistern_archive.sonar.interchange import write_scan
    from cistern_archive.core.scan import Scan

    with tempfile.TemporaryDirectory() as tmp:
        path = write_scan(Scan(np.zeros(2), np.ones((2, 3), np.uint8), 255, 0.1), Path(tmp) / "s.npz")
        return path.read_bytes()


@pytest.mark.parametrize("fmt", sorted(FUZZ_SUFFIX))
def test_fuzz_seed_files_are_readable(fmt, tmp_path):
    path = tmp_path / f"seed{FUZZ_SUFFIX[fmt]}"
    path.write_bytes(_seed(fmt))
    assert read_file(path, fmt).scans


def _read_only_reader_errors(fmt: str, data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"fuzz{FUZZ_SUFFIX[fmt]}"
        path.write_bytes(data)
        try:
            read_file(path, fmt)
        except ReaderError:
            pass


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fmt=st.sampled_from(sorted(FUZZ_SUFFIX)), data=st.binary(max_size=600))
def test_random_bytes_raise_only_reader_error(fmt, data):
    assert fmt in READERS
    _read_only_reader_errors(fmt, data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fmt=st.sampled_from(sorted(FUZZ_SUFFIX)), cut=st.integers(0, 2000),
       flips=st.lists(st.tuples(st.integers(0, 2000), st.integers(0, 255)), max_size=8),
       insert=st.binary(max_size=20))
def test_mutated_files_raise_only_reader_error(fmt, cut, flips, insert):
    data = bytearray(_seed(fmt))
    for index, value in flips:
        if data:
            data[index % len(data)] = value
    at = cut % (len(data) + 1)
    data[at:at] = insert
    _read_only_reader_errors(fmt, bytes(data[: max(len(data) - cut // 4, 0)]))


@pytest.mark.realdata
@pytest.mark.parametrize("key", sorted(REAL), ids=lambda k: k[1])
def test_real_scans_round_trip_through_the_interchange_format(key, tmp_path):
    from cistern_archive.sonar.interchange import read_scan, write_scan

    scan = read_file(_data(*key)).scans[-1]
    back = read_scan(write_scan(scan, tmp_path / "scan.npz"))
    np.testing.assert_array_equal(back.intensities, scan.intensities)
    np.testing.assert_array_equal(back.bearings_rad, scan.bearings_rad)
    assert back.settings == scan.settings and back.bin_size_m == scan.bin_size_m
    assert back.full_scale == scan.full_scale and back.timestamp == pytest.approx(scan.timestamp, nan_ok=True)


def test_marina_loader_names_bad_rows(tmp_path):
    from cistern_archive.sonar import marina

    path = tmp_path / "x_MTi.log"
    path.write_text("% header\n1.0 0 0 10 0 0 0 0 0 0\n2.0 0 0 nan 0 0 0 0 0 0\n")
    with pytest.raises(ReaderError, match="line 3: NaN"):
        marina.load_mti(path)
    path.write_text("1.0 0 0 10\n")
    with pytest.raises(ReaderError, match="line 1: 4 fields"):
        marina.load_mti(path)
    path.write_text("1.0 0 0 350 0 0 0 0 0 0\n2.0 0 0 10 0 0 0 0 0 0\n")
    heading = marina.mean_heading_deg(marina.load_mti(path), 0.0, 3.0)
    assert (heading + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)  # circular mean of 350° and 10°
