"""A chamber is not laid on its twin beyond a short tunnel: silence facing a wall contradicts a pose.

Seed 98 of the random multi-chamber cisterns draws, as its ``cistern-015``, two chambers of nearly one
shape (7.4 × 5.2 m and 7.3 × 5.0 m) joined by a tunnel 1.09 m wide and about a metre long. The station
in the first chamber hears its chamber's whole wall and, through the tunnel, nothing; laid 8.7 m off
onto the second chamber every one of its echoes fits that chamber's walls, so its matches converged
with a confidence of 0.99–1.00 and the site was reported ``ok`` with a scan 7.5 m off. There its silent
beams face the second chamber's solid wall 3.6 m away (:meth:`cistern_plugins.alignment.FreeSpace.unheard_facing`).
"""

from __future__ import annotations

from pathlib import Path

from cistern_archive.catalog.loader import load_record
from cistern_archive.evaluation import position_errors
from cistern_archive.pipeline.runner import build_site
from cistern_archive.simulation.chambers import random_cisterns, simulate_into, write_specs

WRONG_SCAN_M = 0.25


def test_a_chamber_is_not_laid_on_its_look_alike_twin(tmp_path: Path):
    twins = [c for c in random_cisterns(16, 98) if c.spec.id == "cistern-015"]
    record_path = simulate_into(write_specs(twins, tmp_path)[0], tmp_path)
    build = build_site(load_record(record_path, tmp_path))
    errors = position_errors(build.result)
    assert len(errors) >= 7, "the second chamber's scans are placed"
    assert errors.max() <= WRONG_SCAN_M, f"a scan placed {errors.max():.2f} m off"
