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
"""

from cistern_archive.report.config import ReportConfig
from cistern_archive.report.index import IndexEntry, render_index
from cistern_archive.report.site import page_bytes, render_site

__all__ = ["IndexEntry", "ReportConfig", "page_bytes", "render_index", "render_site"]
