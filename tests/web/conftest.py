"""Real-browser tests of the station's web face: Debian's chromium, driven by Selenium.

Fixtures:
    browser     one headless chromium per test module (a fresh profile each)
    artefacts   out/test-artefacts/ (gitignored): the screenshots the tests save (listed at the end)
"""
from __future__ import annotations

from pathlib import Path

import pytest
from webrig import ARTEFACTS, SAVED, new_browser, quit_browser


@pytest.fixture(scope="module")
def browser():
    driver = new_browser()
    driver.set_page_load_timeout(15)
    try:
        yield driver
    finally:
        quit_browser(driver)


@pytest.fixture(scope="session")
def artefacts() -> Path:
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    return ARTEFACTS


def pytest_terminal_summary(terminalreporter):
    if SAVED:
        terminalreporter.section("web test artefacts")
        for name, path in SAVED:
            terminalreporter.write_line(f"{name}: {path}")
