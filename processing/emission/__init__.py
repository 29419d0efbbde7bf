"""Emission rate of the gas (g/s, kg/h) from column density and 3D gas velocity.

- :mod:`.gas`: gas properties (molar mass, band-averaged absorption alpha_g), unit conversion;
- :mod:`.column`: column density from Eq. 1 with Lambert-Beer, background radiance model;
- :mod:`.curtains`: control curtains that contain the viewing rays, flux through them;
- :mod:`.placement`: curtains downstream of the detected source;
- :mod:`.rate`: stereo and single-camera rate of a frame, time window with uncertainty;
- :mod:`.gascell`: gas-cell calibration of alpha_g.
"""

from processing.emission.column import BackgroundModel, ColumnDensity, column_density
from processing.emission.curtains import Curtain, CurtainFlux, curtain_flux
from processing.emission.gas import METHANE, GasProperties, g_s_to_kg_h, ppm_m_to_kg_m2
from processing.emission.gascell import GasCellFit, fit_alpha
from processing.emission.placement import Placement, place_curtains
from processing.emission.rate import (
    FrameRate,
    RateEstimate,
    RateWindow,
    out_of_plane_deg,
)

__all__ = [
    "METHANE",
    "BackgroundModel",
    "ColumnDensity",
    "Curtain",
    "CurtainFlux",
    "FrameRate",
    "GasCellFit",
    "GasProperties",
    "Placement",
    "RateEstimate",
    "RateWindow",
    "column_density",
    "curtain_flux",
    "fit_alpha",
    "g_s_to_kg_h",
    "out_of_plane_deg",
    "place_curtains",
    "ppm_m_to_kg_m2",
]
