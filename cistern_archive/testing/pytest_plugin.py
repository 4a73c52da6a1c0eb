"""pytest fixtures for plugin authors, registered through the ``pytest11`` entry point.

Fixtures
--------
simulated_pair
    One overlapping (≥ 50 %) :class:`~cistern_archive.simulation.pairs.SimulatedPair` with 3 cm range noise (seed 0).
simulated_pairs
    A factory ``simulated_pairs(n, seed=0, no_overlap_fraction=0.0)``.
isolated_registry
    A factory ``isolated_registry(matchers={"name": "module:Class"}, ...)`` returning a
    :class:`~cistern_archive.pipeline.registry.Registry` that sees only the given plugins (none of the
    installed ones), so a test cannot depend on what happens to be installed.
"""

from __future__ import annotations

import importlib.metadata as md
from collections.abc import Callable

import numpy as np
import pytest

from cistern_archive.pipeline.registry import GROUPS, Registry
from cistern_archive.simulation.pairs import SimulatedPair, pair_set, simulated_pair as _draw_pair


@pytest.fixture
def simulated_pair() -> SimulatedPair:
    return _draw_pair(np.random.default_rng(0), overlap_range=(0.5, 1.0), noise_m=0.03)


@pytest.fixture
def simulated_pairs() -> Callable[..., list[SimulatedPair]]:
    def make(n: int, seed: int = 0, no_overlap_fraction: float = 0.0) -> list[SimulatedPair]:
        return pair_set(n, seed, no_overlap_fraction=no_overlap_fraction)

    return make


@pytest.fixture
def isolated_registry() -> Callable[..., Registry]:
    def make(**stages: dict[str, str]) -> Registry:
        unknown = set(stages) - {f"{s}s" for s in GROUPS}
        if unknown:
            raise ValueError(f"unknown stages {sorted(unknown)}; use matchers=, localizers=, mappers=, comparators=")
        eps = {stage: [md.EntryPoint(name, value, group) for name, value in stages.get(f"{stage}s", {}).items()]
               for stage, group in GROUPS.items()}
        return Registry(entry_points=eps)

    return make
