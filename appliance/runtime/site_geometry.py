"""The stereo geometry a run works with, and the check that the chain's settings find in it
what they need (both before any device opens: a problem is a configuration error, exit 2)."""

from __future__ import annotations

from appliance.config import Config, ConfigError
from appliance.runtime.simsite import SimulatedSite
from processing.calibration import load_calibration
from processing.chain import ChainParameters, StereoGeometry


def site_geometry(cfg: Config, site: SimulatedSite) -> StereoGeometry | None:
    """The stereo geometry: the calibration file's, else the simulated scene's cameras;
    None at a single-camera site without either (the single-camera chain needs none).

    Raises
    ------
    ValueError
        Real stereo cameras without a calibration file.
    """
    if cfg.calibration is not None:
        return StereoGeometry.from_calibration(load_calibration(cfg.calibration))
    if site.truth is not None:
        # The simulated cameras' counts models as their radiometric curves, as a
        # calibrated site has them (the opaque-edge gate needs radiance).
        return StereoGeometry.from_synthetic_camera(site.truth.camera,
                                                    site.truth.meta["counts_model"])
    if cfg.cameras.right is None:
        return None
    raise ValueError(
        "calibration: a stereo calibration file is required for real cameras "
        "(run `ogiflow calibrate stereo`, then set calibration: in the config)"
    )


def check_radiometry(params: ChainParameters, geometry: StereoGeometry | None) -> None:
    """ConfigError (exit 2, before any device opens) when a chain setting needs the
    cameras' radiometric curves and the site has none: the opaque-edge gate
    (``processing.opaque_gate`` sets ``opaque_gate_gas_k`` before this check)."""
    if params.opaque_gate_gas_k is not None and (
            geometry is None or geometry.curve_left is None or geometry.curve_right is None):
        raise ConfigError(["processing.opaque_gate / processing.parameters.opaque_gate_gas_k: "
                           "the opaque-edge gate needs both cameras' radiometric curves (a "
                           "stereo calibration with characteristic curves)"])
