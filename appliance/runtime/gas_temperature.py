"""The site's gas temperature, K: what the emission rate and the opaque-edge gate take.

Where a camera sees it, the gas of a leak has mixed with the air and taken about its
temperature. The configured one (``emission.gas_temperature_k``; at a simulated site the
scene's, whose rendered plume is colder than its air) wins; else the anemometer's latest
sonic temperature, which the acquisition thread writes into a value shared with the
workers (a virtual temperature: T (1 + 0.51 q) for specific humidity q, 1-3 K above the
air's in humid air); else 15 degC until the anemometer reports one.

The opaque-edge gate (``processing.opaque_gate``) takes it anew every triple
(:class:`GateTemperature`): the air's changes by 10-20 K between night and noon, and a gate
temperature 10 K off the gas's had already turned two scenes of the wide robustness matrix
(docs/evaluation-sceneflow.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from processing.chain import ChainParameters
from processing.emission.estimator import DEFAULT_GAS_TEMPERATURE_K

#: Sonic temperatures outside this range (K) are a sensor fault, not the air's.
PLAUSIBLE_K = (150.0, 400.0)


def site_gas_temperature_k(configured_k: float | None, sonic_k: Any = None) -> float:
    """The gas temperature now, K: ``configured_k``, else the sonic one (``sonic_k``: a
    ``multiprocessing.Value`` in K, NaN before the first sample), else 15 degC."""
    if configured_k is not None:
        return float(configured_k)
    t = float("nan") if sonic_k is None else float(sonic_k.value)
    return t if np.isfinite(t) and PLAUSIBLE_K[0] < t < PLAUSIBLE_K[1] \
        else DEFAULT_GAS_TEMPERATURE_K


def configured_gas_temperature_k(cfg: Any, truth: Any = None) -> float | None:
    """The configured gas temperature (``emission.gas_temperature_k``), else a simulated
    scene's (``truth``, a :class:`appliance.runtime.simsite.SceneTruth`); None: the
    anemometer's."""
    t_gas = cfg.emission.gas_temperature_k
    if t_gas is None and truth is not None:
        # The simulated anemometer's sonic temperature is not the scene's gas
        # temperature (the renderer's plume is colder than the air around it).
        t_gas = float(truth.meta["radiometry"]["t_gas_k"])
    return None if t_gas is None else float(t_gas)


@dataclass(frozen=True)
class GateTemperature:
    """The opaque-edge gate at the site's gas temperature (picklable, for the workers).

    ``configured_k``: :func:`configured_gas_temperature_k` (None: the sonic one).
    """

    configured_k: float | None

    def parameters(self, params: ChainParameters, sonic_k: Any = None) -> ChainParameters:
        """``params`` with ``opaque_gate_gas_k`` at the gas temperature now (``params``
        itself when it already is)."""
        t = site_gas_temperature_k(self.configured_k, sonic_k)
        if params.opaque_gate_gas_k == t:
            return params
        return dataclasses.replace(params, opaque_gate_gas_k=t)
