"""Time one site's report (3D model + figures + HTML) and weigh its page.

Targets (issue 5): rendering ≤ 10 s on this machine; a site page with its images ≤ 5 MB.

By default the site is built with the real pipeline from the bundled catalog (``--site``, default
``lair-pool``; the pipeline's own time is not counted); ``--synthetic`` renders the synthetic pool of
``tests/report_fixtures.py`` instead. The first render of a process pays the imports of pyvista/VTK
and matplotlib and is reported apart (``cold_s``) from the following ones (``warm_s``).

Usage::

    .venv/bin/python benchmarks/report.py [--site ID] [--synthetic] [--repeat N] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def synthetic_build():
    sys.path.insert(0, str(REPO / "tests"))
    from report_fixtures import make_site_build

    return make_site_build()


def catalog_build(site_id: str, catalog: Path):
    from cistern_archive.catalog.loader import load_record, record_paths
    from cistern_archive.pipeline.runner import build_site

    for path in record_paths(catalog):
        loaded = load_record(path, catalog)
        if loaded.record.id == site_id:
            build = build_site(loaded)
            if build.result.status == "failed":
                raise SystemExit(f"{site_id}: the pipeline failed: {build.result.error}")
            return build
    raise SystemExit(f"no site {site_id!r} in {catalog}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--site", default="lair-pool", help="catalog site id (default lair-pool)")
    parser.add_argument("--catalog", type=Path, default=REPO / "catalog")
    parser.add_argument("--synthetic", action="store_true", help="render the synthetic pool of the tests")
    parser.add_argument("--repeat", type=int, default=3, help="renders (the first is the cold one)")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)

    started = time.perf_counter()
    build = synthetic_build() if args.synthetic else catalog_build(args.site, args.catalog)
    pipeline_s = time.perf_counter() - started

    from cistern_archive.report import ReportConfig, page_bytes, render_site

    config = ReportConfig()
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(max(1, args.repeat)):
            site_dir = Path(tmp) / f"render-{k}"
            site_dir.mkdir()
            t0 = time.perf_counter()
            artifacts = render_site(build, site_dir, config=config)
            times.append(time.perf_counter() - t0)
        page = page_bytes(site_dir / "index.html")
        folder = sum(p.stat().st_size for p in site_dir.iterdir())
        files = len(list(site_dir.iterdir()))
    warm = times[1:] or times
    summary = {
        "site": "synthetic-pool" if args.synthetic else args.site,
        "scans": len(build.result.scans),
        "pairs": len(build.matches),
        "slices": 0 if build.map_result is None else len(build.map_result.grids),
        "pipeline_s": round(pipeline_s, 3),
        "cold_s": round(times[0], 3),
        "warm_s": round(statistics.median(warm), 3),
        "renders": len(times),
        "page_bytes": page,
        "folder_bytes": folder,
        "files": files,
        "artifacts": len(artifacts),
        "target_s": 10.0,
        "target_page_bytes": config.max_page_bytes,
        "meets_targets": times[0] <= 10.0 and page <= config.max_page_bytes,
    }
    if not args.json:
        print(f"site {summary['site']}: {summary['scans']} scans, {summary['pairs']} pairs, "
              f"{summary['slices']} slice(s)")
        print(f"render: cold {summary['cold_s']:.2f} s, warm {summary['warm_s']:.2f} s (target 10 s)")
        print(f"page with images: {page / 1e6:.2f} MB (target 5 MB); folder {folder / 1e6:.2f} MB in {files} files")
    print(json.dumps(summary, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
