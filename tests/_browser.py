"""A real headless browser for the front-door tests: Debian's chromium, driven by Selenium through chromedriver.

`make browser-deps` installs both (`make test` runs it: as root with apt-get, as CI is). Selenium is pointed at
/usr/bin/chromedriver, so it never downloads a browser or driver (selenium-manager stays unused). Where they are
missing the tests fail when the machine could have installed them (root, or the `CI` variable set: a broken setup
must not pass as a skip) and are skipped elsewhere, with the command that installs them.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Screenshots the browser tests keep beside pytest's tmp_path copy (build/ is not committed).
SCREENSHOTS = ROOT / "build" / "test-screenshots"
BROWSERS = ("chromium", "chromium-browser")
DRIVER = "chromedriver"


def find_browser() -> tuple[str, str] | None:
    """(chromium, chromedriver) paths, or None where either is missing."""
    browser = next((path for name in BROWSERS if (path := shutil.which(name))), None)
    driver = shutil.which(DRIVER)
    return (browser, driver) if browser and driver else None


def require_browser() -> tuple[str, str]:
    """The browser and driver, or the test fails (root / CI: setup should have installed them) or skips."""
    found = find_browser()
    if found:
        return found
    message = ("Debian's chromium and chromedriver are missing: `make browser-deps` installs them (as root: "
               "apt-get install chromium chromium-driver); `make test` runs it first")
    if os.geteuid() == 0 or os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


@contextmanager
def headless_chromium(width: int = 1400, height: int = 1000) -> Iterator[Any]:
    """A headless chromium session (Selenium WebDriver), closed afterwards."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    browser, driver_path = require_browser()
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                f"--window-size={width},{height}", "--no-first-run", "--disable-background-networking"):
        options.add_argument(arg)  # --no-sandbox: CI runs as root, where chromium's sandbox refuses to start
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # console messages, for `driver.get_log("browser")`
    driver = webdriver.Chrome(service=Service(driver_path), options=options)
    driver.set_page_load_timeout(120)
    try:
        yield driver
    finally:
        driver.quit()


def wait_for(condition: Callable[[], Any], timeout: float, what: str, poll: float = 0.5) -> Any:
    """Poll `condition` until it returns something truthy; fail naming `what` after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(poll)


def keep_screenshot(driver: Any, tmp_path: Path, name: str) -> Path:
    """Save a screenshot in the test's tmp_path and a copy under build/test-screenshots/; return the copy."""
    shot = tmp_path / name
    driver.save_screenshot(str(shot))
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    kept = SCREENSHOTS / name
    shutil.copyfile(shot, kept)
    return kept
