"""Fixtures of the viewer tests: headless Chromium (Debian's) driven by Playwright."""
from __future__ import annotations

from pathlib import Path

import pytest
from viewer_support import CHROMIUM, CHROMIUM_ARGS, PageProbe


@pytest.fixture
def open_page(browser):
    """Factory: ``open_page(url)`` -> PageProbe of a new page (closed at teardown)."""
    pages = []

    def open_(url: str, width: int = 1280, height: int = 760) -> PageProbe:
        page = browser.new_page(viewport={"width": width, "height": height})
        probe = PageProbe(page)
        page.goto(url)
        pages.append(page)
        return probe

    yield open_
    for p in pages:
        p.close()


