"""Helpers of the real-browser tests (tests/web): chromium, screenshots, the station under test.

`make test` installs /usr/bin/chromium and /usr/bin/chromedriver (apt-get, as root); Selenium
talks to that chromedriver (`Service`), so Selenium Manager never tries to download a browser.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ARTEFACTS = ROOT / "out" / "test-artefacts"
CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"

#: Flags that work on the project's machines (root, no display, a closed network): without the
#: background-networking ones chromium keeps opening connections the network refuses.
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--disable-extensions", "--disable-default-apps",
    "--mute-audio",
)

#: screenshots saved in this run (name, path): conftest lists them in the summary
SAVED: list[tuple[str, Path]] = []


def new_browser(width: int = 1280, height: int = 900):
    """A headless chromium with a fresh --user-data-dir; `quit_browser` removes the profile."""
    if not (os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK)):
        pytest.fail(f"tests/web need {CHROMIUM} and {CHROMEDRIVER} (Debian's chromium, chromium-driver): "
                    "`make test` installs them as root, or run `make .venv/.chromium`", pytrace=False)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="ropemon-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS:
        opts.add_argument(flag)
    opts.add_argument(f"--window-size={width},{height}")
    opts.add_argument(f"--user-data-dir={profile}")
    try:
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    except Exception:
        shutil.rmtree(profile, ignore_errors=True)
        raise
    driver._ropemon_profile = profile  # type: ignore[attr-defined]
    return driver


def quit_browser(driver) -> None:
    try:
        driver.quit()
    finally:
        shutil.rmtree(getattr(driver, "_ropemon_profile", ""), ignore_errors=True)


def save_screenshot(driver, name: str) -> Path:
    """Save the page as out/test-artefacts/NAME.png; the run's summary lists it."""
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTEFACTS / f"{name}.png"
    assert driver.save_screenshot(str(path)), f"chromium saved no screenshot to {path}"
    assert path.stat().st_size > 1000, f"{path}: {path.stat().st_size} bytes, not a page"
    SAVED.append((name, path))
    return path
