"""benchmarks/wall_tests.py on one random site: the figures it reports are there and consistent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_one_site_reports_every_figure():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "wall_tests.py"), "--random", "1", "--seeds", "2",
                           "--workers", "1", "--json"], capture_output=True, text=True, timeout=600, check=True)
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    truth = figures["truth_pairs"]
    assert truth["n"] > 0 and 0.0 <= truth["max_run_m"] <= figures["limit_m"]
    assert truth["behind_quarter_25_points"] <= truth["behind_quarter"] <= truth["n"]
    assert figures["matches"]["right"] > 0 and figures["matches"]["right_max_run_m"] <= figures["limit_m"]
    assert figures["joins"]["right"] + figures["joins"]["wrong"] > 0
    settled = figures["settled"]
    assert settled["right"] > 0 and 0.0 <= settled["right_q999_share"] <= settled["right_max_share"]
    assert settled["right_over_limit"] == 0  # a right split over the limit: a right station cut off
