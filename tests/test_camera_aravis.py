"""Aravis back end against two of Aravis' own fake GigE Vision cameras.

Needs the Debian packages ``aravis-tools`` (``arv-fake-gv-camera-0.8``) and
``gir1.2-aravis-0.8`` plus PyGObject (the ``gige`` extra); ``tools/install.sh --dev``
installs them.

A fake camera binds the GigE Vision control port 3956 on one interface address, so two of
them need two addresses. The scenarios therefore run in a private network namespace
(``unshare -rn``: no privileges needed, host networking untouched, no clash with anything
else on port 3956) whose loopback gets a second address 127.0.0.2. Where namespaces are not
allowed (e.g. a default Docker container), they run in the host namespace on 127.0.0.1 and
another local interface address, if the machine has one. In them: two fake cameras stream
Mono16 320x240 at 30 Hz into two ``AravisCamera`` readers (one thread each), through the
clock model into the stereo pairer; then the right camera's process is killed and started
again, and the reader - never restarted - must deliver frames and pairs again.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.camera.gige_buffers import MAX_POP_DELAY_NS, arrival_mono_ns, frame_id_gap

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
    assert frame_id_gap(None, 5) == 0
    assert frame_id_gap(5, 6) == 0
    assert frame_id_gap(5, 9) == 3
    assert frame_id_gap(65535, 1) == 0  # GigE Vision 1.x ids skip 0
    assert frame_id_gap(65534, 2) == 2
    assert frame_id_gap(40000, 3) == 0  # device restarted


def test_arrival_time_moves_to_monotonic_clock_unless_the_wall_clock_stepped() -> None:
    assert arrival_mono_ns(9_000, 50_000, 10_000) == 49_000  # arrived 1 us before the pop
    assert arrival_mono_ns(11_000, 50_000, 10_000) == 50_000  # arrival after the pop: step
    assert arrival_mono_ns(0, 50_000, 2 * MAX_POP_DELAY_NS) == 50_000  # implausibly old


def _host_addresses() -> list[str]:
    """IPv4 addresses of the interfaces that are up, loopback first."""
    out = subprocess.run(["ip", "-4", "-o", "addr", "show", "up"], capture_output=True,
                         text=True).stdout  # fmt: skip
    addrs = [line.split()[3].split("/")[0] for line in out.splitlines() if " inet " in line]
    return sorted(set(addrs), key=lambda a: (not a.startswith("127."), a))


def _run_scenario(name: str, n_addresses: int, timeout: float = 90) -> dict:
    """Run ``_scenario_<name>`` in a private network namespace (or, failing that, on host
    addresses); return its JSON result."""
    missing = _aravis_missing()
    if missing:
        pytest.skip(missing)
    prefix = _netns_prefix()
    if prefix is not None:
        cmd = [*prefix, sys.executable, __file__, "--scenario", name, "--netns"]
    else:
        addrs = _host_addresses() if shutil.which("ip") else []
        if len(addrs) < n_addresses:
            pytest.skip(
                "cannot create a private network namespace (unshare -rn / unshare -n refused: "
                f"user namespaces disabled and not root) and the host has {len(addrs)} "
                f"interface address(es); the fake cameras need {n_addresses}"
            )
        cmd = [sys.executable, __file__, "--scenario", name, "--addresses",
               ",".join(addrs[:n_addresses])]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT, start_new_session=True,
    )  # fmt: skip
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the fake cameras too
        out, err = proc.communicate()
        pytest.fail(f"scenario {name} hung; stderr:\n{err[-3000:]}")
    assert proc.returncode == 0, err[-3000:]
    r = json.loads(out.strip().splitlines()[-1])
    print(json.dumps(r, indent=1))  # the figures, shown with pytest -s
    return r


def test_lost_packets_drop_incomplete_frames_and_count_them_as_lost() -> None:
    """A fake camera losing 0.1 % of its GVSP packets: incomplete frames are not delivered,
    and every missing frame id is reported in ``Frame.lost``."""
    r = _run_scenario("lossy", 1)
    assert r["frames"] >= 30
    assert r["lost"] >= 1  # at ~75 packets per frame, about 7 % of frames lose one
    assert r["frames"] + r["lost"] == r["id_span"]
    assert r["shapes"] == [[240, 320]]


def test_two_fake_gige_cameras_pair_and_recover_after_one_is_killed() -> None:
    r = _run_scenario("pair", 2)
    assert r["formats"] == ["Mono16"] and r["dtypes"] == ["uint16"]
    assert r["shapes"] == [[240, 320]]
    assert r["device_ts"] and r["frame_ids"]
    assert r["pairs_before"] >= 30
    assert r["right_disconnects"] >= 1 and r["right_reconnects"] >= 1
    assert r["right_frames_after_restart"] >= 30
    assert r["pairs_after"] >= 30  # pairing resumed with the restarted camera
    assert r["max_abs_residual_ms"] <= 1000 / 30 / 2
    assert r["left_disconnects"] == 0


def test_daemon_survives_a_fake_camera_killed_for_5_s() -> None:
    """The whole daemon on two fake GigE cameras; the right one's process is killed and
    started again 5 s later: the left camera and the recording go on, health names the
    outage, and the right camera's frames come back."""
    r = _run_scenario("daemon", 2, timeout=150)
    assert r["code"] == 0
    assert r["silent_seen"]
    assert r["frames_lost"]["left"] == 0 and r["left_during_outage"] > 100
    assert r["right_after"] >= 30 and r["recovery_s"] is not None
    assert r["recorded"]["left"] == r["frames"]["left"]
    assert r["recorded"]["right"] == r["frames"]["right"]


# --------------------------------------------------------------------------------------
# The scenario, run in the private network namespace by the test above.


_FAKES: list[subprocess.Popen] = []


def _start_fake(serial: str, ip: str, *extra: str) -> subprocess.Popen:
    import time

    p = subprocess.Popen([FAKE, "-s", serial, "-i", ip, *extra], stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)  # fmt: skip
    _FAKES.append(p)  # killed when the scenario ends, however it ends
    time.sleep(0.3)
    return p


def _addresses(n: int) -> list[str]:
    """The addresses the fake cameras listen on (namespace: set up lo with two)."""
    if "--netns" in sys.argv:
        subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
        if n > 1:
            subprocess.run(["ip", "addr", "add", "127.0.0.2/8", "dev", "lo"], check=True)
        return ["127.0.0.1", "127.0.0.2"][:n]
    return sys.argv[sys.argv.index("--addresses") + 1].split(",")[:n]


def _scenario_lossy() -> dict:
    import time

    from drivers.camera import CameraError, create_camera

    (ip,) = _addresses(1)
    fake = _start_fake("LOSSY", ip, "-r", "1")
    try:
        cam = create_camera("aravis", address=ip, width=320, height=240)
        ids, lost, shapes = [], 0, set()
        with cam:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:
                try:
                    f = cam.grab(1.0)
                except CameraError:
                    continue
                ids.append(f.device_frame_id)
                lost += f.lost if len(ids) > 1 else 0
                shapes.add(f.image.shape)
        return {"frames": len(ids), "lost": lost, "id_span": ids[-1] - ids[0] + 1,
                "shapes": [list(s) for s in shapes]}  # fmt: skip
    finally:
        fake.kill()
        fake.wait()


def _scenario_pair() -> dict:
    import queue
    import threading
    import time

    from appliance.runtime.clock import ClockModel
    from appliance.runtime.pairing import StereoPairer
    from drivers.camera import CameraError, create_camera

    ip_left, ip_right = _addresses(2)
    addrs = {"left": ("OGIL", ip_left), "right": ("OGIR", ip_right)}

    def start_fake(side: str) -> subprocess.Popen:
        return _start_fake(*addrs[side])

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

    threads = [threading.Thread(target=reader, args=(s,), daemon=True) for s in addrs]
    for t in threads:
        t.start()
    period = round(1e9 / 30)
    clocks = {s: ClockModel(nominal_period_ns=period) for s in addrs}
    pairer: StereoPairer = StereoPairer(period, max_delay_ns=150_000_000)
    out = {"formats": set(), "dtypes": set(), "shapes": set(), "device_ts": True, "frame_ids": True}
    phase = "before"
    counts = {"pairs_before": 0, "pairs_after": 0, "right_frames_after_restart": 0}
    t0 = time.monotonic()
    killed_at = restarted_at = first_after = None
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
            if first_after is None:
                first_after = time.monotonic()
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
        # from starting the new fake process to the first frame of it through the old reader
        "recovery_s": None if first_after is None else round(first_after - restarted_at, 2),
    }


def _scenario_daemon() -> dict:
    import tempfile
    import threading
    import time
    from collections import Counter

    from appliance.config import load_config
    from appliance.recording.reader import LogReader
    from appliance.recording.recorder import closed_files
    from appliance.runtime.daemon import Appliance
    from appliance.runtime.health import status_line
    from processing.calibration import ideal_calibration, save_calibration

    ip_left, ip_right = _addresses(2)
    fakes = {"left": _start_fake("OGIL", ip_left), "right": _start_fake("OGIR", ip_right)}
    tmp = Path(tempfile.mkdtemp(prefix="ogiflow-aravis-daemon-"))
    save_calibration(tmp / "stereo.yaml", ideal_calibration(400.0, 0.25))
    cam = {"pixel_format": "Mono16", "fps": 30.0, "width": 320, "height": 240}
    cfg = load_config(None, [
        ("cameras.left.backend", "aravis"), ("cameras.right.backend", "aravis"),
        ("cameras.left.options", {**cam, "serial": "OGIL", "label": "left"}),
        ("cameras.right.options", {**cam, "serial": "OGIR", "label": "right"}),
        ("calibration", str(tmp / "stereo.yaml")), ("recording.dir", str(tmp / "rec")),
        ("live.mode", "off"), ("processing.enabled", False), ("health.interval_s", 0.2),
        ("recording.split", False),
        ("simulation.cache_dir", str(tmp / "cache"))])
    app = Appliance(cfg, duration_s=120.0)
    c = app.counters
    out: dict = {"silent_seen": False, "recovery_s": None}

    def wait(cond: object, limit: float) -> bool:
        t_end = time.monotonic() + limit
        while not cond() and time.monotonic() < t_end:  # type: ignore[operator]
            time.sleep(0.02)
        return bool(cond())  # type: ignore[operator]

    def control() -> None:
        try:
            wait(lambda: c.pairs >= 60, 30)
            fakes["right"].send_signal(signal.SIGKILL)
            fakes["right"].wait()
            left0 = c.frames["left"]
            right0 = c.frames["right"]
            t_kill = time.monotonic()
            while time.monotonic() - t_kill < 5.0:
                out["silent_seen"] |= "cam/right SILENT" in status_line(app.health.snapshot())
                time.sleep(0.1)
            out["left_during_outage"] = c.frames["left"] - left0
            out["right_during_outage"] = c.frames["right"] - right0
            fakes["right"] = _start_fake("OGIR", ip_right)
            t_start = time.monotonic()
            right1 = c.frames["right"]
            if wait(lambda: c.frames["right"] > right1, 30):
                out["recovery_s"] = round(time.monotonic() - t_start, 2)
            wait(lambda: c.frames["right"] >= right1 + 30, 20)
            out["right_after"] = c.frames["right"] - right1
        finally:
            app.stop_event.set()

    threading.Thread(target=control, daemon=True).start()
    out["code"] = app.run()
    recorded: Counter = Counter()
    for path in closed_files(tmp / "rec"):
        recorded.update(t for t, *_ in LogReader(path))
    out["recorded"] = {s: recorded[f"/camera/{s}/image"] for s in ("left", "right")}
    out["frames"] = dict(c.frames)
    out["frames_lost"] = dict(c.frames_lost)
    out["reconnect_attempts"] = c.camera_reconnects
    out["unpaired"] = dict(c.unpaired)
    for p in fakes.values():
        p.kill()
        p.wait()
    shutil.rmtree(tmp, ignore_errors=True)
    return out


if __name__ == "__main__" and "--scenario" in sys.argv:
    import logging

    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)6.0f %(message)s")
    try:
        scenario = sys.argv[sys.argv.index("--scenario") + 1]
        print(json.dumps(globals()[f"_scenario_{scenario}"]()))
    finally:
        for fake in _FAKES:
            fake.kill()
            fake.wait()
