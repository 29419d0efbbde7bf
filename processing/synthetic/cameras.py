"""The stereo cameras of a synthetic scene: from a frame's gas columns to raw counts.

Rendering is split in two so that one fluid simulation serves many camera conditions:
:class:`GasFrame` holds what the fluid step and the ray marching produce (the column
densities seen by both cameras and the left camera's ground truth, no camera effect at all);
:class:`StereoRenderer` turns it into the raw frames of one set of camera effects
(background, noise, jitter, radiometric mismatch, a moving object). The robustness
evaluation renders each cached :class:`GasFrame` under every condition of its matrix.

Jitter is rendered as a physical shift of the detector: the background (an analytic
function of the ray direction) is evaluated along the shifted rays, and the gas's column,
smooth at the pixel scale, is shifted by a spline (:func:`shift_image`).

A detector pixel integrates the radiance over its area. A textured background (the plant
wall's pipes and flanges, a moving object's rim) has edges far sharper than a pixel, so it
is rendered as the mean of ``PIXEL_SAMPLES`` x ``PIXEL_SAMPLES`` rays spread over the pixel,
not one ray through its centre. With one ray the wall aliased, differently at every
sub-pixel jitter: a frame jittered by (0.5, 0.3) px and moved back differs from the still
one by 6.6e-6 W m^-2 sr^-1 RMS after a 2 px Gaussian (what the chain's smoothing keeps),
3.2e-6 with 2 x 2 rays, 1.5e-6 with 3 x 3 (and 4 x 4). On the robustness matrix's in-plane
scene the image flow under 0.3 px jitter read 0.147 px per frame short with one ray, 0.102
with 2 x 2 (0.076 without jitter), and V_Z under noise and jitter +0.32 m/s for 0, +0.19
with 2 x 2 (measured). 2 x 2 costs four background evaluations per frame (57 ms
each at 320 x 240), 3 x 3 nine. Uniform and sky backgrounds are smooth and keep one ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from processing.synthetic.config import SequenceConfig
from processing.synthetic.imaging import (
    Background,
    CountsModel,
    MovingObject,
    Radiometry,
    background_radiance,
    band_radiance_derivative,
    radiance_image,
    shift_image,
    to_counts,
)
from processing.synthetic.render import GroundTruth, StereoCamera, ray_directions
from processing.synthetic.storage import SyntheticFrame

#: Rays per pixel side for a textured background (module docstring).
PIXEL_SAMPLES = 2


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


def pixel_mean_background(camera: StereoCamera, radiometry: Radiometry,
                          shift: tuple[float, float], camera_x_m: float, t_s: float,
                          moving_object: MovingObject | None, background: Background | None,
                          n: int, centre_dirs: np.ndarray | None = None) -> np.ndarray:
    """Background radiance averaged over ``n`` x ``n`` rays spread over each pixel of a
    detector shifted by ``shift`` px (module docstring), (H, W) W m^-2 sr^-1; n = 1: the
    centre ray. ``centre_dirs``: the unshifted detector's ray directions, if at hand."""
    total = np.zeros((camera.height, camera.width))
    for i in range(n):
        for j in range(n):
            sub = (shift[0] + (i + 0.5) / n - 0.5, shift[1] + (j + 0.5) / n - 0.5)
            dirs = (centre_dirs if sub == (0.0, 0.0) and centre_dirs is not None
                    else ray_directions(camera, sub))
            total += background_radiance(camera, radiometry, dirs, camera_x_m, t_s,
                                         moving_object, background)
    return total / (n * n)


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
        column = column_ppm_m
        if opts.jitter_px > 0:
            shift = self.rng.normal(0.0, opts.jitter_px, 2)
            column = shift_image(column_ppm_m, (float(shift[0]), float(shift[1])))
        textured = (opts.moving_object is not None
                    or (cfg.background is not None and cfg.background.kind == "plant"))
        bg = pixel_mean_background(self.camera, rad, (float(shift[0]), float(shift[1])),
                                   camera_x_m, t_s, opts.moving_object, cfg.background,
                                   PIXEL_SAMPLES if textured else 1, centre_dirs=self.dirs)
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
