"""Synthetic camera rigs of the benches and the tests."""
from __future__ import annotations

import numpy as np


def ring_cameras(target, n: int = 4, radius: float = 4.0, height: float = 2.0, width: int = 128,
                 height_px: int = 96, fov_y_deg: float = 55.0, first_angle: float = 0.4,
                 height_step: float = 0.3) -> list:
    """``n`` colour cameras evenly spaced on a horizontal circle around ``target``, looking at it.

    Camera ``i`` sits at azimuth ``a = 2 pi i / n + first_angle`` (radians, measured from +Z
    towards +X) at ``(target_x + radius sin a, height + height_step (i % 2), target_z +
    radius cos a)``: with ``height_step`` > 0 every second camera is higher, so the rig does not
    look at the subject from one plane only. The defaults are the behaviour-model bench's rig;
    :data:`gltrack.bench.multiview.RING` is the multi-view bench's.

    Parameters
    ----------
    target : (3,) array_like, metres, world point all cameras look at
    n : int, number of cameras (named ``cam0`` ... ``cam{n-1}``)
    radius : float, metres, horizontal distance from ``target``
    height : float, metres, world height (Y) of the even-numbered cameras
    width, height_px : int, image size in pixels
    fov_y_deg : float, degrees, vertical field of view (see :func:`gltrack.camera.look_at_camera`)
    first_angle : float, radians, azimuth of ``cam0``
    height_step : float, metres, added to the height of the odd-numbered cameras

    Returns
    -------
    list of Camera (no distortion)
    """
    from gltrack.camera import look_at_camera

    t = np.asarray(target, dtype=np.float64)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + first_angle
        eye = (t[0] + radius * np.sin(a), height + height_step * (i % 2), t[2] + radius * np.cos(a))
        cams.append(look_at_camera(f"cam{i}", eye, t, width, height_px, fov_y_deg))
    return cams
