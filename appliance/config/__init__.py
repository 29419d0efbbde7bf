"""The appliance configuration: one YAML file, validated at start into typed dataclasses.

Every key has a default (``config/default.yaml`` spells them out: everything simulated); a
site file only names what differs. :mod:`.schema` holds the sections, :mod:`.validate` the
checks (every problem at once, key path, value, "did you mean"), :mod:`.load` the file,
``--set`` overrides and the effective YAML.
"""

from appliance.config.load import (
    add_config_arguments,
    apply_overrides,
    config_from_args,
    config_to_dict,
    config_to_yaml,
    live_overrides,
    load_config,
    parse_set_option,
    read_yaml,
)
from appliance.config.schema import (
    AnemometerConfig,
    CameraConfig,
    CamerasConfig,
    Config,
    ConfigError,
    HealthConfig,
    LiveConfig,
    PairingConfig,
    ProcessingConfig,
    RecordingConfig,
    RingConfig,
    SimulationConfig,
)
from appliance.config.validate import validate_config

__all__ = [
    "AnemometerConfig",
    "CameraConfig",
    "CamerasConfig",
    "Config",
    "ConfigError",
    "HealthConfig",
    "LiveConfig",
    "PairingConfig",
    "ProcessingConfig",
    "RecordingConfig",
    "RingConfig",
    "SimulationConfig",
    "add_config_arguments",
    "apply_overrides",
    "config_from_args",
    "config_to_dict",
    "config_to_yaml",
    "live_overrides",
    "load_config",
    "parse_set_option",
    "read_yaml",
    "validate_config",
]
