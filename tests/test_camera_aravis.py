"""Aravis back end against two of Aravis' own fake GigE Vision cameras (issue 6 acceptance).

Needs the Debian packages ``aravis-tools`` (``arv-fake-gv-camera-0.8``) and
``gir1.2-aravis-0.8`` plus PyGObject (the ``gige`` extra); ``tools/install.sh --dev``
installs them.

A fake camera binds the GigE Vision control port 3956 on one interface address, so two of
them need two addresses. The scenario therefore runs in a private network namespace
(``unshare -rn``: no privileges needed, host networking untouched, no clash with anything
else on port 3956) whose loopback gets a second address 127.0.0.2. In it: two fake cameras
stream Mono16 320x240 at 30 Hz into two ``AravisCamera`` readers (one thread each), through
the clock model into the stereo pairer; then the right camera's process is killed and
started again, and the reader - never restarted - must deliver frames and pairs again.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

FAKE = "arv-fake-gv-camera-0.8"
ROOT = Path(__file__).resolve().parents[1]


def _aravis_missing() -> str | None:
    if shutil.which(FAKE) is None:
        return f"{FAKE} not found: install the Debian package aravis-tools"
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # noqa: F401
    except (ImportError, ValueError) as exc:
        return f"Aravis typelib/PyGObject missing ({exc}): gir1.2-aravis-0.8 + pip 'ogiflow[gige]'"
    return None


def _netns_prefix() -> list[str] | None:
    """A command prefix that runs a program in a fresh network namespace, if one works."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return None
    for prefix in (["unshare", "-rn"], ["unshare", "-n"]):
        ok = subprocess.run([*prefix, "ip", "link", "set", "lo", "up"], capture_output=True)
        if ok.returncode == 0:
            return prefix
    return None


def test_frame_id_gap_handles_16_bit_wrap_and_restart() -> None:
    if _aravis_missing():
        pytest.skip(_aravis_missing())
    from drivers.camera.aravis import frame_id_gap

    assert frame_id_gap(None, 5) == 0
    assert frame_id_gap(5, 6) == 0
    assert frame_id_gap(5, 9) == 3
    assert frame_id_gap(65535, 1) == 0  # GigE Vision 1.x ids skip 0
    assert frame_id_gap(65534, 2) == 2
    assert frame_id_gap(40000, 3) == 0  # device restarted


def test_two_fake_gige_cameras_pair_and_recover_after_one_is_killed() -> None:
    missing = _aravis_missing()
    if missing:
        pytest.skip(missing)
    prefix = _netns_prefix()
    if prefix is None:
        pytest.skip(
            "cannot create a private network namespace (unshare -rn / unshare -n refused: user "
            "namespaces disabled and not root); two fake cameras need two loopback addresses"
        )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [*prefix, sys.executable, __file__, "--scenario"],
        capture_output=True,
        text=True,
        timeout=90,
        env=env,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    print(json.dumps(r, indent=1))  # the figures, shown with pytest -s
    assert r["formats"] == ["Mono16"] and r["dtypes"] == ["uint16"]
    assert r["shapes"] == [[240, 320]]
    assert r["device_ts"] and r["frame_ids"]
    assert r["pairs_before"] >= 30
    assert r["right_disconnects"] >= 1 and r["right_reconnects"] >= 1
    assert r["right_frames_after_restart"] >= 30
    assert r["pairs_after"] >= 30  # pairing resumed with the restarted camera
    assert r["max_abs_residual_ms"] <= 1000 / 30 / 2
    assert r["left_disconnects"] == 0


# --------------------------------------------------------------------------------------
# The scenario, run in the private network namespace by the test above.


def _scenario() -> dict:
    import queue
    import signal
    import threading
    import time

    from appliance.clock import ClockModel
    from appliance.pairing import StereoPairer
    from drivers.camera import CameraError, create_camera

    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    subprocess.run(["ip", "addr", "add", "127.0.0.2/8", "dev", "lo"], check=True)
    addrs = {"left": ("OGIL", "127.0.0.1"), "right": ("OGIR", "127.0.0.2")}

    def start_fake(side: str) -> subprocess.Popen:
        serial, ip = addrs[side]
        p = subprocess.Popen(
            [FAKE, "-s", serial, "-i", ip], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        time.sleep(0.3)
        return p

    fakes = {s: start_fake(s) for s in addrs}
    cams = {
        s: create_camera(
            "aravis",
            serial=addrs[s][0],
            pixel_format="Mono16",
            fps=30.0,
            width=320,
            height=240,
            reconnect_after_s=0.5,
            retry_interval_s=0.2,
            label=s,
        )
        for s in addrs
    }
    q: queue.Queue = queue.Queue()
    stop = threading.Event()

    def reader(side: str) -> None:
        cam = cams[side]
        cam.open()
        cam.start()
        while not stop.is_set():
            try:
                q.put((side, cam.grab(timeout=0.5)))
            except CameraError as exc:
                q.put((side, type(exc).__name__))
        cam.close()

    threads = [threading.Thread(target=reader, args=(s,)) for s in addrs]
    for t in threads:
        t.start()
    period = round(1e9 / 30)
    clocks = {s: ClockModel(nominal_period_ns=period) for s in addrs}
    pairer: StereoPairer = StereoPairer(period, max_delay_ns=150_000_000)
    out = {"formats": set(), "dtypes": set(), "shapes": set(), "device_ts": True, "frame_ids": True}
    phase = "before"
    counts = {"pairs_before": 0, "pairs_after": 0, "right_frames_after_restart": 0}
    t0 = time.monotonic()
    killed_at = restarted_at = None
    while time.monotonic() - t0 < 30:
        now = time.monotonic()
        if phase == "before" and counts["pairs_before"] >= 30:
            fakes["right"].send_signal(signal.SIGKILL)
            fakes["right"].wait()
            killed_at, phase = now, "killed"
        elif phase == "killed" and now - killed_at > 1.5:
            fakes["right"] = start_fake("right")
            restarted_at, phase = now, "after"
        if phase == "after" and counts["pairs_after"] >= 30:
            break
        try:
            side, item = q.get(timeout=0.1)
        except queue.Empty:
            pairer.poll(time.monotonic_ns())
            continue
        if isinstance(item, str):
            continue
        f = item
        out["formats"].add(f.pixel_format)
        out["dtypes"].add(str(f.image.dtype))
        out["shapes"].add(f.image.shape)
        out["device_ts"] &= f.device_ts_ns is not None
        out["frame_ids"] &= f.device_frame_id is not None
        if phase == "after" and side == "right":
            counts["right_frames_after_restart"] += 1
        t = clocks[side].update(f.host_ns, f.device_ts_ns, f.device_frame_id)
        pairs = pairer.push(side, t, f.seq, now_ns=time.monotonic_ns())
        key = "pairs_after" if phase == "after" else "pairs_before" if phase == "before" else None
        if key:
            counts[key] += len(pairs)
    stop.set()
    for t in threads:
        t.join(timeout=5)
    for p in fakes.values():
        p.kill()
        p.wait()
    return {
        "formats": sorted(out["formats"]),
        "dtypes": sorted(out["dtypes"]),
        "shapes": [list(s) for s in sorted(out["shapes"])],
        "device_ts": out["device_ts"],
        "frame_ids": out["frame_ids"],
        **counts,
        "right_disconnects": cams["right"].stats.disconnects,
        "right_reconnects": cams["right"].stats.reconnects,
        "left_disconnects": cams["left"].stats.disconnects,
        "frames": {s: cams[s].stats.frames for s in cams},
        "lost": {s: cams[s].stats.lost for s in cams},
        "unpaired": {"left": pairer.stats.unpaired_left, "right": pairer.stats.unpaired_right},
        "max_abs_residual_ms": pairer.stats.max_abs_residual_ns / 1e6,
        "recovery_s": None if restarted_at is None else round(time.monotonic() - restarted_at, 2),
    }


if __name__ == "__main__" and "--scenario" in sys.argv:
    import logging

    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)6.0f %(message)s")
    print(json.dumps(_scenario()))
