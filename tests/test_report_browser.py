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

from report_fixtures import SITES, render_catalog

pytestmark = pytest.mark.browser

CHROMIUM = Path(os.environ.get("CISTERN_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
PAGES = ["index.html"] + [f"{site}/index.html" for site in SITES]


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.is_file():
        pytest.skip(f"Chromium not found at {CHROMIUM} (Debian: apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


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


BROKEN_IMAGES = "() => Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).map(i => i.src)"
LINKS = "() => Array.from(document.querySelectorAll('a[href]')).map(a => a.href)"


def open_page(browser, url: str, *, javascript: bool = True, media: str = "screen"):
    context = browser.new_context(java_script_enabled=javascript, viewport={"width": 1200, "height": 900})
    page = context.new_page()
    problems: list[str] = []
    page.on("console", lambda msg: problems.append(f"console {msg.type}: {msg.text}") if msg.type == "error" else None)
    page.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
    page.on("requestfailed", lambda req: problems.append(f"request failed: {req.url} {req.failure}"))
    page.emulate_media(media=media)
    page.goto(url, wait_until="load")
    return context, page, problems


@pytest.mark.parametrize("name", PAGES)
def test_page_loads_cleanly(browser, site, name):
    path = site / name
    context, page, problems = open_page(browser, path.as_uri())
    try:
        assert page.evaluate(BROKEN_IMAGES) == []
        for href in page.evaluate(LINKS):
            assert href.startswith("file://"), href
            target, _, anchor = href[len("file://"):].partition("#")
            assert Path(target).is_file(), href
            if anchor and Path(target) == path:
                assert page.locator(f"[id='{anchor}']").count() == 1, href
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
