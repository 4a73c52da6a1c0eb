"""The emulated Micron head: state machine, echoes, faults, and the `emulate` command."""

from __future__ import annotations

import math
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import serial

from cistern_archive.core.errors import CatalogError
from cistern_archive.sonar.geometry import ray_cast
from cistern_archive.simulation.spec import EffectsSpec
from cistern_archive.tritech.codec import MessageType
from cistern_archive.tritech.stream import StreamDecoder, iter_packets
from cistern_archive.tritech.head_data import decode_head_data
from cistern_archive.acquisition.emulator import EmulatedHead, HeadTiming
from cistern_archive.acquisition.emulator_server import build_emulator
from cistern_archive.acquisition.faults import FaultInjector, FaultPlan
from cistern_archive.acquisition.echoes import SimulatedEcho
from cistern_archive.tritech.messages import Alive, BBUserData, SendData, VersionData
from cistern_archive.tritech.codec import command
from cistern_archive.tritech.settings import HeadSettings
from cistern_archive.tritech.head_command import ReverseCommand

from tritech_helpers import tiny_catalog  # noqa: F401  (fixture)

ROOM = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])
REPO = Path(__file__).resolve().parents[1]


def ideal_echo(**kw) -> SimulatedEcho:
    return SimulatedEcho.from_polygon(ROOM, x_m=2.0, y_m=1.5, yaw_deg=30.0, effects=EffectsSpec.ideal(), **kw)


def packet(raw: bytes):
    return next(iter_packets(raw))


def fresh_head(**kw) -> EmulatedHead:
    return EmulatedHead(ideal_echo(), np.random.default_rng(0), timing=HeadTiming(alive_period=1.0, boot=0.5,
                                                                                  realtime=False), **kw)


def decode_all(chunks: list[bytes]):
    return [p for chunk in chunks for p in iter_packets(chunk)]


def configure(head: EmulatedHead, settings: HeadSettings, now: float = 1.0) -> None:
    head.handle(packet(command(MessageType.SEND_VERSION)), now)
    head.handle(packet(command(MessageType.SEND_BB_USER)), now)
    head.handle(packet(settings.head_command().encode()), now)


def test_power_on_sequence_follows_the_state_machine():
    head = fresh_head()
    (alive_raw,) = head.poll(0.0)  # the emulated head starts powered up
    assert head.poll(0.5) == []  # next mtAlive one period later
    alive = Alive.decode(packet(alive_raw))
    assert alive.head_inf == 0x4A and alive.no_params and not alive.sent_cfg
    (version,) = head.handle(packet(command(MessageType.SEND_VERSION)), 0.6)
    assert VersionData.decode(packet(version)).node == 2
    replies = decode_all(head.handle(packet(command(MessageType.SEND_BB_USER)), 0.7))
    assert [p.type for p in replies] == [MessageType.BB_USER_DATA, MessageType.FPGA_CAL_DATA,
                                         MessageType.FPGA_VERSION_DATA]
    assert BBUserData.decode(replies[0]).replies_per_request == 2
    assert head.handle(packet(SendData().encode()), 0.8) == []  # no parameters: no reply
    (ack,) = head.handle(packet(HeadSettings().head_command().encode()), 0.9)
    assert Alive.decode(packet(ack)).head_inf == 0xBA  # Centred|MotorOn|Dir|InScan|SentCfg


def test_send_data_gives_two_lines_stepping_clockwise():
    head = fresh_head()
    configure(head, HeadSettings(range_m=5.0, n_bins=100, step=32))
    head.handle(packet(SendData().encode()), 2.0)
    lines = [decode_head_data(p) for p in decode_all(head.poll(2.0)) if p.type == MessageType.HEAD_DATA]
    assert [line.bearing for line in lines] == [3200, 3232]
    assert all(line.n_bins == 100 and line.adc8on and line.device_type == 0x11 for line in lines)


def test_half_duplex_and_four_bit():
    head = fresh_head(half_duplex=True)
    configure(head, HeadSettings(range_m=5.0, n_bins=100, step=32, bits=4))
    head.handle(packet(SendData().encode()), 2.0)
    (line,) = [decode_head_data(p) for p in decode_all(head.poll(2.0)) if p.type == MessageType.HEAD_DATA]
    assert line.dbytes == 50 and line.n_bins == 100 and line.bins.max() <= 15 and not line.adc8on


def test_sector_scan_bounces_between_the_limits_and_reverses():
    head = fresh_head(half_duplex=True)
    configure(head, HeadSettings(range_m=5.0, n_bins=50, step=64, continuous=False, left_limit=3000,
                                 right_limit=3256))
    seen = []
    for k in range(10):
        head.handle(packet(SendData().encode()), 2.0 + k)
        seen += [decode_head_data(p) for p in decode_all(head.poll(2.0 + k)) if p.type == MessageType.HEAD_DATA]
    assert [line.bearing for line in seen] == [3000, 3064, 3128, 3192, 3256, 3192, 3128, 3064, 3000, 3064]
    assert [line.sweep_code for line in seen][:5] == [1, 0, 0, 0, 2]
    head.handle(packet(ReverseCommand().encode()), 20.0)
    head.handle(packet(SendData().encode()), 20.0)
    (line,) = [decode_head_data(p) for p in decode_all(head.poll(20.0)) if p.type == MessageType.HEAD_DATA]
    assert not line.scan_right


def test_reboot_resets_to_power_on():
    head = fresh_head()
    configure(head, HeadSettings())
    head.handle(packet(command(MessageType.REBOOT)), 3.0)
    assert head.cmd is None and head.poll(3.1) == []
    (alive_raw,) = head.poll(3.6)
    assert Alive.decode(packet(alive_raw)).head_inf == 0x4A


def test_stop_alives_silences_the_periodic_status():
    head = fresh_head()
    head.poll(0.5)
    head.handle(packet(command(MessageType.STOP_ALIVES)), 0.6)
    assert head.poll(5.0) == []


def test_stall_and_spontaneous_reboot_faults():
    head = fresh_head(half_duplex=True, faults=FaultPlan(stall_at=3, stall_s=2.0))
    configure(head, HeadSettings(step=64))
    answered = []
    for k in range(8):
        now = 2.0 + 0.5 * k
        head.handle(packet(SendData().encode()), now)
        answered.append(any(p.type == MessageType.HEAD_DATA for p in decode_all(head.poll(now))))
    assert answered == [True, True, True, False, False, False, False, True]
    head = fresh_head(faults=FaultPlan(reboot_at=4))
    configure(head, HeadSettings(step=64))
    for k in range(3):
        head.handle(packet(SendData().encode()), 2.0 + k)
    assert head.cmd is None and head.reboots == 1


def test_echo_puts_the_wall_where_the_geometry_says():
    echo = ideal_echo()
    settings = HeadSettings(range_m=8.0, n_bins=200, step=32)
    cmd = settings.head_command()
    table = echo.revolution(cmd, np.random.default_rng(1))
    assert table.shape == (200, 200)
    bin_size = settings.bin_size_m()
    # Row k is k steps clockwise from ahead: map angle = yaw - k * step.
    angles = echo.pose.yaw_rad - np.arange(200) * 2 * math.pi / 200
    truth, _ = ray_cast(np.array([echo.pose.x_m, echo.pose.y_m]), angles, echo.rings)
    far = 30  # skip the ring-down near the head
    peaks = (np.argmax(table[:, far:], axis=1) + far + 0.5) * bin_size
    assert np.median(np.abs(peaks - truth)) < 2 * bin_size


def test_gain_and_ad_window_of_the_command_change_the_echoes():
    echo = ideal_echo()
    levels = {}
    for gain in (0.2, 0.4, 0.8):
        cmd = HeadSettings(range_m=8.0, n_bins=200, step=64, gain=gain).head_command()
        levels[gain] = float(echo.revolution(cmd, np.random.default_rng(1)).mean())
    assert levels[0.2] < levels[0.4] < levels[0.8]
    narrow = HeadSettings(range_m=8.0, n_bins=200, step=64, ad_span=40).head_command()
    assert echo.revolution(narrow, np.random.default_rng(1)).mean() > levels[0.4]


def test_fault_injector_is_seeded_and_counts():
    data = bytes(range(256)) * 20
    plan = FaultPlan(drop=0.01, flip=0.01, garbage=0.5, seed=4)
    a = FaultInjector(plan, np.random.default_rng(4))(data)
    b = FaultInjector(plan, np.random.default_rng(4))(data)
    assert a == b and a != data
    injector = FaultInjector(FaultPlan(), np.random.default_rng(0))
    assert injector(data) == data


def test_fault_plan_parsing():
    plan = FaultPlan.parse("drop=0.001, flip=0.002,garbage=0.05,stall=10,stall_s=1.5,reboot=20,seed=7")
    assert plan == FaultPlan(0.001, 0.002, 0.05, 10, 1.5, 20, 7)
    assert FaultPlan.parse("") == FaultPlan()
    for bad in ("drop", "nope=1", "drop=2", "stall=x"):
        with pytest.raises(ValueError):
            FaultPlan.parse(bad)


def test_catalog_echo_errors_name_the_problem(tmp_path):
    with pytest.raises(CatalogError, match="no site record"):
        SimulatedEcho.from_catalog(tmp_path, "nowhere")


def test_server_on_a_real_pty_answers_a_raw_serial_client():
    server = build_emulator(ideal_echo(), timing=HeadTiming(alive_period=0.1, boot=0.0, realtime=False))
    with server:
        assert server.url.startswith("/dev/")
        port = serial.serial_for_url(server.url, baudrate=115200, timeout=0.5)
        try:
            port.write(command(MessageType.SEND_VERSION))
            decoder = StreamDecoder()
            types = set()
            deadline = time.monotonic() + 5
            while MessageType.VERSION_DATA not in types and time.monotonic() < deadline:
                types |= {p.type for p in decoder.feed(port.read(64))}
            assert MessageType.VERSION_DATA in types and MessageType.ALIVE in types
        finally:
            port.close()
    assert server.error is None


def _spawn_emulate(catalog: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen(
        [sys.executable, "-m", "cistern_archive", "emulate", "--catalog", str(catalog), "--site", "pool",
         "--station", "a", "--fast", "--alive-period", "0.2", "--boot", "0.1", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO)


def _first_line(proc: subprocess.Popen, timeout: float = 30.0) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    assert ready, "emulate printed nothing"
    return proc.stdout.readline().decode().strip()


@pytest.mark.parametrize("tcp", [False, True])
def test_emulate_command_prints_the_port_first_and_serves(tiny_catalog, tcp):
    proc = _spawn_emulate(tiny_catalog, *(["--tcp", "0"] if tcp else []))
    try:
        url = _first_line(proc)
        assert url.startswith("socket://127.0.0.1:") if tcp else url.startswith("/dev/")
        port = serial.serial_for_url(url, baudrate=115200, timeout=0.3)
        try:
            decoder = StreamDecoder()
            got = []
            deadline = time.monotonic() + 10
            while not got and time.monotonic() < deadline:
                got = [p for p in decoder.feed(port.read(64)) if p.type == MessageType.ALIVE]
            assert got
        finally:
            port.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err.decode()
    assert b"stopped after" in err


def test_emulate_command_refuses_an_unknown_site(tiny_catalog):
    proc = subprocess.run([sys.executable, "-m", "cistern_archive", "emulate", "--catalog", str(tiny_catalog),
                           "--site", "elsewhere"], capture_output=True, cwd=REPO, timeout=60)
    assert proc.returncode == 2 and b"elsewhere" in proc.stderr
