"""Configuration of a synthetic stereo OGI sequence: the scene, the cameras and their flaws.

A :class:`SequenceConfig` (with its seed) defines a sequence completely; :meth:`SequenceConfig.meta`
is the ``meta.json`` written beside the frames. :class:`RenderOptions` are the non-ideal camera
effects a real site adds (noise, jitter, radiometric mismatch, lens distortion, a moving object).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from processing.calibration import StereoCalibration
from processing.calibration.model import RadiometricCalibration, ideal_calibration
from processing.calibration.radiometric import CharacteristicCurve
from processing.synthetic.fluid import FluidParams
from processing.synthetic.imaging import Background, CountsModel, MovingObject, Radiometry
from processing.synthetic.render import StereoCamera
from processing.synthetic.schedule import ReleaseSchedule
from processing.synthetic.storage import FORMAT

#: Gain mismatch of the right camera that ``radiometric_mismatch=True`` stands for.
DEFAULT_GAIN_MISMATCH = 0.04
#: Offset mismatch (counts) of the right camera whenever a gain mismatch is simulated.
OFFSET_MISMATCH_COUNTS = 150.0


@dataclass(frozen=True)
class RenderOptions:
    """Non-ideal camera effects; all off by default (the paper's ideal conditions, Sec. 5.1).

    Parameters
    ----------
    noise_netd_k : float
        Temporal noise per pixel as a noise-equivalent temperature difference in K at the
        background temperature (Gaussian; e.g. 0.03), 0 = none.
    jitter_px : float
        Standard deviation of a random sub-pixel translation of each camera's frame, px.
    radiometric_mismatch : bool
        Give the right camera a 4 % higher gain and a 150-count higher offset.
    gain_mismatch : float
        Relative gain excess of the right camera (e.g. 0.02-0.08), with the same 150-count
        offset; overrides the 4 % of ``radiometric_mismatch`` when non-zero.
    lens_k1, lens_k2 : float
        Radial distortion of both lenses (see :class:`StereoCamera`).
    moving_object : MovingObject or None
        A disk of another temperature moving behind the gas.
    """

    noise_netd_k: float = 0.0
    jitter_px: float = 0.0
    radiometric_mismatch: bool = False
    gain_mismatch: float = 0.0
    lens_k1: float = 0.0
    lens_k2: float = 0.0
    moving_object: MovingObject | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad option."""
        if self.noise_netd_k < 0 or self.jitter_px < 0:
            raise ValueError("noise_netd_k and jitter_px must be >= 0")
        if not -0.5 < self.gain_mismatch < 0.5:
            raise ValueError(f"gain_mismatch must be within (-0.5, 0.5), got {self.gain_mismatch}")

    @property
    def effective_gain_mismatch(self) -> float:
        """The right camera's relative gain excess these options simulate (0 = matched)."""
        if self.gain_mismatch:
            return float(self.gain_mismatch)
        return DEFAULT_GAIN_MISMATCH if self.radiometric_mismatch else 0.0

    def to_json(self) -> dict[str, Any]:
        """JSON-able form for ``meta.json``."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class SequenceConfig:
    """Everything that defines a synthetic sequence (reproducible from this and the seed).

    Parameters
    ----------
    name : str
    fluid : FluidParams
        Recording-time fluid parameters (``dt_s`` is the step while recording).
    volume_origin_m : (3,)
        Corner of the grid in the left camera frame, m.
    n_frames : int
    substeps : int
        Fluid steps per frame (frame interval = ``substeps * fluid.dt_s``).
    spinup_steps : int
    spinup_dt_s : float
        Steps run before the first frame, with their own (possibly larger) step.
    seed : int
    camera, radiometry, background, counts_left, counts_right, options
        Rendering (see :mod:`processing.synthetic.render` and
        :mod:`processing.synthetic.imaging`).
    necl_ppm_m : float
        Detection limit for the ground-truth gas mask, ppm*m.
    release_schedule : ReleaseSchedule or None
        When the sources release (:mod:`processing.synthetic.schedule`); None = always.
    """

    name: str
    fluid: FluidParams
    volume_origin_m: tuple[float, float, float]
    n_frames: int = 11
    substeps: int = 1
    spinup_steps: int = 50
    spinup_dt_s: float = 0.002
    seed: int = 0
    camera: StereoCamera = field(default_factory=StereoCamera)
    radiometry: Radiometry = field(default_factory=Radiometry)
    background: Background = field(default_factory=Background)
    counts_left: CountsModel = field(default_factory=CountsModel)
    counts_right: CountsModel = field(default_factory=CountsModel)
    options: RenderOptions = field(default_factory=RenderOptions)
    necl_ppm_m: float = 100.0
    release_schedule: ReleaseSchedule | None = None

    @property
    def frame_interval_s(self) -> float:
        """Time between frames, s."""
        return self.substeps * self.fluid.dt_s

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        self.fluid.validate()
        self.camera.validate()
        self.options.validate()
        self.background.validate()
        if self.n_frames < 1 or self.substeps < 1 or self.spinup_steps < 0:
            raise ValueError("n_frames and substeps must be >= 1, spinup_steps >= 0")
        if not self.spinup_dt_s > 0:
            raise ValueError("spinup_dt_s must be > 0")
        if self.release_schedule is not None:
            self.release_schedule.validate()
        if self.volume_origin_m[2] <= 0:
            raise ValueError("the volume must lie in front of the cameras (origin Z > 0)")

    def effective_camera(self) -> StereoCamera:
        """The camera with the options applied (lens distortion)."""
        opts = self.options
        return replace(self.camera, k1=opts.lens_k1 or self.camera.k1,
                       k2=opts.lens_k2 or self.camera.k2)

    def effective_counts(self) -> tuple[CountsModel, CountsModel]:
        """(left, right) counts models with the options applied (radiometric mismatch)."""
        right = self.counts_right
        mismatch = self.options.effective_gain_mismatch
        if mismatch:
            right = CountsModel(gain=right.gain * (1.0 + mismatch),
                                offset=right.offset + OFFSET_MISMATCH_COUNTS)
        return self.counts_left, right

    def meta(self) -> dict[str, Any]:
        """The ``meta.json`` object of this sequence (format ``ogiflow-synthetic/1``); camera
        and counts models are the effective ones (options applied)."""
        cam = self.effective_camera()
        counts_left, counts_right = self.effective_counts()
        fl = self.fluid
        rad = self.radiometry
        return {
            "format": FORMAT,
            "name": self.name,
            "seed": int(self.seed),
            "n_frames": int(self.n_frames),
            "frame_interval_s": float(self.frame_interval_s),
            "camera": {
                "width": cam.width, "height": cam.height, "s_px": cam.s_px,
                "cx_px": cam.cx, "cy_px": cam.cy, "b_m": cam.b_m, "k1": cam.k1, "k2": cam.k2,
            },
            "counts_model": {
                "left": dataclasses.asdict(counts_left),
                "right": dataclasses.asdict(counts_right),
            },
            "radiometry": {
                "t_bg_k": rad.t_bg_k, "t_gas_k": rad.t_gas_k,
                "alpha_per_ppm_m": rad.alpha_per_ppm_m, "band_um": list(rad.band_um),
                "gas_density_kg_m3": rad.gas_density_kg_m3,
            },
            "necl_ppm_m": self.necl_ppm_m,
            "release_rate_g_s": float(sum(s.release_rate_g_s for s in fl.sources)),
            "release_schedule": (None if self.release_schedule is None
                                 else self.release_schedule.to_json()),
            "wind_m_s": [float(x) for x in fl.wind_m_s],
            "simulation": {
                "method": "stable fluids (Stam 1999), MAC grid, exact DST/DCT projection",
                "grid_zyx": list(fl.shape),
                "voxel_m": fl.voxel_m,
                "dt_s": fl.dt_s,
                "substeps_per_frame": self.substeps,
                "spinup_steps": self.spinup_steps,
                "spinup_dt_s": self.spinup_dt_s,
                "boundary": fl.boundary,
                "volume_origin_m": list(self.volume_origin_m),
                "concentration_unit": "kg/m^3",
                "sources": [dataclasses.asdict(s) for s in fl.sources],
            },
            "options": self.options.to_json(),
            "background": dataclasses.asdict(self.background),
            "ground_truth": (
                "gt_velocity[i]: velocity carrying frame i's gas to frame i+1, path-averaged "
                "and concentration-weighted along the left camera's rays (m/s, left frame)"
            ),
        }




def synthetic_calibration(config: SequenceConfig) -> StereoCalibration:
    """The calibration file a field system would have for this sequence's cameras.

    The ideal rectified geometry (s, b, principal point), the lens distortion of the
    options (OpenCV's k1, k2 follow the same radial model), and each camera's
    characteristic curve (its counts model: counts = offset + gain L), as a radiometric
    calibration against black bodies would measure it. ``ogiflow simulate`` writes it as
    ``calibration.yaml`` beside the frames, so a gain mismatch or a lens distortion can be
    evaluated both uncorrected and corrected.
    """
    cam = config.effective_camera()
    calib = ideal_calibration(cam.s_px, cam.b_m, (cam.width, cam.height), cam.cx, cam.cy)
    dist = np.array([cam.k1, cam.k2, 0.0, 0.0, 0.0])
    left, right = config.effective_counts()
    radio = RadiometricCalibration(
        left=CharacteristicCurve(offset=left.offset, gain=left.gain),
        right=CharacteristicCurve(offset=right.offset, gain=right.gain),
    )
    return replace(calib, D_left=dist, D_right=dist.copy(), radiometric=radio,
                   meta={"source": f"ogiflow simulate ({config.name}, seed {config.seed})"})
