"""A normal (non-editable) install renders reports: the core's wheel and the built-in plugins' wheel,
installed alone in a fresh virtual environment, rebuild a bundled site from another folder."""

import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_wheel_rebuilds_a_bundled_site_from_another_folder(tmp_path):
    wheels = tmp_path / "wheels"
    for source in (ROOT, ROOT / "plugins" / "cistern-plugins"):
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", str(source), "-w", str(wheels)],
                       check=True, timeout=600)
    core = next(wheels.glob("cistern_archive-*.whl"))
    plugins = next(wheels.glob("cistern_plugins-*.whl"))
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", str(core), str(plugins)], check=True, timeout=1800)
    work = tmp_path / "elsewhere"
    work.mkdir()
    out, archive = work / "site", work / "archive"
    done = subprocess.run([str(env_dir / "bin" / "cistern-archive"), "rebuild", "--catalog", str(ROOT / "catalog"),
                           "--out", str(out), "--archive", str(archive), "--site", "lair-pool"],
                          cwd=work, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    page = (out / "lair-pool" / "index.html").read_text(encoding="utf-8")
    assert "LAIR swimming pool" in page or "lair-pool" in page
    assert (out / "index.html").is_file() and (out / "lair-pool" / "result.json").is_file()
    listed = subprocess.run([str(env_dir / "bin" / "cistern-archive"), "plugins", "--json"], cwd=work,
                            capture_output=True, text=True, timeout=120)
    assert "site-graph" in listed.stdout and "correlative" in listed.stdout
    assert not (ROOT / "catalog" / ".archive").exists()  # nothing written into the checkout
