"""Headless Chromium for looking at the dashboard from a program (browser tests, latency bench).

Debian's ``chromium`` driven through its own ``chromedriver`` (package ``chromium-driver``, the
same version as the browser) by Selenium, which is given both paths and so downloads nothing.
Selenium is a test/bench dependency, imported only here.
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

__all__ = ["CHROMIUM_FLAGS", "missing", "headless_chromium", "console_errors"]

#: Headless Chromium as root on a machine without GPU, display or network beyond loopback:
#: no sandbox (root), no background connections (refused here, many at a time), a fresh profile.
CHROMIUM_FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                  "--disable-quic", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--window-size=1400,1700")


def missing() -> str | None:
    """Why no headless browser can run here (with what to install), or None."""
    for command, package in (("chromium", "chromium"), ("chromedriver", "chromium-driver")):
        if shutil.which(command) is None:
            return f"{command} not found (Debian package {package})"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    return None


def headless_chromium(profile: Path) -> Any:
    """A Selenium ``webdriver.Chrome`` on Debian's Chromium with a new profile in ``profile``
    (the driver's log goes there too) and the console log recorded. Call ``quit()`` when done."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    reason = missing()
    if reason:
        raise RuntimeError(reason)
    profile.mkdir(parents=True, exist_ok=True)
    options = Options()
    options.binary_location = shutil.which("chromium")
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = Service(executable_path=shutil.which("chromedriver"),
                      log_output=str(profile / "chromedriver.log"))
    return webdriver.Chrome(options=options, service=service)


def console_errors(driver: Any) -> list[str]:
    """The console's errors since the last call (Chromium's ``SEVERE`` log entries)."""
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
