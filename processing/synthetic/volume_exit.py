"""Where a simulated plume leaves the simulation volume, and whether the camera sees it go.

The fluid simulation has open faces: gas carried through one is gone. Through a side of the
volume outside the camera's view that is what a real plume does (it leaves the picture).
Through a face inside the view it is not: the gas vanishes in mid-image, the mass flux
through successive curtains falls along the plume, and the column density has a sink no
real scene has. A wind with a Z component does that with a shallow volume, since the view
widens with depth: the field preset's 1.44 m deep volume lost the plume of a 1.2 m/s
X + 1.2 m/s Z wind through its far face 1 m from the source, in the middle of the image
(measured with ``ogiflow eval emission``: its true flux through the curtains was not
conserved along the plume, and every rate read from the images disagreed with it).

:func:`plume_exit` follows the plume's axis (the source moving with the wind; the source's
own jet and the turbulence are left out, so this is where the bulk of the gas leaves) to
the first face it crosses and projects that point into the left camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from processing.synthetic.geometry import StereoCamera, project_points

#: Face names by (axis, side): side 0 is the face at the volume's origin.
_FACES = {(0, 0): "left", (0, 1): "right", (1, 0): "top", (1, 1): "bottom",
          (2, 0): "near", (2, 1): "far"}


@dataclass(frozen=True)
class PlumeExit:
    """Where the plume's axis leaves the volume.

    Attributes
    ----------
    face : str
        "left", "right" (X), "top", "bottom" (Y, down positive), "near", "far" (Z).
    point_m : (float, float, float)
        The exit point in the left camera frame, m.
    image_xy : (float, float) or None
        Its pixel in the left image; None behind the camera.
    in_view : bool
        True when that pixel lies inside the image: the gas vanishes where the camera
        sees it.
    """

    face: str
    point_m: tuple[float, float, float]
    image_xy: tuple[float, float] | None
    in_view: bool

    @property
    def vanishes_in_view(self) -> bool:
        """Through the near or far face inside the view: the gas vanishes in mid-image
        (a side face inside the view only cuts the plume at its end, as the image border
        does)."""
        return self.in_view and self.face in ("near", "far")

    def describe(self) -> str:
        """One line for a user, e.g. ``far face at Z 6.22 m, inside the view``."""
        where = "inside the view" if self.in_view else "outside the view"
        return f"{self.face} face at Z {self.point_m[2]:.2f} m, {where}"


def plume_exit(source_m: np.ndarray, wind_m_s: np.ndarray, origin_m: np.ndarray,
               extent_m: np.ndarray, camera: StereoCamera) -> PlumeExit | None:
    """First face of the volume the plume's axis crosses (module docstring).

    Parameters
    ----------
    source_m : ndarray, shape (3,)
        Source position in the left camera frame, m.
    wind_m_s : ndarray, shape (3,)
        Ambient wind, m/s, left camera frame (X right, Y down, Z forward).
    origin_m, extent_m : ndarray, shape (3,)
        The volume's corner with the smallest coordinates and its size, m.
    camera : StereoCamera
        The cameras (the left one's projection is used).

    Returns
    -------
    PlumeExit or None
        None without wind or with the source outside the volume.
    """
    p0 = np.asarray(source_m, np.float64)
    w = np.asarray(wind_m_s, np.float64)
    lo = np.asarray(origin_m, np.float64)
    hi = lo + np.asarray(extent_m, np.float64)
    if not np.any(w != 0.0) or np.any(p0 < lo) or np.any(p0 > hi):
        return None
    # Time to reach each face the wind points at (the slab method along one ray).
    best_t, best = np.inf, (0, 0)
    for axis in range(3):
        if w[axis] > 0:
            t, side = (hi[axis] - p0[axis]) / w[axis], 1
        elif w[axis] < 0:
            t, side = (lo[axis] - p0[axis]) / w[axis], 0
        else:
            continue
        if t < best_t:
            best_t, best = t, (axis, side)
    point = p0 + best_t * w
    image_xy, in_view = None, False
    if point[2] > 0:
        x, y = project_points(camera, point)[0]
        image_xy = (float(x), float(y))
        in_view = bool(0.0 <= x <= camera.width - 1 and 0.0 <= y <= camera.height - 1)
    return PlumeExit(_FACES[best], (float(point[0]), float(point[1]), float(point[2])),
                     image_xy, in_view)


def sequence_plume_exit(meta: dict) -> PlumeExit | None:
    """:func:`plume_exit` of a sequence written by ``ogiflow simulate`` (its ``meta.json``,
    or ``SequenceConfig.meta()``); None when it has no source or no wind."""
    sim, cam = meta["simulation"], meta["camera"]
    if not sim.get("sources"):
        return None
    origin = np.asarray(sim["volume_origin_m"], np.float64)
    extent = np.asarray(sim["grid_zyx"][::-1], np.float64) * float(sim["voxel_m"])
    source = origin + np.asarray(sim["sources"][0]["position_m"], np.float64)
    camera = StereoCamera(width=int(cam["width"]), height=int(cam["height"]),
                          s_px=float(cam["s_px"]), cx_px=float(cam["cx_px"]),
                          cy_px=float(cam["cy_px"]), b_m=float(cam["b_m"]),
                          k1=float(cam.get("k1", 0.0)), k2=float(cam.get("k2", 0.0)))
    return plume_exit(source, np.asarray(meta["wind_m_s"], np.float64), origin, extent, camera)
