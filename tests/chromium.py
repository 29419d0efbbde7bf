"""Debian's chromium for the browser tests (driven by playwright through ``executable_path``;
playwright's own browser download cannot work here)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist"]
#: Chromium now and then refuses one capture ("Protocol error (Page.captureScreenshot):
#: Unable to capture screenshot") and takes the same picture when asked again a moment
#: later (a known transient of headless Chromium). Asking again takes the same picture, so
#: what a test checks on it does not change.
SCREENSHOT_ATTEMPTS = 3


def screenshot(page: Any, path: Path) -> None:
    """``page.screenshot(path=path)``, asked again after a transient refusal."""
    from playwright.sync_api import Error

    for attempt in range(SCREENSHOT_ATTEMPTS):
        try:
            page.screenshot(path=str(path))
            return
        except Error as exc:
            if "Unable to capture screenshot" not in str(exc) \
                    or attempt == SCREENSHOT_ATTEMPTS - 1:
                raise
            time.sleep(0.5)
