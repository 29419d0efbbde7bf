"""The stereo cameras of a synthetic scene: from a frame's gas columns to raw counts.

Rendering is split in two so that one fluid simulation serves many camera conditions:
:class:`GasFrame` holds what the fluid step and the ray marching produce (the column
densities seen by both cameras and the left camera's ground truth, no camera effect at all);
:class:`StereoRenderer` turns it into the raw frames of one set of camera effects
(background, noise, jitter, radiometric mismatch, a moving object). The robustness
evaluation renders each cached :class:`GasFrame` under every condition of its matrix.

Jitter is rendered as a physical shift of the detector: the background (an analytic
function of the ray direction) is evaluated along the shifted rays, and the gas's
transmittance, smooth at the pixel scale, is shifted bilinearly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from processing.synthetic.config import SequenceConfig
from processing.synthetic.imaging import (
    CountsModel,
    background_radiance,
    band_radiance_derivative,
    radiance_image,
    shift_image,
    to_counts,
)
from processing.synthetic.render import GroundTruth, ray_directions
from processing.synthetic.storage import SyntheticFrame


@dataclass(frozen=True)
class GasFrame:
    """One frame's gas before any camera effect.

    Attributes
    ----------
    index : int
    t_s : float
        Frame time, s.
    column_left, column_right : ndarray, shape (H, W), float64
        Column density along each camera's rays, ppm*m.
    truth : GroundTruth
        The left camera's ground truth (V*, P*, mask, column density).
    """

    index: int
    t_s: float
    column_left: np.ndarray
    column_right: np.ndarray
    truth: GroundTruth


class StereoRenderer:
    """Raw stereo frames of :class:`GasFrame` s under one configuration's camera effects.

    Parameters
    ----------
    config : SequenceConfig
        Camera, radiometry, background, counts models and options.
    rng : numpy.random.Generator, optional
        Noise and jitter draws; default the config's own stream ``[seed, 1]``, so a
        sequence is reproducible from its config.
    """

    def __init__(self, config: SequenceConfig, rng: np.random.Generator | None = None):
        config.validate()
        self.config = config
        self.camera = config.effective_camera()
        self.counts_left, self.counts_right = config.effective_counts()
        self.dirs = ray_directions(self.camera)
        self.rng = rng if rng is not None else np.random.default_rng([config.seed, 1])

    def _camera(self, column_ppm_m: np.ndarray, camera_x_m: float, t_s: float,
                model: CountsModel) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        opts, rad = cfg.options, cfg.radiometry
        shift = np.zeros(2)
        dirs, column = self.dirs, column_ppm_m
        if opts.jitter_px > 0:
            shift = self.rng.normal(0.0, opts.jitter_px, 2)
            s = (float(shift[0]), float(shift[1]))
            dirs = ray_directions(self.camera, s)
            column = shift_image(column_ppm_m, s)
        bg = background_radiance(self.camera, rad, dirs, camera_x_m, t_s, opts.moving_object,
                                 cfg.background)
        img = radiance_image(column, bg, rad)
        if opts.noise_netd_k > 0:
            sigma = band_radiance_derivative(rad.t_bg_k, rad.band_um) * opts.noise_netd_k
            img = img + self.rng.normal(0.0, sigma, img.shape)
        return to_counts(img, model), shift

    def render(self, gas: GasFrame) -> SyntheticFrame:
        """Raw left and right counts of one frame, with the ground truth and the jitter drawn."""
        left, jl = self._camera(gas.column_left, 0.0, gas.t_s, self.counts_left)
        right, jr = self._camera(gas.column_right, self.camera.b_m, gas.t_s, self.counts_right)
        gt = gas.truth
        return SyntheticFrame(
            index=gas.index, t_s=gas.t_s, left=left, right=right,
            gt_velocity=gt.velocity, gt_position=gt.position, gt_mask=gt.mask,
            column_density_ppm_m=gt.column_density_ppm_m,
            jitter_left_px=jl, jitter_right_px=jr,
            flux_moment_kg_s=gt.flux_moment_kg_s, release_rate_g_s=gt.release_rate_g_s,
        )
