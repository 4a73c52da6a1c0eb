"""``cistern-archive inspect``: JSON summary, table output and the exit code of unreadable files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cistern_archive.cli import app
from cistern_archive.commands import EXIT_USAGE
from cistern_archive.tritech.head_data import HeadData, encode_head_data

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
runner = CliRunner()


def _capture(path: Path, n: int = 300) -> Path:
    lines = [encode_head_data(HeadData(0, 0x11, 0x10, 0, 0x2307, 100, 0, 84, 0, 81, 8, 0, 104, 0, 0, 32,
                                       (i * 32) % 6400, 0, np.full(100, i % 256, np.uint8))) for i in range(n)]
    path.write_bytes(b"".join(lines))
    return path


def test_inspect_json_on_a_raw_capture(tmp_path):
    path = _capture(tmp_path / "scan.seanet")
    result = runner.invoke(app, ["inspect", str(path), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["format"] == "seanet-raw" and doc["warnings"] == []
    assert [s["beams"] for s in doc["scans"]] == [200, 100]
    first = doc["scans"][0]
    assert first["bins"] == 100 and first["bin_size_m"] == pytest.approx(1500 * 104 * 640e-9 / 2)
    assert first["bearing_min_deg"] == pytest.approx(-180.0) and first["bearing_max_deg"] == pytest.approx(178.2)


def test_inspect_table_and_format_option(tmp_path):
    path = _capture(tmp_path / "capture.dat", n=20)
    result = runner.invoke(app, ["inspect", str(path), "--format", "seanet-raw"])
    assert result.exit_code == 0, result.output
    assert "seanet-raw" in result.stdout and "100" in result.stdout


def test_inspect_unreadable_file_exits_2_naming_file_and_offset(tmp_path):
    path = tmp_path / "broken.V4LOG"
    path.write_bytes(b"not a log at all")
    proc = subprocess.run([sys.executable, "-m", "cistern_archive", "inspect", str(path), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_USAGE
    assert str(path) in proc.stderr and "byte offset 0" in proc.stderr and proc.stdout == ""


def test_inspect_garbage_raw_capture_exits_2(tmp_path):
    path = tmp_path / "noise.seanet"
    path.write_bytes(bytes(range(256)) * 4)
    result = runner.invoke(app, ["inspect", str(path), "--json"])
    assert result.exit_code == EXIT_USAGE
    assert str(path) in result.output and "byte offset" in result.output


@pytest.mark.realdata
def test_inspect_real_v4log_json():
    path = DATA / "seanet" / "90degree_scan_target_moving_in.V4LOG"
    if not path.exists():
        pytest.skip(f"real recording {path} not found (../shared/data beside the repository)")
    result = runner.invoke(app, ["inspect", str(path), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["format"] == "seanet-v4log" and len(doc["scans"]) == 19
    assert sum(s["beams"] for s in doc["scans"]) == 468 and {s["bins"] for s in doc["scans"]} == {642}
    assert doc["scans"][1]["bearing_max_deg"] - doc["scans"][1]["bearing_min_deg"] == pytest.approx(86.4)


def test_inspect_table_prints_warnings_without_raw_markup(tmp_path):
    path = _capture(tmp_path / "scan.seanet", n=60)
    data = path.read_bytes()
    path.write_bytes(data[:2000] + b"\x00garbage[/]\x00" * 5 + data[2000:])
    doc = json.loads(runner.invoke(app, ["inspect", str(path), "--json"]).stdout)
    assert doc["warnings"], "the damaged capture should warn"
    result = runner.invoke(app, ["inspect", str(path)])
    assert result.exit_code == 0, result.output
    assert "warning:" in result.stdout and "[yellow]" not in result.stdout and "[/]" not in result.stdout


def test_help_texts_carry_no_markup():
    from cistern_archive.commands import COMMAND_MODULES

    for command in ("",) + COMMAND_MODULES:
        result = runner.invoke(app, [command, "--help"] if command else ["--help"], env={"COLUMNS": "200"})
        assert result.exit_code == 0, (command, result.output)
        assert "``" not in result.output and ":func:" not in result.output, (command, result.output)


def test_command_list_gives_each_summary_as_running_text():
    """A docstring's line breaks do not split a sentence across rows of the command list (on a wide
    terminal every summary fits on its command's own row) nor across lines of a command's help."""
    result = runner.invoke(app, ["--help"], env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    rows = [line for line in result.output.splitlines() if line.startswith("│ ")]
    continued = [line for line in rows if line[2:].startswith(" ")]  # a row with no command or option name
    assert "ingest" in result.output and not continued, continued
    own = runner.invoke(app, ["rebuild", "--help"], env={"COLUMNS": "400"}).output
    assert "two parts of the map joined imprecisely" in own  # later paragraphs run on too
