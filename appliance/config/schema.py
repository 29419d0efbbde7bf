"""The configuration's schema: one frozen dataclass per section, every key with its default,
documentation and validation rules (``config/default.yaml`` spells the defaults out).

Validation lives in :mod:`appliance.config.validate`, loading and command-line overrides in
:mod:`appliance.config.load`.
"""

# Every field is built by _opt() so that its documentation and validation rules live beside it.
# ruff: noqa: RUF009

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal


class ConfigError(ValueError):
    """The configuration is invalid; ``errors`` lists one ``"key.path: problem"`` per line.

    A ``ValueError`` so the CLI reports it as bad input (exit code 2, before any device
    opens: restarting the service cannot fix it).
    """

    def __init__(self, errors: Sequence[str], source: str = "config") -> None:
        self.errors = list(errors)
        self.source = source
        super().__init__("\n".join(f"{source}: {e}" for e in self.errors))


def _opt(doc: str, default: Any = dataclasses.MISSING, *, factory: Any = None, **rules: Any):
    """A dataclass field carrying its documentation and validation rules.

    ``rules``: ``min``/``max`` (inclusive), ``gt`` (exclusive lower bound), ``nonempty``,
    ``polygons`` for lists of image polygons ``[[x, y], ...]`` (at least 3 points each).
    """
    meta = {"doc": doc, **rules}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class CameraConfig:
    """One camera of the stereo pair."""

    backend: str = _opt(
        "camera back end name (simulated, replay, aravis, opencv, ...)", "simulated",
        nonempty=True,
    )
    options: dict[str, Any] = _opt("back-end specific options, checked by the back end",
                                   factory=dict)
    frame_rate_hz: float = _opt("nominal frame rate in Hz", 30.0, gt=0.0, max=1000.0)


@dataclass(frozen=True)
class CamerasConfig:
    """The stereo pair: ``left`` is the reference camera of the scene flow.

    ``right: null`` is a single-camera site: the left camera alone runs the single-camera
    chain (no stereo calibration, no rectification, no 3D velocity).
    """

    left: CameraConfig | None = _opt(
        "left (reference) camera; the camera of a single-camera site", factory=CameraConfig)
    right: CameraConfig | None = _opt(
        "right camera; null = a single-camera site (the left camera alone)",
        factory=CameraConfig)
    lost_after_s: float = _opt(
        "a camera of the pair that delivers nothing for this long is lost: the daemon goes "
        "on with the other one (single-camera chain, same leak events) until it returns",
        3.0, gt=0.0, max=3600.0)


@dataclass(frozen=True)
class AnemometerConfig:
    """The 3D ultrasonic anemometer on a serial line."""

    backend: str = _opt("anemometer back end (simulated, serial, replay, ...)", "simulated",
                        nonempty=True)
    protocol: str = _opt(
        "wire protocol of the sensor (gill, gill_polar, campbell_csat3b, young_81000, "
        "young_81000_uvw, metek_usonic3)", "gill", nonempty=True)
    port: str | None = _opt(
        "serial port URL for pyserial (/dev/ttyUSB0, loop://, spy:///dev/ttyUSB0); null lets "
        "the simulated back end create its own pseudo terminal", None,
    )
    baud: int = _opt("baud rate", 9600, min=50, max=4_000_000)
    parity: Literal["N", "E", "O", "M", "S"] = _opt("parity: N, E, O, M or S", "N")
    options: dict[str, Any] = _opt("back-end specific options, checked by the back end",
                                   factory=dict)
    mounting: dict[str, Any] = _opt(
        "mounting into the left camera frame: azimuth_deg / tilt_deg / roll_deg, or a 3x3 "
        "'matrix' (rows X, Y, Z; columns the sensor's F, L, U), and optionally "
        "'native_axes'; checked by drivers.anemometer.mounting", factory=dict)


@dataclass(frozen=True)
class PairingConfig:
    """Left/right frame pairing by nearest arrival time."""

    tolerance_s: float | None = _opt(
        "largest |t_left - t_right| of a pair in seconds; null = half a frame period", None,
        gt=0.0, max=10.0,
    )
    max_delay_s: float = _opt(
        "seconds a frame waits for its partner before it is given up as unpaired (a busy "
        "machine delays camera threads by a few hundred ms)", 1.0, gt=0.0, max=60.0)


@dataclass(frozen=True)
class RingConfig:
    """Shared-memory ring of stereo pairs between acquisition and the worker processes."""

    capacity: int = _opt("number of stereo-pair slots (>= 3: the method needs t0, t1, t2)",
                         32, min=3, max=100_000)


@dataclass(frozen=True)
class ProcessingConfig:
    """Scene-flow worker processes."""

    enabled: bool = _opt("run the scene-flow chain at all", True)
    workers: int = _opt("number of worker processes", 2, min=1, max=64)
    parameters: dict[str, Any] = _opt(
        "parameters passed to the processing chain as they are (checked by it)", factory=dict,
    )
    opaque_gate: bool = _opt(
        "remove the moving edges of warm objects at the gas's depth (the opaque-edge gate) "
        "at the site's gas temperature, taken anew every triple: emission.gas_temperature_k, "
        "else the anemometer's sonic temperature, 288.15 K until it reports one; needs "
        "radiometric curves (parameters.opaque_gate_gas_k is the same gate at one fixed "
        "temperature: not both)", False)

    def chain_parameters(self, defaults: Mapping[str, Any] | None = None, *,
                         site: bool = False) -> Any:
        """The scene-flow chain's parameters (:class:`processing.chain.ChainParameters`):
        ``defaults`` (what the scene implies, e.g. a simulated site's or a sequence's gas
        depth band) with this section's ``parameters`` over them. The one place the daemon
        and the evaluations build them, so an evaluation runs what ``ogiflow run`` runs.
        An unknown or invalid key raises ValueError naming it; so does ``opaque_gate``
        unless for a ``site`` (the daemon, which sets the gate's temperature itself): an
        evaluated sequence has no anemometer."""
        from processing.chain import ChainParameters

        if self.opaque_gate and not site:
            raise ValueError(
                "processing.opaque_gate takes a site's gas temperature (`ogiflow run` and its "
                "replays); for an evaluation give the sequence's as processing.parameters."
                "opaque_gate_gas_k (the simulated scenes': 285 K)")
        return ChainParameters.from_mapping({**(defaults or {}), **self.parameters})


@dataclass(frozen=True)
class RecordingConfig:
    """MCAP recording of every raw frame, wind sample, pair, result and health snapshot."""

    enabled: bool = _opt("write MCAP files", True)
    dir: Path = _opt("directory of the MCAP files", Path("recordings"))
    rotate_mb: float = _opt("start a new file past this size, MB (1e6 bytes)", 1024.0, gt=0.0)
    rotate_s: float = _opt("start a new file after this many seconds", 3600.0, gt=0.0)
    quota_gb: float | None = _opt(
        "delete the oldest closed recordings when their total passes this, GB (1e9 bytes); "
        "null = no quota", 50.0, gt=0.0,
    )
    fsync_s: float = _opt("flush the open chunk and fsync at least this often, seconds",
                          5.0, gt=0.0, max=3600.0)
    compression: Literal["zstd", "lz4", "none"] = _opt("chunk compression", "zstd")
    chunk_kb: int = _opt("uncompressed chunk size, KiB", 1024, min=16, max=65536)
    queue_size: int = _opt(
        "messages the recorder queue holds before it drops (>= 2 s of 2 x 30 Hz frames)",
        4096, min=16, max=1_000_000,
    )
    fields_every: int = _opt(
        "record the full result fields (flow, disparity, velocity, mask) of every N-th "
        "processed pair; summaries are recorded for every pair and the raw frames allow "
        "any field to be recomputed with `ogiflow replay`", 10, min=1, max=1_000_000,
    )
    split: bool = _opt(
        "retention layout: raw frames (with the raw wind) in <dir>/raw, a rolling buffer "
        "under raw_quota_gb; results, wind, health and events in <dir>/data under quota_gb; "
        "every leak event's raw files kept in <dir>/events under events_quota_gb. "
        "false = everything in <dir> under quota_gb (the layout before)", True)
    raw_quota_gb: float | None = _opt(
        "split layout: the rolling buffer of raw frames, GB (about 9 GB an hour)", 100.0,
        gt=0.0)
    raw_rotate_s: float = _opt(
        "split layout: length of one raw file, s (the granularity of event clips)", 30.0,
        gt=0.0, max=3600.0)
    events_quota_gb: float | None = _opt(
        "split layout: the event clips (raw frames of every leak event), GB", 300.0, gt=0.0)
    pre_trigger_s: float = _opt("raw frames kept before an event's start, s", 30.0,
                                min=0.0, max=3600.0)
    post_trigger_s: float = _opt("raw frames kept after an event's end, s", 30.0,
                                 min=0.0, max=3600.0)


@dataclass(frozen=True)
class PageConfig:
    """The operator's web page (appliance.page): status, picture, /status.json, /metrics."""

    enabled: bool = _opt("serve the operator's page, /status.json and /metrics", True)
    bind: str = _opt("address the page's HTTP server binds to", "127.0.0.1", nonempty=True)
    port: int = _opt("HTTP port of the page (0: any free port, announced at start)", 8080,
                     min=0, max=65535)
    max_image_hz: float = _opt(
        "pictures encoded for the page at most this often (a browser without GPU shows "
        "5 JPEGs a second easily)", 5.0, gt=0.0, max=30.0)
    jpeg_quality: int = _opt("JPEG quality of the page's pictures", 75, min=1, max=100)
    max_clients: int = _opt("browsers (event streams) served at once; more get 503", 64,
                            min=1, max=10_000)


@dataclass(frozen=True)
class LiveConfig:
    """Rerun live view, and the operator's page (``page``)."""

    mode: Literal["serve", "connect", "save", "off"] = _opt(
        "serve: web viewer on this box; connect: stream to a viewer at url; "
        "save: write an .rrd file; off", "serve",
    )
    bind: str = _opt("address the gRPC and web servers bind to (serve mode)", "127.0.0.1",
                     nonempty=True)
    grpc_port: int = _opt("gRPC port of the served recording", 9876, min=1, max=65535)
    web_port: int = _opt("HTTP port of the web viewer", 9090, min=1, max=65535)
    url: str = _opt("viewer to stream to in connect mode", "rerun+http://127.0.0.1:9876/proxy",
                    nonempty=True)
    file: Path = _opt(".rrd file written in save mode", Path("ogiflow.rrd"))
    queue_size: int = _opt("health samples queued for the live plots before new ones are "
                           "dropped (frames and status: only the newest waits)", 8, min=1,
                           max=10_000)
    jpeg_quality: int = _opt("JPEG quality of live images", 80, min=1, max=100)
    max_image_hz: float = _opt(
        "images sent to the viewer at most this often (plots and text with every result): "
        "a browser decodes a few JPEGs a second, more piles up as display latency", 5.0,
        gt=0.0, max=60.0)
    server_memory_mb: int = _opt(
        "serve mode: MB of recent live data the viewer server keeps for browsers that "
        "connect later (0 = none); bounds its memory (about 1.6x this + 60 MB)", 64,
        min=0, max=100_000)
    page: PageConfig = _opt("the operator's web page (independent of Rerun and of mode)",
                            factory=PageConfig)


@dataclass(frozen=True)
class HealthConfig:
    """Health snapshots and the systemd watchdog."""

    interval_s: float = _opt("seconds between health snapshots", 1.0, gt=0.0, max=3600.0)
    watchdog: bool = _opt("send WATCHDOG=1 to systemd when it asks for it", True)
    stall_s: float = _opt(
        "stop the watchdog pings when no new frame arrived for this many seconds", 10.0,
        gt=0.0, max=3600.0,
    )


@dataclass(frozen=True)
class SimulationConfig:
    """The synthetic gas scene that simulated cameras show (ignored for real cameras).

    The plume is simulated once (Stable Fluids, paper ref. [22]) with the simulated
    anemometer's mean wind, rendered into both cameras, cached on disk and looped.
    """

    frames: int = _opt("length of the pre-rendered loop, frames (30 Hz)", 240, min=10,
                       max=100_000)
    voxel_m: float = _opt("voxel size of the fluid grid, m (smaller = finer and slower)",
                          0.04, min=0.005, max=0.2)
    distance_m: float = _opt("distance of the plume from the cameras, m", 5.5, gt=0.5,
                             max=100.0)
    baseline_m: float = _opt("stereo baseline of the simulated cameras, m", 0.3, gt=0.0,
                             max=10.0)
    release_rate_g_s: float = _opt("gas release rate of the simulated leak, g/s", 3.0,
                                   gt=0.0, max=1000.0)
    seed: int = _opt("random seed of the simulated turbulence", 7, min=0)
    width_px: Literal[320, 640] = _opt(
        "image width of the simulated cameras, px: 320 (GF320 class) or 640 (GF620 class); "
        "the camera constant grows with it (780 px at 320), so the field of view stays",
        320)
    height_px: Literal[240, 480] = _opt(
        "image height of the simulated cameras, px: 240 with width_px 320, 480 with 640",
        240)
    scene: Literal["leak", "no_release"] = _opt(
        "what the simulated cameras show: leak (the gas release) or no_release (no gas, "
        "but temporal noise, camera jitter, a warm person walking to and fro once per loop "
        "and a slow background drift, in front of a plant wall: for false-alarm tests)",
        "leak")
    release_schedule: list[Any] = _opt(
        "leak scene: release on/off intervals [[on_s, off_s], ...], seconds from the start "
        "of the loop; the loop (frames at 30 Hz) is the schedule's period and repeats it. "
        "Empty = always on. The simulation starts from the gas the end of the loop leaves "
        "and the ground truth follows the gas that is really there (it drifts on after "
        "the release stops); end the last interval about 3 s before the loop ends so the "
        "gas has left the view when the loop restarts", factory=list, intervals=True)
    cache_dir: Path | None = _opt(
        "where rendered scenes are cached; null = $XDG_CACHE_HOME/ogiflow or "
        "~/.cache/ogiflow", None,
    )


@dataclass(frozen=True)
class EventsConfig:
    """Leak events (appliance.runtime.events): when a leak starts, lasts and ends."""

    min_gas_pixels: int = _opt("gas pixels inside the zones for a frame to count", 150,
                               min=1, max=10_000_000)
    min_coherence: float = _opt("least coherence (0-1) of the gas motion in a frame", 0.5,
                                min=0.0, max=1.0)
    min_rate_g_s: float = _opt("least emission rate of a frame when it is known, g/s", 0.0,
                               min=0.0)
    max_source_shift_px: float = _opt("largest distance of a frame's source from the "
                                      "event's, px", 25.0, gt=0.0)
    min_duration_s: float = _opt("evidence needed before an event starts, s", 2.0, gt=0.0,
                                 max=3600.0)
    start_window_s: float = _opt("window of the start rule, s", 3.0, gt=0.0, max=3600.0)
    start_fraction: float = _opt("share of positive frames in it to start", 0.6, gt=0.0,
                                 max=1.0)
    end_window_s: float = _opt("window of the end rule, s", 6.0, gt=0.0, max=3600.0)
    end_fraction: float = _opt("share of positive frames in it below which it ends", 0.2,
                               min=0.0, max=1.0)
    watch_zones: list[Any] = _opt(
        "polygons [[x, y], ...] in left-image pixels to watch; empty = the whole image",
        factory=list, polygons=True)
    ignore_zones: list[Any] = _opt("polygons to ignore (a vent, a road, a tree)",
                                   factory=list, polygons=True)
    rate_window_s: float = _opt("window of the emission-rate average, s", 30.0, gt=0.0,
                                max=86400.0)


@dataclass(frozen=True)
class EmissionConfig:
    """Emission rate (processing.emission): how much gas escapes, g/s and kg/h."""

    enabled: bool = _opt("compute the emission rate of processed frames", True)
    every: int = _opt(
        "compute it on every this many processed triples of each worker: the rate is a "
        "30 s average, and each estimate costs about 7 ms of a worker's ~35 ms per triple "
        "at 320x240 (1: every triple)", 3, min=1, max=1000)
    gas_file: Path | None = _opt(
        "gas file from `ogiflow calibrate gascell` (molar mass, absorption); null = methane "
        "with the literature absorption coefficient", None)
    gas_temperature_k: float | None = _opt(
        "gas temperature, K; null = the anemometer's sonic temperature (ambient air), "
        "288.15 K until it reports one", None, min=150.0, max=400.0)
    pressure_pa: float = _opt("ambient pressure, Pa", 101325.0, min=50_000.0, max=120_000.0)
    background_frames: int = _opt("frames (per worker) of the background radiance model", 60,
                                  min=8, max=10_000)
    single_camera_distance_m: float | None = _opt(
        "distance of the leak from the camera, m, for the single-camera rate (one camera "
        "has no depth: without it, single-camera results carry no rate); such rates are "
        "flagged single_camera", None, gt=0.0, max=10_000.0)


@dataclass(frozen=True)
class MqttAlarmConfig:
    """MQTT alarms (appliance.alarms.mqtt): status, events and summaries for the plant."""

    enabled: bool = _opt("publish to an MQTT broker", False)
    host: str = _opt("broker host name or address", "127.0.0.1", nonempty=True)
    port: int = _opt("broker port", 1883, min=1, max=65535)
    topic_prefix: str = _opt("topics are <prefix>/status, /event, /summary", "ogiflow",
                             nonempty=True)
    client_id: str = _opt("MQTT client id (unique on the broker)", "ogiflow", nonempty=True)
    keepalive_s: int = _opt("MQTT keep-alive, s", 30, min=5, max=3600)
    tls: bool = _opt("connect with TLS", False)
    ca_file: Path | None = _opt("TLS: CA certificate file; null = the system's", None)
    cert_file: Path | None = _opt("TLS: client certificate", None)
    key_file: Path | None = _opt("TLS: client key", None)
    username: str | None = _opt("broker user; null = anonymous", None)
    password_file: Path | None = _opt("file holding the password (not in this config)", None)
    queue_size: int = _opt("events and status kept while the broker is unreachable", 1000,
                           min=1, max=1_000_000)
    summary_interval_s: float = _opt("least time between two summaries, s", 1.0, min=0.0)
    update_s: float = _opt(
        "least time between two messages of one leak event on <prefix>/event: an update "
        "goes out when its state, source or rate class changed, at most this often, s",
        1.0, min=0.0, max=3600.0)


@dataclass(frozen=True)
class AlarmsConfig:
    """Alarm sinks."""

    mqtt: MqttAlarmConfig = _opt("MQTT", factory=MqttAlarmConfig)


@dataclass(frozen=True)
class Config:
    """The whole appliance configuration (one YAML file)."""

    cameras: CamerasConfig = _opt("the two OGI cameras", factory=CamerasConfig)
    anemometer: AnemometerConfig = _opt("the anemometer", factory=AnemometerConfig)
    pairing: PairingConfig = _opt("stereo pairing", factory=PairingConfig)
    ring: RingConfig = _opt("ring buffer", factory=RingConfig)
    processing: ProcessingConfig = _opt("scene flow workers", factory=ProcessingConfig)
    recording: RecordingConfig = _opt("MCAP recording", factory=RecordingConfig)
    live: LiveConfig = _opt("Rerun live view", factory=LiveConfig)
    health: HealthConfig = _opt("health and watchdog", factory=HealthConfig)
    calibration: Path | None = _opt(
        "stereo calibration file (YAML from `ogiflow calibrate stereo`); null = none", None,
    )
    simulation: SimulationConfig = _opt("scene of the simulated cameras",
                                        factory=SimulationConfig)
    events: EventsConfig = _opt("leak events", factory=EventsConfig)
    emission: EmissionConfig = _opt("emission rate", factory=EmissionConfig)
    alarms: AlarmsConfig = _opt("alarm sinks", factory=AlarmsConfig)
