"""The pyserial driver against the emulated head: pty, TCP, loop://, faults, failures."""

from __future__ import annotations

import math
import os
import socket
import threading
import time

import numpy as np
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from cistern_archive.simulation.spec import EffectsSpec
from cistern_archive.tritech.head_data import encode_head_data, rad_to_bearing
from cistern_archive.acquisition.driver import DriverConfig, LinkError, MicronDriver
from cistern_archive.acquisition.assembly import ScanAssembler, collect_scan
from cistern_archive.acquisition.emulator import HeadTiming
from cistern_archive.acquisition.emulator_server import build_emulator
from cistern_archive.acquisition.faults import FaultPlan
from cistern_archive.acquisition.echoes import SimulatedEcho
from cistern_archive.tritech.messages import Alive, BBUserData, HeadInf, VersionData, head_data_for
from cistern_archive.tritech.settings import HeadSettings

ROOM = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])
FAST = HeadTiming(alive_period=0.2, boot=0.3, realtime=False)
CONFIG = DriverConfig(reply_timeout_s=0.3, alive_timeout_s=5.0, config_timeout_s=5.0)
SETTINGS = HeadSettings(range_m=6.0, n_bins=120, step=32)


def echo(ideal: bool = True) -> SimulatedEcho:
    return SimulatedEcho.from_polygon(ROOM, x_m=2.0, y_m=1.5, yaw_deg=30.0,
                                      effects=EffectsSpec.ideal() if ideal else EffectsSpec())


def record_scan(url: str, settings: HeadSettings = SETTINGS, config: DriverConfig = CONFIG, **kw):
    with MicronDriver(url, settings, config=config) as driver:
        capture = collect_scan(driver, station="x", **kw)
        return capture, driver.stats


@pytest.fixture(scope="module")
def clean_scan():
    """A fault-free reference scan of the ideal room (over a pty)."""
    with build_emulator(echo(), timing=FAST) as server:
        capture, _ = record_scan(server.url)
    assert capture.complete
    return capture.scan


def test_full_scan_over_a_real_pseudo_terminal(clean_scan):
    scan = clean_scan
    assert scan.n_beams == 200 and scan.n_bins == 120
    assert scan.bin_size_m == pytest.approx(SETTINGS.bin_size_m())
    assert scan.full_scale == 255 and scan.intensities.dtype == np.uint8
    # The head starts ahead (3200 -> 0 rad) and turns clockwise: sonar-frame bearings decrease.
    assert scan.bearings_rad[0] == pytest.approx(0.0)
    steps = np.diff(np.unwrap(scan.bearings_rad))
    np.testing.assert_allclose(steps, -2 * math.pi / 200)
    assert scan.settings["partial"] is False and scan.settings["missing_beams"] == 0
    assert scan.settings["ad_interval"] == SETTINGS.ad_interval()
    assert scan.intensities.max() > 100  # the walls are there


def test_full_scan_over_tcp_matches_the_pty_scan(clean_scan):
    # Same seed, same echoes: the transport must not change a byte.
    with build_emulator(echo(), timing=FAST, tcp_port=0) as server:
        assert server.url.startswith("socket://127.0.0.1:")
        capture, stats = record_scan(server.url)
    assert capture.complete and stats.requests == 100  # full duplex: two lines per request
    np.testing.assert_array_equal(capture.scan.intensities, clean_scan.intensities)
    np.testing.assert_array_equal(capture.scan.bearings_rad, clean_scan.bearings_rad)


def test_half_duplex_four_bit_and_anticlockwise():
    settings = HeadSettings(range_m=6.0, n_bins=120, step=64, bits=4, direction="left")
    with build_emulator(echo(), timing=FAST, half_duplex=True) as server:
        capture, stats = record_scan(server.url, settings)
    scan = capture.scan
    assert capture.complete and stats.requests == 100 and scan.n_beams == 100
    assert scan.full_scale == 15 and scan.intensities.max() <= 15
    steps = np.diff(np.unwrap(scan.bearings_rad))
    np.testing.assert_allclose(steps, 2 * math.pi / 100)


def test_realtime_pace_is_bounded_by_the_acoustics():
    settings = HeadSettings(range_m=6.0, n_bins=120, step=128)
    timing = HeadTiming(alive_period=0.2, boot=0.3, realtime=True)
    with build_emulator(echo(), timing=timing) as server:
        start = time.monotonic()
        capture, _ = record_scan(server.url, settings)
        elapsed = time.monotonic() - start
    per_line = 2 * 6.0 / 1500 + (45 + 120) * 10 / 115200
    assert capture.complete and elapsed >= 50 * per_line


def assert_lines_were_sent(scan, history) -> None:
    """Every beam of ``scan`` is byte-for-byte a line the head sent at that bearing."""
    sent: dict[int, list[bytes]] = {}
    for bearing, bins in history:
        sent.setdefault(bearing, []).append(bins.tobytes())
    for theta, row in zip(scan.bearings_rad, scan.intensities):
        bearing = int(rad_to_bearing(theta))
        assert row.tobytes() in sent.get(bearing, []), f"beam at bearing {bearing} was never sent"


def test_faults_are_recovered_and_the_data_is_intact():
    plan = FaultPlan(drop=0.0003, garbage=0.05, stall_at=40, reboot_at=120, seed=5)
    with build_emulator(echo(), timing=FAST, faults=plan, tcp_port=0, keep_history=True) as server:
        capture, stats = record_scan(server.url)
        injected = server.injector
    assert capture.complete, capture.error
    assert stats.reboots >= 1 and stats.reconfigurations >= 1 and stats.timeouts >= 5
    assert injected.dropped > 0 and stats.discarded_bytes >= injected.garbage_bytes > 0
    # Dropped bytes and garbage cost whole lines, never corrupt them.
    assert_lines_were_sent(capture.scan, server.head.history)
    np.testing.assert_allclose(np.diff(np.unwrap(capture.scan.bearings_rad)), -2 * math.pi / 200)


def test_flipped_bits_still_give_a_full_scan():
    plan = FaultPlan(flip=0.0005, seed=9)
    with build_emulator(echo(), timing=FAST, faults=plan) as server:
        capture, _ = record_scan(server.url)
    assert capture.scan.n_beams >= 195 and capture.scan.n_bins == 120


def test_inverted_head_sees_the_same_room(clean_scan):
    settings = SETTINGS.model_copy(update={"inverted": True})
    with build_emulator(echo(), timing=FAST) as server:
        capture, _ = record_scan(server.url, settings)
    assert capture.complete
    order_up = np.argsort(capture.scan.bearings_rad)
    order_ref = np.argsort(clean_scan.bearings_rad)
    np.testing.assert_allclose(capture.scan.bearings_rad[order_up], clean_scan.bearings_rad[order_ref])
    walls = lambda scan, order: np.argmax(scan.intensities[order][:, 20:], axis=1)  # noqa: E731
    assert np.median(np.abs(walls(capture.scan, order_up) - walls(clean_scan, order_ref))) <= 1


def test_corrupted_header_fields_are_refused():
    cmd = SETTINGS.head_command()
    assembler = ScanAssembler(step=32)
    assert assembler.add(head_data_for(cmd, 3200, np.zeros(120)))
    flipped_gain = head_data_for(cmd.__class__(**{**cmd.__dict__, "ad_span": cmd.ad_span ^ 4}), 3232,
                                 np.zeros(120))
    assert not assembler.add(flipped_gain)
    assert not assembler.add(head_data_for(cmd, 3232 ^ 1, np.zeros(120)))  # bearing off the step grid
    assert assembler.add(head_data_for(cmd, 3232, np.zeros(120)))
    assert assembler.refused == 2 and len(assembler.lines) == 2


@settings(max_examples=40, deadline=None)
@given(garbage=st.binary(max_size=3000))
def test_driver_reads_through_garbage_to_the_next_packet(garbage):
    alive = Alive(0, 7, 3200, HeadInf(0xAA)).encode()
    port = serial.serial_for_url("loop://", timeout=0)
    port.write(garbage + alive)
    driver = MicronDriver(port, SETTINGS).open()
    try:
        packets = []
        while (packet := driver.next_packet(0.05)) is not None:
            packets.append(packet)
        assert packets and packets[-1].to_bytes() == alive
        assert driver.last_alive == Alive(0, 7, 3200, HeadInf(0xAA))
    finally:
        port.close()


def test_accepting_a_few_gaps_stops_after_one_revolution():
    plan = FaultPlan(drop=0.0005, seed=3)
    with build_emulator(echo(), timing=FAST, faults=plan) as server:
        capture, stats = record_scan(server.url, accept_missing=20)
    assert capture.complete and 0 < capture.missing <= 20
    assert capture.scan.settings["partial"] is False and capture.scan.settings["missing_beams"] == capture.missing
    assert stats.lines < 230  # one revolution, not two


def test_transient_stall_recovers_without_reboot():
    plan = FaultPlan(stall_at=30, stall_s=0.5, seed=1)
    with build_emulator(echo(), timing=FAST, faults=plan) as server:
        capture, stats = record_scan(server.url)
    assert capture.complete and stats.reboots == 0 and stats.timeouts >= 1


def test_silent_port_fails_with_a_clear_message():
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    url = f"socket://127.0.0.1:{listener.getsockname()[1]}"
    try:
        driver = MicronDriver(url, SETTINGS, config=DriverConfig(alive_timeout_s=0.5))
        with pytest.raises(LinkError, match=r"socket://127\.0\.0\.1:\d+: no mtAlive from the head"):
            driver.start()
        driver.close()
    finally:
        listener.close()


def test_unopenable_port_names_itself():
    with pytest.raises(LinkError, match="/dev/does-not-exist: cannot open the port"):
        MicronDriver("/dev/does-not-exist", SETTINGS).open()


@pytest.mark.parametrize("tcp", [False, True])
def test_stopping_from_two_threads_at_once_closes_each_descriptor_once(tcp, monkeypatch):
    """A second close of a descriptor number closes whatever the process opened under it since
    (seen as a later test's socket failing with EBADF)."""
    import cistern_archive.acquisition.emulator_server as emulator_server

    closed: list[object] = []  # descriptor numbers, and sockets by identity
    real_close = os.close
    monkeypatch.setattr(emulator_server.os, "close", lambda fd: (closed.append(fd), real_close(fd))[1])
    real_socket_close = socket.socket.close
    monkeypatch.setattr(socket.socket, "close",
                        lambda sock: (closed.append(("socket", id(sock))), real_socket_close(sock))[1])
    server = build_emulator(echo(), timing=FAST, tcp_port=0 if tcp else None).start()
    stoppers = [threading.Thread(target=server.stop) for _ in range(4)]
    for thread in stoppers:
        thread.start()
    for thread in stoppers:
        thread.join()
    assert closed and len(closed) == len(set(closed))


@pytest.mark.parametrize("tcp", [False, True])
def test_cable_pulled_mid_scan_keeps_the_lines_received(tcp):
    server = build_emulator(echo(), timing=HeadTiming(alive_period=0.2, boot=0.3, realtime=True),
                            tcp_port=0 if tcp else None).start()
    received = []

    stopper = threading.Thread(target=server.stop)

    def pull(assembler: ScanAssembler) -> None:
        received.append(assembler.received)
        if assembler.received == 60:
            stopper.start()

    capture, _ = record_scan(server.url, on_line=pull)
    server.stop()
    stopper.join()
    assert not capture.complete
    assert capture.error.startswith(server.url) and "link lost" in capture.error
    assert capture.scan is not None and capture.scan.settings["partial"] is True
    assert 60 <= capture.scan.n_beams < 200


def test_interrupt_returns_a_partial_scan():
    with build_emulator(echo(), timing=FAST) as server:
        def interrupt(assembler: ScanAssembler) -> None:
            if assembler.received == 50:
                raise KeyboardInterrupt

        capture, _ = record_scan(server.url, on_line=interrupt)
    assert capture.error == "interrupted" and capture.scan.n_beams == 50 and capture.missing == 150


def test_driver_over_loop_url_with_a_scripted_head():
    """``loop://`` echoes what is written: pre-load the head's side of the conversation into it.

    (Its queue holds 4096 bytes, so the script is a short, coarse revolution.)
    """
    settings = HeadSettings(range_m=1.0, n_bins=10, step=128)
    cmd = settings.head_command()
    script = [Alive(1, 0, 3200, HeadInf(0x4A)).encode(), VersionData(3, 1, 1, 1, 1).encode(),
              BBUserData.build(half_duplex=True).encode(), Alive(0, 5, 3200, HeadInf(0xAA)).encode()]
    script += [encode_head_data(head_data_for(cmd, (3200 + 128 * k) % 6400, np.full(10, k))) for k in range(50)]
    port = serial.serial_for_url("loop://", timeout=0.02)
    port.write(b"".join(script))
    with MicronDriver(port, settings, config=CONFIG) as driver:
        capture = collect_scan(driver)
    assert capture.complete and capture.scan.n_beams == 50
    np.testing.assert_array_equal(capture.scan.intensities[:, 0], np.arange(50))
    assert driver.version == VersionData(3, 1, 1, 1, 1)


@settings(max_examples=60, deadline=None)
@given(bearings=st.lists(st.integers(0, 6399), max_size=300), step=st.sampled_from([4, 16, 32, 128]))
def test_assembler_accepts_any_bearing_sequence(bearings, step):
    cmd = HeadSettings(range_m=5, n_bins=10, step=step).head_command()
    assembler = ScanAssembler(step=step)
    for bearing in bearings:
        assembler.add(head_data_for(cmd, bearing, np.zeros(10)))
    assert len(assembler.lines) + assembler.missing == 6400 // step
    scan = assembler.build()
    if bearings:
        assert scan.n_beams == len(assembler.lines) and np.all(np.abs(scan.bearings_rad) <= math.pi)
    else:
        assert scan is None
