"""Sonar scans: the scan model, the interchange format, readers, segmentation and the simulator."""

from cistern_archive.core.scan import RangeScan, Scan

__all__ = ["RangeScan", "Scan"]
