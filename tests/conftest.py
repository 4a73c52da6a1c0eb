"""Shared fixtures: paths to the repository, the bundled catalog and the real recordings; one random
multi-chamber cistern built by the runner."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
BUNDLED_CATALOG = REPO / "catalog"

os.environ.setdefault("SOURCE_DATE_EPOCH", "1700000000")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (the real recordings); skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} (../shared/data beside the repository)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def bundled_catalog() -> Path:
    return BUNDLED_CATALOG


@pytest.fixture
def random_site_errors(tmp_path: Path) -> Callable[[int, str], np.ndarray]:
    """A function of ``(seed, site)`` that draws that site of the random multi-chamber cisterns
    (:func:`cistern_archive.simulation.chambers.random_cisterns`, ``site`` as ``cistern-NNN``), builds it
    with the runner and returns its placed scans' position errors after alignment
    (:func:`cistern_archive.evaluation.position_errors`)."""
    from cistern_archive.catalog.loader import load_record
    from cistern_archive.evaluation import position_errors
    from cistern_archive.pipeline.runner import build_site
    from cistern_archive.simulation.chambers import random_cisterns, simulate_into, write_specs

    def errors(seed: int, site: str) -> np.ndarray:
        drawn = [c for c in random_cisterns(int(site.split("-")[1]) + 1, seed) if c.spec.id == site]
        record_path = simulate_into(write_specs(drawn, tmp_path)[0], tmp_path)
        return position_errors(build_site(load_record(record_path, tmp_path)).result)

    return errors
