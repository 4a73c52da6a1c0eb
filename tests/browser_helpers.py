"""Headless Chromium (Debian's ``chromium``) driven by playwright, for the report tests."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

CHROMIUM = Path(os.environ.get("CISTERN_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
BROKEN_IMAGES = "() => Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).map(i => i.src)"
LINKS = "() => Array.from(document.querySelectorAll('a[href]')).map(a => a.href)"


@contextmanager
def launch_browser() -> Iterator[object]:
    """A headless Chromium; skips the test when Chromium or playwright is missing."""
    if not CHROMIUM.is_file():
        pytest.skip(f"Chromium not found at {CHROMIUM} (Debian: apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
    with sync_api.sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


def open_page(browser, url: str, *, javascript: bool = True, media: str = "screen"):
    """Open ``url`` in a fresh context; returns (context, page, problems seen while loading)."""
    context = browser.new_context(java_script_enabled=javascript, viewport={"width": 1200, "height": 900})
    page = context.new_page()
    problems: list[str] = []
    page.on("console", lambda msg: problems.append(f"console {msg.type}: {msg.text}") if msg.type == "error" else None)
    page.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
    page.on("requestfailed", lambda req: problems.append(f"request failed: {req.url} {req.failure}"))
    page.emulate_media(media=media)
    page.goto(url, wait_until="load")
    return context, page, problems


def broken_links(page, path: Path) -> list[str]:
    """Links of the page that leave the file system or point at a missing file or anchor."""
    broken = []
    for href in page.evaluate(LINKS):
        if not href.startswith("file://"):
            broken.append(href)
            continue
        target, _, anchor = href[len("file://"):].partition("#")
        if not Path(target).is_file():
            broken.append(href)
        elif anchor and Path(target) == path and page.locator(f"[id='{anchor}']").count() != 1:
            broken.append(href)
    return broken
