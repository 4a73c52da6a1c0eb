"""A search peak the refinement does not confirm: sites of the random multi-chamber cisterns where the
group fit's coarse search ranked a wrong place first, each pinned where it was found.

* Seed 128, ``cistern-018`` (three chambers, six stations): the last chamber's lone station was fitted to
  the others' group at a coarse peak of 81 that, on the sharper fields, laid 43 cells of wall in water
  and scored −7.3, 6.3 m from its true place; the search's next peak, the true place (0.04–0.09 m off),
  scored 68 coarse and 50 refined, and no other peak more than 20. The station stayed unplaced.
"""

from __future__ import annotations


def test_the_peak_that_holds_once_refined_is_the_fit(random_site_errors):
    errors = random_site_errors(128, "cistern-018")
    assert len(errors) == 6, f"{len(errors)} of 6 scans placed"  # was 5
    assert errors.max() <= 0.25, f"a scan placed {errors.max():.2f} m off"
