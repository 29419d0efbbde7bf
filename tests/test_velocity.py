"""3D velocity (paper Eq. 4) and surface position: hand-computed cases, masking, and the
acceptance test of a textured plane moving with a known 3D velocity."""

from __future__ import annotations

import numpy as np
import pytest

from processing.flow.brox import brox_optical_flow
from processing.stereo.joint import joint_disparity
from processing.velocity.triangulate import scene_flow_velocity, surface_position
from tests.scene_flow_plane import B_M, PP, S_PX, moving_plane

GEOM = {"principal_point": (1.0, 0.5), "camera_constant": 100.0, "baseline": 0.5}


def test_eq4_hand_computed() -> None:
    # Pixel (x, y) = (3, 2), x0 = 1, y0 = 0.5: x - x0 = 2, y - y0 = 1.5.
    # d = 10, d' = -2 (moving away), u = 1, v = -0.5, f = 1 / dt = 20 Hz, b = 0.5 m, s = 100:
    # f b = 10; V_X = 10 * ((2 + 1) / 8 - 2 / 10) = 1.75
    #           V_Y = 10 * ((1.5 - 0.5) / 8 - 1.5 / 10) = -0.25
    #           V_Z = 10 * (100 / 8 - 100 / 10) = 25
    d = np.full((3, 4), 10.0, np.float32)
    dp = np.full((3, 4), -2.0, np.float32)
    flow = np.zeros((3, 4, 2), np.float32)
    flow[..., 0] = 1.0
    flow[..., 1] = -0.5
    vel, valid = scene_flow_velocity(flow, d, dp, dt=0.05, **GEOM)
    assert vel.dtype == np.float32 and vel.shape == (3, 4, 3)
    assert valid.all()
    np.testing.assert_allclose(vel[2, 3], [1.75, -0.25, 25.0], rtol=1e-6)


def test_static_point_has_zero_velocity() -> None:
    d = np.full((5, 6), 7.0, np.float32)
    vel, valid = scene_flow_velocity(np.zeros((5, 6, 2), np.float32), d,
                                     np.zeros_like(d), dt=1 / 30, **GEOM)
    assert valid.all()
    assert np.abs(vel).max() == 0.0


def test_surface_position_hand_computed() -> None:
    d = np.full((3, 4), 10.0)
    pos, valid = surface_position(d, **GEOM)
    # X = (3 - 1) 0.5 / 10 = 0.1, Y = (2 - 0.5) 0.5 / 10 = 0.075, Z = 100 * 0.5 / 10 = 5
    np.testing.assert_allclose(pos[2, 3], [0.1, 0.075, 5.0], rtol=1e-6)
    assert valid.all() and pos.dtype == np.float32


def test_invalid_geometry_is_masked_never_nan() -> None:
    d = np.array([[10.0, 0.0, -3.0, 10.0, np.nan, 1e-40, 5.0]], np.float32)
    dp = np.array([[0.0, 1.0, 5.0, -10.0, 0.0, 1e-40, np.inf]], np.float32)
    flow = np.zeros((1, 7, 2), np.float32)
    flow[0, 3, 0] = np.nan
    vel, valid = scene_flow_velocity(flow, d, dp, dt=1 / 30, **GEOM)
    # d > 0 and d + d' > 0 only in pixel 0; pixel 5 (d tiny) overflows float32: masked too.
    assert valid.tolist() == [[True, False, False, False, False, False, False]]
    assert np.all(np.isfinite(vel))
    assert np.all(vel[~valid] == 0.0)
    pos, pvalid = surface_position(d, **GEOM)
    assert pvalid.tolist() == [[True, False, False, True, False, False, True]]
    assert np.all(np.isfinite(pos)) and np.all(pos[~pvalid] == 0.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dt": 0.0}, "dt"),
        ({"dt": -1.0}, "dt"),
        ({"baseline": 0.0}, "baseline"),
        ({"camera_constant": float("nan")}, "camera_constant"),
        ({"principal_point": (1.0,)}, "principal_point"),
        ({"flow": np.zeros((3, 4), np.float32)}, "flow must have shape"),
        ({"d_change": np.zeros((3, 5), np.float32)}, "d_change must have shape"),
        ({"d": np.zeros((3, 4), np.int32)}, "floating-point"),
    ],
)
def test_bad_input_raises(kwargs: dict, message: str) -> None:
    args = {"flow": np.zeros((3, 4, 2), np.float32), "d": np.ones((3, 4), np.float32),
            "d_change": np.zeros((3, 4), np.float32), "dt": 0.1, **GEOM}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        scene_flow_velocity(args.pop("flow"), args.pop("d"), args.pop("d_change"), **args)


@pytest.mark.parametrize(
    ("z0", "velocity", "seed"),
    [
        (2.0, (0.6, -0.3, -0.9), 0),  # oblique, approaching
        (1.9, (0.0, 0.0, 1.5), 4),  # straight away from the cameras: all in d'
    ],
)
def test_moving_plane_velocity_within_5_percent_and_3_degrees(
    z0: float, velocity: tuple[float, float, float], seed: int
) -> None:
    """Acceptance: textured plane at Z ~ 2 m (d ~ 78-82 px) moving with a known V,
    s = 780 px, b = 0.2 m, 320x240, 30 Hz; w from our Brox flow, d and d' from Eq. 6
    initialised with the minimum disparity d0 = 60 px (Z <= 2.6 m)."""
    scene = moving_plane(z0=z0, velocity=velocity, seed=seed)
    flow = brox_optical_flow(scene.il0, scene.il1)
    d, dp = joint_disparity(scene.il0, scene.ir0, scene.il1, scene.ir1, flow, d0=60.0)
    vel, valid = scene_flow_velocity(flow, d, dp, principal_point=PP, camera_constant=S_PX,
                                     baseline=B_M, dt=scene.dt)
    # Textured region: pixels seen by both cameras at t0 and t1 (x - d >= 0 needs
    # x >= 78 px; at t1 x + u - d - d' >= 0), with a margin for the pyramid borders.
    region = np.zeros(d.shape, bool)
    region[15:-15, 100:-15] = True
    assert valid[region].all()
    v_true = scene.velocity
    v = vel[region].astype(np.float64)
    mean = v.mean(axis=0)
    rel = abs(np.linalg.norm(mean) - np.linalg.norm(v_true)) / np.linalg.norm(v_true)
    ang = np.degrees(np.arccos(mean @ v_true / np.linalg.norm(mean) / np.linalg.norm(v_true)))
    assert rel < 0.05, rel
    assert ang < 3.0, ang
    # Pixel-wise as well: at least 95 % of the region within the same bounds.
    mag = np.abs(np.linalg.norm(v, axis=1) - np.linalg.norm(v_true)) / np.linalg.norm(v_true)
    cos = (v @ v_true) / np.linalg.norm(v, axis=1) / np.linalg.norm(v_true)
    px_ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    assert np.mean((mag < 0.05) & (px_ang < 3.0)) > 0.95
