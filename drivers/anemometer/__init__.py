"""3-D ultrasonic anemometers on a serial line: protocol decoders, transports, back ends.

Pick a back end and a protocol by name (``drivers.anemometer.registry``); decoders turn
arbitrary byte chunks into :class:`~drivers.anemometer.base.WindSample` s, ``mounting`` turns
sensor axes into the left camera frame and ``history`` interpolates wind at any host time.
"""

from drivers.anemometer.base import (
    Anemometer,
    AnemometerConfigError,
    AnemometerConnectionError,
    AnemometerError,
    AnemometerSetupError,
    Decoder,
    DecoderCounts,
    WindSample,
)
from drivers.anemometer.registry import (
    BACKENDS,
    PROTOCOLS,
    make_anemometer,
    make_decoder,
)

__all__ = [
    "BACKENDS",
    "PROTOCOLS",
    "Anemometer",
    "AnemometerConfigError",
    "AnemometerConnectionError",
    "AnemometerError",
    "AnemometerSetupError",
    "Decoder",
    "DecoderCounts",
    "WindSample",
    "make_anemometer",
    "make_decoder",
]
