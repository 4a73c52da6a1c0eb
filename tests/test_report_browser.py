"""Real-browser checks of the report: headless Chromium (Debian's ``chromium``) driven by playwright.

Every page loads from the file system with no console error, no failed request, no broken image or
link; site pages show the dimension table; pages read with JavaScript off; the print stylesheet hides
the navigation. Screenshots of the index and one site page go to ``$CISTERN_TEST_OUTPUT/report`` when
that variable is set, else to the test's temporary folder (printed with ``-s``).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from browser_helpers import BROKEN_IMAGES, broken_links, launch_browser, open_page
from report_fixtures import SITES, render_catalog

pytestmark = pytest.mark.browser

PAGES = ["index.html"] + [f"{site}/index.html" for site in SITES]


@pytest.fixture(scope="module")
def browser():
    with launch_browser() as chromium:
        yield chromium


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("report-site")
    render_catalog(root)
    return root


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    base = os.environ.get("CISTERN_TEST_OUTPUT")
    folder = Path(base) / "report" if base else tmp_path_factory.mktemp("report-screenshots")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.mark.parametrize("name", PAGES)
def test_page_loads_cleanly(browser, site, name):
    path = site / name
    context, page, problems = open_page(browser, path.as_uri())
    try:
        assert page.evaluate(BROKEN_IMAGES) == []
        assert broken_links(page, path) == []
        if name != "index.html" and not name.startswith("broken"):
            table = page.locator("#dimension-table")
            assert table.is_visible()
            assert table.locator("tbody tr").count() >= 2
        if name == "index.html":
            assert page.locator("#difference-table").is_visible()
        assert problems == []
    finally:
        context.close()


def test_pages_read_without_javascript_and_print(browser, site):
    path = site / "pool" / "index.html"
    context, page, problems = open_page(browser, path.as_uri(), javascript=False, media="print")
    try:
        assert page.locator("#dimension-table").is_visible()
        assert page.evaluate("() => getComputedStyle(document.querySelector('nav.toc')).display") == "none"
        assert page.evaluate(BROKEN_IMAGES) == []
        assert problems == []
    finally:
        context.close()


def test_screenshots(browser, site, shots):
    for name, out in (("index.html", "index.png"), ("pool/index.html", "site-pool.png"),
                      ("broken/index.html", "site-broken.png")):
        context, page, problems = open_page(browser, (site / name).as_uri())
        try:
            page.screenshot(path=str(shots / out), full_page=True)
        finally:
            context.close()
        assert (shots / out).stat().st_size > 10_000
        assert problems == []
    shutil.copy(site / "pool" / "model-oblique-ne.png", shots / "model-oblique-ne.png")
    print(f"report screenshots in {shots}")


def test_interactive_model_loads_offline_without_errors(browser, site, shots):
    """The vendored three.js viewer parses model.glb.js and draws it; nothing leaves the file system."""
    from browser_helpers import CHROMIUM, CHROMIUM_ARGS

    # WebGL without a GPU: Chromium's software renderer, in a second browser of the same playwright
    chromium = browser.browser_type.launch(executable_path=str(CHROMIUM),
                                           args=CHROMIUM_ARGS + ["--enable-unsafe-swiftshader", "--use-gl=angle",
                                                                 "--use-angle=swiftshader"])
    try:
        context = chromium.new_context(viewport={"width": 1200, "height": 900})
        page = context.new_page()
        problems, requests = [], []
        page.on("console", lambda msg: problems.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: problems.append(str(exc)))
        page.on("request", lambda req: requests.append(req.url))
        page.goto((site / "bell" / "index.html").as_uri(), wait_until="load")
        page.wait_for_selector("#model-viewer[data-state]", state="attached", timeout=30_000)
        viewer = page.locator("#model-viewer")
        assert viewer.get_attribute("data-state") == "loaded", problems
        assert int(float(viewer.get_attribute("data-triangles"))) > 1000
        assert viewer.is_visible() and viewer.locator("canvas").count() == 1
        viewer.scroll_into_view_if_needed()
        viewer.screenshot(path=str(shots / "viewer-bell.png"))
        assert problems == []
        assert [u for u in requests if not u.startswith("file://")] == []
    finally:
        chromium.close()


def test_status_badges_and_export_links(browser, site):
    context, page, problems = open_page(browser, (site / "index.html").as_uri())
    try:
        badges = {row: page.locator(f"#site-{row} .badge").inner_text() for row in ("pool", "bell", "broken")}
        assert badges == {"pool": "ok", "bell": "partial", "broken": "failed"}
        assert page.locator("#site-bell td.reasons").inner_text().strip().startswith(
            "1 of 4 scans not placed (S4). The survey's chain breaks between S3 and S4: a station between them")
    finally:
        context.close()
    context, page, problems = open_page(browser, (site / "pool" / "index.html").as_uri())
    try:
        for name in ("plan.dxf", "plan.svg", "report.pdf", "model.glb"):
            link = page.locator(f'.downloads a[href="{name}"]')
            assert link.count() == 1 and (site / "pool" / name).is_file(), name
        assert problems == []
    finally:
        context.close()
