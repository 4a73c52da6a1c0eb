"""Parameters of ``pf-pairwise``: one section per step of the matcher, and the paper's configuration.

A record sets them section by section::

    matcher:
      plugin: pf-pairwise
      params:
        filter: {n_particles: 300, measurement_model: raycast}
        verify: {unique: true, fit: {min_inlier_ratio: 0.3}}
        refine: {method: none}

Every section refuses unknown keys; a key of the former flat layout (``n_particles``, ``verify_fit``,
...) is refused with the section it moved to (:data:`MOVED`).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from cistern_plugins.registration import ConvergenceParams, SonarScaled


class Section(BaseModel):
    """A section of :class:`PFParams`: unknown keys refused, values frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class FilterParams(Section):
    """The particle filter of Tables I–II and its measurement model (eqs. 3–6)."""

    n_particles: int = Field(500, ge=10, le=100_000, description="Num_Particles")
    n_iterations: int = Field(60, ge=1, le=10_000, description="Num_Iterations")
    l_init_m: float = Field(8.0, gt=0, description="side of the uniform initial square L_init (m)")
    theta_init_std_deg: float = Field(2.0, ge=0, description="std of the initial heading correction (deg)")
    sigma_n_xy_m: float = Field(0.02, ge=0, description="propagation noise sigma_n of x and y (m)")
    sigma_n_theta_deg: float = Field(0.5, ge=0, description="propagation noise sigma_n of theta (deg)")
    delta_max_m: float = Field(0.3, gt=0, description="delta_max of eq. 4 (m)")
    chi_w: float = Field(2.0 / 7.0, gt=0, le=1, description="smoothing of the weight average (eq. 6)")
    chi_sigma: float = Field(2.0 / 5.0, gt=0, le=1, description="smoothing of the std average (eq. 5)")
    tau_pw: float = Field(0.25, ge=-1, le=1, description="weight threshold of eq. 6 (mean per-beam units)")
    measurement_model: Literal["raycast", "distance-field"] = Field(
        "distance-field", description="delta_m by ray casting, or the likelihood field (end-point distance)"
    )
    unknown_score: float = Field(
        0.0, ge=-1, le=1, description="contribution of a beam whose end lies where m_i has no evidence (paper: -1)"
    )
    min_informative: float = Field(
        1.0, gt=0, le=1, description="weight = sum over beams / max(informative beams, this share of beams)"
    )
    resample_weighting: Literal["shifted", "exponential"] = Field(
        "exponential", description="resampling in proportion to w - min w (paper), or to exp(sharpness w)"
    )
    sharpness: float = Field(40.0, gt=0, description="exponent scale of 'exponential' resampling")
    init_oversample: int = Field(4, ge=1, le=100, description="uniform samples weighed at start, per particle")
    max_beams: int = Field(200, ge=1, description="beams of the moving scan used (evenly subsampled)")
    min_beams: int = Field(10, ge=1, description="fewer echoes than this: not converged")
    restarts: int = Field(
        0, ge=0, le=10, description="filters restarted at the best-scoring grid positions when the first fails"
    )


class MapParams(Section):
    """The evidence grid ``m_i`` of the reference scan (Table I, line 2)."""

    cell_m: float = Field(0.05, gt=0, description="map cell size r_c (m); sigma_c = 2 r_c; eq. 5's std threshold")
    weight_threshold: float = Field(0.6, gt=0, lt=1, description="WEIGHT_THRESHOLD: occupied probability")
    l_occ: float = Field(0.85, gt=0, description="log-odds of an echo cell in m_i")
    l_free: float = Field(-0.4, lt=0, description="log-odds of a free cell in m_i")
    occupied: Literal["cone", "step", "axis"] = Field(
        "step", description="part of the beam cone marked occupied in m_i: all, one beam step, the axis"
    )
    free: Literal["cone", "step", "axis"] = Field(
        "cone", description="part of the beam cone marked free in m_i in front of the echo"
    )


class FitCheckParams(ConvergenceParams):
    """The point matchers' shared fit verdict as a check of a verified estimate (``min_points`` is not
    used: ``filter.min_beams`` refuses scans with too few echoes)."""

    enabled: bool = Field(True, description="reject estimates that fail the point matchers' shared fit verdict")
    calibrated: bool = Field(False, description="use the fixed limits below, not the calibrated model")
    min_inlier_ratio: float = Field(0.25, ge=0, le=1, description="least inlier share, both ways")
    min_constraint: float = Field(0.0, ge=0, description="off (the ambiguity search does this)")
    max_weak_std_m: float = Field(1.0, gt=0, description="off (the ambiguity search does this)")
    max_violation_ratio: float = Field(1.0, ge=0, le=1, description="share of wall points in free space")
    partial_inlier_ratio: float = Field(
        0.5, ge=0, le=1, description="below this inlier share, partial_max_violation applies"
    )
    partial_max_violation: float = Field(
        0.2, ge=0, le=1, description="largest free-space violation ratio of a partial-overlap fit"
    )


class VerifyParams(Section):
    """The checks a converged estimate must pass: uniqueness in ``m_i`` and the fit of the echoes."""

    unique: bool = Field(True, description="reject converged estimates that are ambiguous or on the search edge")
    step_m: float = Field(0.15, gt=0, description="grid step of the ambiguity search (m)")
    ambiguity_radius_m: float = Field(0.5, gt=0, description="alternatives farther than this count as other modes")
    ambiguity_ratio: float = Field(0.85, gt=0, le=1, description="an alternative scoring this share of the best is a rival")
    max_crossing: float = Field(0.1, ge=0, le=1, description="largest share of beams that may cross a wall of m_i")
    beams: int = Field(100, ge=10, description="beams used by the ambiguity search (evenly subsampled)")
    fit: FitCheckParams = Field(default_factory=FitCheckParams, description="the fit check of the refined estimate")


class RefineParams(Section):
    """The point-to-line refinement of a verified estimate."""

    method: Literal["none", "point-to-line"] = Field(
        "point-to-line", description="refine a verified estimate by point-to-line ICP of the two scans' echoes"
    )
    iterations: int = Field(30, ge=1, description="most ICP iterations of the refinement")
    correspondence_m: float = Field(0.3, gt=0, description="farthest paired echoes (m)")
    trim_fraction: float = Field(0.8, gt=0, le=1, description="share of closest pairs kept")
    max_shift_m: float = Field(0.2, gt=0, description="a refinement moving the estimate farther than this is discarded (m)")


class HistoryParams(Section):
    """What the match keeps for the report's convergence and particle figures."""

    snapshots: int = Field(4, ge=0, le=50, description="particle snapshots kept for the report")
    particles: int = Field(200, ge=1, description="particles kept per snapshot")


MOVED = {
    **{key: f"filter.{key}" for key in FilterParams.model_fields},
    "cell_m": "map.cell_m", "weight_threshold": "map.weight_threshold", "map_l_occ": "map.l_occ",
    "map_l_free": "map.l_free", "map_occupied": "map.occupied", "map_free": "map.free",
    "verify": "verify.unique", "verify_step_m": "verify.step_m", "verify_beams": "verify.beams",
    **{key: f"verify.{key}" for key in ("ambiguity_radius_m", "ambiguity_ratio", "max_crossing")},
    "verify_fit": "verify.fit.enabled",
    **{key: f"verify.fit.{key}" for key in FitCheckParams.model_fields if key != "enabled"},
    "refine": "refine.method", "refine_iterations": "refine.iterations",
    "refine_correspondence_m": "refine.correspondence_m", "refine_trim_fraction": "refine.trim_fraction",
    "refine_max_shift_m": "refine.max_shift_m",
    "history_snapshots": "history.snapshots", "snapshot_particles": "history.particles",
}
"""Where each key of the former flat ``PFParams`` lives now (``section.field``)."""


class PFParams(SonarScaled):
    """Parameters of :class:`~cistern_plugins.pf_pairwise.PFPairwiseMatcher` (Tables I–II and Sec. IV
    of the paper), one section per step: ``filter``, ``map``, ``verify``, ``refine``, ``history``."""

    filter: FilterParams = Field(default_factory=FilterParams)
    map: MapParams = Field(default_factory=MapParams)
    verify: VerifyParams = Field(default_factory=VerifyParams)
    refine: RefineParams = Field(default_factory=RefineParams)
    history: HistoryParams = Field(default_factory=HistoryParams)

    @model_validator(mode="before")
    @classmethod
    def _no_flat_keys(cls, data: Any) -> Any:
        """Refuse a key of the former flat layout with the section it moved to."""
        if isinstance(data, dict):
            moved = [f"{key} (now {MOVED[key]})" for key, value in data.items()
                     if key in MOVED and (key not in cls.model_fields or not isinstance(value, dict | BaseModel))]
            if moved:
                raise ValueError("pf-pairwise parameters are grouped in sections (filter, map, verify, refine, "
                                 "history); move " + ", ".join(moved))
        return data

    @classmethod
    def paper(cls, **changes: Any) -> "PFParams":
        """McVicker et al.'s filter exactly as written (:data:`PAPER_CONFIGURATION`), with ``changes``
        laid over it section by section (``PFParams.paper(filter={"n_particles": 200})``)."""
        return cls.model_validate(_merged(PAPER_CONFIGURATION, changes))


def _merged(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in changes.items():
        out[key] = _merged(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


PAPER_CONFIGURATION: dict[str, dict[str, Any]] = {
    "filter": {
        "measurement_model": "raycast",
        "resample_weighting": "shifted",
        "init_oversample": 1,
        "unknown_score": -1.0,
        "min_informative": 1.0,
        "restarts": 0,
        "max_beams": 100_000,
        "chi_w": 2.0 / 7.0,
        "chi_sigma": 2.0 / 5.0,
    },
    "map": {"occupied": "cone", "free": "cone", "cell_m": 0.05},
    "verify": {"unique": False, "fit": {"enabled": False}},
    "refine": {"method": "none"},
}
"""The paper's method (Tables I–II, eqs. 3–6): ray casting, proportional resampling, a uniform start,
every disagreeing beam penalised, cone walls, every beam, no verification and no refinement. ``tau_pw``
stays in this plugin's per-beam units (the paper's 6.0 was a sum over its beams)."""
