"""The Girona marina as a catalog site, end to end: ``survey marina`` → ``rebuild`` → the site's page.

A few revolutions only (``--keyframes``): the full run is ``benchmarks/marina.py``'s.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from cistern_archive.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.realdata]

KEYFRAMES = 12


@pytest.fixture(scope="module")
def marina_data(shared_data: Path) -> Path:
    root = shared_data / "marina"
    if not root.is_dir():
        pytest.skip(f"marina recordings not found at {root}")
    return root


def _cli(args: list[str]) -> int:
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    return exit_info.value.code


@pytest.fixture(scope="module")
def built(marina_data: Path, tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("marina-site")
    catalog, out = work / "catalog", work / "site"
    assert _cli(["survey", "marina", str(marina_data), "--catalog", str(catalog), "--keyframes", str(KEYFRAMES)]) == 0
    assert not list(catalog.rglob("*.pcd")), "the data must stay where it is"
    assert _cli(["validate", "--catalog", str(catalog)]) == 0
    assert _cli(["rebuild", "--catalog", str(catalog), "--out", str(out), "--archive", str(work / "archive"),
                 "--site", "girona-marina", "--workers", "1"]) == 0
    return out / "girona-marina"


def test_the_result_carries_the_key_frames_and_the_track_summary(built):
    result = json.loads((built / "result.json").read_text())
    assert result["status"] == "ok"
    assert len(result["scans"]) == KEYFRAMES and all(s["placed"] for s in result["scans"])
    assert result["scans"][0]["file"].startswith("survey/derived_tim_pcd/pclKeyFrame")
    assert result["pairs"] and not result["dimensions"]
    track = result["track"]
    assert track["revolutions"] == KEYFRAMES and track["revolutions_available"] > 200
    names = [t["name"] for t in track["tracks"]]
    assert names[0].startswith("dead reckoning") and names[-1].startswith("pipeline")
    for t in track["tracks"]:  # a dozen revolutions (~150 s, ~20 m): errors of metres, not tens of metres
        assert 0 < t["rigid"]["mean_m"] <= t["start_aligned"]["mean_m"] + 1e-9 < 5.0
    assert [r["mean_m"] for r in track["published"]] == [17.46, 3.99, 1.91, 1.90]
    assert "Autonomous Robots 36 (2014), Table 2" in track["published_source"]
    assert json.loads((built / "record.json").read_text())["pipeline"]["mapper"]["params"]["cell_m"] == 0.25


def test_the_page_has_the_track_section_its_figures_and_the_table(built):
    html = (built / "index.html").read_text()
    assert re.search(r'<h2 id="track">Track</h2>', html)
    for name in ("track.png", "track_error.png", "map.png"):
        assert f'src="{name}"' in html and (built / name).stat().st_size > 10_000
    table = html[html.index('id="track-table"'):]
    table = table[:table.index("</table>")]
    for text in ("dead reckoning, DVL compass as logged", "pipeline (guided-correlative + nav-graph)",
                 "published: pose-based scan-matching SLAM", "4.93", "Mallios", "Only part of the run was processed",
                 "Every fix of the span lies in the DGPS window"):  # a dozen revolutions, inside its 300 s
        assert text in table, text
