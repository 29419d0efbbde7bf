"""Back ends and protocols chosen by name (python-can's interface table).

Each table maps a name to ``"module:Class"``; the module is imported only when that name is
chosen, so an unused back end costs nothing and a missing optional dependency fails with a
message naming it.
"""

from __future__ import annotations

import importlib
from typing import Any

from drivers.anemometer.base import Anemometer, AnemometerConfigError, Decoder

#: Protocol name -> decoder class.
PROTOCOLS: dict[str, str] = {
    "gill": "drivers.anemometer.gill:GillDecoder",
    "gill_uvw": "drivers.anemometer.gill:GillUVWDecoder",
    "gill_polar": "drivers.anemometer.gill:GillPolarDecoder",
    "campbell_csat3b": "drivers.anemometer.campbell:CampbellCSAT3BDecoder",
    "young_81000": "drivers.anemometer.young:Young81000Decoder",
    "young_81000_uvw": "drivers.anemometer.young:Young81000UVWDecoder",
    "metek_usonic3": "drivers.anemometer.metek:MetekDecoder",
}

#: Back-end name -> Anemometer class.
BACKENDS: dict[str, str] = {
    "serial": "drivers.anemometer.serial_transport:SerialAnemometer",
    "simulated": "drivers.anemometer.simulated:SimulatedAnemometer",
    "replay": "drivers.anemometer.replay:ReplayAnemometer",
}


def _load(table: dict[str, str], kind: str, name: str) -> type:
    try:
        target = table[name]
    except KeyError:
        known = ", ".join(sorted(table))
        raise AnemometerConfigError(f"unknown anemometer {kind} {name!r}; known: {known}") from None
    module_name, class_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise AnemometerConfigError(
            f"anemometer {kind} {name!r} needs a package that is not installed: {exc}"
        ) from exc
    return getattr(module, class_name)


def decoder_class(name: str) -> type[Decoder]:
    """The decoder class registered as ``name``."""
    return _load(PROTOCOLS, "protocol", name)


def make_decoder(name: str, **options: Any) -> Decoder:
    """A new decoder for protocol ``name`` (see :data:`PROTOCOLS`) with its options."""
    cls = decoder_class(name)
    try:
        return cls(**options)
    except TypeError as exc:
        raise AnemometerConfigError(f"bad options for protocol {name!r}: {exc}") from exc


def make_anemometer(backend: str, **options: Any) -> Anemometer:
    """A new back end ``backend`` (see :data:`BACKENDS`) built from its config options."""
    cls = _load(BACKENDS, "back end", backend)
    try:
        return cls(**options)
    except TypeError as exc:
        raise AnemometerConfigError(f"bad options for back end {backend!r}: {exc}") from exc
