"""A third-party matcher package (plugins/example-matcher) is found through its entry point and runs.

Each test runs a fresh interpreter whose path holds only the installed copy of the example, so the
registry sees it exactly as it would see any package installed from an index.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "plugins" / "example-matcher"

PROBE = """
import json, numpy as np
from cistern_archive.pipeline.registry import Registry
from cistern_archive.testing import simulated_pair
reg = Registry()
plugin = reg.load("matcher", "example-grid")
pair = simulated_pair(np.random.default_rng(3), overlap_range=(0.6, 1.0), noise_m=0.02)
res = plugin.instance.match(pair.reference, pair.moving, plugin.instance.Params(), rng=np.random.default_rng(0))
print(json.dumps({"names": reg.names("matcher"), "distribution": plugin.info.distribution,
                  "converged": bool(res.converged), "error_m": float(np.hypot(res.dx_m - pair.dx_m, res.dy_m - pair.dy_m))}))
"""


def _probe(site: Path) -> dict:
    env_path = [str(site)] + [p for p in sys.path if p]
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": ":".join(env_path), "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _check(found: dict) -> None:
    assert "example-grid" in found["names"]
    assert found["distribution"] == "cistern-example-matcher"
    assert found["converged"]
    assert found["error_m"] < 0.1


def test_entry_point_in_a_site_directory(tmp_path):
    """The package and a hand-written ``.dist-info`` (what an installer writes) in a temporary directory."""
    site = tmp_path / "site"
    shutil.copytree(EXAMPLE / "cistern_example_matcher", site / "cistern_example_matcher")
    info = site / "cistern_example_matcher-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: cistern-example-matcher\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text(
        "[cistern_archive.matchers]\nexample-grid = cistern_example_matcher.matcher:GridSearchMatcher\n")
    _check(_probe(site))


@pytest.mark.slow
def test_pip_install_target(tmp_path):
    """Build and install the example with pip into a temporary target directory."""
    src = tmp_path / "src"
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    site = tmp_path / "site"
    out = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(src)],
                         capture_output=True, text=True, timeout=300)
    if out.returncode != 0:
        pytest.fail(f"pip could not build the example plugin: {out.stderr[-2000:]}")
    _check(_probe(site))
