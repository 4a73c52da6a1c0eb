"""A moving survey's tracks against ground truth: what the report draws and ``result.json`` summarises.

The errors are the horizontal distances between an estimated track and each DGPS fix, as in Mallios
et al., Autonomous Robots 36 (2014), Table 2: *start-aligned* (the estimate translated onto the fix
where it starts) and *rigid* (after the best 2-D rotation and translation onto the evaluated fixes),
summarised over the fixes after the calibration window. The navigation layer computes them
(:mod:`cistern_archive.navigation.accuracy`); this module only holds them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ErrorSummary:
    """Mean, standard deviation and maximum of position errors (m) over ``fixes`` fixes."""

    mean_m: float
    sd_m: float
    max_m: float
    fixes: int

    @classmethod
    def of(cls, errors: np.ndarray) -> "ErrorSummary":
        errors = np.asarray(errors, dtype=float)
        if errors.size == 0:
            raise ValueError("no fixes to summarise")
        return cls(float(errors.mean()), float(errors.std()), float(errors.max()), int(errors.size))

    def as_dict(self) -> dict[str, float | int]:
        return {"mean_m": round(self.mean_m, 3), "sd_m": round(self.sd_m, 3), "max_m": round(self.max_m, 3),
                "fixes": self.fixes}


@dataclass(frozen=True)
class PublishedRow:
    """One row of a published comparison table: a method and its error mean / SD / max (m)."""

    method: str
    mean_m: float
    sd_m: float
    max_m: float


@dataclass(frozen=True, eq=False)
class EstimatedTrack:
    """One estimate of the vehicle's track at the fix times.

    Attributes
    ----------
    name : str
        What made it (``dead reckoning, as logged``, ``pipeline``…).
    xy_m : ndarray, shape (N, 2)
        East/north positions at the fix times, in the estimate's own frame (not aligned).
    start_aligned_errors_m, rigid_errors_m : ndarray, shape (N,)
        Distance to each fix after the start alignment and after the rigid alignment.
    evaluated : ndarray of bool, shape (N,), or None
        The fixes the summaries count (those after the calibration window); ``None``: all of them.
    """

    name: str
    xy_m: np.ndarray
    start_aligned_errors_m: np.ndarray
    rigid_errors_m: np.ndarray
    evaluated: np.ndarray | None = None

    @property
    def start_aligned(self) -> ErrorSummary:
        return ErrorSummary.of(self._evaluated(self.start_aligned_errors_m))

    @property
    def rigid(self) -> ErrorSummary:
        return ErrorSummary.of(self._evaluated(self.rigid_errors_m))

    def _evaluated(self, errors: np.ndarray) -> np.ndarray:
        return errors if self.evaluated is None else errors[self.evaluated]

    def start_aligned_xy(self, fixes_xy: np.ndarray) -> np.ndarray:
        """The track translated so that it starts on the first fix (as the start-aligned error sees it)."""
        return self.xy_m + (fixes_xy[0] - self.xy_m[0])


@dataclass(frozen=True, eq=False)
class TrackComparison:
    """Estimated tracks of a moving survey against its DGPS fixes, with a published table beside them.

    Attributes
    ----------
    time_s : ndarray, shape (N,)
        Times of the fixes of the span (navigation clock, Unix s); the tracks keep their errors at each.
    fixes_xy_m : ndarray, shape (N, 2)
        The DGPS fixes (east, north, m).
    tracks : tuple of EstimatedTrack
        Every estimate evaluated at those fixes.
    published : tuple of PublishedRow
        The published results on the same run, and ``published_source`` the citation.
    calibration_end_s : float or None
        End of the DGPS window the dead reckoning was calibrated on (those fixes are not independent
        of the estimate), ``None`` without one.
    revolutions, revolutions_available : int
        Sonar revolutions used, and how many the dataset holds (fewer used: a shorter span is evaluated).
    clock_offset_s : float
        Sonar-to-navigation clock offset the survey estimated.
    """

    time_s: np.ndarray
    fixes_xy_m: np.ndarray
    tracks: tuple[EstimatedTrack, ...]
    published: tuple[PublishedRow, ...] = ()
    published_source: str = ""
    calibration_end_s: float | None = None
    revolutions: int = 0
    revolutions_available: int = 0
    clock_offset_s: float = 0.0

    @property
    def span_s(self) -> float:
        """Seconds between the first and the last fix of the span."""
        return float(self.time_s[-1] - self.time_s[0]) if len(self.time_s) else 0.0

    @property
    def partial(self) -> bool:
        """Whether only part of the run was processed (its errors are not comparable to a whole run's)."""
        return self.revolutions < self.revolutions_available
