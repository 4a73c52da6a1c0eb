"""An example cistern-archive matcher plugin (brute-force grid search)."""

from cistern_example_matcher.matcher import GridSearchMatcher

__all__ = ["GridSearchMatcher"]
