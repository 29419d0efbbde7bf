"""The emission rate of the workers: its settings from the configuration, and one triple's rate.

:class:`EmissionSetup` is what a worker process needs to compute the rate (picklable, and
recorded as JSON so that replay uses the same); :func:`emission_setup` builds it from the
``emission`` section; :func:`emission_rate` is the stereo rate of one chain result.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from appliance.runtime.gas_temperature import (
    configured_gas_temperature_k,
    site_gas_temperature_k,
)
from processing.calibration.calfile import curve_from_dict, curve_to_dict
from processing.calibration.radiometric import CharacteristicCurve
from processing.chain.binning import binned_geometry
from processing.chain.driver import SceneFlowResult, StereoGeometry
from processing.emission.estimator import (
    TUNED_WIDTH_PX,
    EmissionEstimator,
    EmissionSettings,
)
from processing.emission.gas import METHANE, GasProperties, load_gas
from processing.emission.rate import FrameRate


@dataclass(frozen=True)
class EmissionSetup:
    """What a worker needs for the emission rate (picklable).

    ``gas_temperature_k`` None: the anemometer's sonic temperature, shared by the daemon
    through a ``multiprocessing.Value`` (NaN until the first sample). ``curve_left``: the
    left camera's characteristic curve when the geometry has none (the simulated site's
    known counts model); without any, counts are not radiance and there is no rate.
    """

    settings: EmissionSettings
    gas_temperature_k: float | None = None
    curve_left: CharacteristicCurve | None = None
    every: int = 1  # a rate on every this many triples of a worker (config emission.every)

    def to_json(self) -> str:
        """The setup as JSON (the recording's ``emission`` metadata, so replay uses it)."""
        st = self.settings
        curve = self.curve_left
        return json.dumps({
            "gas": dataclasses.asdict(st.gas), "pressure_pa": st.pressure_pa,
            "background_frames": st.background_frames,
            "gas_temperature_k": self.gas_temperature_k,
            "curve_left": None if curve is None else curve_to_dict(curve)})

    @classmethod
    def from_json(cls, text: str) -> EmissionSetup:
        """Inverse of :meth:`to_json` (ValueError on a malformed record)."""
        try:
            d = json.loads(text)
            curve = d.get("curve_left")
            return cls(EmissionSettings(gas=GasProperties(**d["gas"]),
                                        pressure_pa=float(d["pressure_pa"]),
                                        background_frames=int(d["background_frames"])),
                       None if d["gas_temperature_k"] is None
                       else float(d["gas_temperature_k"]),
                       None if curve is None else curve_from_dict(
                           curve, "curve_left", "the recording's emission metadata"))
        except (KeyError, TypeError, ValueError) as exc:  # JSONDecodeError is a ValueError
            raise ValueError(f"bad emission metadata: {exc}") from None

    def estimator(self, geometry: StereoGeometry, binning: int = 1) -> EmissionEstimator | None:
        """The estimator, or None without a radiometric calibration; with the chain's
        ``binning`` > 1 it works on the blocks the chain measured (the rate of a 640x480
        pair binned by 2 costs what that of a 320x240 pair does)."""
        curve = geometry.curve_left or self.curve_left
        if curve is None:
            return None
        geometry = binned_geometry(geometry, binning)
        # the settings in px were measured on 320x240 frames; a wider camera of the same
        # field of view sees the plume with more pixels (measured at 640x480 with them
        # unscaled: the rate read 15 % low, the background taking the plume's faint edges)
        settings = dataclasses.replace(
            self.settings, pixel_scale=geometry.image_size[0] / TUNED_WIDTH_PX)
        return EmissionEstimator(settings, geometry.principal_point,
                                 geometry.camera_constant, curve, binning)

    def temperature_k(self, sonic_k: Any = None) -> float:
        """The gas temperature now: configured, else the sonic one, else 15 degC
        (:func:`appliance.runtime.gas_temperature.site_gas_temperature_k`)."""
        return site_gas_temperature_k(self.gas_temperature_k, sonic_k)


#: The rate of a frame when the cameras have no radiometric calibration.
NO_RADIOMETRY = FrameRate(None, (), "no radiometric calibration (counts are not radiance)")


def emission_rate(estimator: EmissionEstimator, left_t1: np.ndarray, res: SceneFlowResult,
                  gas_temperature_k: float) -> FrameRate:
    """The stereo emission rate of one triple from the raw left frame at t1; a failure is a
    rate with its reason, never a lost result.

    ``res`` is the chain's result as it measured it: with the estimator's ``binning`` k > 1,
    on k x k blocks (``compute_scene_flow(..., at_camera_size=False)``), which is what the
    estimator works on.
    """
    if "implausible_speed" in res.summary.flags:
        return FrameRate(None, (), "implausible gas speed (not a measurement)")
    if "scene_change" in res.summary.flags:
        # The picture jumped (a bumped camera, a shutter, the simulated loop's wrap): the
        # gas mask and the velocities are the jump's. Measured at the simulated site: 27-29
        # g/s on the wrap's triples against 2.8 g/s released, +12 % on the 30 s rate. Nor
        # does the frame go into the background model.
        return FrameRate(None, (), "scene change: the picture jumped (not a measurement)")
    expected = tuple(n // estimator.binning for n in left_t1.shape)
    if res.gas_mask.shape != expected:
        raise ValueError(f"the emission rate of a chain binned by {estimator.binning} takes "
                         f"its {expected} block fields, got {res.gas_mask.shape}")
    try:
        return estimator.frame_rate(
            left_t1, flow=res.flow, velocity=res.velocity, depth=res.position[..., 2],
            valid=res.valid, gas_mask=res.gas_mask, dt_s=res.dt_s,
            gas_temperature_k=gas_temperature_k)
    except (ValueError, FloatingPointError) as exc:
        return FrameRate(None, (), f"emission rate failed: {exc}")


def emission_setup(cfg: Any, truth: Any = None) -> EmissionSetup | None:
    """The workers' emission settings from the ``emission`` section (None: disabled);
    ValueError for a bad gas file (a configuration error). A simulated scene (``truth``, a
    :class:`SceneTruth`) lends its camera's counts model as the characteristic curve, its
    gas absorption as the gas-cell calibration, and its gas temperature."""
    em = cfg.emission
    if not em.enabled:
        return None
    gas = METHANE if em.gas_file is None else load_gas(em.gas_file)
    curve, t_gas = None, configured_gas_temperature_k(cfg, truth)
    if truth is not None:
        curve = CharacteristicCurve.from_counts_model(truth.meta["counts_model"]["left"])
        rad = truth.meta["radiometry"]
        if em.gas_file is None:
            gas = dataclasses.replace(gas, alpha_per_ppm_m=float(rad["alpha_per_ppm_m"]),
                                      source="the simulated scene's")
    return EmissionSetup(EmissionSettings(gas=gas, pressure_pa=em.pressure_pa,
                                          background_frames=em.background_frames,
                                          typed_distance_m=em.single_camera_distance_m),
                         t_gas, curve, every=em.every)
