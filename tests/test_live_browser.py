"""The operator's live view in a real browser: Debian's chromium driven by playwright.

Starts ``ogiflow run`` (simulated devices, small scene, ``live.mode: serve`` on free
loopback ports), opens the web viewer in headless chromium (playwright's
``executable_path``: no browser download), waits until the recording is connected and
drawn, and checks the screenshot: the operator tab's panels are there (titles read back
with tesseract OCR: the viewer draws everything on a canvas, so there is no DOM text) and
the IR picture is not blank. Needs the Debian packages ``chromium`` and ``tesseract-ocr``
and playwright from PyPI (``tools/install.sh --dev``); missing ones fail the test.

``OGIFLOW_SCREENSHOT=PATH`` also writes the final screenshot there (the picture in README.md).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.chromium import ARGS, CHROMIUM, screenshot
from tests.conftest import SMALL_SCENE
from tests.mosquitto import free_port

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.alone  # chromium's timing, not another module's daemon (conftest)
# Frames per second the page draws, counted over 5 s of requestAnimationFrame callbacks.
UI_FPS_JS = """new Promise(done => {
  let n = 0; const t0 = performance.now();
  function tick() {
    n++;
    if (performance.now() - t0 < 5000) requestAnimationFrame(tick);
    else done(n / ((performance.now() - t0) / 1000));
  }
  requestAnimationFrame(tick);
})"""
TITLES = ("gas camera", "status", "emission rate", "leak events")


def ocr(png: Path) -> str:
    """Text of a screenshot (tesseract)."""
    out = subprocess.run(["tesseract", str(png), "-"], capture_output=True, text=True,
                         timeout=60, check=True)
    return out.stdout


def ocr_status(png: Path) -> str:
    """Text of the status panel (top right), enlarged 2x: tesseract reads the small digits
    of its "Newest frame" time far more reliably than in the whole screenshot."""
    import cv2

    img = _read_png(png)
    h, w = img.shape
    panel = img[int(0.09 * h):int(0.55 * h), int(0.6 * w):]
    big = png.with_name(png.stem + "-status.png")
    cv2.imwrite(str(big), cv2.resize(panel, None, fx=2.0, fy=2.0,
                                     interpolation=cv2.INTER_CUBIC))
    return ocr(big)


def latency_s(text: str) -> float | None:
    """The viewer's own latency indicator ("12.3 s latency"), when it shows one."""
    m = re.search(r"(\d+(?:\.\d+)?)\s*(m?s)\s+latency", text)
    if m is None:
        return None
    return float(m.group(1)) / (1000.0 if m.group(2) == "ms" else 1.0)


def shown_frame_age_s(text: str, t_shot: float) -> float | None:
    """Seconds between taking the screenshot (UNIX ``t_shot``) and the capture time of the
    newest frame the status panel shows ("Newest frame: 21:40:13.4 UTC"), or None."""
    m = re.search(r"newest frame:?\s*(\d\d):(\d\d):(\d\d)[.,](\d)", text)
    if m is None:
        return None
    hh, mm, ss, tenth = (int(g) for g in m.groups())
    day = t_shot - t_shot % 86400
    shown = day + hh * 3600 + mm * 60 + ss + tenth / 10
    if shown > t_shot + 3600:  # the frame was captured before midnight UTC
        shown -= 86400
    return t_shot - shown


def test_operator_view_renders_in_chromium(tmp_path: Path, scene_cache: Path) -> None:
    from playwright.sync_api import sync_playwright

    assert Path(CHROMIUM).exists(), "install the Debian package chromium (tools/install.sh --dev)"
    assert shutil.which("tesseract"), "install the Debian package tesseract-ocr"
    web, grpc = free_port(), free_port()
    cmd = [sys.executable, "-m", "appliance", "run", "--duration", "300",
           "--record-dir", str(tmp_path / "rec"), "--live", "serve",
           "--set", f"live.web_port={web}", "--set", f"live.grpc_port={grpc}",
           *(a for k, v in SMALL_SCENE for a in ("--set", f"{k}={v}")),
           "--set", f"simulation.cache_dir={scene_cache}", "--log-level", "WARNING"]
    log_file = (tmp_path / "run.log").open("w")
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=log_file,
                            start_new_session=True)
    url = (f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy")
    shot = tmp_path / "live.png"
    text = ""
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            deadline = time.monotonic() + 180  # scene render + viewer start
            while True:
                try:
                    page.goto(url, timeout=10_000)
                    break
                except Exception:
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise
                    time.sleep(1.0)
            deadline = time.monotonic() + 180
            drawn = False
            while time.monotonic() < deadline and proc.poll() is None:
                time.sleep(2.0)
                screenshot(page, shot)
                text = ocr(shot).lower()
                img = np.asarray(_read_png(shot), np.float32)
                ir = img[100:650, 20:780]  # the IR picture's panel
                status = "no leak" in text or re.search(r"leak\s*-\s*for", text) is not None
                drawn = all(t in text for t in TITLES) and status and float(ir.std()) > 8.0
                if drawn:
                    break
            # What the operator sees is this old: capture -> processing -> status push (1 Hz)
            # -> viewer -> pixels. Read from the panel's "Newest frame" line a few times.
            ages: list[float] = []
            # Two readings show whether the age grows (each takes seconds: the viewer
            # draws under a frame per second in a browser without GPU).
            for _ in range(6 if drawn else 0):
                time.sleep(1.0)
                t_shot = time.time()
                screenshot(page, tmp_path / "age.png")
                age = shown_frame_age_s(ocr_status(tmp_path / "age.png").lower(), t_shot)
                if age is not None:
                    ages.append(age)
                if len(ages) >= 2:
                    break
            # The web viewer ingests about 10 ms of data per rendered frame (rerun issue
            # 7678): its frame rate bounds how fast the shown time can advance.
            fps = page.evaluate(UI_FPS_JS) if drawn else None
            browser.close()
        if os.environ.get("OGIFLOW_SCREENSHOT"):
            shutil.copy(shot, os.environ["OGIFLOW_SCREENSHOT"])
        assert drawn, f"operator view not drawn within the deadline; OCR text: {text[:600]!r}"
        print(f"viewer latency indicator: {latency_s(text)} s; age of the newest frame on "
              f"screen (capture to pixels): {[round(a, 1) for a in ages]} s; the viewer drew "
              f"{fps and round(fps, 2)} frames/s")
        assert ages, "the status panel's 'Newest frame' time was not readable"
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
        log_file.close()
    assert code == 0, (tmp_path / "run.log").read_text()[-2000:]


def _read_png(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"could not read {path}"
    return img


def test_shown_frame_age_reads_the_status_line() -> None:
    import datetime as dt

    from appliance.live.status import OperatorStatus, status_markdown

    t = dt.datetime(2026, 11, 29, 21, 40, 13, 400_000, tzinfo=dt.timezone.utc).timestamp()
    panel = status_markdown(OperatorStatus(t_capture_ns=int(t * 1e9),
                                           newest_result_ns=int(t * 1e9)))
    assert "Newest frame: 21:40:13.4 UTC" in panel
    assert abs(shown_frame_age_s(panel.lower(), t + 1.5) - 1.5) < 1e-6
    assert shown_frame_age_s("no time here", t) is None
    midnight = dt.datetime(2026, 11, 30, 0, 0, 1, tzinfo=dt.timezone.utc).timestamp()
    assert abs(shown_frame_age_s("newest frame: 23:59:59.0 utc", midnight) - 2.0) < 1e-6
