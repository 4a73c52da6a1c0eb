"""The Girona marina as a catalog site: its record, written from the dataset folder.

:func:`write_marina_record` writes ``CATALOG/sites/<id>.yaml``, a survey record (``survey.kind:
marina``) whose data stays where it is (the record names the folder); ``cistern-archive rebuild``
builds it like a cistern (:mod:`cistern_archive.navigation.site`). The record names every stage:
the survey's matcher and localizer (:class:`~cistern_archive.navigation.pipeline.SurveyConfig`'s
defaults) and the installed mapper at a cell size for a 50 m-range sonar, without the correction for
leaning walls (:mod:`cistern_archive.grid.lobe`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from cistern_archive.catalog.loader import load_record
from cistern_archive.catalog.models import PipelineSpec, SiteRecord
from cistern_archive.core.errors import CatalogError, ReaderError
from cistern_archive.core.files import write_text_atomic
from cistern_archive.navigation.pipeline import SurveyConfig
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.sonar.marina import dataset_problems

PUBLISHED_SOURCE = ("Mallios, Ridao, Ribas, Hernández, \"Scan matching SLAM in underwater environments\", "
                    "Autonomous Robots 36 (2014), Table 2")
PUBLISHED_TABLE2 = {"dead reckoning": (17.46, 11.47, 45.42), "MSISpIC": (3.99, 2.11, 8.49),
                    "EKF SLAM, line features": (1.91, 1.32, 5.08), "pose-based scan-matching SLAM": (1.90, 1.09, 4.93)}
"""Absolute position error against DGPS on this run (m): method → mean, SD, max."""

MAP_CELL_M = 0.25
"""Evidence-grid cell for the Miniking's 50 m range and 0.1 m bins: a 300 m × 200 m marina in about a
million cells; the DGPS (good to about 1 m) and the ~1-2 m track errors make finer cells meaningless."""

SITE_ID = "girona-marina"


def record_data_path(data: Path, catalog: Path) -> str:
    """The data folder as the record names it: relative to the catalog root when inside it, else absolute."""
    data, catalog = data.resolve(), catalog.resolve()
    return data.relative_to(catalog).as_posix() if data.is_relative_to(catalog) else str(data)


def marina_record(data: Path, catalog: Path, *, keyframes: int | None = None, site_id: str = SITE_ID,
                  registry: Registry | None = None) -> dict[str, Any]:
    """The site record of the marina dataset at ``data`` (a plain mapping, validated as a :class:`SiteRecord`)."""
    registry = registry or default_registry()
    survey = SurveyConfig()
    mapper = registry.choice(PipelineSpec(), "mapper").plugin
    record = {
        "schema_version": 1,
        "id": site_id,
        "name": "Girona abandoned marina (moving AUV)",
        "description": "The Ictineu AUV's survey of an abandoned marina at St. Pere Pescador, 25 August 2004: "
                       "a Tritech Miniking scanning sonar on a moving vehicle, with DVL, Xsens MTi and a DGPS "
                       "buoy as ground truth (dataset of Ribas, Ridao, Tardós, Neira, J. Field Robotics 25, 2008).",
        "expedition": {"name": "Ictineu AUV, abandoned marina", "date": "2004-08-25",
                       "team": ["D. Ribas", "P. Ridao", "J. D. Tardós", "J. Neira"]},
        "location": {"place": "St. Pere Pescador, Girona, Spain", "redact": False},
        "sonar": {"model": "Tritech Miniking", "frequency_khz": 675.0, "range_m": 50.0, "bins": 500,
                  "step_deg": 1.8, "beam_width_deg": 3.0, "vertical_beam_width_deg": 40.0},
        "survey": {
            "kind": "marina",
            "data": record_data_path(data, catalog),
            "settings": {} if keyframes is None else {"max_keyframes": keyframes},
            "published": {"source": PUBLISHED_SOURCE,
                          "rows": [{"method": m, "mean_m": a, "sd_m": b, "max_m": c}
                                   for m, (a, b, c) in PUBLISHED_TABLE2.items()]},
        },
        "pipeline": {
            "matcher": {"plugin": survey.matcher, "params": survey.matcher_params},
            "localizer": {"plugin": survey.localizer, "params": survey.localizer_params},
            # The vehicle's changes of depth are not levels of one room whose walls lean between them.
            "mapper": {"plugin": mapper, "params": {"cell_m": MAP_CELL_M, "lobe_correction": False}},
        },
        "seed": survey.seed,
    }
    SiteRecord.model_validate(record)
    return record


def write_marina_record(data: Path, catalog: Path, *, keyframes: int | None = None, site_id: str = SITE_ID,
                        overwrite: bool = False) -> Path:
    """Write ``catalog/sites/<site_id>.yaml`` for the marina dataset at ``data`` (atomically).

    Raises
    ------
    ReaderError
        ``data`` is not a complete marina dataset (naming what is missing).
    CatalogError
        The record exists and ``overwrite`` is false, or the written record does not load.
    """
    problems = dataset_problems(data)
    if problems:
        raise ReaderError(str(data), "not a marina dataset: " + "; ".join(problems))
    path = catalog / "sites" / f"{site_id}.yaml"
    if path.exists() and not overwrite:
        raise CatalogError([f"{path}:1: (record): already exists; pass --force to replace it"])
    record = marina_record(data, catalog, keyframes=keyframes, site_id=site_id)
    header = ("# A moving-vehicle survey (cistern-archive survey marina). The data stays in survey.data;\n"
              "# `cistern-archive rebuild --site " + site_id + "` builds it.\n")
    text = header + yaml.safe_dump(record, sort_keys=False, allow_unicode=True, width=110)
    os.makedirs(path.parent, exist_ok=True)
    write_text_atomic(path, text, validate=lambda staged: load_record(staged, catalog))
    return path
