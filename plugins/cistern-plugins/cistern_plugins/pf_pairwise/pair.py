"""The two scans of a pair as echo points, for the steps that judge and refine an estimate by them."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from cistern_archive.core.scan import RangeScan
from cistern_plugins.registration import ReferenceModel, scan_points


class ScanPair:
    """The reference and moving scans; the reference's points, tree, normals and free space
    (:class:`~cistern_plugins.registration.ReferenceModel`) and the moving scan's echo points are built
    on first use, so a pair the filter rejects never pays for them."""

    def __init__(self, reference: RangeScan, moving: RangeScan):
        self.reference, self.moving = reference, moving

    @cached_property
    def model(self) -> ReferenceModel:
        """The reference scan's points with their k-d tree, normals and free space."""
        return ReferenceModel(self.reference)

    @cached_property
    def moving_points(self) -> np.ndarray:
        """The moving scan's echoes (N, 2), map-oriented, relative to its sonar."""
        return scan_points(self.moving)
