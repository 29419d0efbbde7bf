"""The browser tests' screenshot asks again after Chromium's transient refusal, only then."""

from __future__ import annotations

from pathlib import Path

import pytest
from playwright.sync_api import Error

from tests import chromium


class _Page:
    def __init__(self, failures: list[str]) -> None:
        self.failures = failures
        self.calls = 0

    def screenshot(self, path: str) -> None:
        self.calls += 1
        if self.failures:
            raise Error(self.failures.pop(0))
        Path(path).write_bytes(b"png")


REFUSED = "Page.screenshot: Protocol error (Page.captureScreenshot): Unable to capture screenshot"


def test_a_refused_capture_is_asked_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                          ) -> None:
    monkeypatch.setattr(chromium.time, "sleep", lambda s: None)
    page = _Page([REFUSED])
    chromium.screenshot(page, tmp_path / "a.png")
    assert page.calls == 2 and (tmp_path / "a.png").read_bytes() == b"png"


def test_other_errors_and_lasting_refusals_are_raised(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(chromium.time, "sleep", lambda s: None)
    with pytest.raises(Error, match="Target closed"):
        chromium.screenshot(_Page(["Target closed"]), tmp_path / "b.png")
    page = _Page([REFUSED] * chromium.SCREENSHOT_ATTEMPTS)
    with pytest.raises(Error, match="Unable to capture"):
        chromium.screenshot(page, tmp_path / "c.png")
    assert page.calls == chromium.SCREENSHOT_ATTEMPTS
