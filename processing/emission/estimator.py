"""The emission rate of a stream of chain results: one object per camera pair.

:class:`EmissionEstimator` holds the background model and does, per processed triple, what
the appliance, the replay and ``ogiflow eval emission`` all do: raw left counts ->
radiance (characteristic curve) -> column density (Eq. 1 with Lambert-Beer, against the
background model fed the chain's gas masks) -> kg/m^2 at the gas temperature -> curtains
downstream of the detected source -> stereo rate (3D velocity, per-pixel depth) and,
when a typed-in distance is given, the single-camera QOGI rate through the same curtains.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from processing.calibration.radiometric import (
    OGI_BAND_M,
    CharacteristicCurve,
    apply_characteristic_curve,
    band_radiance,
)
from processing.emission.column import FILL_SIGMA_PX, BackgroundModel, column_density
from processing.emission.curtains import Curtain, curtain_flux
from processing.emission.gas import METHANE, STANDARD_PRESSURE_PA, GasProperties, ppm_m_to_kg_m2
from processing.emission.placement import (
    EXCLUSION_PX,
    MARGIN_PX,
    MIN_PIXELS,
    Placement,
    place_curtains,
)
from processing.emission.rate import FrameRate, out_of_plane_deg, single_camera_velocity
from processing.preprocess.binning import bin_image
from processing.preprocess.offset import offset_step

#: Gas temperature when neither the configuration nor an anemometer gives one (15 degC).
DEFAULT_GAS_TEMPERATURE_K = 288.15
#: Image width the settings in px were measured at (the simulated field scene, s = 780 px).
TUNED_WIDTH_PX = 320


@dataclass(frozen=True)
class EmissionSettings:
    """What the rate needs beyond the chain's result.

    Attributes
    ----------
    gas : GasProperties
        Molar mass and band-averaged alpha (default methane; a gas-cell calibration's file).
    pressure_pa : float
        Ambient pressure, Pa.
    typed_distance_m : float or None
        The single-camera baseline's typed-in distance, m; None: no baseline.
    background_frames : int
        Frames the background model keeps.
    background_min_free : float
        Share of those frames in which a pixel must lie outside the gas (and its
        ``faint_gas_px`` margin) for its own temporal estimate; pixels under the plume more
        often take the spatial fill (:class:`processing.emission.column.BackgroundModel`).
        A pixel that a steady plume covers most of the time is, in its "free" frames,
        still under the plume's faint edge, which the segmentation misses: with 8 of 60
        frames (the former setting) the background absorbed that gas and the rate of a
        0.3-1 g/s release read 13 % low (measured, ``eval emission``); with half, -1 to
        -4 %. The cost: on a textured background those pixels get the spatial fill.
    faint_gas_px : int
        Pixels within this distance of the segmented gas whose column density stands out
        of the noise count as gas too (:func:`faint_gas`); 0: only the segmentation.
    faint_floor_ppm_m : float
        Least column density of such a pixel, ppm*m.
    background_margin_px : int
        Pixels within this distance of the segmented gas are not background samples. Twice
        ``faint_gas_px``: downstream, where a plume widens and fades, gas lies beyond the
        counted faint edge too, and with a 15 px margin the background took it: the column
        density on the outer curtains of a 0.3-1 g/s release read 25-40 % low (measured
        against the simulator's column, ``benchmarks/emission_decomposition.py``); with 30 px
        the rate moved from -3.5 / -7.6 % to +4.0 / +1.4 % (``eval emission``).
    pixel_scale : float
        Camera pixels per pixel of the 320x240 frames every setting in px was measured on
        (:data:`TUNED_WIDTH_PX`): the margins above, the spatial fill's scale and the
        curtains' placement grow by it, so that on a 640x480 camera of the same field of
        view (2) they keep covering the same part of the plume. The appliance sets it from
        the camera's width (``appliance.runtime.emission_setup``).
    """

    gas: GasProperties = METHANE
    pressure_pa: float = STANDARD_PRESSURE_PA
    typed_distance_m: float | None = None
    background_frames: int = 60
    background_min_free: float = 0.5
    faint_gas_px: int = 15
    faint_floor_ppm_m: float = 10.0
    background_margin_px: int = 30
    pixel_scale: float = 1.0

    def px(self, value: float) -> float:
        """A distance in px of the 320x240 frames, in this camera's px."""
        return value * self.pixel_scale


@dataclass(frozen=True)
class CurtainRates:
    """One triple's rates, per curtain on which the stereo flux is defined.

    Attributes
    ----------
    placement : Placement
    curtains : tuple of Curtain
        The curtains with a defined stereo flux.
    stereo_g_s, single_g_s : tuple of float
        Their stereo and single-camera rates, g/s (``single_g_s`` empty without a typed-in
        distance).
    out_of_plane_deg : float or None
        The gas's motion out of the image plane (:func:`processing.emission.rate.out_of_plane_deg`).
    """

    placement: Placement
    curtains: tuple[Curtain, ...]
    stereo_g_s: tuple[float, ...]
    single_g_s: tuple[float, ...]
    out_of_plane_deg: float | None = None

    def stereo(self) -> FrameRate:
        """The stereo :class:`FrameRate` (mean over the curtains; None when there are none)."""
        return _frame_rate(self.stereo_g_s, self.placement, self.out_of_plane_deg)

    def single(self) -> FrameRate:
        """The single-camera :class:`FrameRate`."""
        return _frame_rate(self.single_g_s, self.placement)


def _frame_rate(rates: tuple[float, ...], placement: Placement,
                out_of_plane: float | None = None) -> FrameRate:
    if rates:
        return FrameRate(float(np.mean(rates)), rates, "", out_of_plane)
    return FrameRate(None, (), placement.reason or "no valid velocity on the curtains")


class EmissionEstimator:
    """Per-triple emission rate of one camera pair (module docstring).

    Parameters
    ----------
    settings : EmissionSettings
    principal_point : (float, float)
        Rectified (x0, y0) of the left camera, px.
    camera_constant : float
        s, px.
    curve : CharacteristicCurve or None
        The left camera's characteristic curve (None: counts are radiance already).
    binning : int
        The chain works on k x k blocks (``ChainParameters.binning``): the radiance of a
        raw frame is binned likewise, and every field given to :meth:`rates` and the
        principal point and camera constant above are those of the blocks.
    """

    def __init__(self, settings: EmissionSettings, principal_point: tuple[float, float],
                 camera_constant: float, curve: CharacteristicCurve | None,
                 binning: int = 1) -> None:
        self.settings = settings
        self.binning = binning
        self.principal_point = (float(principal_point[0]), float(principal_point[1]))
        self.camera_constant = float(camera_constant)
        self.curve = curve
        self.band_m = curve.band_m if curve is not None else OGI_BAND_M
        if not 0.0 < settings.background_min_free <= 1.0:
            raise ValueError("background_min_free must be in (0, 1], got "
                             f"{settings.background_min_free!r}")
        min_free = max(1, math.ceil(settings.background_min_free * settings.background_frames))
        self.background = BackgroundModel(capacity=settings.background_frames,
                                          min_samples=min_free, refresh=5,
                                          fill_sigma_px=settings.px(FILL_SIGMA_PX))

    def column_kg_m2(self, counts: np.ndarray, gas_mask: np.ndarray,
                     gas_temperature_k: float) -> np.ndarray:
        """Mass column density of a raw left frame, kg/m^2, (H, W); updates the background.

        ``gas_mask`` (the chain's segmentation of this frame) keeps gas out of the
        background; ``gas_temperature_k`` is the gas's (ambient air's) temperature, K.
        """
        # the curve on each pixel's counts, then the blocks' means: radiance is what adds up
        radiance = bin_image(apply_characteristic_curve(np.asarray(counts), self.curve),
                             self.binning)
        # The segmentation misses faint plume edges: keep a margin around it out of the
        # background too (filled spatially from farther away when needed).
        margin = round(self.settings.px(self.settings.background_margin_px))
        keep_out = (grow_mask(gas_mask, margin)
                    if margin > 0 and np.any(gas_mask) else gas_mask)
        # Levelled onto the background: a flat-field shutter or a drift of the camera's
        # offset moves the whole picture, and the background's median takes 30-90 frames to
        # follow (measured: a 0.17 K step of the left camera read the rate 5-7 % low for the
        # 30 triples after it, simulated r3_inplane_5m).
        previous = self.background.estimate()
        if previous is not None and previous.shape == radiance.shape:
            level = float(np.abs(previous[::2, ::2]).mean())
            step = offset_step(radiance - previous, level, ~keep_out)
            if step:
                radiance = radiance - np.float32(step)
        self.background.update(radiance, keep_out)
        l_gas = float(band_radiance(gas_temperature_k, self.band_m))
        cd = column_density(radiance, self.background.estimate(), l_gas,
                            self.settings.gas.alpha_per_ppm_m)
        return np.asarray(ppm_m_to_kg_m2(cd.ppm_m.astype(np.float64),
                                         molar_mass_kg_mol=self.settings.gas.molar_mass_kg_mol,
                                         temperature_k=gas_temperature_k,
                                         pressure_pa=self.settings.pressure_pa))

    def faint_mask(self, sigma_kg_m2: np.ndarray, gas_mask: np.ndarray) -> np.ndarray | None:
        """The faint plume edge the segmentation missed (:func:`faint_gas` with the
        settings), (H, W) bool; None when ``faint_gas_px`` is 0 or there is no gas."""
        if self.settings.faint_gas_px <= 0 or not gas_mask.any():
            return None
        floor = float(ppm_m_to_kg_m2(self.settings.faint_floor_ppm_m,
                                     molar_mass_kg_mol=self.settings.gas.molar_mass_kg_mol,
                                     temperature_k=288.15))
        return faint_gas(sigma_kg_m2, gas_mask, round(self.settings.px(self.settings.faint_gas_px)),
                         floor)

    def rates(self, sigma_kg_m2: np.ndarray, *, flow: np.ndarray, velocity: np.ndarray,
              depth: np.ndarray, valid: np.ndarray, gas_mask: np.ndarray,
              dt_s: float) -> CurtainRates:
        """Stereo and single-camera rates of one triple through curtains downstream of the
        detected source (shapes and units as in
        :func:`processing.emission.curtains.curtain_flux`; ``flow`` in px per ``dt_s``)."""
        pp, s = self.principal_point, self.camera_constant
        faint = self.faint_mask(sigma_kg_m2, gas_mask)
        # The curtains cut the whole plume, faint edges included.
        # the placement's defaults in px are those of 320x240 frames (an area: twice)
        es = self.settings
        placement = place_curtains(gas_mask if faint is None else gas_mask | faint, flow,
                                   exclusion_px=es.px(EXCLUSION_PX),
                                   margin_px=es.px(MARGIN_PX),
                                   min_pixels=round(es.px(es.px(MIN_PIXELS))))
        z_typed = self.settings.typed_distance_m
        single_v = (single_camera_velocity(flow, z_typed, s, dt_s) if z_typed else None)
        z_single = np.full(gas_mask.shape, z_typed or 0.0)
        flow_ok = (np.isfinite(flow[..., 0]) & np.isfinite(flow[..., 1])
                   if single_v is not None else None)
        curtains, st, sc = [], [], []
        for c in placement.curtains:
            f = curtain_flux(c, sigma_kg_m2, velocity, depth, valid, gas_mask,
                             principal_point=pp, camera_constant=s, column_mask=faint)
            if not f.defined:
                continue
            curtains.append(c)
            st.append(f.rate_kg_s * 1e3)
            if single_v is not None:
                g = curtain_flux(c, sigma_kg_m2, single_v, z_single, flow_ok, gas_mask,
                                 principal_point=pp, camera_constant=s, column_mask=faint)
                sc.append(g.rate_kg_s * 1e3)
        angle = (out_of_plane_deg(sigma_kg_m2, velocity, valid, gas_mask, principal_point=pp,
                                  camera_constant=s) if curtains else None)
        return CurtainRates(placement, tuple(curtains), tuple(st), tuple(sc), angle)

    def frame_rate(self, counts: np.ndarray, *, flow: np.ndarray, velocity: np.ndarray,
                   depth: np.ndarray, valid: np.ndarray, gas_mask: np.ndarray, dt_s: float,
                   gas_temperature_k: float) -> FrameRate:
        """The stereo rate of one triple from its raw left frame (the appliance's path)."""
        sigma = self.column_kg_m2(counts, gas_mask, gas_temperature_k)
        return self.rates(sigma, flow=flow, velocity=velocity, depth=depth, valid=valid,
                          gas_mask=gas_mask, dt_s=dt_s).stereo()


def faint_gas(sigma_kg_m2: np.ndarray, gas_mask: np.ndarray, distance_px: int,
              floor_kg_m2: float) -> np.ndarray:
    """Pixels near the segmented gas whose column density is gas, not noise.

    The motion segmentation (Eq. 9) needs contrast in the differential images, so it misses
    the faint edges of a plume, which carry a share of the flux that grows as the release
    falls (measured: half of it at 0.3 g/s). The column density sees them. A pixel counts
    when it lies within ``distance_px`` of the segmented gas and its sigma exceeds both
    ``floor_kg_m2`` and twice the 95th percentile of sigma far from the gas (the noise).

    Returns
    -------
    ndarray, shape (H, W), bool
    """
    near = grow_mask(gas_mask, distance_px)
    far = ~grow_mask(near, distance_px)
    noise = float(np.percentile(sigma_kg_m2[far], 95)) if far.any() else 0.0
    return near & ~gas_mask & (sigma_kg_m2 > max(floor_kg_m2, 2.0 * noise))


#: The 4-neighbourhood: ``steps`` dilations by it reach every pixel within L1 distance.
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def grow_mask(mask: np.ndarray, steps: int) -> np.ndarray:
    """The pixels within ``steps`` 4-neighbour steps of ``mask`` (H, W) bool, nothing from
    beyond the image's edge: ``scipy.ndimage.binary_dilation(mask, iterations=steps)`` to
    the bit, by OpenCV (a sixth of its time at 320 x 240, measured; three of these ran in
    every emission rate)."""
    ones = np.ascontiguousarray(mask, bool)
    if steps < 1:
        return ones.copy()
    # bool and uint8 share their bytes (0/1), and a dilation of 0/1 stays 0/1
    grown = cv2.dilate(ones.view(np.uint8), _CROSS, iterations=steps,
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return grown.view(bool)
