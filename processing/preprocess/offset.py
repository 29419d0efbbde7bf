"""The step of a camera's offset between two pictures of it (a shutter, a drift).

A flat-field shutter or a non-uniformity correction moves every pixel of one camera by
about the same amount at once, and the offset drifts with the housing's temperature. The
chain's differential images (Eq. 2, :func:`processing.preprocess.differential.differential_image`)
and the emission's background (:class:`processing.emission.estimator.EmissionEstimator`)
both compare two pictures of one camera, and both take such a step for gas: the
differences for motion, the background for absorption. Both level it out with
:func:`offset_step`.
"""

from __future__ import annotations

import numpy as np

from processing.preprocess.order_statistics import median

#: A median of the difference beyond this many times its median absolute deviation is a
#: step of the camera's offset. Without a step, noise and gas pull the median by 0.05-0.19
#: of that deviation (simulated scene s23 under 0.03 K noise: -1 to -4 counts against 20-22),
#: and taking that out of every difference moved the combined disturbances' unsteady scenes
#: (wide-long s53 71 -> 79 %); a step that small does little harm.
STEP_SPREAD = 0.5

#: Nor is a step below this share of the picture's level one: 0.02 K at 300 K in 3.2-3.4 um,
#: under the noise of a cooled OGI camera (0.03 K NETD is 1.5e-3 of that radiance). Below
#: it lies float rounding: the simulated sky's float32 radiance differences had medians of
#: 1e-10 to 1e-7 W m^-2 sr^-1 beside a deviation as small, and taken out they moved its
#: scenes by up to a point of RMVE. (Against the far lower level of a cold sky, the 1-3
#: counts by which 0.2 px of jitter moves its smooth gradient stay above it: the default
#: matrix's sky jitter reads 24.5 % levelled against 23.9 %.)
STEP_FLOOR = 1e-3


def offset_step(diff: np.ndarray, level: float, where: np.ndarray | None = None) -> float:
    """The change of the camera's offset between two frames: the median of their plain
    difference I(t) - I(t+1) (Eq. 2), radiance units (every 2nd pixel each way).

    Gas changes less than half of the picture, and a still background's difference is 0
    (noise around it), so the median is that step; a median within half the difference's
    median absolute deviation (:data:`STEP_SPREAD`), or below :data:`STEP_FLOOR` of the
    picture's level, is taken for no step. Left in, a step of
    0.17 K (100 counts of the simulated camera, half its tracked normalisation scale) read
    0.86 and 1.91 m/s on the two triples around it against 1.3 m/s (simulated scene s23):
    the flow of Eq. 5 takes a uniform change of one differential image for motion.

    Parameters
    ----------
    diff : ndarray, shape (H, W), float32
        I(t) - I(t+1) of one camera (or a frame less its background,
        :meth:`processing.emission.estimator.EmissionEstimator.column_kg_m2`).
    level : float
        The picture's level, in the unit of ``diff`` (the mean of one frame's |I|): a step
        under :data:`STEP_FLOOR` times it is taken for none.
    where : ndarray of bool, shape (H, W), or None
        The pixels to take it from (None: all); none at all gives 0.0.

    Returns
    -------
    float
        The step, in the unit of ``diff``; 0.0 for none.
    """
    sample = diff[::2, ::2] if where is None else diff[::2, ::2][where[::2, ::2]]
    if sample.size == 0:
        return 0.0
    sample = np.ascontiguousarray(sample, dtype=np.float32)
    step = median(sample)
    # The floor first: most differences stop there, and the deviation is a second median.
    if abs(step) <= STEP_FLOOR * abs(level):
        return 0.0
    spread = median(np.abs(sample - np.float32(step)))
    return float(step) if abs(step) > STEP_SPREAD * spread else 0.0
