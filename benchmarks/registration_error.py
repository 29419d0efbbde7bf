"""How well does the registration remove the simulated jitter? Its error per triple, and d'.

Run from the repository root on one scene of a robustness matrix:

    PYTHONPATH=. python benchmarks/registration_error.py --matrix benchmarks/matrices/wide.yaml \\
        --seed 59 [--condition "all realistic"] [--part holdout] [--config FILE]

The simulator knows each frame's jitter (the detector's shift, px); the chain reports the
shift it removed between a triple's first two frames of each camera
(``SceneFlowResult.shifts_left``, ``shifts_right``). Per triple: the true shift, the
registration's error in x and y for both cameras, and the error of the difference of the
two cameras' horizontal errors, which is what reaches d' (the left view's motion less the
right one's along the rows). At the end: the RMS of each error over the scene, the mean of
the d' error (a bias that does not average out) and the V_Z that much d' is at the gas's
mean disparity (Eq. 4: Z = s b / d, V_Z = (Z(d + d') - Z(d)) f).
"""

from __future__ import annotations

import numpy as np

from benchmarks.common import matrix_scene, scene_arguments, scene_triples
from processing.velocity.triangulate import scene_flow_velocity


def registration_errors(removed_left: tuple[float, float], removed_right: tuple[float, float],
                        jitter_left: tuple[np.ndarray, np.ndarray],
                        jitter_right: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The registration's error between two frames of each camera.

    Parameters
    ----------
    removed_left, removed_right : (float, float)
        Shift (dx, dy) the chain removed from frame t0 to frame t1, px (content of t1
        displaced by it with respect to t0).
    jitter_left, jitter_right : (ndarray, ndarray)
        Each camera's simulated jitter at t0 and t1, shape (2,) each, px (content displaced
        by it).

    Returns
    -------
    ndarray, shape (5,)
        Error (removed - true) of the left x, left y, right x, right y, and left x less
        right x: the last is the d' error in px per frame.
    """
    true_left = np.asarray(jitter_left[1], float) - np.asarray(jitter_left[0], float)
    true_right = np.asarray(jitter_right[1], float) - np.asarray(jitter_right[0], float)
    err_left = np.asarray(removed_left, float) - true_left
    err_right = np.asarray(removed_right, float) - true_right
    return np.array([err_left[0], err_left[1], err_right[0], err_right[1],
                     err_left[0] - err_right[0]])


def vz_of_change(change_px: float, disparity_px: float, camera_constant_px: float,
                 baseline_m: float, frame_rate_hz: float) -> float:
    """V_Z in m/s that a d' of ``change_px`` is at disparity ``disparity_px`` on the optical
    axis: the chain's own Eq. 4 (:func:`processing.velocity.triangulate.scene_flow_velocity`)."""
    velocity, _ = scene_flow_velocity(
        np.zeros((1, 1, 2)), np.full((1, 1), float(disparity_px)),
        np.full((1, 1), float(change_px)), principal_point=(0.0, 0.0),
        camera_constant=camera_constant_px, baseline=baseline_m, dt=1.0 / frame_rate_hz)
    return float(velocity[0, 0, 2])


def main(argv: list[str] | None = None) -> int:
    ap = scene_arguments(__doc__ or "")
    scene, cond, frames, geometry, params = matrix_scene(ap, ap.parse_args(argv))
    print(f"{scene.name} {cond.name}: registration error (removed - simulated), px\n"
          "triple  true L (dx, dy)   error L (dx, dy)   true R (dx, dy)   error R (dx, dy)"
          "   d' error  flags")
    errors, disparities, rates = [], [], []
    for i, f0, f1, res in scene_triples(frames, geometry, params):
        jl = (f0.jitter_left_px, f1.jitter_left_px)
        jr = (f0.jitter_right_px, f1.jitter_right_px)
        err = registration_errors(res.shifts_left[0], res.shifts_right[0], jl, jr)
        errors.append(err)
        gas = res.gas_mask & res.valid
        if gas.any():
            disparities.append(float(res.disparity[gas].mean()))
        rates.append(1.0 / res.dt_s)
        tl = np.subtract(jl[1], jl[0])
        tr = np.subtract(jr[1], jr[0])
        print(f"{i:6d}  ({tl[0]:+.3f}, {tl[1]:+.3f})  ({err[0]:+.4f}, {err[1]:+.4f})  "
              f"({tr[0]:+.3f}, {tr[1]:+.3f})  ({err[2]:+.4f}, {err[3]:+.4f})  {err[4]:+.4f}  "
              f"{','.join(res.summary.flags) or '-'}")
    e = np.array(errors)
    rms = np.sqrt((e ** 2).mean(axis=0))
    print(f"RMS over {len(e)} triples: left ({rms[0]:.4f}, {rms[1]:.4f}), right "
          f"({rms[2]:.4f}, {rms[3]:.4f}); d' error {rms[4]:.4f} px RMS, mean {e[:, 4].mean():+.4f}")
    if disparities:
        d = float(np.mean(disparities))
        vz = vz_of_change(rms[4], d, geometry.camera_constant, geometry.baseline,
                          float(np.mean(rates)))
        print(f"at the gas's mean disparity {d:.1f} px that RMS is V_Z {abs(vz):.3f} m/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
