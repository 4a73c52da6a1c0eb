"""`acquire`: raw stream, interchange scan, site record and archive, including interruptions."""

from __future__ import annotations

import difflib
import hashlib
import threading
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.archive import catalog_store
from cistern_archive.catalog.loader import load_record
from cistern_archive.core.errors import CatalogError
from cistern_archive.sonar.interchange import read_scan
from cistern_archive.sonar.readers import read_file
from cistern_archive.core.scan import compass_deg_from_yaw
from cistern_archive.acquisition.session import acquire_scan, insert_scan_text
from cistern_archive.tritech.stream import iter_packets
from cistern_archive.acquisition.driver import DriverConfig
from cistern_archive.acquisition.emulator import HeadTiming
from cistern_archive.acquisition.emulator_server import build_emulator
from cistern_archive.acquisition.faults import FaultPlan
from cistern_archive.acquisition.echoes import SimulatedEcho
from service_helpers import default_sigint
from tritech_helpers import make_catalog, tiny_catalog  # noqa: F401  (fixture)

REPO = Path(__file__).resolve().parents[1]

FAST = HeadTiming(alive_period=0.2, boot=0.3, realtime=False)
CONFIG = DriverConfig(reply_timeout_s=0.3, alive_timeout_s=5.0, config_timeout_s=5.0)


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def station_b(catalog: Path) -> SimulatedEcho:
    return SimulatedEcho.from_catalog(catalog, "pool", "b")


def heading_of(echo: SimulatedEcho) -> float:
    return compass_deg_from_yaw(echo.pose.yaw_rad)


def test_acquire_writes_raw_scan_record_and_archive(tiny_catalog, tmp_path):
    echo = station_b(tiny_catalog)
    before = digests(tiny_catalog / "data")
    record_path = tiny_catalog / "sites" / "pool.yaml"
    record_text = record_path.read_text()
    with build_emulator(echo, timing=FAST) as server:
        result = acquire_scan(tiny_catalog, server.url, "pool", "b", depth_m=1.0, heading_deg=heading_of(echo),
                              config=CONFIG, store=catalog_store(tiny_catalog, tmp_path / "archive"))
    assert result.capture.complete and result.station == "b" and not result.partial
    # 1. raw stream: every byte as received, decodable.
    raw = result.raw_path.read_bytes()
    assert result.raw_path == tiny_catalog / "data" / "pool" / "b.seanet"
    assert len(raw) == result.capture.scan.settings["link"]["bytes_received"]
    assert sum(1 for _ in iter_packets(raw)) > 200
    from_raw = read_file(result.raw_path)
    assert from_raw.format == "seanet-raw" and from_raw.scans[0].n_bins == 120
    # 2. interchange scan
    scan = read_scan(result.scan_path)
    assert scan.n_beams == 200 and scan.station == "b" and scan.settings["partial"] is False
    assert scan.yaw_rad == pytest.approx(echo.pose.yaw_rad) and scan.depth_m == 1.0
    assert scan.settings["raw_file"] == "data/pool/b.seanet"
    # 3. record: the old text is kept verbatim, the new entry validates
    diff = list(difflib.ndiff(record_text.splitlines(), record_path.read_text().splitlines()))
    assert not [line for line in diff if line.startswith("- ")]
    assert len([line for line in diff if line.startswith("+ ")]) == 6
    loaded = load_record(record_path, tiny_catalog)
    assert [s.station for s in loaded.record.scans] == ["a", "c", "b"]
    entry = loaded.record.scans[-1]
    assert entry.file == "data/pool/b.npz" and entry.depth_m == 1.0
    assert entry.yaw_deg == pytest.approx(heading_of(echo))
    # earlier data untouched
    after = digests(tiny_catalog / "data")
    assert {k: v for k, v in after.items() if k in before} == before
    # 4. archive
    assert sorted(result.archived) == ["data/pool/b.npz", "data/pool/b.seanet", "sites/pool.yaml"]
    assert (tmp_path / "archive" / "index.sqlite").is_file()


def test_record_insertion_keeps_every_other_byte():
    text = ("# header comment\nid: a\nscans:\n  - file: a.npz  # inline\n    station: a\n\n"
            "# about references\nreferences: []\nseed: 1\n")
    updated = insert_scan_text(text, {"file": "b.npz", "station": "b"})
    assert updated == text.replace("    station: a\n", "    station: a\n  - file: b.npz\n    station: b\n")


def test_existing_station_is_refused_before_anything_is_written(tiny_catalog):
    before = digests(tiny_catalog)
    with pytest.raises(CatalogError, match="station 'a' is already in site 'pool'"):
        acquire_scan(tiny_catalog, "socket://127.0.0.1:9", "pool", "a", depth_m=1.0, heading_deg=0.0)
    with pytest.raises(CatalogError, match="no site record with id 'nope'"):
        acquire_scan(tiny_catalog, "socket://127.0.0.1:9", "nope", "z", depth_m=1.0, heading_deg=0.0)
    assert digests(tiny_catalog) == before


@pytest.mark.parametrize("how", ["interrupt", "cable"])
def test_interrupted_scan_is_kept_as_partial(tiny_catalog, tmp_path, how):
    echo = station_b(tiny_catalog)
    before = digests(tiny_catalog / "data")
    server = build_emulator(echo, timing=HeadTiming(alive_period=0.2, boot=0.3, realtime=True)).start()
    received_at_cut = []

    def cut(assembler) -> None:
        if assembler.received == 80:
            received_at_cut.append(server.bytes_out)
            if how == "interrupt":
                raise KeyboardInterrupt
            threading.Thread(target=server.stop).start()

    try:
        result = acquire_scan(tiny_catalog, server.url, "pool", "b", depth_m=1.0, heading_deg=10.0,
                              config=CONFIG, store=catalog_store(tiny_catalog, tmp_path / "archive"), on_line=cut)
    finally:
        server.stop()
    assert result.partial and result.station == "b-partial"
    scan = read_scan(result.scan_path)
    assert scan.settings["partial"] is True and scan.settings["missing_beams"] == 200 - scan.n_beams
    assert 80 <= scan.n_beams < 200
    assert any("partial scan" in note for note in result.notes)
    if how == "interrupt":
        assert result.capture.error == "interrupted"
    else:
        assert "link lost" in result.capture.error
    # The raw capture holds every line that was decoded, and more.
    assert len(result.raw_path.read_bytes()) >= received_at_cut[0] - 4096
    loaded = load_record(tiny_catalog / "sites" / "pool.yaml", tiny_catalog)
    assert loaded.record.scans[-1].station == "b-partial"
    after = digests(tiny_catalog / "data")
    assert {k: v for k, v in after.items() if k in before} == before


def test_no_head_changes_nothing(tiny_catalog):
    record_before = (tiny_catalog / "sites" / "pool.yaml").read_bytes()
    result = acquire_scan(tiny_catalog, "/dev/does-not-exist", "pool", "b", depth_m=1.0, heading_deg=0.0,
                          config=CONFIG)
    assert result.capture.scan is None and result.scan_path is None and result.record_path is None
    assert "cannot open the port" in result.capture.error
    assert (tiny_catalog / "sites" / "pool.yaml").read_bytes() == record_before
    assert result.raw_path is None and not (tiny_catalog / "data" / "pool" / "b.seanet").exists()


def test_second_session_never_overwrites_a_raw_capture(tiny_catalog):
    raw = tiny_catalog / "data" / "pool" / "b.seanet"
    raw.write_bytes(b"earlier capture")
    echo = station_b(tiny_catalog)
    with build_emulator(echo, timing=FAST) as server:
        result = acquire_scan(tiny_catalog, server.url, "pool", "b", depth_m=1.0, heading_deg=0.0,
                              config=CONFIG)
    assert result.raw_path.name == "b-2.seanet" and raw.read_bytes() == b"earlier capture"
    assert read_scan(result.scan_path).settings["raw_file"] == "data/pool/b-2.seanet"


def test_acquire_command_with_faults_and_progress(tiny_catalog, tmp_path, capsys):
    from cistern_archive.cli import main

    echo = station_b(tiny_catalog)
    plan = FaultPlan(drop=0.0002, garbage=0.03, stall_at=50, seed=2)
    with build_emulator(echo, timing=FAST, faults=plan, tcp_port=0) as server:
        with pytest.raises(SystemExit) as exit_info:
            main(["acquire", "--catalog", str(tiny_catalog), "--port", server.url, "--site", "pool", "--station",
                  "b", "--depth", "1.0", "--heading", f"{heading_of(echo):.2f}", "--reply-timeout", "0.3",
                  "--archive", str(tmp_path / "archive")])
    assert exit_info.value.code == 0
    err = capsys.readouterr().err
    assert "200/200" in err and "record:" in err and "archived:" in err
    scan = read_scan(tiny_catalog / "data" / "pool" / "b.npz")
    assert scan.n_beams == 200 and scan.settings["link"]["reboots"] >= 1


def test_acquired_scan_builds_into_the_site_report(tmp_path):
    """Done-when: a scan recorded from the emulator through `acquire` builds like any other scan.

    The LAIR pool spec of the bundled catalog is simulated with station s1 only; its neighbour s2 is then
    acquired from the emulated head, and the pipeline must place it where the spec put it.
    """
    from cistern_archive.pipeline.runner import build_site

    spec = REPO / "catalog" / "specs" / "lair-pool.yaml"
    if not spec.is_file():
        pytest.skip(f"bundled spec {spec} is absent")
    catalog = make_catalog(tmp_path / "catalog", spec.read_text(), ("s1",))
    echo = SimulatedEcho.from_catalog(catalog, "lair-pool", "s2")
    with build_emulator(echo, timing=FAST) as server:
        result = acquire_scan(catalog, server.url, "lair-pool", "s2", depth_m=echo.pose.depth_m,
                              heading_deg=heading_of(echo), config=CONFIG)
    assert result.capture.complete
    build = build_site(load_record(catalog / "sites" / "lair-pool.yaml", catalog))
    assert build.result.status == "ok", build.result.failure
    assert [s.station for s in build.raw_scans] == ["s1", "s2"]
    assert build.raw_scans[-1].n_beams == 400
    poses = build.poses
    assert poses is not None and poses.placed.all(), poses
    true_offset = np.subtract((echo.pose.x_m, echo.pose.y_m), (1.25, 1.70))  # s2 - s1 in the spec
    assert np.hypot(*(poses.xy_m[1] - poses.xy_m[0] - true_offset)) < 0.25, poses.xy_m


def test_ctrl_c_on_the_command_line_keeps_a_partial_scan(tiny_catalog):
    """Two real processes: `emulate` at the acoustic pace, `acquire` interrupted with SIGINT mid-scan."""
    import os
    import select
    import signal
    import subprocess
    import sys
    import time

    base = [sys.executable, "-m", "cistern_archive"]
    emulate = subprocess.Popen(base + ["emulate", "--catalog", str(tiny_catalog), "--site", "pool", "--station", "b",
                                       "--alive-period", "0.2", "--boot", "0.2"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=REPO)
    try:
        assert select.select([emulate.stdout], [], [], 30)[0], "emulate printed nothing"
        url = emulate.stdout.readline().decode().strip()
        acquire = subprocess.Popen(base + ["acquire", "--catalog", str(tiny_catalog), "--port", url, "--site",
                                           "pool", "--station", "b", "--depth", "1", "--heading", "95",
                                           "--no-archive"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO,
                                   env=dict(os.environ, COLUMNS="100"), preexec_fn=default_sigint)
        raw = tiny_catalog / "data" / "pool" / "b.seanet"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (not raw.exists() or raw.stat().st_size < 8000):
            time.sleep(0.05)
        acquire.send_signal(signal.SIGINT)
        _, err = acquire.communicate(timeout=60)
    finally:
        emulate.send_signal(signal.SIGTERM)
        emulate.communicate(timeout=20)
    assert acquire.returncode == 130, err.decode()
    scan = read_scan(tiny_catalog / "data" / "pool" / "b-partial.npz")
    assert scan.settings["partial"] is True and 0 < scan.n_beams < 200
    loaded = load_record(tiny_catalog / "sites" / "pool.yaml", tiny_catalog)
    assert loaded.record.scans[-1].station == "b-partial"
    assert b"partial scan" in err
