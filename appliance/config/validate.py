"""Validation of the raw configuration mapping into :class:`~appliance.config.schema.Config`.

It happens once, before any device is opened, and reports *every* problem at once, each
line naming the key path and the bad value, with a suggestion for near misses::

    site.yaml: recording.rotate_mb: must be > 0, got -5
    site.yaml: live.mod: unknown key (did you mean 'mode'?)
    site.yaml: cameras.left.backend: unknown camera back end 'simulted' (did you mean
        'simulated'?); known: aravis, opencv, replay_folder, replay_mcap, simulated

Types and ranges come from each field's rules in :mod:`appliance.config.schema`
(:mod:`appliance.config.convert`); then what can be known before devices open: back-end and
protocol names, the option keys each back end accepts and the mounting
(:mod:`appliance.config.devices`), and here the rules across keys: the processing
parameters, the calibration file, paths, ports and the release schedule. Option *values*
are checked by the back end when it is created.
"""

from __future__ import annotations

import ipaddress
import os
from typing import Any

from appliance.config.convert import build
from appliance.config.devices import device_checks
from appliance.config.schema import Config, ConfigError
from processing.synthetic.schedule import ReleaseSchedule

__all__ = ["validate_config"]


def _check_schedule(cfg: Config, errors: list[str]) -> None:
    """The release schedule fits in the simulated loop, sorted and without overlap."""
    # Imported here: `ogiflow --help` loads this module, and the presets bring in the
    # renderer's compiled kernels (~0.3 s).
    from processing.synthetic.presets import FIELD_FRAME_RATE_HZ

    sim = cfg.simulation
    if not sim.release_schedule:
        return
    if sim.scene != "leak":
        errors.append("simulation.release_schedule: only the leak scene releases gas "
                      f"(simulation.scene is {sim.scene!r})")
        return
    try:
        ReleaseSchedule.from_lists(sim.release_schedule, sim.frames / FIELD_FRAME_RATE_HZ)
    except ValueError as exc:
        errors.append(f"simulation.release_schedule: {exc} (the loop is simulation.frames "
                      f"= {sim.frames} frames at {FIELD_FRAME_RATE_HZ:g} Hz)")


def _cross_checks(cfg: Config, errors: list[str]) -> None:
    """Rules that involve more than one key."""
    live = cfg.live
    if live.mode == "serve":
        _check_serve(live, errors)
    if live.page.enabled:
        _check_page(live, errors)
    if live.mode == "connect" and not live.url.startswith(("rerun+http://", "rerun+https://",
                                                           "rerun://")):
        errors.append(f"live.url: must be a Rerun gRPC URL such as "
                      f"rerun+http://127.0.0.1:9876/proxy, got {live.url!r}")
    if cfg.recording.quota_gb is not None and cfg.recording.quota_gb * 1000 < (
            2 * cfg.recording.rotate_mb):
        errors.append(
            f"recording.quota_gb: {cfg.recording.quota_gb} GB cannot hold two files of "
            f"recording.rotate_mb = {cfg.recording.rotate_mb} MB; raise the quota or rotate "
            f"sooner")
    for key, path in (("recording.dir", cfg.recording.dir),
                      ("simulation.cache_dir", cfg.simulation.cache_dir)):
        if path is not None and path.exists() and not path.is_dir():
            errors.append(f"{key}: {str(path)!r} exists and is not a directory")
    if cfg.live.mode == "save" and cfg.live.file.is_dir():
        errors.append(f"live.file: {str(cfg.live.file)!r} is a directory")
    _check_calibration(cfg, errors)
    _check_processing(cfg, errors)
    _check_schedule(cfg, errors)


def _check_serve(live: Any, errors: list[str]) -> None:
    if live.grpc_port == live.web_port:
        errors.append(f"live.web_port: must differ from live.grpc_port, both are "
                      f"{live.grpc_port}")
    _check_bind("live.bind", live.bind, errors)
    if os.geteuid() != 0:
        for key in ("grpc_port", "web_port"):
            if getattr(live, key) < 1024:
                errors.append(f"live.{key}: ports below 1024 need root, got "
                              f"{getattr(live, key)}")


def _check_bind(key: str, bind: str, errors: list[str]) -> None:
    """A bind address: ``localhost`` or an IP address of this machine."""
    if bind == "localhost":
        return
    try:
        ipaddress.ip_address(bind)
    except ValueError:
        errors.append(f"{key}: must be an IP address of this machine (127.0.0.1, "
                      f"0.0.0.0, ...), got {bind!r}")


def _check_page(live: Any, errors: list[str]) -> None:
    page = live.page
    _check_bind("live.page.bind", page.bind, errors)
    if 0 < page.port < 1024 and os.geteuid() != 0:
        errors.append(f"live.page.port: ports below 1024 need root, got {page.port}")
    if live.mode == "serve" and page.port in (live.grpc_port, live.web_port) and (
            page.bind == live.bind):
        errors.append(f"live.page.port: {page.port} is also the Rerun viewer's port; "
                      f"choose another")


def _check_calibration(cfg: Config, errors: list[str]) -> None:
    # Imported here: `ogiflow --help` loads this module, and calibration brings in OpenCV.
    from processing.calibration import load_calibration

    if cfg.calibration is None:
        if cfg.cameras.right is not None and not any(
                c is not None and c.backend == "simulated" and "source" not in c.options
                for c in (cfg.cameras.left, cfg.cameras.right)):
            errors.append("calibration: a stereo calibration file is required unless a "
                          "simulated camera renders the scene (run `ogiflow calibrate "
                          "stereo`, then set calibration: to its file) or the site has "
                          "one camera (cameras.right: null)")
        return
    if not cfg.calibration.is_file():
        errors.append(f"calibration: file not found: {str(cfg.calibration)!r}")
        return
    try:
        load_calibration(cfg.calibration)
    except (ValueError, OSError, TypeError, KeyError) as exc:
        errors.append(f"calibration: {exc}")


def _check_processing(cfg: Config, errors: list[str]) -> None:
    # Imported here: `ogiflow --help` loads this module, and the chain brings in numba and
    # OpenCV (~0.4 s).
    from processing.chain.driver import ChainParameters

    try:
        params = ChainParameters.from_mapping(cfg.processing.parameters)
    except (ValueError, TypeError) as exc:
        errors.append(f"processing.parameters: {exc}")
        return
    if cfg.processing.opaque_gate and params.opaque_gate_gas_k is not None:
        errors.append("processing.opaque_gate: the gate at the site's gas temperature and "
                      "processing.parameters.opaque_gate_gas_k (the gate at a fixed one) "
                      "are both set; keep one")
    size = _stereo_image_size(cfg) if params.binning > 1 else None
    if size is not None:
        from processing.chain.binning import check_binning

        try:
            check_binning(size, params.binning)
        except ValueError as exc:
            errors.append(f"processing.parameters.binning: {exc}")


def _stereo_image_size(cfg: Config) -> tuple[int, int] | None:
    """(W, H) of the stereo pair's frames, px: the calibration file's, else the simulated
    cameras'; None when neither says (a single camera, or a calibration error reported)."""
    from processing.calibration import load_calibration

    if cfg.calibration is not None:
        try:
            size = load_calibration(cfg.calibration).image_size
        except (ValueError, OSError, TypeError, KeyError):
            return None
        return int(size[0]), int(size[1])
    if cfg.cameras.right is None:
        return None
    return int(cfg.simulation.width_px), int(cfg.simulation.height_px)


def validate_config(data: Any, source: str = "config") -> Config:
    """Validate a raw mapping (as loaded from YAML) into a :class:`Config`.

    Raises
    ------
    ConfigError
        Listing every problem found, each naming its key path and bad value.
    """
    errors: list[str] = []
    cfg = build(Config, data, "", errors)
    if not errors:
        device_checks(cfg, errors)
        _cross_checks(cfg, errors)
    if errors:
        raise ConfigError(errors, source)
    return cfg
