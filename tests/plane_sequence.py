"""A textured plane moving at 2 m in front of the stereo pair: stereo sequences for the tests
of the chain's temporal reuse (warm starts, shared shifts and images)."""

from __future__ import annotations

import numpy as np

from processing.chain import ChainParameters, StereoGeometry
from tests.scene_flow_plane import B_M, PP, S_PX, SIZE, render, texture

GEOMETRY = StereoGeometry(
    camera_constant=S_PX, principal_point=PP, baseline=B_M, image_size=(SIZE[1], SIZE[0])
)
# temporal_weight 0: the warm start alone; with the d' coherence filter
# (processing.stereo.coherence) a warm triple also blends the previous d' on purpose.
PARAMS = ChainParameters(register=False, disparity_init="d0", d0=60.0, temporal_weight=0.0)
V_TRUE = np.array([0.3, -0.2, -0.5])
DT = 1 / 30
REGION = (slice(20, -20), slice(110, -20))  # seen by both cameras, away from borders


def sequence(n: int) -> tuple[list[np.ndarray], list[np.ndarray], list[float]]:
    """n stereo frames (16-bit counts) of a textured plane at 2 m moving with V_TRUE."""
    tex = texture(0)
    left, right = [], []
    for k in range(n):
        z = 2.0 + V_TRUE[2] * DT * k
        shift = (V_TRUE[0] * DT * k, V_TRUE[1] * DT * k)
        for frames, cam_x in ((left, 0.0), (right, B_M)):
            frames.append(np.rint(1000.0 + 20000.0 * render(tex, z, shift, cam_x))
                          .astype(np.uint16))
    return left, right, [10.0 + k * DT for k in range(n)]


def triple(seq: tuple, k: int) -> tuple:
    left, right, times = seq
    return left[k:k + 3], right[k:k + 3], times[k:k + 3]
