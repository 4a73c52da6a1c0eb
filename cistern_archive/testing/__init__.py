"""Tools for plugin authors: simulated scan pairs with known truth, scoring, and the matcher
conformance check.

>>> from cistern_archive.testing import check_matcher
>>> report = check_matcher(MyMatcher(), n_pairs=20, seed=0)   # doctest: +SKIP
>>> assert report.passed

Random multi-chamber cisterns for the physical sonar simulator, with truth poses, are in
:mod:`cistern_archive.simulation.chambers` (used by ``benchmarks/sites.py --random``).

The pytest plugin :mod:`cistern_archive.testing.pytest_plugin` (registered through ``pytest11``) gives
tests the ``simulated_pair``, ``simulated_pairs`` and ``isolated_registry`` fixtures.
"""

from cistern_archive.testing.conformance import Check, ConformanceReport, check_matcher
from cistern_archive.simulation.pairs import PairSpec, SimulatedPair, pair_set, simulated_pair
from cistern_archive.testing.scoring import PairScore, score

__all__ = [
    "Check",
    "ConformanceReport",
    "PairScore",
    "PairSpec",
    "SimulatedPair",
    "check_matcher",
    "pair_set",
    "score",
    "simulated_pair",
]
