"""Helpers for the service tests: a small generated catalog and result comparison."""

from __future__ import annotations

import json
import shutil
import signal
import sys
from pathlib import Path

from cistern_archive.archive.digest import file_sha256

CLI = [sys.executable, "-m", "cistern_archive"]


def default_sigint() -> None:
    """``preexec_fn`` for a child that a test interrupts as a terminal's Ctrl-C would: SIGINT back to its
    default action. A test run started in the background by a shell without job control inherits SIGINT
    ignored, and a Python started so never raises KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
# Reports without the 3D model and the per-pair/per-scan figures render in a fraction of the time;
# the report has its own tests.
FAST_REPORT = {"model": False, "pdf": False, "max_pair_figures": 0, "max_fan_figures": 0, "dpi": 50}


def make_catalog(root: Path, n_sites: int = 2, *, seed: int = 7) -> Path:
    """A catalog of ``n_sites`` simulated two-station cisterns under ``root``."""
    from cistern_archive.simulation.synthetic import write_synthetic_catalog

    write_synthetic_catalog(root, n_sites, seed=seed, stations=2)
    return root


def copy_catalog(template: Path, target: Path) -> Path:
    shutil.copytree(template, target)
    return target


def _without_timings(value):
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items()
                if k not in ("timings_s", "seconds") and not k.endswith("_seconds")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def comparable_result(path: Path) -> dict:
    """``result.json`` without wall-clock timings (which differ between runs and machines)."""
    return _without_timings(json.loads(path.read_text(encoding="utf-8")))


def report_is_complete(site_dir: Path) -> bool:
    """Every file listed in ``build.json`` exists with the digest recorded there."""
    info = json.loads((site_dir / "build.json").read_text(encoding="utf-8"))
    return bool(info["files"]) and all(
        file_sha256(site_dir / name)[0] == digest for name, digest in info["files"].items())


def copy_built(template: tuple[Path, Path], target: Path) -> tuple[Path, Path]:
    """Copies of a catalog and of its published reports (build keys do not depend on their location)."""
    catalog, out = template
    return copy_catalog(catalog, target / "catalog"), Path(shutil.copytree(out, target / "site", symlinks=True))


def build_once(tmp_path_factory, *, workers: int = 1) -> tuple[Path, Path]:
    """A generated two-site catalog rebuilt once with :data:`FAST_REPORT` (both sites ``ok``): the
    ``(catalog, out)`` a module's tests copy with :func:`copy_built`."""
    from cistern_archive.service.rebuild import rebuild

    catalog = make_catalog(tmp_path_factory.mktemp("template") / "catalog")
    out = catalog.parent / "site"
    summary = rebuild(catalog, out, workers=workers, report_config=FAST_REPORT)
    assert [s.status for s in summary.sites] == ["ok", "ok"], summary.sites
    return catalog, out
