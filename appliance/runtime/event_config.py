"""The thresholds of the leak-event logic (config section ``events``).

Apart from the logic (:mod:`appliance.runtime.events`) so that the command line can show
their defaults without loading the image processing behind the events.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EventConfig:
    """Thresholds of the leak-event logic (config section ``events``).

    Attributes
    ----------
    min_gas_pixels : int
        Gas pixels inside the watched zones for a frame to count as positive.
    min_coherence : float
        Smallest flow coherence (0-1) of a positive frame.
    min_rate_g_s : float
        Smallest emission rate of a positive frame when the rate is known (0: any).
    max_source_shift_px : float
        Largest distance of a frame's source from the event's median source, px.
    min_duration_s, start_window_s, start_fraction : float
        Start rule (module docstring).
    end_window_s, end_fraction : float
        End rule (module docstring).
    watch_zones, ignore_zones : tuple of polygons
        Polygons in left-image pixel coordinates; no watch zone = the whole image.
    """

    min_gas_pixels: int = 150
    min_coherence: float = 0.5
    min_rate_g_s: float = 0.0
    max_source_shift_px: float = 25.0
    min_duration_s: float = 2.0
    start_window_s: float = 3.0
    start_fraction: float = 0.6
    end_window_s: float = 6.0
    end_fraction: float = 0.2
    watch_zones: tuple[tuple[tuple[float, float], ...], ...] = ()
    ignore_zones: tuple[tuple[tuple[float, float], ...], ...] = ()
