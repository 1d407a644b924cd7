"""Tests of the station's web face: through Starlette's TestClient (test_web.py, test_web_sessions.py; no browser), and
in a real browser (Debian's chromium, driven by Selenium; only a test that asks for `browser` starts one).

Fixtures:
    browser     one headless chromium per test module (a fresh profile each)
    station     per test module: `ropemon serve` with [web] on a free localhost port, hoists north
                and south fed by simulated winds through pty receivers (`ropemon.lab.webstation`),
                an operator olga in the users file (made with the web face's `add_user`)
    artefacts   out/test-artefacts/ (gitignored): the screenshots the tests save (listed at the end)
"""
from __future__ import annotations

from pathlib import Path

import pytest
from web_rig import ARTEFACTS, OPERATOR, SAVED, SHORT_WIND, new_browser, quit_browser


@pytest.fixture(scope="module")
def browser():
    driver = new_browser()
    driver.set_page_load_timeout(15)
    try:
        yield driver
    finally:
        quit_browser(driver)


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    from ropemon.lab.webstation import WebStation

    ws = WebStation(tmp_path_factory.mktemp("station"), hoists=2, users={OPERATOR[0]: ("operator", OPERATOR[1])},
                    wind=SHORT_WIND)
    try:
        ws.start()
        yield ws
    finally:
        ws.stop()


@pytest.fixture(scope="session")
def artefacts() -> Path:
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    return ARTEFACTS


def pytest_terminal_summary(terminalreporter):
    if SAVED:
        terminalreporter.section("web test artefacts")
        for name, path in SAVED:
            terminalreporter.write_line(f"{name}: {path}")
