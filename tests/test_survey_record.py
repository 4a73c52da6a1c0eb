"""Survey records (a moving vehicle's dataset as a catalog site): schema, validation, inputs, the command.

No recording is needed: the dataset folder is a skeleton with the marina's file layout.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from pydantic import ValidationError

from cistern_archive.catalog.loader import load_record
from cistern_archive.catalog.models import SiteRecord
from cistern_archive.cli import main
from cistern_archive.navigation.records import marina_record, write_marina_record
from cistern_archive.pipeline.validate import validate_catalog
from cistern_archive.service.planning import site_inputs

LOGS = ("_040825_1735_DVL.log", "_040825_1735_MTi.log", "dgps_local_EN_m.csv", "_040825_1735_IS_timestamps.log")


def skeleton_dataset(root: Path, frames: int = 3) -> Path:
    """The marina's layout with placeholder logs and ``frames`` key frames."""
    (root / "derived_tim_pcd").mkdir(parents=True)
    for name in LOGS:
        (root / name).write_text("1 2 3\n")
    rows = "".join(f"{k},{1000.0 + 14 * k},{1014.0 + 14 * k}\n" for k in range(1, frames + 1))
    (root / "derived_tim_pcd" / "keyFrameTimeStamps.csv").write_text("keyFrame,keyFrameBeginning,keyFrameEnd\n" + rows)
    for k in range(1, frames + 1):
        (root / "derived_tim_pcd" / f"pclKeyFrame{k}.pcd").write_text("# .PCD v0.7\n")
    return root


def survey_yaml(data: str) -> str:
    return textwrap.dedent(f"""\
        id: moving
        name: A moving survey
        survey:
          kind: marina
          data: {data}
          settings:
            max_keyframes: 4
          published:
            source: Someone et al. 2014, Table 2
            rows:
              - {{method: dead reckoning, mean_m: 17.46, sd_m: 11.47, max_m: 45.42}}
        """)


def write_record(catalog: Path, text: str) -> Path:
    (catalog / "sites").mkdir(parents=True, exist_ok=True)
    path = catalog / "sites" / "moving.yaml"
    path.write_text(text)
    return path


def test_a_survey_record_outside_the_catalog_validates(tmp_path):
    data = skeleton_dataset(tmp_path / "shared" / "marina")
    catalog = tmp_path / "catalog"
    write_record(catalog, survey_yaml(str(data)))
    report = validate_catalog(catalog)
    assert report.ok, report.problems
    loaded = report.records[0]
    assert loaded.survey_root() == data.resolve()
    assert loaded.record.survey.settings.max_keyframes == 4 and not loaded.record.scans


def test_a_relative_data_folder_is_taken_from_the_catalog_root(tmp_path):
    skeleton_dataset(tmp_path / "catalog" / "data" / "marina")
    write_record(tmp_path / "catalog", survey_yaml("data/marina"))
    report = validate_catalog(tmp_path / "catalog")
    assert report.ok, report.problems
    assert report.records[0].survey_root() == (tmp_path / "catalog" / "data" / "marina").resolve()


def test_a_record_needs_scans_or_a_survey_not_both():
    with pytest.raises(ValidationError, match="either scans .* or a survey .*not neither"):
        SiteRecord(id="x", name="x")
    with pytest.raises(ValidationError, match="not both"):
        SiteRecord(id="x", name="x", scans=[{"file": "a.seanet", "station": "A"}],
                   survey={"kind": "marina", "data": "/d"})


@pytest.mark.parametrize("change, expected", [
    (lambda d: (d / "derived_tim_pcd" / "pclKeyFrame2.pcd").unlink(), "no point cloud for 1 key frame(s) of derived_tim_pcd/keyFrameTimeStamps.csv (2)"),
    (lambda d: (d / "_040825_1735_MTi.log").unlink(), "no file matching '*_MTi.log'"),
    (lambda d: (d / "derived_tim_pcd" / "keyFrameTimeStamps.csv").write_text("keyFrame,b,e\n1,oops,3\n"), "line 2"),
])
def test_an_incomplete_dataset_names_the_record_line_and_the_file(tmp_path, change, expected):
    data = skeleton_dataset(tmp_path / "marina")
    change(data)
    record = write_record(tmp_path / "catalog", survey_yaml(str(data)))
    problems = validate_catalog(tmp_path / "catalog").problems
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"{record}:5: survey.data: ") and expected in problems[0]


def test_a_missing_data_folder_is_refused(tmp_path):
    record = write_record(tmp_path / "catalog", survey_yaml(str(tmp_path / "nowhere")))
    (problem,) = validate_catalog(tmp_path / "catalog").problems
    assert problem == f"{record}:5: survey.data: {tmp_path / 'nowhere'}: the survey's data folder does not exist (or is not a folder)"


def test_unknown_survey_settings_are_refused_with_their_line(tmp_path):
    data = skeleton_dataset(tmp_path / "marina")
    write_record(tmp_path / "catalog", survey_yaml(str(data)).replace("max_keyframes: 4", "max_keyframe: 4"))
    (problem,) = validate_catalog(tmp_path / "catalog").problems
    assert ":7: survey.settings.max_keyframe:" in problem


def test_the_inputs_of_a_survey_are_every_file_it_reads(tmp_path):
    data = skeleton_dataset(tmp_path / "marina", frames=2)
    (data / "_040825_1735_PID.log").write_text("not read\n")
    write_record(tmp_path / "catalog", survey_yaml(str(data)))
    loaded = validate_catalog(tmp_path / "catalog").records[0]
    names = [name for role, name in site_inputs(loaded)]
    assert names == sorted(["survey/" + n for n in LOGS] + ["survey/derived_tim_pcd/keyFrameTimeStamps.csv",
                                                             "survey/derived_tim_pcd/pclKeyFrame1.pcd",
                                                             "survey/derived_tim_pcd/pclKeyFrame2.pcd"])
    assert loaded.input_path("survey/derived_tim_pcd/pclKeyFrame2.pcd") == data / "derived_tim_pcd" / "pclKeyFrame2.pcd"


def test_the_marina_record_names_every_stage_and_the_published_table(tmp_path):
    data = skeleton_dataset(tmp_path / "marina")
    path = write_marina_record(data, tmp_path / "catalog", keyframes=12)
    assert path == tmp_path / "catalog" / "sites" / "girona-marina.yaml"
    record = load_record(path, tmp_path / "catalog").record
    assert record.survey.data == str(data.resolve()) and record.survey.settings.max_keyframes == 12
    assert {"matcher", "localizer", "mapper"} <= {k for k, v in record.pipeline if v is not None}
    assert record.pipeline.mapper.params["cell_m"] == 0.25
    assert [r.mean_m for r in record.survey.published.rows] == [17.46, 3.99, 1.91, 1.90]
    assert validate_catalog(tmp_path / "catalog").ok
    inside = marina_record(tmp_path / "catalog" / "data", tmp_path / "catalog")
    assert inside["survey"]["data"] == "data"


def test_the_survey_command_refuses_a_folder_that_is_not_a_marina_dataset(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["survey", "marina", str(tmp_path), "--catalog", str(tmp_path / "catalog")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "not a marina dataset" in err and "*_DVL.log" in err and "Traceback" not in err
    assert not (tmp_path / "catalog" / "sites").exists()


def test_the_survey_command_keeps_an_existing_record_unless_forced(tmp_path, capsys):
    data = skeleton_dataset(tmp_path / "marina")
    catalog = tmp_path / "catalog"
    args = ["survey", "marina", str(data), "--catalog", str(catalog), "--keyframes", "12"]
    with pytest.raises(SystemExit) as first:
        main(args)
    assert first.value.code == 0
    path = catalog / "sites" / "girona-marina.yaml"
    before = path.read_text()
    with pytest.raises(SystemExit) as second:
        main(args[:-1] + ["14"])
    assert second.value.code == 2 and "--force" in capsys.readouterr().err and path.read_text() == before
    with pytest.raises(SystemExit) as third:
        main(args[:-1] + ["14", "--force"])
    assert third.value.code == 0 and "max_keyframes: 14" in path.read_text()


def test_a_stationary_scan_is_not_acquired_into_a_survey(tmp_path):
    from cistern_archive.acquisition.session import acquire_scan
    from cistern_archive.core.errors import CatalogError

    data = skeleton_dataset(tmp_path / "shared" / "marina")
    record = write_record(tmp_path / "catalog", survey_yaml(str(data)))
    before = record.read_bytes()
    with pytest.raises(CatalogError, match="'moving' is a moving survey"):
        acquire_scan(tmp_path / "catalog", "socket://127.0.0.1:9", "moving", "s1", depth_m=1.0, heading_deg=0.0)
    assert record.read_bytes() == before and not (tmp_path / "catalog" / "data").exists()
