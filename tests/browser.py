"""The browser the tests drive: Debian's chromium, headless, through Debian's chromedriver and
Selenium (installed by scripts/install-browser.sh from the test command; no browser is downloaded
from elsewhere). A machine without them skips the browser tests, saying why."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

ARGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync")


def chromium(profile: Path, window: str = "1300,2000", *extra: str):
    """A headless chromium session with its profile in ``profile``/chromium, ``window`` wide x high."""
    if not (shutil.which("chromium") and shutil.which("chromedriver")):
        pytest.skip("chromium and chromedriver are not installed (scripts/install-browser.sh)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium")
    for a in (*ARGS, *extra, f"--user-data-dir={Path(profile) / 'chromium'}", f"--window-size={window}"):
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
