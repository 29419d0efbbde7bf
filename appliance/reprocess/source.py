"""One recording as reprocessing sees it: geometry, parameters, wind, and its stereo pairs.

Everything here is read from the recording itself (metadata records written by the
appliance at the start of every file) unless the caller overrides it, so a file carries
what is needed to reprocess it anywhere. Pairs are formed exactly as the live appliance
formed them: every camera frame in file order through the same
:class:`~appliance.runtime.stamping.StereoStamper` (clock model per camera + pairer). The
clock models carry state from the first frame on, which is why every reader of a
recording - a whole-file replay or one segment of it - runs the stamper from the start of
the file (cheap next to the chain).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from appliance.config.schema import PairingConfig
from appliance.recording.reader import iter_json, read_metadata
from appliance.runtime.stamping import StereoStamper
from drivers.anemometer.base import AnemometerConfigError
from drivers.anemometer.history import WindHistory
from drivers.anemometer.mounting import CameraWind, Mounting
from drivers.camera.mcap_format import FrameLogReader
from processing.calibration import load_calibration
from processing.calibration.calfile import curve_from_dict
from processing.chain import ChainParameters, StereoGeometry


def load_geometry(meta: Mapping[str, Mapping[str, str]],
                  calibration: Path | None = None) -> StereoGeometry:
    """The stereo geometry: ``calibration`` if given, else the recorded calibration or geometry.

    Raises
    ------
    ValueError
        When the recording carries neither and no calibration file is given.
    """

    if calibration is not None:
        return StereoGeometry.from_calibration(load_calibration(calibration))
    cal_yaml = meta.get("calibration", {}).get("yaml", "")
    if cal_yaml.strip():
        with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
            f.write(cal_yaml)
        try:
            return StereoGeometry.from_calibration(load_calibration(Path(f.name)))
        finally:
            Path(f.name).unlink()
    geo = meta.get("geometry", {}).get("json")
    if geo is None:
        raise ValueError("the recording carries no calibration or geometry; give --calibration")
    g = json.loads(geo)
    curves = [None if g.get(f"curve_{side}") is None
              else curve_from_dict(g[f"curve_{side}"], f"curve_{side}", "recorded geometry")
              for side in ("left", "right")]
    return StereoGeometry(camera_constant=float(g["camera_constant"]),
                          principal_point=tuple(g["principal_point"]),
                          baseline=float(g["baseline"]), image_size=tuple(g["image_size"]),
                          curve_left=curves[0], curve_right=curves[1])


def parse_override(text: str) -> tuple[str, str]:
    """``KEY=VALUE`` -> (key, raw value text); ValueError naming the text otherwise."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"--param expects KEY=VALUE, got {text!r}")
    return key.strip(), raw


def load_parameters(meta: Mapping[str, Mapping[str, str]],
                    overrides: Mapping[str, Any]) -> ChainParameters:
    """The recorded chain parameters with ``overrides`` (already parsed values) applied.

    Recorded keys this version does not know are dropped (older or newer recordings); an
    unknown override raises ValueError naming it.
    """
    values: dict[str, Any] = {}
    recorded = meta.get("processing", {}).get("json")
    if recorded is not None:
        values.update(json.loads(recorded))
    names = {f.name for f in dataclasses.fields(ChainParameters)}
    values = {k: v for k, v in values.items() if k in names}
    values.update(overrides)
    return ChainParameters.from_mapping(values)


def parameters_json(params: ChainParameters) -> str:
    """The parameters as recorded in output metadata (``processing.json``)."""
    return json.dumps(dataclasses.asdict(params), default=str)


@dataclass(frozen=True)
class Recording:
    """What every reader of one recording needs, read once from its metadata.

    Attributes
    ----------
    path : Path
    meta : dict
        Metadata records ``{name: {key: value}}``.
    config : dict
        The appliance configuration recorded in the file (empty if none).
    frame_rate_hz : float
        Nominal frame rate of the cameras (pairing period).
    tolerance_s : float or None
        Pairing tolerance (None: half a period).
    max_delay_s : float
        How long the live pairer let a frame wait for its partner; replay must use the same
        value, or frames that a busy machine delivered late are paired live but given up
        offline.
    wall_offset_ns : int
        UNIX ns minus host monotonic ns, from the first pair or wind sample.
    appliance_id : str
        The recording host's name (``recording`` metadata), else the file's stem.
    """

    path: Path
    meta: dict[str, dict[str, str]]
    config: dict[str, Any]
    frame_rate_hz: float
    tolerance_s: float | None
    max_delay_s: float
    wall_offset_ns: int
    appliance_id: str

    @classmethod
    def open(cls, path: Path) -> Recording:
        """Read the metadata of ``path``; ValueError when it is missing or not MCAP."""

        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        meta = read_metadata(path)
        text = meta.get("config", {}).get("yaml", "")
        config = (yaml.safe_load(text) or {}) if text.strip() else {}
        left = (config.get("cameras") or {}).get("left") or {}
        pairing = config.get("pairing") or {}
        return cls(path=path, meta=meta, config=config,
                   frame_rate_hz=float(left.get("frame_rate_hz", 30.0)),
                   tolerance_s=pairing.get("tolerance_s"),
                   max_delay_s=float(pairing.get("max_delay_s", PairingConfig.max_delay_s)),
                   wall_offset_ns=_wall_offset(path),
                   appliance_id=meta.get("recording", {}).get("host") or path.stem)

    def wall_ns(self, mono_ns: int) -> int:
        """Host monotonic ns -> UNIX ns."""
        return int(mono_ns + self.wall_offset_ns)

    def output_metadata(self, params: ChainParameters,
                        segment_s: float | None) -> dict[str, dict[str, str]]:
        """Metadata records of a reprocessed file: source, parameters, segmenting, setup."""
        out = {"replay": {"source": str(self.path.resolve()),
                          "parameters": parameters_json(params),
                          "segment_s": "" if segment_s is None else repr(float(segment_s))}}
        # The source's own records: which appliance recorded it, with what setup.
        for name in ("recording", "config", "calibration", "geometry"):
            if name in self.meta:
                out[name] = dict(self.meta[name])
        out["processing"] = {"json": parameters_json(params)}
        return out


def _wall_offset(path: Path) -> int:

    _reader, messages = iter_json(path, ["/pairs", "/wind/raw"])
    for _topic, m in messages:
        return int(m["t_wall_ns"]) - int(m["t_mono_ns"])
    return 0


def read_wind(path: Path) -> list[dict[str, Any]]:
    """Every recorded raw wind sample (``/wind/raw``) in file order."""

    _reader, messages = iter_json(path, ["/wind/raw"])
    return [m for _topic, m in messages]


def wind_history(rec: Recording, samples: Sequence[Mapping[str, Any]]) -> Any:
    """Wind in the camera frame (a ``WindHistory``) from raw samples, or None.

    None when the recorded mounting is unusable (warned) or there are no samples.
    """

    anem = rec.config.get("anemometer", {}) or {}
    try:
        mounting = Mounting.from_config(anem.get("protocol", "gill"), anem.get("mounting", {}))
    except AnemometerConfigError as exc:
        print(f"warning: {rec.path}: recorded anemometer mounting unusable ({exc}); no wind "
              "in the camera frame", file=sys.stderr)
        return None
    history = WindHistory()
    for m in samples:
        # A failed axis is recorded as null: NaN here, so the sample counts as invalid.
        axes = [float("nan") if m[k] is None else float(m[k]) for k in ("u", "v", "w")]
        vec = mounting.rotation @ axes
        history.add(CameraWind(host_ns=m["t_mono_ns"], vector=vec,
                               valid=bool(m["valid"]) and all(np.isfinite(axes)),
                               vertical_measured=True))
    return history if len(history) else None


class PairStream:
    """Stereo pairs of a recording in order, ``(index, pair)``, as the appliance paired them.

    Attributes after iteration: ``truncated`` (the file ends inside a record: cut by a
    crash; everything before was delivered), ``unpaired`` (frames per side left without
    a partner), ``skipped`` (malformed frame messages).
    """

    def __init__(self, rec: Recording) -> None:
        self.rec = rec
        self.truncated = False
        self.unpaired: dict[str, int] = {"left": 0, "right": 0}
        self.skipped = 0

    def __iter__(self) -> Iterator[tuple[int, Any]]:

        stamper = StereoStamper(self.rec.frame_rate_hz, self.rec.tolerance_s,
                                self.rec.max_delay_s)
        reader = FrameLogReader(self.rec.path)
        index = 0
        try:
            for side, frame in reader:
                for pair in stamper.push(side, frame, frame.host_ns):
                    yield index, pair
                    index += 1
            for pair in stamper.flush():
                yield index, pair
                index += 1
        finally:
            self.truncated = reader.truncated
            self.skipped = reader.skipped
            self.unpaired = stamper.unpaired()
