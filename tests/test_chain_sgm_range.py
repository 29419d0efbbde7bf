"""The chain's SGM initialisation searches from the minimum disparity d0 upwards.

A gas ~2 m in front of a 0.2 m baseline has d = s b / Z far above 16 px; with a search
range [0, N) below it SGM finds nothing useful and the joint solver, started far off, ends
wrong. With [d0, d0 + N) the same N suffices.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from processing.chain import ChainParameters, StereoGeometry, compute_scene_flow
from processing.synthetic.render import StereoCamera
from processing.synthetic.sequences import generate_sequence, preset_table2_1


def test_sgm_search_starts_at_d0() -> None:
    cfg = preset_table2_1()
    n = 24
    fluid = replace(cfg.fluid, shape=(n, n, n), voxel_m=cfg.fluid.voxel_m * 100 / n)
    cam = StereoCamera(width=128, height=96, s_px=312.0)
    cfg = replace(cfg, fluid=fluid, n_frames=3, spinup_steps=10, camera=cam)
    frames = list(generate_sequence(cfg))
    geo = StereoGeometry(camera_constant=cam.s_px, principal_point=(cam.cx, cam.cy),
                         baseline=cam.b_m, image_size=(cam.width, cam.height))
    params = ChainParameters(register=False, disparity_init="sgm", d0=20.0,
                             sgm_num_disparities=16)
    res = compute_scene_flow([f.left for f in frames], [f.right for f in frames],
                             [f.t_s for f in frames], geo, params)
    mask = frames[0].gt_mask & res.valid
    gt_d = cam.s_px * cam.b_m / frames[0].gt_position[..., 2][mask]
    assert gt_d.mean() > 20 + 8  # the gas lies inside [d0, d0 + 16), outside [0, 16)
    # Measured 0.02 px; the former search over [0, 16) left the mean 30 px off.
    assert abs(float(np.mean(res.disparity[mask] - gt_d))) < 0.5
