"""Whether a triple is a scene change: the whole picture changed at once.

A bumped camera, a jump of the scene or a garbled frame makes a triple's differential
images far stronger than gas ever does, over a large part of the picture (a flat-field
shutter's uniform step is not one: the differential images are levelled,
:func:`processing.preprocess.offset.offset_step`). A warm start would
carry that triple's fields into the next ones (measured: four triples after the simulated
scene's loop jump at 4-19 m/s against 1.3 m/s true), so the chain starts it cold and leaves
nothing to warm from (:class:`processing.chain.state.ChainState`). Both conditions below
must hold: a warm object walking into the view is as strong on a few hundred pixels, and a
camera shift the registration rejected is spread but weak; neither is a scene change
(measured on the simulated 60-frame scenes: the object, taken for one, was flagged as a
moved camera, lost its emission rate and started cold; the rejected shift, started cold,
read 189 % against 4 % warm).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from processing.preprocess.normalisation import share_above

#: The triple's differential images ask for more than this many times the tracked
#: normalisation scale (measured: the simulated scene's loop jump asked for 4-9x,
#: consecutive gas frames for 0.6-1.5x) ...
SCENE_CHANGE_FACTOR = 3.0

#: ... and in one of its four raw differential images more than this share of the pixels
#: changed by more than the tracked scale (in steady state about 0.1 % do: the scale is the
#: 0.999 quantile of recent changes). Measured on the simulated 60-frame scenes: the loop
#: jump 0.18-0.26, a 2-3 px bump 0.15-0.17; a warm object walking into or out of the view,
#: which asks for up to 12x the scale, at most 0.014. One image is enough: bumps come a
#: camera at a time.
SCENE_CHANGE_SHARE = 0.05


def is_scene_change(scale: float | None, target: float | None,
                    measured: Sequence[np.ndarray]) -> bool:
    """Whether a triple is a scene change.

    Parameters
    ----------
    scale : float or None
        The tracked normalisation scale before this triple, radiance units (None: no
        tracked scale yet, no test).
    target : float or None
        The scale the triple's raw differential images ask for (the tracker's 0.999
        quantile of |D|, :meth:`processing.preprocess.normalisation.DiffScaleTracker.target`).
    measured : sequence of ndarray, each (H, W)
        The triple's raw differential images D = I(t) - I(t+1) (Eq. 2), radiance units.

    Returns
    -------
    bool
        ``target`` > :data:`SCENE_CHANGE_FACTOR` x ``scale`` and more than
        :data:`SCENE_CHANGE_SHARE` of one image's pixels with |D| > ``scale``.
    """
    if scale is None or target is None:
        return False
    return (target > SCENE_CHANGE_FACTOR * scale
            and any(share_above(d, scale) > SCENE_CHANGE_SHARE for d in measured))
