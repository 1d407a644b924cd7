"""Helpers of the real-browser tests (tests/web): chromium, screenshots, the station under test.

`make test` installs /usr/bin/chromium and /usr/bin/chromedriver (apt-get, as root); Selenium
talks to that chromedriver (`Service`), so Selenium Manager never tries to download a browser.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import time
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

#: the operator the station's users file has: name, password
OPERATOR = ("olga", "hoist-room 2")

#: A short shaft, so that a whole trip (rest, wind, rest) is in the log within ~20 s.
SHORT_WIND = {"shaft_m": 30.0, "v_max": 5.0, "accel": 2.5, "rest_s": 6.0, "payload_n": 60_000.0}


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


#: Resolves with the page's epoch time in ms (performance.timeOrigin + performance.now()) at the
#: first DOM change after which `document.querySelector(css)` finds something (or, with `gone`,
#: finds nothing); null on timeout. No eval: the page's CSP has no 'unsafe-eval'.
_WAIT_JS = """
const css = arguments[0], gone = arguments[1], timeoutMs = arguments[2], done = arguments[arguments.length - 1];
const now = () => performance.timeOrigin + performance.now();
const ok = () => gone ? !document.querySelector(css) : !!document.querySelector(css);
if (ok()) { done(now()); return; }
let finished = false;
const obs = new MutationObserver(() => {
  if (!finished && ok()) { finished = true; obs.disconnect(); clearTimeout(timer); done(now()); }
});
obs.observe(document, {subtree: true, childList: true, attributes: true, characterData: true});
const timer = setTimeout(() => { if (!finished) { finished = true; obs.disconnect(); done(null); } }, timeoutMs);
"""


def wait_for(driver, css: str, timeout_s: float = 10.0, gone: bool = False) -> float:
    """Wait until `css` matches an element in the page (or none, with `gone`); return the time it
    did as the page's epoch seconds (comparable with time.time()); AssertionError on timeout.

    Watched in slices of at most a second: a click that loads another page (a form post)
    ends the script of the page it ran in, so each slice starts again on whatever page is
    there now."""
    from selenium.common.exceptions import WebDriverException

    end = time.monotonic() + timeout_s
    while True:
        left = end - time.monotonic()
        if left <= 0:
            break
        chunk = min(left, 1.0)
        driver.set_script_timeout(chunk + 5)
        try:
            t = driver.execute_async_script(_WAIT_JS, css, gone, int(chunk * 1000))
        except WebDriverException:   # the page was replaced while the script watched it
            time.sleep(0.05)
            continue
        if t is not None:
            return t / 1000.0
    raise AssertionError(f"after {timeout_s} s the page {'still has' if gone else 'has no'} {css!r}")


def js_fixed(x: float, digits: int) -> str:
    """JavaScript's Number(x).toFixed(digits) for x >= 0 (ties of the exact binary value go up)."""
    from decimal import ROUND_HALF_UP, Decimal

    q = Decimal(1).scaleb(-digits)
    return str(Decimal(x).quantize(q, rounding=ROUND_HALF_UP))
