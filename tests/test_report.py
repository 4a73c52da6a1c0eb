"""Reports: volume stacking, mesh exports, deterministic files, and the site and index pages."""

from __future__ import annotations

import hashlib
import json
import math
import re
import shutil
import struct
import zlib
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from cistern_archive.grid.surface import SurfaceParams, wall_surface
from cistern_archive.pipeline.contracts import EvidenceGrid, MapResult, Poses
from cistern_archive.report import ReportConfig, page_bytes, render_site
from cistern_archive.pipeline.export import npz_bytes, read_npz
from cistern_archive.pipeline.runner import write_site_result
from cistern_archive.report.files import build_time_from_env, slug, unique_slugs
from cistern_archive.report.gltf import glb_bytes, read_glb
from cistern_archive.report.html import signed
from report_fixtures import LATITUDE, LENGTH_M, LONGITUDE, SITES, WIDTH_M, make_site_build, render_catalog

@pytest.fixture(scope="module")
def catalog(tmp_path_factory) -> tuple[Path, dict[str, dict[str, str]]]:
    root = tmp_path_factory.mktemp("report")
    return root, render_catalog(root)


# ------------------------------------------------------------------------------------------ surface
def _box_grid(half: float, depth: float, cell: float = 0.05, *, open_side: bool = False) -> EvidenceGrid:
    """A square room: free inside (−2), walls (+4), unknown outside; ``open_side`` leaves the east wall
    unseen (the free water just ends in unknown space)."""
    n = int(round(2 * (half + 0.5) / cell))
    centres = -(half + 0.5) + (np.arange(n) + 0.5) * cell
    gx, gy = np.meshgrid(centres, centres)
    inside = half - np.maximum(np.abs(gx), np.abs(gy))
    log_odds = np.zeros((n, n), dtype=np.float32)
    log_odds[inside > cell] = -2.0
    log_odds[np.abs(inside) <= cell / 2 + 1e-9] = 4.0
    if open_side:
        log_odds[(gx > half - cell) & (log_odds > 0)] = 0.0
    return EvidenceGrid(log_odds, (-(half + 0.5), -(half + 0.5)), cell, depth)


def _poses(n: int = 1) -> Poses:
    return Poses(np.zeros((n, 2)), np.zeros(n), np.ones(n, dtype=bool), ("",) * n, 0)


def test_surface_follows_the_walls_of_one_slice_extruded():
    mesh = wall_surface(MapResult((_box_grid(1.0, depth=0.6),)), _poses(), [0.6])
    x0, x1, y0, y1 = mesh.points[:, 0].min(), mesh.points[:, 0].max(), mesh.points[:, 1].min(), mesh.points[:, 1].max()
    assert_allclose([x0, x1, y0, y1], [-1.0, 1.0, -1.0, 1.0], atol=0.06)  # the walls' inner faces
    assert mesh.depth_range_m == (0.0, 1.6)  # 1 m above (not past the surface) and below
    assert mesh.n_triangles <= SurfaceParams().max_faces


def test_ghost_echoes_outside_the_walls_leave_no_posts():
    grid = _box_grid(1.0, depth=1.0)
    log_odds = grid.log_odds.copy()
    log_odds[2:4, 2:4] = 4.0  # an isolated echo in unknown space beyond the wall
    log_odds[20:22, 20:22] = 4.0  # and one in the water (a fish, the tether)
    ghosts = EvidenceGrid(log_odds, grid.origin_xy_m, grid.cell_m, grid.depth_m)
    clean = wall_surface(MapResult((grid,)), _poses(), [1.0])
    spooked = wall_surface(MapResult((ghosts,)), _poses(), [1.0])
    assert_allclose(spooked.points.min(axis=0), clean.points.min(axis=0), atol=1e-6)
    assert spooked.n_triangles == clean.n_triangles


def test_an_unseen_wall_is_left_open_not_invented():
    mesh = wall_surface(MapResult((_box_grid(1.0, depth=1.0, open_side=True),)), _poses(), [1.0])
    centroids = mesh.points[mesh.triangles].mean(axis=1)
    east = (centroids[:, 0] > 0.8) & (np.abs(centroids[:, 1]) < 0.6)
    assert not east.any()  # the middle of the unseen wall is farther than max_gap_m / 2 from any seen wall
    assert (centroids[:, 0] < -0.8).any()  # the seen west wall is there


def test_a_gap_in_one_slice_between_walls_seen_above_and_below_is_closed():
    depths = [1.0, 2.0, 3.0]
    gap_in_middle = (_box_grid(1.0, depth=1.0), _box_grid(1.0, depth=2.0, open_side=True), _box_grid(1.0, depth=3.0))
    gap_everywhere = tuple(_box_grid(1.0, depth=d, open_side=True) for d in depths)

    def east_wall(grids):
        mesh = wall_surface(MapResult(grids), _poses(3), depths)
        centroids = mesh.points[mesh.triangles].mean(axis=1)
        return ((centroids[:, 0] > 0.8) & (np.abs(centroids[:, 1]) < 0.6) & (np.abs(-centroids[:, 2] - 2.0) < 0.3)).any()

    assert east_wall(gap_in_middle)  # seen above and below: no hole that reads as a passage
    assert not east_wall(gap_everywhere)  # seen at no depth: left open


def test_walls_curve_through_several_slices_like_a_bell():
    grids = (_box_grid(1.0, depth=1.0), _box_grid(2.0, depth=2.0), _box_grid(2.5, depth=3.0))
    mesh = wall_surface(MapResult(grids), _poses(3), [1.0, 2.0, 3.0])
    assert mesh.depth_range_m == (1.0, 3.0)  # nothing was seen above or below the slices
    for depth, half in ((1.0, 1.0), (2.0, 2.0), (3.0, 2.5)):
        ring = mesh.points[np.abs(-mesh.points[:, 2] - depth) < 0.05]
        assert abs(ring[:, 0].max() - half) < 0.1, depth
    between = mesh.points[np.abs(-mesh.points[:, 2] - 1.5) < 0.05]
    assert 1.0 < between[:, 0].max() < 2.0  # the wall moves smoothly from one outline to the next


# ------------------------------------------------------------------------------------------ files
def test_glb_round_trip_and_axes():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 2, -1]], dtype=float)
    data = glb_bytes(points, np.array([[0, 1, 2]]), colors=np.array([[255, 0, 0]] * 3, dtype=np.uint8))
    assert data == glb_bytes(points, np.array([[0, 1, 2]]), colors=np.array([[255, 0, 0]] * 3, dtype=np.uint8))
    document, blob = read_glb(data)
    assert document["asset"]["version"] == "2.0"
    position = document["accessors"][document["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert position["count"] == 3
    view = document["bufferViews"][position["bufferView"]]
    xyz = np.frombuffer(blob, dtype=np.float32, count=9, offset=view["byteOffset"]).reshape(3, 3)
    assert_allclose(xyz[2], [0, -1, -2])  # (x, z up, -y)
    assert position["min"] == [0.0, -1.0, -2.0] and position["max"] == [1.0, 0.0, 0.0]
    assert len(data) % 4 == 0


def test_npz_is_reproducible_and_loadable(tmp_path):
    arrays = {"b": np.arange(5.0), "a": np.eye(2, dtype=np.float32)}
    (tmp_path / "one.npz").write_bytes(npz_bytes(arrays))
    (tmp_path / "two.npz").write_bytes(npz_bytes(dict(reversed(arrays.items()))))
    assert (tmp_path / "one.npz").read_bytes() == (tmp_path / "two.npz").read_bytes()
    with np.load(tmp_path / "one.npz") as loaded:
        assert_allclose(loaded["b"], arrays["b"])
        assert loaded["a"].dtype == np.float32


def test_build_time_comes_only_from_source_date_epoch():
    assert build_time_from_env({}) is None
    assert build_time_from_env({"SOURCE_DATE_EPOCH": "0"}).year == 1970
    with pytest.raises(ValueError, match="SOURCE_DATE_EPOCH"):
        build_time_from_env({"SOURCE_DATE_EPOCH": "yesterday"})


def test_ids_from_titles():
    assert slug("Pair S1 → S2") == "pair-s1-s2"
    assert unique_slugs(["Map", "map", "Map!"]) == ["map", "map-2", "map-3"]
    assert signed(-0.0261) == "\u22120.026" and signed(0.105) == "+0.105" and signed(None) == "—"


# ------------------------------------------------------------------------------------------ pages
class PageAudit(HTMLParser):
    """Collects what the accessibility and offline checks need from a page."""

    def __init__(self) -> None:
        super().__init__()
        self.lang = None
        self.images: list[dict] = []
        self.links: list[str] = []
        self.ids: set[str] = set()
        self.tables = 0
        self.captions = 0
        self.th: list[dict] = []
        self.scripts: list[str] = []
        self.figures = 0
        self.figcaptions = 0
        self.external: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "html":
            self.lang = a.get("lang")
        elif tag == "img":
            self.images.append(a)
        elif tag == "a" and "href" in a:
            self.links.append(a["href"])
        elif tag == "table":
            self.tables += 1
        elif tag == "caption":
            self.captions += 1
        elif tag == "th":
            self.th.append(a)
        elif tag == "script":
            self.scripts.append(a.get("src", ""))
        elif tag == "figure":
            self.figures += 1
        elif tag == "figcaption":
            self.figcaptions += 1
        for key in ("src", "href"):
            if re.match(r"^(https?:)?//", a.get(key) or ""):
                self.external.append(a[key])


def audit(page: Path) -> PageAudit:
    parser = PageAudit()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


PAGES = ["index.html", "pool/index.html", "bell/index.html", "broken/index.html"]


@pytest.mark.parametrize("page", PAGES)
def test_pages_are_accessible_and_offline(catalog, page):
    root, _ = catalog
    path = root / page
    found = audit(path)
    assert found.lang == "en"
    assert found.external == []
    for src in found.scripts:  # only the vendored viewer, from the site folder; no inline code
        assert src and (path.parent / src).is_file(), src
    for image in found.images:
        assert image.get("alt", "").strip(), image
        assert (path.parent / image["src"]).is_file(), image["src"]
    for href in found.links:
        target, _, anchor = href.partition("#")
        if target:
            assert (path.parent / target).is_file(), href
            if anchor:
                assert anchor in audit(path.parent / target).ids, href
        elif anchor:
            assert anchor in found.ids, href
    assert found.tables == found.captions
    assert all(th.get("scope") in ("col", "row", "rowgroup") for th in found.th)
    assert found.figures == found.figcaptions
    assert "<style>" in path.read_text() and "@media print" in path.read_text()


def test_site_folder_holds_every_artifact(catalog):
    root, artifacts = catalog
    pool = artifacts["pool"]
    for key in ("page", "grid", "grid-png-0", "grids-csv", "map", "thumbnail", "probes", "mesh-ply", "mesh-gltf",
                "render-top", "render-oblique-ne", "render-oblique-sw", "render-section", "dimensions-csv",
                "pairs-csv", "scans-csv", "fans", "pairs-convergence", "pairs-particles-1"):
        assert (root / "pool" / pool[key]).is_file(), key
    assert "result" not in pool  # the report never writes result.json; its caller does, once
    result = json.loads((root / "pool" / "result.json").read_text())
    assert result["artifacts"] == {**pool, "result": "result.json"}
    (grid,) = read_npz(root / "pool" / "grid.npz")
    assert grid.log_odds.ndim == 2 and grid.depth_m == 1.5
    read_glb((root / "pool" / "model.glb").read_bytes())
    assert (root / "pool" / "model.ply").read_bytes().startswith(b"ply\nformat binary_little_endian")
    rows = (root / "pool" / "dimensions.csv").read_text().splitlines()
    assert rows[0].startswith("name,reference_kind,depth_m,map_m,ci95_m,reference_m,diff_m") and len(rows) == 3
    assert "slices" in artifacts["bell"] and "mesh-ply" in artifacts["bell"]


def test_site_page_shows_tables_and_unplaced_scans(catalog):
    root, _ = catalog
    html = (root / "bell" / "index.html").read_text()
    assert 'id="dimension-table"' in html
    for text in ("Width", "Length", "Difference (m)", "Probe std (m)", "Scans not placed, and why",
                 "no converged match links it to the reference scan", "Parameters and provenance",
                 "pf-pairwise", "model.glb", "result.json", "dimensions.csv", "walls curved through them"):
        assert text in html, text


def test_failed_build_page_shows_error_stage_and_input(catalog):
    root, artifacts = catalog
    html = (root / "broken" / "index.html").read_text()
    assert 'role="alert"' in html and "Build failed" in html
    assert "reference scan has no valid beams" in html
    assert "pair (0, 2): broken/scan1.npz → broken/scan3.npz" in html
    assert "fans" in artifacts["broken"] and "mesh-ply" not in artifacts["broken"]
    assert "the build stopped before the mapping stage" in html


def test_coordinates_are_redacted_when_the_record_asks(catalog):
    root, _ = catalog
    needle = str(LATITUDE)[:6]  # "35.885", a prefix of any rounding the page could print
    for path in (root / "pool").iterdir():  # record.json included: the published record is redacted too
        if path.suffix in (".html", ".json", ".csv"):
            assert needle not in path.read_text(), path
    assert "withheld" in (root / "pool" / "index.html").read_text()
    assert needle in (root / "bell" / "index.html").read_text()


class _Table(HTMLParser):
    """The header and body cells of the table with a given id."""

    def __init__(self, table_id: str) -> None:
        super().__init__()
        self.table_id, self.inside, self.cell = table_id, False, None
        self.head: list[str] = []
        self.rows: list[list[str]] = []
        self.section = ""

    def handle_starttag(self, tag, attrs):
        if tag == "table" and dict(attrs).get("id") == self.table_id:
            self.inside = True
        elif self.inside and tag in ("thead", "tbody"):
            self.section = tag
        elif self.inside and tag == "tr" and self.section == "tbody":
            self.rows.append([])
        elif self.inside and tag in ("th", "td"):
            self.cell = ""

    def handle_endtag(self, tag):
        if tag == "table":
            self.inside = False
        elif self.inside and tag in ("th", "td") and self.cell is not None:
            (self.head if self.section == "thead" else self.rows[-1]).append(" ".join(self.cell.split()))
            self.cell = None

    def handle_data(self, data):
        if self.cell is not None:
            self.cell += data


def read_table(html: str, table_id: str) -> tuple[list[str], list[list[str]]]:
    parser = _Table(table_id)
    parser.feed(html)
    return parser.head, parser.rows


def test_index_lists_sites_with_honest_status(catalog):
    root, _ = catalog
    html = (root / "index.html").read_text()
    for text in ("Swimming pool", "Bell cistern", "Broken site", "4 of 4", "3 of 4", "0 of 4",
                 "reference scan has no valid beams", "pool/thumbnail.png", "2024-01-01T00:00:00Z",
                 "1 ok, 1 partial, 1 failed", "1 of 4 scans not placed (S4). The survey", "chain breaks between S3 and S4",
                 "two parts of the map joined less precisely than ±0.25 m (95 %)"):
        assert text in html, text
    assert "broken/thumbnail.png" not in html
    for site, status in (("pool", "ok"), ("bell", "partial"), ("broken", "failed")):
        assert re.search(rf'id="site-{site}".*?badge badge-{status}">{status}<', html, re.S), site


def test_index_has_one_row_per_site_and_dimension_truth_first_and_no_sparse_column(catalog):
    root, _ = catalog
    html = (root / "index.html").read_text()
    head, rows = read_table(html, "difference-table")
    for k, row in enumerate(rows):  # the site cell spans its rows
        if len(row) == len(head) - 1:
            rows[k] = [rows[k - 1][0]] + row
    assert head == ["Site", "Dimension", "Map (m)", "Truth (m)", "Map − truth (m)", "Map − truth (%)",
                    "Mosaic (m)", "Map − mosaic (m)", "Probes", "Probe std (m)"]
    assert [(r[0], r[1]) for r in rows] == [("Swimming pool", "Width"), ("Swimming pool", "Length"),
                                            ("Bell cistern", "Width"), ("Bell cistern", "Length")]
    assert all(r[3] == "3.610" and r[6] == "—" for r in rows if r[1] == "Width")  # truth, no mosaic
    assert all(r[3] == "—" and r[6] == "7.210" for r in rows if r[1] == "Length")
    assert all(r[8] == "10 of 10" for r in rows)
    for k in range(2, len(head)):
        assert any(r[k] != "—" for r in rows), head[k]
    caption = re.search(r'id="difference-table".*?<caption>(.*?)</caption>', html, re.S).group(1)
    for heading in head[2:]:
        assert f"<strong>{heading}</strong>:" in caption, heading
    assert 'id="summary-figures"' in html and "median" in html and "Weak dimensions" in html


def test_site_page_with_images_fits_the_size_budget(catalog):
    root, _ = catalog
    for site in SITES:
        assert page_bytes(root / site / "index.html") <= ReportConfig().max_page_bytes


def _png_chunks(data: bytes) -> list[bytes]:
    chunks, offset = [], 8
    while offset < len(data):
        length, kind = struct.unpack(">I4s", data[offset:offset + 8])
        chunks.append(kind)
        offset += 12 + length
    return chunks


def test_pngs_carry_no_metadata(catalog):
    root, _ = catalog
    for png in sorted((root / "pool").glob("*.png")):
        chunks = _png_chunks(png.read_bytes())
        assert not {b"tEXt", b"iTXt", b"zTXt", b"tIME"} & set(chunks), (png.name, chunks)


def test_same_build_gives_the_same_bytes_quietly(catalog, tmp_path, capfd):
    root, _ = catalog
    again = tmp_path / "pool"
    again.mkdir()
    capfd.readouterr()
    build = make_site_build(**SITES["pool"])
    written = render_site(build, again)
    assert not (again / "result.json").exists() and not (again / "record.json").exists()  # the caller's
    write_site_result(build, again, written)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # no X / VTK warnings on a machine without a display

    def digest(folder: Path) -> dict[str, str]:
        return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(folder.rglob("*")) if p.is_file()}

    first, second = digest(root / "pool"), digest(again)
    assert first.keys() == second.keys()
    assert [name for name in first if first[name] != second[name]] == []
    assert zlib.crc32((again / "index.html").read_bytes()) == zlib.crc32((root / "pool" / "index.html").read_bytes())


def test_download_list_prints_no_size_for_the_timed_result(tmp_path):
    """result.json holds timings; printing its size would change the page from build to build."""
    from cistern_archive.report.downloads import download_rows

    (tmp_path / "result.json").write_text("{}" * 700)
    (tmp_path / "dimensions.csv").write_text("a,b\n")
    rows = {d["file"]: d["size"] for d in download_rows({"result": "result.json", "dimensions-csv": "dimensions.csv"},
                                                        tmp_path)}
    assert rows == {"result.json": "", "dimensions.csv": "4 B"}


def test_stations_above_one_another_share_one_label():
    from cistern_archive.report.maps import stacked_labels

    xy = np.array([[0.0, 0.0], [0.01, -0.01], [2.0, 0.0], [0.0, 0.02]])
    shown = stacked_labels(xy, ["d1a", "d2a", "d1b", "d3a"], tolerance_m=0.05)
    assert [text for _, text in shown] == ["d1a / d2a / d3a", "d1b"]


def test_depth_colour_bar_runs_the_models_way():
    from cistern_archive.report.model3d import depth_annotations

    labels = depth_annotations((0.6, 4.6))
    # coloured by elevation (−depth): the shallowest depth sits at the top of the bar, the deepest at the bottom
    top, bottom = max(labels), min(labels)
    assert labels[top] == "0.6" and labels[bottom] == "4.6"


def test_parameters_read_as_key_and_value(catalog):
    from cistern_archive.report.page import parameter_items

    assert parameter_items({"tau_pw": 6.0, "below": {"s2": "s1"}, "refine": True, "sizes": [1, 2]}) == [
        {"key": "below", "value": "s2: s1"}, {"key": "refine", "value": "yes"}, {"key": "sizes", "value": "1, 2"},
        {"key": "tau_pw", "value": "6"}]
    assert parameter_items({"verify": {"unique": True, "fit": {"enabled": False, "min_inliers": 25}}}) == [
        {"key": "verify", "value": "fit: (enabled: no; min_inliers: 25); unique: yes"}]
    root, _ = catalog
    html = (root / "pool" / "index.html").read_text()
    assert "<dt>tau_pw</dt><dd>6</dd>" in html and "{&#34;" not in html and '{"' not in html


def test_dimensions_carry_a_95_percent_interval(catalog):
    root, _ = catalog
    result = json.loads((root / "pool" / "result.json").read_text())
    for d in result["dimensions"]:
        assert 0.03 < d["ci95_m"] < 0.1, d  # the cell term alone is 1.96 × 0.05 / √6 = 0.040 m
    html = (root / "pool" / "index.html").read_text()
    width = result["dimensions"][0]
    assert f"{width['map_m']:.3f} ± {width['ci95_m']:.3f}" in html


def test_interval_combines_spread_cell_pose_and_heading():
    from cistern_archive.pipeline.intervals import ci95_half_width, pose_term

    assert ci95_half_width([3.5], 0.05) == pytest.approx(1.959964 * 0.05 / 6 ** 0.5)
    wide = ci95_half_width([3.4, 3.6, 3.5, 3.45, 3.55], 0.05)
    assert wide > ci95_half_width([3.5, 3.5, 3.5, 3.5, 3.5], 0.05)
    cov = np.zeros((2, 3, 3))
    cov[:, 0, 0] = 0.02 ** 2  # 2 cm along x for both scans
    poses = Poses(np.array([[0.0, 0.0], [3.0, 0.0]]), np.zeros(2), np.ones(2, dtype=bool), ("", ""), 0, cov)
    across = [(-0.2, 0.0, 3.2, 0.0)]  # from the first scan's wall to the second's
    assert pose_term(across, poses) == pytest.approx(1.959964 * (2 * 0.02 ** 2) ** 0.5)
    assert pose_term([(-0.2, 0.0, 0.3, 0.0)], poses) == 0.0  # one scan saw both walls
    assert pose_term(across, Poses(poses.xy_m, poses.yaw_rad, poses.placed, poses.reasons, 0)) == 0.0
    cell = ci95_half_width([3.5], 0.05)
    assert ci95_half_width([3.5], 0.05, heading_shift_m=0.3) == pytest.approx((cell ** 2 + 0.3 ** 2) ** 0.5)
    assert ci95_half_width([3.5], 0.05, heading_shift_m=math.inf) == pytest.approx(cell)  # flagged weak instead


def test_plan_round_trips_through_dxf_and_svg(catalog):
    import xml.etree.ElementTree as ET

    import ezdxf

    root, artifacts = catalog
    for site, depths in (("pool", [1.5]), ("bell", [1.0, 2.0, 3.0])):
        doc = ezdxf.readfile(root / site / artifacts[site]["plan-dxf"])
        assert doc.units == ezdxf.units.M
        layers = sorted({e.dxf.layer for e in doc.modelspace().query("LWPOLYLINE")})
        assert len(layers) == len(depths), (site, layers)
        svg = ET.parse(root / site / artifacts[site]["plan-svg"]).getroot()
        ns = {"svg": "http://www.w3.org/2000/svg"}
        assert svg.find(".//svg:g[@id='scale-bar']", ns) is not None
        assert svg.find(".//svg:g[@id='north-arrow']", ns) is not None
        assert len(svg.findall(".//svg:g[@stroke]", ns)) == len(depths)
    doc = ezdxf.readfile(root / "pool" / "plan.dxf")
    points = np.concatenate([np.array(e.get_points("xy")) for e in doc.modelspace().query("LWPOLYLINE")])
    # the outline runs along the walls' inner faces
    assert points[:, 0].max() - points[:, 0].min() == pytest.approx(WIDTH_M, abs=0.12)
    assert points[:, 1].max() - points[:, 1].min() == pytest.approx(LENGTH_M, abs=0.12)
    html = (root / "pool" / "index.html").read_text()
    assert 'href="plan.dxf"' in html and 'href="plan.svg"' in html


def test_report_pdf_is_printed_and_pinned(catalog, tmp_path):
    from cistern_archive.report.pdf import chromium_path, pin_dates, print_pdf

    if chromium_path() is None:
        pytest.skip("Chromium not found (Debian: apt-get install chromium)")
    root, artifacts = catalog
    data = (root / "pool" / artifacts["pool"]["report-pdf"]).read_bytes()
    assert data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF")
    assert len(re.findall(rb"/Type\s*/Page\b", data)) >= 2  # the whole page, on several sheets
    assert b"/CreationDate (D:20231114221320+00'00')" in data  # SOURCE_DATE_EPOCH of the tests, not the clock
    # every cross-reference entry points at its object after the links were made relative
    start = int(re.search(rb"startxref\n(\d+)", data[-200:]).group(1))
    assert data[start:start + 4] == b"xref"
    rows = data[start:].split(b"\n")[2:2 + int(re.match(rb"xref\n0 (\d+)\n", data[start:]).group(1))]
    assert all(data[int(r[:10]):].startswith(b"%d 0 obj" % k) for k, r in enumerate(rows) if r.endswith(b" n "))
    links = re.findall(rb"/URI \(([^)]*)\)", data)
    assert b"grid.npz" in links and b"../index.html" in links and not any(b"file:" in u for u in links)
    copy = tmp_path / "pool"
    shutil.copytree(root / "pool", copy)  # printed elsewhere: the same bytes
    assert print_pdf(copy / "index.html", tmp_path / "again.pdf", when=build_time_from_env()) == ""
    assert (tmp_path / "again.pdf").read_bytes() == data
    assert 'href="report.pdf"' in (root / "pool" / "index.html").read_text()
    assert pin_dates(b"/CreationDate (D:20260101120000+00'00')", None) == b"/CreationDate (D:19700101000000+00'00')"


def test_geotiff_only_for_a_georeferenced_unredacted_site(catalog):
    import rasterio
    from rasterio.warp import transform

    root, artifacts = catalog
    assert "grid-tif" not in artifacts["pool"] and not (root / "pool" / "grid.tif").exists()  # redacted
    with rasterio.open(root / "bell" / artifacts["bell"]["grid-tif"]) as tif:
        assert tif.count == 3 and tif.crs.to_epsg() == 32633  # Malta: UTM zone 33 N
        assert tif.res == pytest.approx((0.05, 0.05))
        band = tif.read(1)
        assert np.isnan(band).any() and np.nanmax(band) > 0.9 and np.nanmin(band) < 0.2
        # the reference scan (map origin) sits at the record's coordinates
        (east,), (north,) = transform("EPSG:4326", tif.crs, [LONGITUDE], [LATITUDE])
        row, col = tif.index(east, north)
        assert 0 <= row < tif.height and 0 <= col < tif.width
        assert "depth" in tif.descriptions[0]
    world = (root / "bell" / "grid.tfw").read_text().split()
    assert [float(world[0]), float(world[3])] == [0.05, -0.05]


def test_convergence_figure_draws_the_thresholds_the_histories_carry(tmp_path):
    """The matcher names its thresholds in the history; the report draws them and knows no plugin."""
    from cistern_archive.pipeline.contracts import HistoryThreshold, MatchHistory, MatchResult
    from cistern_archive.report.figures import convergence_figure, history_thresholds

    def pair(i, j, history):
        return MatchResult(i, j, 1.0, 0.0, 0.0, 0.5, True, len(history.weight_avg), 0.1, "", None, history)

    curve = np.linspace(0.0, 0.5, 10)
    tau, r_c = HistoryThreshold(0.25, "τ_pw"), HistoryThreshold(0.05, "r_c")
    drawn = [pair(0, 1, MatchHistory(curve, 1.0 - curve, weight_threshold=tau, std_threshold=r_c)),
             pair(1, 2, MatchHistory(curve, 1.0 - curve, weight_threshold=tau, std_threshold=r_c))]
    assert history_thresholds(drawn) == ([tau], [r_c])
    fig = convergence_figure(tmp_path / "c.png", drawn, ["a", "b", "c"], dpi=40)
    left, right = fig.axes
    assert [t.get_text() for t in left.texts] == ["τ_pw"] and [t.get_text() for t in right.texts] == ["r_c"]
    assert any(list(line.get_ydata()) == [0.25, 0.25] for line in left.lines)
    bare = [pair(0, 1, MatchHistory(curve, 1.0 - curve))]
    assert history_thresholds(bare) == ([], [])
    fig = convergence_figure(tmp_path / "d.png", bare, ["a", "b"], dpi=40)
    assert not fig.axes[0].texts and not fig.axes[1].texts


def test_index_shows_a_surveys_track_errors_beside_the_published_rows(tmp_path):
    from cistern_archive.pipeline.results import SiteResult, TrackErrors, TrackSummary
    from cistern_archive.report.index import IndexEntry, render_index

    track = TrackSummary(fixes=120, span_s=600.0, revolutions=40, revolutions_available=40, clock_offset_s=-0.7,
                         tracks=[TrackErrors(name="pipeline", start_aligned={"mean_m": 2.381, "sd_m": 1.03,
                                                                             "max_m": 4.94, "fixes": 120},
                                             rigid={"mean_m": 2.151, "sd_m": 0.9, "max_m": 4.0, "fixes": 120})],
                         published_source="Mallios et al. 2014, Table 2",
                         published=[{"method": "EKF SLAM", "mean_m": 1.91, "sd_m": 1.32, "max_m": 5.08}])
    survey = SiteResult(site_id="marina", name="Marina", status="ok", track=track)
    cistern = SiteResult(site_id="pool", name="Pool", status="ok")
    html = render_index([IndexEntry.from_result(cistern), IndexEntry.from_result(survey)], tmp_path).read_text()
    head, rows = read_table(html, "track-table")
    assert head == ["Site", "Track", "Mean (m)", "SD (m)", "Max (m)", "Rigid mean (m)", "Fixes"]
    assert rows == [["Marina", "pipeline", "2.381", "1.030", "4.940", "2.151", "120"],
                    ["published: EKF SLAM", "1.910", "1.320", "5.080", "—", "—"]]
    assert "Mallios et al. 2014, Table 2" in html
    cisterns_only = tmp_path / "cisterns"
    cisterns_only.mkdir()
    assert 'id="track-table"' not in render_index([IndexEntry.from_result(cistern)], cisterns_only).read_text()


def test_a_tracks_table_counts_only_the_fixes_after_the_calibration_window():
    """The figure draws every fix of the span; the table's errors leave out those the dead reckoning was
    calibrated on, and its caption says how many it counts."""
    from cistern_archive.core.tracks import EstimatedTrack, TrackComparison
    from cistern_archive.report.track import track_context

    times = np.arange(10.0)
    errors = times / 10.0
    estimate = EstimatedTrack("pipeline", np.column_stack([times, times]), errors, errors, evaluated=times > 3.0)
    track = TrackComparison(time_s=times, fixes_xy_m=np.column_stack([times, times]), tracks=(estimate,),
                            calibration_end_s=3.0, revolutions=5, revolutions_available=5)
    context = track_context(track)
    assert context["rows"][0]["fixes"] == "6"
    assert context["rows"][0]["start"][0] == f"{errors[4:].mean():.2f}" and context["rows"][0]["start"][2] == "0.90"
    assert "first 4 fixes of the span lie in the DGPS window" in context["calibration"]
    assert "the 6 fixes after it" in context["calibration"]


def test_map_marks_the_joins_of_groups_fitted_as_wholes(tmp_path):
    """A join that no match made (``Poses.group_links``) is drawn and explained, so the map does not
    suggest the scans were placed by the failed matches drawn between them."""
    from cistern_archive.core.matches import MatchResult
    from cistern_archive.report.maps import map_figure

    xy = np.array([[0.0, 0.0], [2.0, 0.0], [6.0, 1.0]])
    failed = [MatchResult(1, 2, 4.0, 1.0, 0.0, 0.1, False, 1, 0.0, reason="ambiguous")]
    plain = Poses(xy, np.zeros(3), np.ones(3, bool), ("", "", ""), 0)
    fitted = Poses(xy, np.zeros(3), np.ones(3, bool), ("", "", ""), 0, group_links=((1, 2),), group_link_radius95_m=(0.39,))
    without = map_figure(tmp_path / "a.png", None, plain, failed, ["s1", "s2", "s3"], dpi=60)
    with_fit = map_figure(tmp_path / "b.png", None, fitted, failed, ["s1", "s2", "s3"], dpi=60)
    assert "fitting each group" not in without.caption
    assert "dotted lines join groups of scans that no match could join" in with_fit.caption
    assert "s2–s3 to ±0.39 m (95 %)" in with_fit.caption  # with how precisely the join places the groups
    assert (tmp_path / "a.png").read_bytes() != (tmp_path / "b.png").read_bytes()


def test_map_says_over_what_depths_its_stations_lie_when_they_spread(tmp_path):
    """One slice is drawn with every placed station; stations spread over depth are named with their
    depths (the unplaced station's depth does not count), stations at one depth are not."""
    from cistern_archive.report.maps import map_figure

    xy = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0]])
    poses = Poses(xy, np.zeros(3), np.array([True, True, False]), ("", "", "not placed"), 0)
    spread = map_figure(tmp_path / "a.png", None, poses, [], ["s1", "s2", "s3"], dpi=60,
                        station_depths_m=[1.45, 2.6, 4.0])
    level = map_figure(tmp_path / "b.png", None, poses, [], ["s1", "s2", "s3"], dpi=60,
                       station_depths_m=[1.45, 1.5, 4.0])
    assert "(stations at 1.45–2.60 m)" in spread.caption and "(stations at 1.45–2.60 m)" in spread.alt
    assert "stations at" not in level.caption


def test_a_dimension_with_truth_and_mosaic_is_one_set_of_probes_in_the_figure():
    from cistern_archive.core.dimensions import DimensionRow
    from cistern_archive.report.maps import probe_groups

    lines = ((0.0, 0.0, 3.5, 0.0), (0.0, 0.2, 3.5, 0.2))
    rows = [DimensionRow("width", 3.5, 3.45, "truth", 0.05, probes=(3.5, 3.5), probe_lines=lines),
            DimensionRow("length", 7.2, 7.21, "truth", -0.01, probes=(7.2,), probe_lines=((0, 1, 7.2, 1),)),
            DimensionRow("width", 3.5, 3.40, "mosaic", 0.10, probes=(3.5, 3.5), probe_lines=lines),
            DimensionRow("length", float("nan"), 7.3, "mosaic", float("nan"))]  # not measured: not drawn
    assert [label for _, label in probe_groups(rows)] == ["width (truth, mosaic): 3.50 m", "length (truth): 7.20 m"]
