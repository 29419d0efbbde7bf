"""The metadata records every recording carries, so a file can be reprocessed as it ran.

``config`` (the effective configuration as YAML), ``calibration`` (path and text of the
calibration file), ``geometry`` (Eq. 4 geometry) and ``processing`` (chain parameters).
``ogiflow replay`` reads them back (:func:`appliance.recording.reader.read_metadata`).
"""

from __future__ import annotations

import dataclasses
import json

from appliance.config import Config, config_to_yaml
from processing.calibration.calfile import curve_to_dict
from processing.chain import ChainParameters, StereoGeometry


def file_metadata(cfg: Config, calibration_text: str | None = None) -> dict[str, dict[str, str]]:
    """Metadata records for every file: the effective config and the calibration.

    Parameters
    ----------
    cfg
        The validated configuration; stored as YAML text (``config`` record, key ``yaml``).
    calibration_text
        The calibration file's text, if any (``calibration`` record, keys ``path``, ``yaml``).
    """
    cal_path = str(cfg.calibration) if cfg.calibration is not None else ""
    return {
        "config": {"yaml": config_to_yaml(cfg)},
        "calibration": {"path": cal_path, "yaml": calibration_text or ""},
    }


def processing_metadata(geometry: StereoGeometry, params: ChainParameters
                        ) -> dict[str, dict[str, str]]:
    """MCAP metadata records that let ``ogiflow replay`` reprocess a file as it was run:
    the geometry of Eq. 4 (``geometry``) and the chain parameters (``processing``)."""
    geo: dict[str, object] = {
        "camera_constant": geometry.camera_constant,
        "principal_point": list(geometry.principal_point), "baseline": geometry.baseline,
        "image_size": list(geometry.image_size),
        "rectified": geometry.maps_left is None and geometry.maps_right is None}
    # The curves of a site without a calibration file (the simulated cameras'): a replay
    # then corrects counts as the run did.
    for side, curve in (("left", geometry.curve_left), ("right", geometry.curve_right)):
        if curve is not None:
            geo[f"curve_{side}"] = curve_to_dict(curve)
    return {"geometry": {"json": json.dumps(geo)},
            "processing": {"json": json.dumps(dataclasses.asdict(params), default=str)}}
