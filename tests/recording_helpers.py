"""Small appliance recordings for replay/reprocess tests, written directly (no daemon).

A warm gas-like blob drifts right in front of a flat background, seen by two ideal,
rectified cameras (the right view shifted by a fixed disparity), at 30 Hz with a little
arrival jitter and a 20 Hz anemometer. Images are 64x48 so the chain takes milliseconds;
the file carries the same metadata records as the appliance writes (config, geometry,
processing), so replay and reprocess read it like a real recording.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from appliance.config import load_config
from appliance.recording.metadata import file_metadata, processing_metadata
from appliance.recording.schemas import WIND_SAMPLE, MessageSchema, encode_json
from appliance.reprocess.sink import McapSink
from drivers.camera.base import Frame
from drivers.camera.mcap_format import frame_to_messages
from processing.chain import ChainParameters, StereoGeometry

W, H = 64, 48
DISPARITY_PX = 4.0
PERIOD_NS = 33_333_333
#: Fast chain settings for the tiny frames (d0 start, no SGM, no registration).
PARAMS = ChainParameters(disparity_init="d0", d0=DISPARITY_PX, register=False,
                         denoise_lambda=0.0)
GEOMETRY = StereoGeometry(camera_constant=60.0, principal_point=(W / 2, H / 2), baseline=0.3,
                          image_size=(W, H))


def _image(i: int, shift_px: float, rng: np.random.Generator) -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    cx, cy = 20.0 + 0.5 * i - shift_px, 24.0 + 0.1 * i
    blob = np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 6.0**2))
    ripple = 0.3 * np.sin(0.6 * (x - 0.5 * i - shift_px)) * blob
    img = 20000 + 3000 * (blob + ripple) + rng.normal(0, 15, (H, W))
    return np.clip(img, 0, 65535).astype(np.uint16)


def write_recording(path: Path, n_frames: int, *, seed: int = 0,
                    host: str | None = None, right_stall: range | None = None) -> Path:
    """Write a finished recording of ``n_frames`` per camera to ``path``; returns it.

    ``right_stall``: the right camera's thread stalls over these frames (a busy machine) and
    delivers them all at once with the frame after the stall - late in arrival and in file
    order, as the recorder receives them; the cameras then carry device clocks (as GigE
    Vision cameras do), which is what lets the clock model place a late frame.
    """
    cfg = load_config(None, [])
    meta = file_metadata(cfg, None)
    meta.update(processing_metadata(GEOMETRY, PARAMS))
    meta["recording"] = {"host": host or f"test-appliance-{seed}"}
    sink = McapSink(path, meta, chunk_size=64 * 1024)  # small files, several chunks
    rng = np.random.default_rng(seed)
    wall0 = 1_700_000_000_000_000_000 + seed * 10**12
    mono0 = 5_000_000_000
    schemas: dict[str, MessageSchema] = {}
    next_wind = 0
    held: list[tuple[int, Frame]] = []
    for i in range(n_frames):
        t = mono0 + i * PERIOD_NS
        while mono0 + next_wind * 50_000_000 <= t:  # 20 Hz anemometer
            tw = mono0 + next_wind * 50_000_000
            sample = {"t_mono_ns": tw, "t_wall_ns": tw - mono0 + wall0, "t_device": None,
                      "sensor": "gill", "u": 1.5, "v": 0.1 * np.sin(next_wind / 7), "w": 0.2,
                      "speed_of_sound_m_s": 340.0, "sonic_temperature_c": 15.0, "status": 0,
                      "valid": True}
            sink.record("/wind/raw", WIND_SAMPLE, encode_json(WIND_SAMPLE, sample),
                        sample["t_wall_ns"], tw)
            next_wind += 1
        for side, offset_ns, shift in (("left", 0, 0.0), ("right", 900_000, DISPARITY_PX)):
            host_ns = t + offset_ns + int(rng.integers(0, 2_000_000))
            frame = Frame(image=_image(i, shift, rng), pixel_format="Mono16", host_ns=host_ns,
                          seq=i, device_ts_ns=None if right_stall is None else t + offset_ns,
                          device_frame_id=None if right_stall is None else i)
            if side == "right" and right_stall is not None and i in right_stall:
                held.append((i, frame))
                continue
            if side == "right":
                for late_i, late in held:  # the stalled thread catches up, in order
                    late = dataclasses.replace(late, host_ns=host_ns - (i - late_i))
                    _record_frame(sink, schemas, side, late, late.host_ns - mono0 + wall0)
                held.clear()
            _record_frame(sink, schemas, side, frame, host_ns - mono0 + wall0)
    return sink.close()


def _record_frame(sink: McapSink, schemas: dict[str, MessageSchema], side: str, frame: Frame,
                  wall_ns: int) -> None:
    for m in frame_to_messages(side, frame, wall_ns):
        schema = schemas.setdefault(m.schema_name, MessageSchema(
            m.schema_name, m.schema_encoding, m.schema_data, m.message_encoding))
        sink.record(m.topic, schema, m.data, m.log_time, m.publish_time)


def cut_recording(src: Path, dst: Path, keep_fraction: float) -> Path:
    """A copy of ``src`` cut like kill -9 would leave it: no summary, a torn last chunk."""
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * keep_fraction)])
    os.sync()
    return dst


def _default_sigint() -> None:
    """In the child before exec: Ctrl-C as in a shell. A child inherits an ignored or
    blocked SIGINT from the test process (libraries loaded by earlier tests may set either
    at the C level), and Python then never raises KeyboardInterrupt: the full suite saw
    children finish their work with the interrupt ignored, alone they passed."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt_cli(args: Sequence[str], ready: Callable[[str], bool], *, after_s: float = 0.0,
                  timeout_s: float = 120.0) -> tuple[int, str]:
    """Run ``python -m appliance ARGS`` from this checkout, Ctrl-C it once ``ready(output)``.

    ``ready`` gets the combined output so far (a condition on progress lines does not depend
    on how fast a loaded machine runs). Waits at most ``timeout_s`` for it, then ``after_s``
    more; returns the exit code and the combined output. The process is killed if it does
    not end.
    """
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.Popen([sys.executable, "-m", "appliance", *args], cwd=root, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=_default_sigint)
    lines: list[str] = []
    assert proc.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")),
                              daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not ready("".join(lines)):
            time.sleep(0.02)
        time.sleep(after_s)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        reader.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, "".join(lines)
