"""What ``ogiflow eval sceneflow`` runs on one sequence, and where each value came from.

A sequence's ``meta.json`` (written by ``ogiflow simulate``) holds its cameras (camera
constant s, principal point, baseline b), its frame interval and the simulated volume, whose
depth extent [Z_near, Z_far] is the gas depth band. The band gives the disparity search of
the chain: d0 = floor(s b / Z_far) (the farthest gas) and a range of at least 64 px that
reaches s b / Z_near (:func:`band_disparities`, the rule the robustness matrix uses).
Explicit command-line values override the sequence's; every value is reported with its
source (:attr:`SequenceSetup.sources`).

Two chains:

- ``paper``: the paper's ideal conditions (Sec. 5.1): no registration, the ideal
  rectified cameras of ``meta.json``
  (:func:`appliance.evaluation.sceneflow.chain_parameters`);
- ``appliance``: what ``ogiflow run`` runs on a site: the chain's defaults (registration,
  depth gate, ...) with the gas depth band of the sequence and a configuration file's
  ``processing.parameters`` over them
  (:meth:`appliance.config.ProcessingConfig.chain_parameters`, as the daemon builds them),
  and the sequence's calibration file (``calibration.yaml``: characteristic curves, lens
  distortion) as a site's calibration when it has one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from appliance.config import ProcessingConfig
from appliance.evaluation.sceneflow import (
    Log,
    Metrics,
    configured_workers,
    evaluate_frames,
    sequence_geometry,
)
from appliance.evaluation.sceneflow import chain_parameters as paper_parameters
from processing.chain import ChainParameters, StereoGeometry
from processing.synthetic import SyntheticFrame, read_frame

CHAINS = ("paper", "appliance")

#: Narrowest SGM search range of the depth band's rule, px (the chain's default width).
MIN_SGM_RANGE = 64

#: The calibration file ``ogiflow simulate`` writes beside a sequence's frames.
CALIBRATION_NAME = "calibration.yaml"


@dataclass(frozen=True)
class Overrides:
    """Values given on the command line (None: take the sequence's)."""

    focal_length_px: float | None = None
    baseline_m: float | None = None
    principal_point: tuple[float, float] | None = None
    depth_band_m: tuple[float, float] | None = None
    frame_interval_s: float | None = None
    d0: float | None = None
    sgm_range: int | None = None
    disparity_init: str | None = None
    workers: int | None = None


@dataclass(frozen=True)
class SequenceSetup:
    """The geometry, frame interval and chain parameters one sequence is evaluated with.

    ``sources`` maps each reported value's name to where it came from (``meta.json``, the
    command line, the configuration file, the chain's default, or a value derived from
    others); ``values`` holds those values as printed.
    """

    geometry: StereoGeometry
    params: ChainParameters
    frame_interval_s: float
    chain: str
    workers: int = 1
    values: dict[str, str] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line per value: ``name = value (source)``."""
        return "\n".join(f"  {k} = {v} ({self.sources[k]})" for k, v in self.values.items())


def gas_depth_band(meta: dict[str, Any]) -> tuple[float, float] | None:
    """[Z_near, Z_far] of the simulated volume in m (left camera frame), None when the
    meta does not say (a sequence not written by ``ogiflow simulate``)."""
    sim = meta.get("simulation") or {}
    try:
        z0 = float(sim["volume_origin_m"][2])
        depth = float(sim["grid_zyx"][0]) * float(sim["voxel_m"])
    except (KeyError, IndexError, TypeError, ValueError):
        return None
    return (z0, z0 + depth) if depth > 0 and z0 > 0 else None


def band_disparities(s_px: float, b_m: float, z_near_m: float,
                     z_far_m: float) -> tuple[float, int]:
    """d0 and the SGM search range N (px) covering gas between ``z_near_m`` and ``z_far_m``.

    d0 = floor(s b / Z_far); N the smallest multiple of 16 that reaches s b / Z_near, at
    least :data:`MIN_SGM_RANGE` (SGM and the depth gate then tolerate a plume that pokes
    out of the band a little).
    """
    if not 0 < z_near_m < z_far_m:
        raise ValueError(f"the gas depth band must satisfy 0 < Z_near < Z_far, got "
                         f"[{z_near_m:g}, {z_far_m:g}] m")
    d0 = float(math.floor(s_px * b_m / z_far_m))
    need = math.ceil(s_px * b_m / z_near_m) - d0 + 1
    return d0, max(MIN_SGM_RANGE, 16 * math.ceil(need / 16))


def _geometry(meta: dict[str, Any], directory: Path, chain: str, ov: Overrides,
              values: dict[str, str], sources: dict[str, str]) -> StereoGeometry:
    calib_path = directory / CALIBRATION_NAME
    if chain == "appliance" and calib_path.is_file():
        from processing.calibration import load_calibration

        calib = load_calibration(calib_path)
        distorted = bool(meta["camera"].get("k1") or meta["camera"].get("k2"))
        geometry = StereoGeometry.from_calibration(calib, rectify=distorted)
        src = CALIBRATION_NAME
    else:
        geometry = sequence_geometry(meta)
        src = "meta.json"
    pp = geometry.principal_point
    for name, given, current, fmt in (
            ("focal length s", ov.focal_length_px, geometry.camera_constant, "{:g} px"),
            ("baseline b", ov.baseline_m, geometry.baseline, "{:g} m")):
        values[name] = fmt.format(current if given is None else given)
        sources[name] = src if given is None else "command line"
    geometry = replace(
        geometry,
        camera_constant=float(geometry.camera_constant if ov.focal_length_px is None
                              else ov.focal_length_px),
        baseline=float(geometry.baseline if ov.baseline_m is None else ov.baseline_m),
        principal_point=pp if ov.principal_point is None else tuple(ov.principal_point))
    values["principal point"] = "({:g}, {:g}) px".format(*geometry.principal_point)
    sources["principal point"] = src if ov.principal_point is None else "command line"
    return geometry


def _band(meta: dict[str, Any], geometry: StereoGeometry, ov: Overrides,
          values: dict[str, str], sources: dict[str, str]) -> tuple[float, int] | None:
    """d0 and N implied by the gas depth band (None when no band is known)."""
    band = ov.depth_band_m if ov.depth_band_m is not None else gas_depth_band(meta)
    if band is None:
        return None
    values["gas depth band"] = f"[{band[0]:.2f}, {band[1]:.2f}] m"
    sources["gas depth band"] = ("command line" if ov.depth_band_m is not None
                                 else "meta.json (simulated volume)")
    return band_disparities(geometry.camera_constant, geometry.baseline, *band)


def sequence_setup(meta: dict[str, Any], directory: Path, *, chain: str = "paper",
                   overrides: Overrides | None = None,
                   config: Path | None = None) -> SequenceSetup:
    """Geometry, frame interval and chain parameters of one sequence (see module doc).

    Parameters
    ----------
    meta
        The sequence's ``meta.json``.
    directory
        Its folder (for ``calibration.yaml`` with the appliance chain).
    chain
        ``"paper"`` or ``"appliance"``.
    overrides
        Command-line values; they win over the sequence's and the configuration's.
    config
        Configuration file whose ``processing.parameters`` the appliance chain runs (None:
        the built-in defaults, ``config/default.yaml``). Only with ``chain="appliance"``.

    Raises
    ------
    ValueError
        Unknown chain, a configuration file with the paper chain, an invalid configuration
        or parameter, no gas depth band and no --d0.
    """
    if chain not in CHAINS:
        raise ValueError(f"unknown chain {chain!r}; choose from {', '.join(CHAINS)}")
    if config is not None and chain != "appliance":
        raise ValueError("--config applies to --chain appliance only (the paper chain runs "
                         "the paper's conditions)")
    ov = overrides or Overrides()
    values: dict[str, str] = {}
    sources: dict[str, str] = {}
    geometry = _geometry(meta, directory, chain, ov, values, sources)
    dt = float(meta["frame_interval_s"] if ov.frame_interval_s is None else ov.frame_interval_s)
    values["frame interval"] = f"{dt * 1e3:g} ms"
    sources["frame interval"] = "meta.json" if ov.frame_interval_s is None else "command line"
    band = _band(meta, geometry, ov, values, sources)
    if band is None and ov.d0 is None:
        raise ValueError(f"sequence {meta.get('name')!r}: its meta.json gives no gas depth "
                         f"band (simulation.volume_origin_m, grid_zyx, voxel_m); give "
                         f"--depth-band ZNEAR ZFAR or --d0")
    band_src = "from the gas depth band"
    d0 = ov.d0 if ov.d0 is not None else band[0]  # type: ignore[index]
    n = ov.sgm_range if ov.sgm_range is not None else (
        band[1] if band is not None else MIN_SGM_RANGE)
    d0_src = "command line" if ov.d0 is not None else band_src
    n_src = ("command line" if ov.sgm_range is not None else
             band_src if band is not None else "chain default")
    init = ov.disparity_init or "sgm"
    # The appliance chain's configuration, read once: its parameters and its workers.
    processing = None if chain == "paper" else load_processing(config)
    cfg_src = "chain default" if chain == "paper" else (
        f"configuration {config}" if config is not None else "built-in configuration")
    if processing is None:
        params = paper_parameters(init, d0, n)
        init_src = "command line" if ov.disparity_init else "chain default"
    else:
        params, d0_src, n_src, init_src = _appliance_parameters(processing, cfg_src, d0, n,
                                                                ov, d0_src, n_src)
    values["d0"] = f"{params.d0:g} px"
    sources["d0"] = d0_src
    values["SGM range"] = (f"[{math.floor(params.d0)}, "
                           f"{math.floor(params.d0) + params.sgm_num_disparities}) px")
    sources["SGM range"] = n_src
    values["disparity init"] = params.disparity_init
    sources["disparity init"] = init_src
    values["registration"] = "on" if params.register else "off"
    values["depth gate"] = "on" if params.depth_gate else "off"
    sources["registration"] = sources["depth gate"] = (
        "paper's conditions" if chain == "paper" else cfg_src)
    workers = _workers(processing, cfg_src, ov, values, sources)
    return SequenceSetup(geometry=geometry, params=params, frame_interval_s=dt, chain=chain,
                         workers=workers, values=values, sources=sources,
                         notes=_notes(meta, chain))


def _workers(processing: ProcessingConfig | None, where: str, ov: Overrides,
             values: dict[str, str], sources: dict[str, str]) -> int:
    """How many of the daemon's workers take the triples: the command line's, else the
    appliance chain's configuration's (``processing``, read from ``where``), else one."""
    if ov.workers is not None:
        n, src = ov.workers, "command line"
    elif processing is not None:
        n, src = configured_workers(processing.workers, where), where
    else:
        n, src = 1, "paper's conditions"
    values["workers"] = ("1 (every triple warm from the one before)" if n == 1 else
                         f"{n} (every other triple each, warm from two frames back)")
    sources["workers"] = src
    return n


def load_processing(config: Path | None) -> ProcessingConfig:
    """The ``processing`` section of a configuration file (None: the built-in one), checked
    as ``ogiflow run`` checks it (ValueError naming every wrong key).

    Only that section is read: the evaluated scene gives the cameras and the geometry, so
    a site file's devices and calibration (a file under /etc) need not exist here.
    """
    from appliance.config import read_yaml, validate_config

    if config is None:
        return validate_config({}, "defaults").processing
    data = read_yaml(config)
    if not isinstance(data, dict):
        raise ValueError(f"{config}: the configuration file's top level must be a mapping")
    section = {"processing": data["processing"]} if "processing" in data else {}
    return validate_config(section, str(config)).processing


def _appliance_parameters(processing: ProcessingConfig, where: str, d0: float, n: int,
                          ov: Overrides, d0_src: str, n_src: str
                          ) -> tuple[ChainParameters, str, str, str]:
    """The daemon's parameters: the band's d0 and N under the configuration's parameters
    (``processing``, read from ``where``), command-line values over both. Returns the
    parameters and the sources of d0, N and the disparity initialisation."""
    given = processing.parameters
    params = processing.chain_parameters({"d0": d0, "sgm_num_disparities": n})
    flags: dict[str, Any] = {}
    if ov.d0 is not None:
        flags["d0"] = ov.d0
    if ov.sgm_range is not None:
        flags["sgm_num_disparities"] = ov.sgm_range
    if ov.disparity_init is not None:
        flags["disparity_init"] = ov.disparity_init
    if flags:
        params = replace(params, **flags)  # replace() runs the parameters' own checks
    d0_src = d0_src if ov.d0 is not None or "d0" not in given else where
    n_src = n_src if ov.sgm_range is not None or "sgm_num_disparities" not in given else where
    init_src = ("command line" if ov.disparity_init is not None else
                where if "disparity_init" in given else "chain default")
    return params, d0_src, n_src, init_src


def rectified_truth(frame: SyntheticFrame, geometry: StereoGeometry) -> SyntheticFrame:
    """``frame`` with its ground truth moved onto the rectified grid the chain works on.

    The simulator's truth lies on the distorted pixel grid of the left camera; a rectified
    pixel sees the ray of the distorted pixel its map points to, so the truth is resampled
    with the same maps (nearest neighbour: a gas velocity is never blended with "no gas").
    Without maps the frame is returned as it is.
    """
    if geometry.maps_left is None:
        return frame
    mx, my = geometry.maps_left

    def remap(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a)
        src = a.astype(np.float32) if a.dtype != np.float32 else a
        out = cv2.remap(src, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=0)
        return out.astype(a.dtype) if a.dtype != bool else out > 0.5

    return replace(frame, gt_velocity=remap(frame.gt_velocity),
                   gt_position=remap(frame.gt_position), gt_mask=remap(frame.gt_mask),
                   column_density_ppm_m=remap(frame.column_density_ppm_m))


def evaluate_sequence(directory: Path, setup: SequenceSetup, meta: dict[str, Any], *,
                      max_triples: int | None = None,
                      log: Log | None = None) -> tuple[Metrics, dict[str, Any]]:
    """:func:`appliance.evaluation.sceneflow.evaluate_frames` with all three methods on a
    sequence directory, with ``setup``'s geometry, frame interval and parameters.

    A frame interval other than the sequence's re-stamps the frames (t_i = i dt); with
    rectification maps the ground truth moves onto the rectified grid.
    """
    frames = []
    for i in range(int(meta["n_frames"])):
        f = rectified_truth(read_frame(directory, i, meta), setup.geometry)
        if setup.frame_interval_s != float(meta["frame_interval_s"]):
            f = replace(f, t_s=i * setup.frame_interval_s)
        frames.append(f)
    return evaluate_frames(frames, setup.geometry, setup.params, max_triples=max_triples,
                           name=Path(directory).name, log=log, workers=setup.workers)


def _notes(meta: dict[str, Any], chain: str) -> tuple[str, ...]:
    """Hints on a sequence the chosen chain is not made for."""
    opts = meta.get("options") or {}
    if chain != "paper":
        return ()
    notes = []
    if opts.get("jitter_px"):
        notes.append(f"the sequence has camera jitter ({opts['jitter_px']:g} px) and the "
                     f"paper chain does not register: --chain appliance removes it")
    return tuple(notes)
