"""The gas scene of the simulated cameras: simulated once, cached on disk, looped.

The default configuration runs the appliance with two simulated cameras and a simulated
anemometer. The cameras show a synthetic plume (processing.synthetic, Stable Fluids with
the stereo OGI renderer) blown by the anemometer's mean wind expressed in the camera frame,
so the live view can show the measured gas velocity approaching the wind. Rendering runs at
a few frames per second on this class of machine, far below 30 Hz, and acquisition must not
steal the pipeline's CPU: the scene is rendered once per set of parameters into a cache
folder (``ogiflow-synthetic/1`` format) and the simulated cameras loop over it.

The ground truth of every frame is kept beside the images, so the daemon can put the
simulator's true mean gas velocity next to the measured one.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from appliance.config import SimulationConfig
from appliance.progress import ProgressBar
from processing.synthetic import read_frame, read_sequence_meta
from processing.synthetic.reference import triplet_reference

#: Bump when the way a scene is generated changes, so stale caches are not reused.
SCENE_VERSION = 1


def cache_root(configured: Path | None) -> Path:
    """The folder holding cached scenes (config value, else the XDG cache directory)."""
    if configured is not None:
        return Path(configured)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ogiflow"


def scene_key(sim: SimulationConfig, wind_camera_m_s: tuple[float, float, float]) -> str:
    """Stable short hash of everything that shapes the rendered scene."""
    params = {k: v for k, v in asdict(sim).items() if k != "cache_dir"}
    params["wind_m_s"] = [round(float(w), 3) for w in wind_camera_m_s]
    params["version"] = SCENE_VERSION
    text = json.dumps(params, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


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
    from processing.synthetic import write_sequence
    from processing.synthetic.sequences import generate_sequence, preset_field

    root = cache_root(sim.cache_dir)
    folder = root / f"field-{scene_key(sim, wind_camera_m_s)}"
    if (folder / "meta.json").is_file():
        return folder
    config = preset_field(
        n_frames=sim.frames,
        wind_m_s=tuple(float(w) for w in wind_camera_m_s),
        b_m=sim.baseline_m,
        distance_m=sim.distance_m,
        release_rate_g_s=sim.release_rate_g_s,
        seed=sim.seed,
        voxel_m=sim.voxel_m,
    )
    if not quiet:
        sys.stderr.write(f"ogiflow: rendering the simulated gas scene once into {folder} "
                         "(cached for later runs)\n")
    root.mkdir(parents=True, exist_ok=True)
    progress = None if quiet else ProgressBar("rendering simulated scene", unit="frames")
    write_sequence(folder, config.meta(), generate_sequence(config, progress))
    return folder


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
        self.n_frames = int(meta["n_frames"])
        self.camera = dict(meta["camera"])
        self.wind_m_s = tuple(float(w) for w in meta.get("wind_m_s", (0.0, 0.0, 0.0)))
        frames = [read_frame(folder, i, meta) for i in range(self.n_frames)]
        self._means: list[np.ndarray | None] = []
        for i in range(self.n_frames - 1):
            v, mask = triplet_reference(frames[i], frames[i + 1])
            self._means.append(v[mask].astype(np.float64).mean(axis=0) if mask.any() else None)
        self._means.append(None)  # frame n-1 starts a triple that wraps

    def mean_velocity(self, k0: int) -> np.ndarray | None:
        i = int(k0) % self.n_frames
        if i >= self.n_frames - 2:
            return None  # (n-2, n-1, 0) and (n-1, 0, 1) wrap around the loop
        return self._means[i]
