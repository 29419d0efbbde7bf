"""The simulated site: the gas scene of the simulated cameras, the simulated anemometer's
wind that blows it, and the simulator's ground truth.

The default configuration runs the appliance with two simulated cameras and a simulated
anemometer. The cameras show a synthetic plume (processing.synthetic, Stable Fluids with
the stereo OGI renderer) blown by the anemometer's mean wind expressed in the camera frame,
so the live view can show the measured gas velocity approaching the wind. Rendering runs at
a few frames per second on this class of machine, far below 30 Hz, and acquisition must not
steal the pipeline's CPU: the scene is rendered once per set of parameters into a cache
folder (``ogiflow-synthetic/1`` format) and the simulated cameras loop over it.

The ground truth of every frame is kept beside the images, so the daemon can put the
simulator's true mean gas velocity next to the measured one. :class:`SimulatedSite` bundles
all of this for the daemon.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import subprocess
import sys
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from appliance.config import CameraConfig, Config, ConfigError, SimulationConfig
from appliance.progress import ProgressBar
from drivers.camera.replay_folder import folder_frame_rate_hz
from processing.chain import ChainParameters
from processing.synthetic import read_frame, read_sequence_meta, write_sequence
from processing.synthetic.presets import (
    FIELD_FRAME_RATE_HZ,
    FIELD_IMAGE_SIZES,
    preset_field,
    preset_no_release,
)
from processing.synthetic.reference import triplet_reference
from processing.synthetic.schedule import ReleaseSchedule
from processing.synthetic.sequences import generate_sequence

log = logging.getLogger("ogiflow.simsite")

#: Bump when the way a scene is generated changes, so stale caches are not reused.
SCENE_VERSION = 2  # 2: time-correlated release, flux and release-rate truth
#: Mean wind of the simulated anemometer when the config gives none, in Gill axes (U toward
#: the north mark, V to its left, W up): with the default mounting (north mark along the
#: optical axis) this is 1.5 m/s to the camera's right and 0.3 m/s away from it, a wind the
#: stereo system sees mostly in the image plane, as in the paper's field test.
SIMULATED_MEAN_WIND = (0.3, -1.5, 0.0)
#: Wind that blows the simulated plume when the anemometer is real: 1.5 m/s to the right.
DEFAULT_SCENE_WIND = (1.5, 0.0, 0.0)


def cache_root(configured: Path | None) -> Path:
    """The folder holding cached scenes (config value, else the XDG cache directory)."""
    if configured is not None:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ogiflow"


def scene_key(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float]) -> str:
    """Stable short hash of everything that shapes the rendered scene."""
    params = {k: v for k, v in asdict(sim).items() if k != "cache_dir"}
    # keys added later stay out of the hash at their defaults: cached scenes stay valid
    if params.get("scene") == "leak":
        del params["scene"]
    if (params.get("width_px"), params.get("height_px")) == (320, 240):
        del params["width_px"], params["height_px"]
    if not params.get("release_schedule"):
        params.pop("release_schedule", None)
    params["wind_m_s"] = [round(float(w), 3) for w in wind_camera_m_s]
    params["version"] = SCENE_VERSION
    text = json.dumps(params, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


#: Voxel of the quick first scene shown while the configured one renders (first start), m.
PREVIEW_VOXEL_M = 0.12
#: Frames of the quick first scene's loop (2 s at 30 Hz).
PREVIEW_FRAMES = 60


def scene_folder(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float]) -> Path:
    """Cache folder of the scene for these parameters (rendered or not)."""
    return cache_root(sim.cache_dir) / f"field-{scene_key(sim, wind_camera_m_s)}"


def preview_of(sim: SimulationConfig) -> SimulationConfig | None:
    """The quick first scene of ``sim``: the same leak on a coarser grid and a shorter loop
    (about 20x less rendering than the default), or None when there is none to gain or it
    would not be the same experiment (a release schedule needs its whole loop; the
    no-release scene has no fluid to simulate and renders about 5x faster anyway)."""
    if sim.scene != "leak" or sim.release_schedule:
        return None
    if sim.voxel_m >= PREVIEW_VOXEL_M and sim.frames <= PREVIEW_FRAMES:
        return None
    return replace(sim, voxel_m=max(sim.voxel_m, PREVIEW_VOXEL_M),
                   frames=min(sim.frames, PREVIEW_FRAMES))


def render_in_background(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float]
                         ) -> subprocess.Popen[bytes]:
    """Render (and cache) the scene in a separate, lowest-priority process: the running
    appliance keeps its CPU, the next start finds the scene in the cache."""
    args = {"sim": {k: (None if v is None else str(v) if isinstance(v, Path) else v)
                    for k, v in asdict(sim).items()},
            "wind": list(wind_camera_m_s)}
    return subprocess.Popen(
        [sys.executable, "-m", "appliance.runtime.simsite", json.dumps(args)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def ensure_scene(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float],
                 *, quiet: bool = False) -> Path:
    """Return the folder of the scene for these parameters, rendering it if not cached.

    Parameters
    ----------
    sim : SimulationConfig
        Scene parameters from the configuration.
    wind_camera_m_s : (float, float, float)
        Mean wind in the left camera frame (X right, Y down, Z forward), m/s.
    quiet : bool
        Do not draw the progress bar on stderr.
    """
    root = cache_root(sim.cache_dir)
    folder = scene_folder(sim, wind_camera_m_s)
    if (folder / "meta.json").is_file():
        return folder
    config = scene_config(sim, wind_camera_m_s)
    if not quiet:
        sys.stderr.write(f"ogiflow: rendering the simulated gas scene once into {folder} "
                         "(cached for later runs)\n")
    root.mkdir(parents=True, exist_ok=True)
    progress = None if quiet else ProgressBar("rendering simulated scene", unit="frames")
    write_sequence(folder, config.meta(), generate_sequence(config, progress))
    return folder


def check_image_size(sim: SimulationConfig) -> tuple[int, int]:
    """(W, H) of the simulated cameras, px.

    Raises
    ------
    ConfigError
        When ``width_px`` and ``height_px`` are not a size the field scene renders (one
        field of view: 320x240 or 640x480); exit code 2, before any device opens.
    """


    size = (int(sim.width_px), int(sim.height_px))
    if size not in FIELD_IMAGE_SIZES:
        known = " or ".join(f"{w}x{h}" for w, h in FIELD_IMAGE_SIZES)
        raise ConfigError([f"simulation.height_px: {size[1]} does not go with width_px "
                           f"{size[0]}: the simulated cameras are {known} (one field of view)"])
    return size


def scene_config(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float]) -> Any:
    """The synthetic sequence (``SequenceConfig``) of the configured scene.

    ``leak``: the ``field`` preset, its release switched by ``release_schedule`` whose period
    is the loop. ``no_release``: the ``no_release`` preset with the walker's to-and-fro and
    the background drift both lasting one loop, so the looped scene has no jump (the drift's
    steepest slope stays that of the preset). Both at ``width_px`` x ``height_px``.
    """

    common = {"n_frames": sim.frames, "wind_m_s": tuple(float(w) for w in wind_camera_m_s),
              "b_m": sim.baseline_m, "distance_m": sim.distance_m, "seed": sim.seed,
              "voxel_m": sim.voxel_m, "image_size": check_image_size(sim)}
    loop_s = sim.frames / FIELD_FRAME_RATE_HZ
    if sim.scene == "no_release":
        return preset_no_release(walker_period_s=loop_s, drift_period_s=loop_s, **common)
    config = preset_field(release_rate_g_s=sim.release_rate_g_s, **common)
    if sim.release_schedule:
        config = replace(config, release_schedule=ReleaseSchedule.from_lists(
            sim.release_schedule, loop_s))
    return config


class SceneTruth:
    """Ground-truth mean gas velocity of every raw triple of a looped scene.

    ``mean_velocity(k0)`` is the simulator's mean 3D gas velocity (m/s, left camera frame)
    over the reference gas mask for the triple of source frames (k0, k0+1, k0+2), taken
    modulo the loop length; None when the triple wraps around the loop (its images jump
    from the last frame back to the first, so no physical motion corresponds to it) or
    when no pixel holds gas.
    """

    def __init__(self, folder: Path) -> None:
        meta = read_sequence_meta(folder)
        self.meta = meta
        self.n_frames = int(meta["n_frames"])
        self.camera = dict(meta["camera"])
        self.wind_m_s = tuple(float(w) for w in meta.get("wind_m_s", (0.0, 0.0, 0.0)))
        self.frame_interval_s = float(meta["frame_interval_s"])
        self.schedule = ReleaseSchedule.from_json(meta.get("release_schedule"))
        self._rate_g_s = float(meta.get("release_rate_g_s", 0.0))
        # Two frames at a time: a frame holds the scene's 3D fields, and the whole loop at
        # once takes 0.9 GB (320x240) or 3.3 GB (640x480) of the daemon's memory.
        self._means: list[np.ndarray | None] = []
        # The true release of every frame (scene version 2 on: it follows the schedule and
        # the fluctuation exactly), else the nominal one switched by the schedule.
        self.release_g_s: list[float] = []
        previous = None
        for i in range(self.n_frames):
            frame = read_frame(folder, i, meta)
            self.release_g_s.append(self._nominal_g_s(i) if frame.release_rate_g_s is None
                                    else frame.release_rate_g_s)
            if previous is not None:
                v, mask = triplet_reference(previous, frame)
                self._means.append(v[mask].astype(np.float64).mean(axis=0) if mask.any()
                                   else None)
            previous = frame
        self._means.append(None)  # frame n-1 starts a triple that wraps
        #: Mean true release rate over the loop, g/s (what the measured rate should reach).
        self.mean_release_g_s = float(np.mean(self.release_g_s))

    def _nominal_g_s(self, k: int) -> float:
        t = k * self.frame_interval_s
        return self._rate_g_s * (1.0 if self.schedule is None else
                                 self.schedule.rate_factor(t))

    def release_rate_g_s(self, k: int) -> float:
        """True release rate at scene frame ``k`` (looped), g/s: 0 while a scheduled
        release is off (gas released before may still be in view)."""
        return self.release_g_s[int(k) % self.n_frames]

    def mean_velocity(self, k0: int) -> np.ndarray | None:
        i = int(k0) % self.n_frames
        if i >= self.n_frames - 2:
            return None  # (n-2, n-1, 0) and (n-1, 0, 1) wrap around the loop
        return self._means[i]


class SimulatedSite:
    """Everything the default configuration simulates, for the daemon.

    The simulated cameras loop over one rendered scene whose plume is blown by the mean
    wind of the simulated anemometer (rotated into the camera frame by the site mounting),
    so the measured gas velocity can be compared with the anemometer and with the
    simulator's ground truth.

    Parameters
    ----------
    cfg : Config
        The validated configuration.
    rotation : ndarray, shape (3, 3)
        Anemometer-to-camera rotation of the site mounting.
    """

    def __init__(self, cfg: Config, rotation: np.ndarray) -> None:
        if self.renders_scene(cfg):
            check_image_size(cfg.simulation)  # a configuration error: before any device
        self.cfg = cfg
        self.wind_camera_m_s = self._scene_wind(rotation)
        self.folder: Path | None = None
        self.truth: SceneTruth | None = None
        self.background: subprocess.Popen[bytes] | None = None

    @staticmethod
    def renders_scene(cfg: Config) -> bool:
        """True when a simulated camera needs the rendered scene (no explicit source)."""
        return any(c is not None and c.backend == "simulated" and "source" not in c.options
                   for c in (cfg.cameras.left, cfg.cameras.right))

    def _scene_wind(self, rotation: np.ndarray) -> tuple[float, float, float]:
        a = self.cfg.anemometer
        if a.backend != "simulated":
            return DEFAULT_SCENE_WIND
        sensor = np.asarray(a.options.get("mean_wind", SIMULATED_MEAN_WIND), dtype=np.float64)
        v = rotation @ sensor
        return (float(v[0]), float(v[1]), float(v[2]))

    def prepare(self, *, full: bool = False) -> None:
        """Render (once; cached) the scene and load its ground truth, when needed.

        ``full``: render the configured scene now, in the foreground, never the preview
        (``ogiflow run --prepare``).

        On the first start (nothing cached) a leak scene without a schedule is first
        rendered as its quick preview (:func:`preview_of`, about 20x less work) and shown
        for this run, with the preview's own exact ground truth, while the configured
        scene renders in a background process for the next start.
        """
        if not self.renders_scene(self.cfg):
            return
        sim = self.cfg.simulation
        preview = preview_of(sim)
        if (preview is not None and not full
                and not (scene_folder(sim, self.wind_camera_m_s) / "meta.json").is_file()):
            log.warning("first start: showing a coarser %d-frame preview of the simulated "
                        "scene (%.2f m voxels) while the configured one renders in the "
                        "background for the next start", preview.frames, preview.voxel_m)
            self.folder = ensure_scene(preview, self.wind_camera_m_s)
            self.background = render_in_background(sim, self.wind_camera_m_s)
        else:
            self.folder = ensure_scene(sim, self.wind_camera_m_s)
        self.truth = SceneTruth(self.folder)

    def close(self) -> None:
        """Stop a background render still running (the next start renders again)."""
        if self.background is not None and self.background.poll() is None:
            self.background.terminate()
            try:
                self.background.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.background.kill()
                self.background.wait()
        self.background = None

    def chain_defaults(self, camera_constant_px: float, baseline_m: float) -> dict[str, object]:
        """Chain parameters the rendered scene needs (the config may override them).

        The leak scene has no jitter and a featureless background (the paper's ideal
        conditions): registration could only lock onto the gas. The minimum disparity d0 is
        that of twice the plume distance. Wider cameras than 320 px see the same scene with
        more pixels: the chain's settings in px (the SGM search range, hence the depth band;
        the depth gate's tolerance; the largest motion; the active region's margin) grow
        with the width, so they keep meaning the same metres and m/s.
        """
        if self.folder is None:
            return {}
        sim = self.cfg.simulation
        # the no-release scene's plant wall is textured and jittered: register on it
        out: dict[str, object] = {
            "register": sim.scene == "no_release",
            "d0": camera_constant_px * baseline_m / (2.0 * sim.distance_m)}
        k = check_image_size(sim)[0] // 320
        if k > 1:
            base = ChainParameters()
            out.update(sgm_num_disparities=k * base.sgm_num_disparities,
                       max_motion_px=k * base.max_motion_px,
                       region_margin_px=k * base.region_margin_px,
                       gate_tolerance_px=k * base.gate_tolerance_px)
        return out

    def shown_true_rate_g_s(self) -> float | None:
        """The true release rate shown beside the measured one (operator's status), g/s:
        0 for the no-release scene, the loop's mean otherwise; None for real cameras and
        for a scheduled release, which has no single true rate (the summaries carry it per
        frame) - none is shown rather than a wrong one."""
        if self.truth is None or self.cfg.simulation.release_schedule:
            return None
        if self.cfg.simulation.scene == "no_release":
            return 0.0
        return self.truth.mean_release_g_s

    def camera_options(self, side: str, cam: CameraConfig) -> dict[str, object]:
        """Options of a camera back end, with the simulated camera's site defaults."""
        options = dict(cam.options)
        if cam.backend == "replay_folder" and "fps" not in options:
            # a folder that says its own frame rate (labels.json) is served at it
            path = options.get("path")
            if path is None or folder_frame_rate_hz(path) is None:
                options["fps"] = cam.frame_rate_hz
        if cam.backend == "simulated":
            options.setdefault("side", side)
            options.setdefault("fps", cam.frame_rate_hz)
            if self.folder is not None:
                options.setdefault("source", str(self.folder))
            # The two cameras are not triggered together (paper Sec. 4.1).
            options.setdefault("phase_s", 0.0 if side == "left" else 0.004)
            options.setdefault("seed", 1 if side == "left" else 2)
        return options

    def anemometer_options(self) -> dict[str, object]:
        """Options of the anemometer back end, with the simulated anemometer's mean wind."""
        a = self.cfg.anemometer
        options = dict(a.options)
        if a.backend == "simulated":
            options.setdefault("mean_wind", SIMULATED_MEAN_WIND)
        return options

    def true_velocity(self, frame_id0: int | None, frame_id2: int | None) -> np.ndarray | None:
        """Ground-truth mean gas velocity (m/s, camera frame) of a raw triple.

        ``frame_id0``/``frame_id2`` are the scene frame numbers of the triple's first and
        last left frames; None when the triple is not three consecutive scene frames (a
        dropped frame) or there is no rendered scene.
        """
        if self.truth is None or frame_id0 is None or frame_id2 is None:
            return None
        if frame_id2 - frame_id0 != 2:
            return None
        return self.truth.mean_velocity(frame_id0)


if __name__ == "__main__":  # render_in_background's child process
    os.nice(19)
    _args = json.loads(sys.argv[1])
    _sim = dict(_args["sim"])
    if _sim.get("cache_dir") is not None:
        _sim["cache_dir"] = Path(_sim["cache_dir"])
    ensure_scene(SimulationConfig(**_sim), tuple(_args["wind"]), quiet=True)
