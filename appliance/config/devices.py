"""Device checks of the configuration: known before any device opens.

Back-end and protocol names, the option keys each back end accepts (its constructor's
keywords), option values as far as building a camera object checks them (it opens
nothing), the anemometer's port and mounting.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

from appliance.config.convert import did_you_mean
from appliance.config.schema import Config
from drivers.anemometer import registry as anemometers
from drivers.anemometer.base import AnemometerConfigError
from drivers.anemometer.mounting import Mounting
from drivers.camera import registry as cameras
from drivers.camera.base import CameraBackendMissing


def _accepted_options(cls: type, *also: type) -> set[str]:
    """Keyword names ``cls(...)`` accepts (and the classes it forwards ``**kwargs`` to)."""
    names: set[str] = set()
    for c in (cls, *also):
        params = inspect.signature(c.__init__).parameters  # type: ignore[misc]
        names |= {n for n, p in params.items() if n != "self"
                  and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
    return names


def _check_options(path: str, options: Mapping[str, Any], accepted: set[str],
                   errors: list[str]) -> bool:
    """Report option keys the back end does not take; True when all are known."""
    unknown = sorted(set(options) - accepted)
    for key in unknown:
        errors.append(f"{path}.{key}: not an option of this back end"
                      f"{did_you_mean(key, accepted)}; accepted: {', '.join(sorted(accepted))}")
    return not unknown


def _check_name(path: str, name: str, table: Mapping[str, str], kind: str,
                errors: list[str]) -> bool:
    if name in table:
        return True
    errors.append(f"{path}: unknown {kind} {name!r}{did_you_mean(name, table)}; "
                  f"known: {', '.join(sorted(table))}")
    return False


def _check_cameras(cfg: Config, errors: list[str]) -> bool:
    """Which cameras the site has: both, or the left one alone (the left camera is the
    reference of the chain, its pixels those of the zones). False when it makes no sense."""
    if cfg.cameras.left is None and cfg.cameras.right is None:
        errors.append("cameras: no camera configured (cameras.left and cameras.right are "
                      "both null); set cameras.left to the camera (a single-camera site "
                      "has cameras.right: null)")
        return False
    if cfg.cameras.left is None:
        errors.append("cameras.left: null while cameras.right names a camera; set "
                      "cameras.left to the camera and cameras.right: null (a single-camera "
                      "site uses the left camera, the chain's reference)")
        return False
    return True


def device_checks(cfg: Config, errors: list[str]) -> None:
    """Back-end and protocol names and option keys: known before any device opens."""
    if not _check_cameras(cfg, errors):
        return
    for side in ("left", "right"):
        cam = getattr(cfg.cameras, side)
        if cam is None:
            continue
        path = f"cameras.{side}"
        if not _check_name(f"{path}.backend", cam.backend, cameras.BACKENDS,
                           "camera back end", errors):
            continue
        try:
            cls = cameras.camera_class(cam.backend)
        except CameraBackendMissing as exc:
            errors.append(f"{path}.backend: {exc}")
            continue
        accepted = _accepted_options(cls)
        if _check_options(f"{path}.options", cam.options, accepted, errors):
            try:  # values: building a camera object opens nothing
                cls(**cam.options)
            except (ValueError, TypeError) as exc:
                errors.append(f"{path}.options: {exc}")
    a = cfg.anemometer
    protocol_ok = _check_name("anemometer.protocol", a.protocol, anemometers.PROTOCOLS,
                              "anemometer protocol", errors)
    if _check_name("anemometer.backend", a.backend, anemometers.BACKENDS,
                   "anemometer back end", errors):
        try:
            cls = anemometers._load(anemometers.BACKENDS, "back end", a.backend)
            serial = anemometers._load(anemometers.BACKENDS, "back end", "serial")
        except AnemometerConfigError as exc:
            errors.append(f"anemometer.backend: {exc}")
        else:
            # The simulated anemometer hands its remaining options to the serial back end.
            accepted = _accepted_options(cls, serial) if a.backend == "simulated" else (
                _accepted_options(cls))
            _check_options("anemometer.options", a.options, accepted, errors)
    if a.backend == "serial" and not a.port:
        errors.append("anemometer.port: the serial back end needs a port "
                      "(e.g. /dev/ttyUSB0), got null")
    if protocol_ok:
        try:
            Mounting.from_config(a.protocol, a.mounting)
        except AnemometerConfigError as exc:
            errors.append(f"anemometer.mounting: {exc}")
