"""Where a simulated plume leaves its volume (processing.synthetic.volume_exit) and the field
preset's deeper volume (``ogiflow simulate --volume-depth``)."""

from __future__ import annotations

import numpy as np
import pytest

from processing.synthetic.geometry import StereoCamera
from processing.synthetic.presets import preset_field
from processing.synthetic.volume_exit import PlumeExit, plume_exit, sequence_plume_exit


def _exit(cfg) -> PlumeExit | None:
    return sequence_plume_exit(cfg.meta())


def test_plume_exit_finds_the_first_face_and_whether_the_camera_sees_it() -> None:
    kw = dict(camera=StereoCamera())  # s 780 px, principal point (159.5, 119.5), 320 x 240
    origin, extent = np.array([-1.5, -1.0, 5.0]), np.array([3.0, 2.0, 1.0])
    # Straight away from the camera, on the axis: through the far face, mid-image.
    e = plume_exit(np.array([0.0, 0.0, 5.5]), np.array([0.0, 0.0, 2.0]), origin, extent, **kw)
    assert e is not None and e.face == "far" and e.in_view
    assert e.point_m == pytest.approx((0.0, 0.0, 6.0))
    assert e.image_xy == pytest.approx((159.5, 119.5))
    # Across: through the right face, 1.5 m off the axis at 5.5 m, i.e. outside the view.
    e = plume_exit(np.array([0.0, 0.0, 5.5]), np.array([1.0, 0.0, 0.0]), origin, extent, **kw)
    assert e is not None and e.face == "right" and not e.in_view
    assert e.describe() == "right face at Z 5.50 m, outside the view"
    # Towards the camera: the near face.
    e = plume_exit(np.array([0.0, 0.0, 5.5]), np.array([0.0, 0.0, -1.0]), origin, extent, **kw)
    assert e is not None and e.face == "near" and e.point_m[2] == pytest.approx(5.0)
    # No wind, or a source outside the volume: nothing to say.
    assert plume_exit(np.array([0.0, 0.0, 5.5]), np.zeros(3), origin, extent, **kw) is None
    assert plume_exit(np.array([5.0, 0.0, 5.5]), np.ones(3), origin, extent, **kw) is None


def test_the_default_volume_loses_a_plume_moving_away_in_mid_image_a_deeper_one_does_not() -> None:
    away = (1.2, 0.0, 1.2)
    shallow = _exit(preset_field(wind_m_s=away))
    assert shallow is not None and shallow.face == "far" and shallow.in_view
    deep = _exit(preset_field(wind_m_s=away, depth_m=2.88))
    assert deep is not None and deep.face == "right" and not deep.in_view
    towards = _exit(preset_field(wind_m_s=(1.0, 0.0, -1.5), distance_m=6.0))
    assert towards is not None and towards.face == "near" and towards.in_view
    towards = _exit(preset_field(wind_m_s=(1.0, 0.0, -1.5), distance_m=6.0, depth_m=2.88))
    assert towards is not None and not towards.in_view
    across = _exit(preset_field(wind_m_s=(1.5, 0.0, 0.0)))
    assert across is not None and across.face == "right" and not across.in_view


@pytest.mark.parametrize("wind_z", [1.2, -1.2, 0.0])
def test_a_deeper_volume_grows_downwind_and_keeps_the_source(wind_z: float) -> None:
    wind = (1.2, 0.0, wind_z)
    base, deep = preset_field(wind_m_s=wind), preset_field(wind_m_s=wind, depth_m=2.88)
    assert preset_field(wind_m_s=wind, depth_m=1.44) == base  # the default is 1.44 m
    h = base.fluid.voxel_m
    assert base.fluid.shape[0] == 48 and deep.fluid.shape[0] == 96
    assert deep.fluid.shape[1:] == base.fluid.shape[1:]

    def absolute_source(cfg) -> np.ndarray:
        return np.asarray(cfg.volume_origin_m) + np.asarray(cfg.fluid.sources[0].position_m)

    np.testing.assert_allclose(absolute_source(deep), absolute_source(base), atol=1e-9)
    near = (base.volume_origin_m[2], deep.volume_origin_m[2])
    far = (near[0] + 48 * h, near[1] + 96 * h)
    if wind_z > 0:  # grows behind: the near face stays
        assert near[1] == pytest.approx(near[0]) and far[1] == pytest.approx(far[0] + 1.44)
        assert deep.spinup_steps == base.spinup_steps + 72  # 1.44 m at 1.2 m/s, 60 steps/s
    elif wind_z < 0:  # grows in front
        assert far[1] == pytest.approx(far[0]) and near[1] == pytest.approx(near[0] - 1.44)
    else:  # both ways
        assert near[1] == pytest.approx(near[0] - 0.72) and far[1] == pytest.approx(far[0] + 0.72)
        assert deep.spinup_steps == base.spinup_steps
    with pytest.raises(ValueError, match="depth_m"):
        preset_field(depth_m=1.0)


def test_simulate_says_when_the_plume_vanishes_in_view_and_checks_the_depth(tmp_path,
                                                                             capsys) -> None:
    from appliance import cli

    common = ["simulate", "--preset", "field", "--out", str(tmp_path), "--frames", "1",
              "--grid-scale", "0.25", "--spinup-steps", "2", "--wind", "1.2", "0", "1.2"]
    assert cli.main([*common, "--name", "shallow"]) == cli.EXIT_OK
    out = capsys.readouterr().out
    assert "shallow: note: the plume leaves the simulated volume through its far face" in out
    assert "--volume-depth" in out
    assert cli.main([*common, "--name", "deep", "--volume-depth", "2.88"]) == cli.EXIT_OK
    assert "note:" not in capsys.readouterr().out
    assert cli.main([*common, "--name", "bad", "--volume-depth", "0.5"]) == cli.EXIT_USAGE
    assert "--volume-depth must be within 1.44..12 m" in capsys.readouterr().err
    assert cli.main(["simulate", "--preset", "table2_1", "--out", str(tmp_path),
                     "--volume-depth", "3"]) == cli.EXIT_USAGE
