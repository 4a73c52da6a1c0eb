"""Reports: 3D models (pyvista off screen), figures (matplotlib) and static HTML (jinja2).

Public API
----------
render_site(build, site_dir, *, config=None) -> dict[str, str]
    One site's page, figures, 3D renders, mesh exports, arrays and CSV tables.
render_index(entries, out_dir, *, title=..., config=None) -> Path
    The catalog index with the cross-site table of dimension differences.
IndexEntry
    One row of the index, built with :meth:`IndexEntry.from_result`.
ReportConfig
    Rendering settings.

The names are imported on first use, so that importing ``cistern_archive.report.index`` (the catalog
index alone) does not load matplotlib, scipy and scikit-image.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cistern_archive.report.config import ReportConfig
    from cistern_archive.report.index import IndexEntry, render_index
    from cistern_archive.report.site import page_bytes, render_site

_MODULE_OF = {"ReportConfig": "config", "IndexEntry": "index", "render_index": "index",
              "page_bytes": "site", "render_site": "site"}

__all__ = ["IndexEntry", "ReportConfig", "page_bytes", "render_index", "render_site"]


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
