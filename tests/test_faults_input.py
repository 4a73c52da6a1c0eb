"""Hostile input: YAML bombs and deep nesting, NaN and infinite values, records symlinked from outside the
catalog, site ids with a trailing newline, station labels that leave the catalog, .npz files whose
headers lie about their size. Each is refused with ``file:line`` (or the file and the problem), before
anything is written or allocated, and only the project's own error type escapes the catalog loader."""

from __future__ import annotations

import io
import json
import math
import re
import resource
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from catalog_helpers import RECORD, ring_scan, write_catalog
from cistern_archive.catalog.loader import load_record
from cistern_archive.pipeline.validate import validate_catalog
from cistern_archive.core.errors import CatalogError, ReaderError
from cistern_archive.sonar.interchange import read_scan, write_scan
from fault_helpers import digest_tree, guard, one_line_error, run_cli  # noqa: F401  (guard is a fixture)


def _problems(catalog: Path) -> list[str]:
    return validate_catalog(catalog).problems


def _refused(catalog: Path, record: Path, line: int, words: str) -> None:
    problems = _problems(catalog)
    assert any(p.startswith(f"{record}:{line}: ") and re.search(words, p) for p in problems), problems


# ------------------------------------------------------------------------------------------- YAML
BOMB = "\n".join(["a: &a [x, x, x, x, x, x, x, x, x]"] + [
    f"{chr(98 + k)}: &{chr(98 + k)} [*{chr(97 + k)}, *{chr(97 + k)}, *{chr(97 + k)}, *{chr(97 + k)}, "
    f"*{chr(97 + k)}, *{chr(97 + k)}, *{chr(97 + k)}, *{chr(97 + k)}, *{chr(97 + k)}]" for k in range(8)]) + "\n"


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path):
    assert len(BOMB) < 500  # expands to 9**9 = 387 million values
    record = write_catalog(tmp_path, RECORD + BOMB)
    start = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(CatalogError) as refused:
        load_record(record, tmp_path)
    # expanded, the bomb would take minutes and gigabytes; refused, it takes a fraction of a second on a
    # quiet machine (a first import of the catalog's modules on a loaded one has taken 2 s)
    assert time.perf_counter() - start < 30.0
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # KiB
    assert re.match(rf"{re.escape(str(record))}:\d+: yaml: more than \d+ values once aliases are expanded",
                    refused.value.problems[0])


def test_a_huge_record_is_refused_unread(tmp_path):
    record = write_catalog(tmp_path, RECORD + "description: " + "x" * 5_000_000 + "\n")
    start = time.perf_counter()
    _refused(tmp_path, record, 1, r"larger than \d+ bytes")
    assert time.perf_counter() - start < 2.0


@pytest.mark.parametrize("opener, closer", [("[", "]"), ("{a: ", "}")])
def test_thousands_of_nested_brackets_are_refused_with_their_line(tmp_path, opener, closer):
    record = write_catalog(tmp_path, RECORD + "description: " + opener * 5000 + "1" + closer * 5000 + "\n")
    _refused(tmp_path, record, RECORD.count("\n") + 1, "nested more than")


@pytest.mark.parametrize("text, words", [
    ("? [a, b]\n: 1\n", "mapping key must be a plain value"),
    ("when: 2012-13-45\n", "bad value"),
    ("x: !!python/object:os.system 1\n", "bad value|could not determine a constructor"),
    ("n: !!int 12abc\n", "bad value"),
    ("n: !!int ''\n", "bad value"),  # found by the property test below: PyYAML raised IndexError
])
def test_values_yaml_cannot_construct_are_refused_with_their_line(tmp_path, text, words):
    record = write_catalog(tmp_path, RECORD + text)
    _refused(tmp_path, record, RECORD.count("\n") + 1, words)


# ----------------------------------------------------------------------------- NaN, ids, symlinks
@pytest.mark.parametrize("field, value, line", [
    ("depth_m", ".nan", 6), ("depth_m", "-.inf", 6), ("yaw_deg", ".inf", 6)])
def test_nan_and_inf_in_a_float_field_are_refused(tmp_path, field, value, line):
    text = RECORD.replace("    depth_m: 1.0\n", f"    {field}: {value}\n", 1)
    record = write_catalog(tmp_path, text)
    _refused(tmp_path, record, line, "finite number")


def test_nan_in_plugin_params_is_refused(tmp_path):
    record = write_catalog(tmp_path, RECORD + "pipeline:\n  matcher: {plugin: pf-pairwise, params: {sigma_m: .nan}}\n")
    _refused(tmp_path, record, RECORD.count("\n") + 2, "not a finite number")


def test_a_site_id_with_a_trailing_newline_is_refused(tmp_path):
    record = write_catalog(tmp_path, RECORD.replace("id: test-site", 'id: "test-site\\n"'))
    _refused(tmp_path, record, 1, "must be a slug")


def test_a_record_symlinked_from_outside_the_catalog_is_refused(tmp_path):
    outside = write_catalog(tmp_path / "elsewhere", RECORD.replace("test-site", "outside-site"))
    catalog = tmp_path / "catalog"
    write_catalog(catalog)
    (catalog / "linked.yaml").symlink_to(outside)
    report = validate_catalog(catalog)
    assert [r.record.id for r in report.records] == ["test-site"]
    assert any(p.startswith(f"{catalog / 'linked.yaml'}:1: (record): resolves to") and "outside the catalog" in p
               for p in report.problems), report.problems


@pytest.mark.parametrize("label", ["../../x", "/tmp/abs", ".hidden", "s 1", "a/b", "x" * 65, "s1\n"])
def test_station_labels_that_cannot_name_a_file_are_refused(tmp_path, label):
    record = write_catalog(tmp_path, RECORD.replace("station: S2", f"station: {json.dumps(label)}"))
    _refused(tmp_path, record, 8, "station label")


# ------------------------------------------------------------------------ property: the loader
VALID = RECORD + """\
pipeline:
  matcher: {plugin: pf-pairwise, params: {filter: {n_particles: 200}}}
truth:
  - {station: S1, x_m: 0.0, y_m: 0.0}
base: &anchor {place: here}
"""
PROBLEM = re.compile(r"^(?P<path>.+?):(?P<line>\d+): \S.*", re.S)  # the first ":N: " ends the path: a field may hold ":1"


def _assert_only_catalog_errors(tmp_path: Path, text: str) -> None:
    record = tmp_path / "site.yaml"
    record.write_text(text, encoding="utf-8")
    try:
        load_record(record, tmp_path)
    except CatalogError as exc:
        assert exc.problems
        for problem in exc.problems:
            match = PROBLEM.match(problem)
            assert match and match["path"] == str(record), problem
            assert 1 <= int(match["line"]) <= text.count("\n") + 2, problem


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=400))
def test_random_text_gives_only_catalog_errors_with_file_and_line(tmp_path, text):
    _assert_only_catalog_errors(tmp_path, text)


YAML_PIECES = ["[", "]", "{", "}", ":", ": ", "- ", "\n", "\n  ", "&a ", "*a", "*b", "!!int ", "!!binary ",
               "!!python/name:os ", "? ", ",", "'", '"', "|", ">", "#", ".nan", ".inf", "~", "1e999", "0x1G",
               "2012-13-45", "station: ", "id: ", "scans: ", "\t", "%YAML 1.1\n", "---\n", "...\n", "<<: *anchor\n"]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.tuples(st.integers(0, len(VALID)), st.integers(0, 8), st.sampled_from(YAML_PIECES)),
                     min_size=1, max_size=6))
@example(cuts=[(VALID.index("n_particles: 200") + 13, 3, "!!int ")])  # `n_particles: !!int }`
@example(cuts=[(VALID.index("{station: S1") + 3, 8, ":")])  # a field named `st:1`, whose problem holds ":1: "
def test_mutated_records_give_only_catalog_errors_with_file_and_line(tmp_path, cuts):
    text = VALID
    for at, delete, piece in cuts:
        at = min(at, len(text))
        text = text[:at] + piece + text[at + delete:]
    _assert_only_catalog_errors(tmp_path, text)


# ------------------------------------------------------------------------------------ .npz files
def _npz(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def _good_members(scan=None) -> dict[str, bytes]:
    scan = scan or ring_scan()
    meta = json.dumps({"schema": "cistern-archive/scan", "schema_version": 1, "full_scale": 255.0,
                       "bin_size_m": 0.05, "start_range_m": 0.0, "yaw_rad": 0.0, "depth_m": 1.0, "timestamp": None,
                       "sonar_model": "x", "beam_width_rad": 0.05, "station": "S1", "settings": {}}).encode()
    return {"bearings_rad.npy": _npy(scan.bearings_rad), "intensities.npy": _npy(scan.intensities),
            "metadata.npy": _npy(np.frombuffer(meta, dtype=np.uint8))}


def _lying_header(shape: tuple[int, ...]) -> bytes:
    """A ``.npy`` header claiming ``shape`` of uint8, followed by a few bytes of data."""
    header = {"descr": "|u1", "fortran_order": False, "shape": shape}
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue() + b"\0" * 64


def _peak_kib_of(code: str) -> tuple[subprocess.CompletedProcess, int]:
    """Run ``code`` in a fresh interpreter; its peak resident memory (``VmHWM``: unlike ``ru_maxrss`` it
    does not include the forking parent's)."""
    probe = (code + "\nimport re, sys\n"
             "hwm = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)\n"
             "print('PEAK', hwm, file=sys.stderr)\n")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    peak = int(re.search(r"PEAK (\d+)", run.stderr).group(1))
    return run, peak


def test_an_npy_header_claiming_a_trillion_elements_is_refused_without_allocating(tmp_path):
    path = _npz(tmp_path / "huge.npz", {**_good_members(), "intensities.npy": _lying_header((10 ** 6, 10 ** 6))})
    with pytest.raises(ReaderError, match=r"huge.npz: intensities.npy header claims shape \(1000000, 1000000\)"):
        read_scan(path)
    run = run_cli("inspect", str(path))
    one_line_error(run, code=2, naming="huge.npz")


def test_a_zip_bomb_npz_is_refused_from_its_headers(tmp_path):
    zeros = np.zeros((20_000, 20_000), dtype=np.uint8)  # 400 MB of zeros deflate to about 400 kB
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in _good_members().items():
            if name != "intensities.npy":
                archive.writestr(name, data)
        with archive.open("intensities.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array(member, zeros, allow_pickle=False)
    del zeros
    assert path.stat().st_size < 2_000_000
    run, peak_kib = _peak_kib_of(f"from cistern_archive.sonar.readers import read_file\n"
                                 f"from cistern_archive.core.errors import ReaderError\n"
                                 f"try:\n    read_file({str(path)!r})\nexcept ReaderError as exc:\n"
                                 f"    print('REFUSED', exc)\n")
    assert "REFUSED" in run.stdout and "at most" in run.stdout, run.stdout + run.stderr
    assert peak_kib < 300_000, f"peak memory {peak_kib} KiB while refusing a 1.5 MB file"


@pytest.mark.parametrize("case", ["zero beams", "nan depth", "inf bin size", "string yaw"])
def test_inspect_refuses_empty_scans_and_non_finite_metadata_in_one_line(tmp_path, case):
    members = _good_members()
    meta = json.loads(np.lib.format.read_array(io.BytesIO(members["metadata.npy"])).tobytes())
    if case == "zero beams":
        members["bearings_rad.npy"] = _npy(np.zeros(0))
        members["intensities.npy"] = _npy(np.zeros((0, 10), dtype=np.uint8))
    else:
        key, value = {"nan depth": ("depth_m", math.nan), "inf bin size": ("bin_size_m", math.inf),
                      "string yaw": ("yaw_rad", "north")}[case]
        meta[key] = value
    members["metadata.npy"] = _npy(np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
    path = _npz(tmp_path / "odd.npz", members)
    for args in (("inspect", str(path)), ("inspect", str(path), "--json")):
        one_line_error(run_cli(*args), code=2, naming="odd.npz")


def test_a_good_scan_still_reads_after_the_header_checks(tmp_path):
    path = write_scan(ring_scan(), tmp_path / "good.npz")
    assert read_scan(path).n_beams == 200


# --------------------------------------------------------------------------------- acquire station
@pytest.mark.parametrize("label", ["../../escaped", "/tmp/absolute-capture", ".hidden", "a/b"])
def test_acquire_refuses_a_station_label_before_writing_anything(tmp_path, label, guard):
    catalog = tmp_path / "catalog"
    write_catalog(catalog)
    guard.watch_raw(tmp_path)
    before = digest_tree(tmp_path)
    run = run_cli("acquire", "--catalog", str(catalog), "--port", "loop://", "--site", "test-site",
                  "--station", label, "--depth", "1", "--heading", "0", "--no-archive", "--alive-timeout", "0.2")
    one_line_error(run, code=2, naming="station")
    assert digest_tree(tmp_path) == before
    assert not Path("/tmp/absolute-capture.seanet").exists()
    assert guard.check() == []
