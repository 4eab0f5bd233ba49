"""The user's world frame and gltrack's internal +Y-up frame.

gltrack tracks in a right-handed world with +Y up (the body model, the floor prior and the
canonical start poses assume it). A user's calibration may be Z-up (Pose2Sim, Qualisys: the
floor is z = 0), Y-up, or anything its tool chose. ``gltrack ingest`` therefore rotates the
cameras into the internal frame and records the rotation back, in ``meta.json``::

    "world": {"up": "z", "R_user_from_internal": [[1, 0, 0], [0, 0, -1], [0, 1, 0]]}

``X_user = R_user_from_internal @ X_internal``: the rotation is proper (det +1) and about the
origin, so the user's origin, units and floor height are kept (a Z-up floor at z = 0 becomes the
internal y = 0). Datasets without ``"world"`` are already internal (identity).
:meth:`gltrack.data.dataset.Dataset.user_frame` and :meth:`~gltrack.data.dataset.Dataset.to_user_frame`
read it back, so exports write results in the user's frame.

Up axes are named ``"x" "y" "z" "-x" "-y" "-z"`` (a bare letter is the positive axis).
"""
from __future__ import annotations

import logging

import numpy as np

from gltrack.camera import Camera

log = logging.getLogger(__name__)

AXES = ("x", "y", "z", "-x", "-y", "-z")
#: Cameras whose mean up direction is further than this from the chosen axis get a warning.
UP_WARN_DEG = 25.0


def axis_vector(up: str) -> np.ndarray:
    """(3,) float64 unit vector of an axis name (``"z"``, ``"-y"``, ...)."""
    if up not in AXES:
        raise ValueError(f"up axis must be one of {AXES}, got {up!r}")
    v = np.zeros(3)
    v["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
    return v


def cameras_up(cameras) -> np.ndarray:
    """(3,) float64: the mean of the cameras' image-up directions in world coordinates.

    A camera's image up is its -y axis (OpenCV: y points down the image), ``-R[1]`` in world
    coordinates. People film level or tilted a little, rarely rolled, so the mean points up;
    its length (<= 1) says how much the cameras agree.
    """
    return np.mean([-c.R[1] for c in cameras], axis=0)


def detect_up(cameras) -> tuple[str, float]:
    """The world axis closest to the cameras' common up direction.

    Returns
    -------
    up : str
        One of :data:`AXES`.
    angle : float, degrees
        Between the mean up direction and that axis (a warning is logged above
        :data:`UP_WARN_DEG`, or when the cameras disagree).
    """
    mean = cameras_up(cameras)
    norm = float(np.linalg.norm(mean))
    if norm < 1e-6:
        raise ValueError("the cameras' up directions cancel out: give the up axis explicitly")
    k = int(np.argmax(np.abs(mean)))
    up = ("-" if mean[k] < 0 else "") + "xyz"[k]
    angle = float(np.degrees(np.arccos(np.clip(abs(mean[k]) / norm, -1.0, 1.0))))
    if angle > UP_WARN_DEG or norm < 0.5:
        log.warning("the cameras' mean up direction %s is %.0f deg from the %s axis (agreement "
                    "%.2f): the up axis is uncertain, give it explicitly", np.round(mean / norm, 2),
                    angle, up, norm)
    return up, angle


def internal_from_user(up: str) -> np.ndarray:
    """(3, 3) proper rotation taking user coordinates to internal (+Y up) ones.

    Its middle row is the user's up axis (so the user's up becomes internal +Y); its first row is
    the first user axis perpendicular to up (user x, or user y when up is along x), and the
    third completes a right-handed frame. ``"y"`` gives the identity; ``"z"`` maps
    ``(x, y, z) -> (x, z, -y)``.
    """
    r1 = axis_vector(up)
    r0 = np.array([0.0, 1.0, 0.0]) if up[-1] == "x" else np.array([1.0, 0.0, 0.0])
    r2 = np.cross(r0, r1)
    return np.stack([r0, r1, r2])


def to_internal(cameras, R_user_from_internal) -> list[Camera]:
    """The same cameras with world coordinates in the internal frame.

    ``X_cam = R X_user + t = (R @ R_user_from_internal) X_internal + t``: ``R`` changes, ``t``
    (and the intrinsics) do not.
    """
    M = np.asarray(R_user_from_internal, dtype=np.float64)
    return [Camera(c.name, c.kind, c.width, c.height, c.K, c.dist, c.R @ M, c.t) for c in cameras]


def world_meta(up: str, floor: float | None = None) -> dict:
    """The ``meta.json`` ``"world"`` record for a user frame with the given up axis.

    ``floor`` (metres along the up axis, the same in the user's frame and the internal one:
    the rotation is about the origin) is recorded when known, ``null`` otherwise.
    """
    return {"up": up.lstrip("+"), "R_user_from_internal": internal_from_user(up).T.tolist(),
            "floor": None if floor is None else float(floor)}


#: Every camera at least this far (metres) above the calibration's origin plane makes that
#: plane the floor (:func:`detect_floor`).
FLOOR_CAMERA_MIN = 0.5


def detect_floor(cameras) -> float | None:
    """The floor's height (internal +Y, metres) when the calibration's origin plane is the floor.

    Pose2Sim, Qualisys and anipose rigs are calibrated with the board (or wand frame) on the
    floor, so the floor is the origin plane (z = 0 of a Z-up world) and every camera is above
    it by the height it is mounted at. A caliscope rig puts the origin wherever the board lay
    (a desk), with cameras around and below it: then the floor is unknown. The rule: the origin
    plane is the floor when every camera is at least :data:`FLOOR_CAMERA_MIN` above it (lower
    mounts would film the floor at a grazing angle); otherwise None.

    Parameters
    ----------
    cameras : list of Camera in the internal (+Y up) frame
    """
    heights = np.array([float(c.center[1]) for c in cameras])
    if heights.min() >= FLOOR_CAMERA_MIN:
        log.info("floor: the calibration's origin plane (cameras %.2f-%.2f m above it)",
                 heights.min(), heights.max())
        return 0.0
    log.info("floor: unknown (a camera is %.2f m from the calibration's origin plane, under "
             "%.1f m); give --floor to use the support cue", heights.min(), FLOOR_CAMERA_MIN)
    return None


def check_world(obj, where) -> np.ndarray:
    """Validate a ``meta.json`` ``"world"`` record; return ``R_user_from_internal`` (3, 3)."""
    if not isinstance(obj, dict):
        raise ValueError(f"{where}: field 'world' must be an object")
    try:
        R = np.array(obj.get("R_user_from_internal"), dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: field 'world.R_user_from_internal' must be a 3x3 list of "
                         "numbers") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"{where}: field 'world.R_user_from_internal' must be 3x3 and finite, "
                         f"got shape {R.shape}")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6:
        raise ValueError(f"{where}: field 'world.R_user_from_internal' must be a rotation "
                         "(orthonormal, det +1)")
    up = obj.get("up")
    if up is not None and up not in AXES:
        raise ValueError(f"{where}: field 'world.up' must be one of {AXES}, got {up!r}")
    floor = obj.get("floor")
    if floor is not None and (isinstance(floor, bool) or not isinstance(floor, (int, float))
                              or not np.isfinite(floor)):
        raise ValueError(f"{where}: field 'world.floor' must be a finite number or null, got "
                         f"{floor!r}")
    return R


def world_record(obj, where) -> dict | None:
    """A validated, normalised ``"world"`` record (``{"up", "R_user_from_internal"}`` with the
    matrix as nested lists), or None for ``obj`` None (the internal frame itself)."""
    if obj is None:
        return None
    R = check_world(obj, where)
    return {"up": obj.get("up"), "R_user_from_internal": R.tolist()}


def same_world(a, b, tol: float = 1e-9) -> bool:
    """Whether two ``"world"`` records (or None = identity) describe the same rotation."""
    Ra = np.eye(3) if a is None else np.asarray(a["R_user_from_internal"], dtype=np.float64)
    Rb = np.eye(3) if b is None else np.asarray(b["R_user_from_internal"], dtype=np.float64)
    return bool(np.abs(Ra - Rb).max() <= tol)

