"""The driver of the chain (paper Sec. 4, Fig. 2): stages, parameters, stream state, summary."""

from processing.chain.driver import (
           SceneFlowResult,
           compute_scene_flow,
           frame_interval,
           initial_scale,
)
from processing.chain.parameters import ChainParameters
from processing.chain.state import ChainState
from processing.stereo_geometry import StereoGeometry

__all__ = ["ChainParameters", "ChainState", "SceneFlowResult", "StereoGeometry",
           "compute_scene_flow", "frame_interval", "initial_scale"]
