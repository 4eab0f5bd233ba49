"""Feature vectors for behaviour learning (Caillette, Galata & Howard 2008, section 4).

A frame's feature vector is ``X_t = (x_t, dx_t)``: the joint angles ``x_t = params[t, 6:]``
(root translation and root orientation are excluded so the behaviour model does not depend on
where the subject stands or faces) and their first time derivatives in radians per second.

Training data can be augmented as in the paper (section 7): each clip is resampled at slightly
different playback speeds and smoothed by different amounts, which multiplies the number of
frames and makes the clusters cover small variations in tempo and jitter.
"""
from __future__ import annotations

import logging

import numpy as np
from scipy.ndimage import gaussian_filter1d

log = logging.getLogger(__name__)

N_ROOT = 6  # root translation (3) + root rotation (3), see gltrack.body.dofs


def _as_params(params, name: str = "params") -> np.ndarray:
    a = np.asarray(params, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] <= N_ROOT or a.shape[0] < 1:
        raise ValueError(f"{name} must have shape (T, D) with T >= 1 and D > {N_ROOT}, "
                         f"got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values")
    return a


def _unwrap_rotations(params: np.ndarray) -> np.ndarray:
    """Unwrap every rotation column over time (translations untouched).

    Euler angles read from BVH can jump by 2*pi between frames; differentiating or
    interpolating across such a jump would invent a huge velocity.
    """
    out = params.copy()
    out[:, 3:] = np.unwrap(out[:, 3:], axis=0)
    return out


def joint_angles(params) -> np.ndarray:
    """Joint angles of a pose sequence, without the six root parameters.

    Parameters
    ----------
    params : (T, D) float array, body parameters (``params[:, :3]`` root translation in metres,
        ``params[:, 3:6]`` root rotation, the rest joint angles in radians).

    Returns
    -------
    (T, D - 6) float64 array, radians.
    """
    return _as_params(params)[:, N_ROOT:].copy()


def motion_features(params, fps: float) -> np.ndarray:
    """Feature vectors ``X_t = (x_t, dx_t)`` of one pose sequence.

    Derivatives are central differences (one-sided at the ends) of the unwrapped angles,
    multiplied by ``fps``; a single frame has zero velocity.

    Parameters
    ----------
    params : (T, D) float array, body parameters.
    fps : float, frames per second of ``params``.

    Returns
    -------
    (T, 2 * (D - 6)) float64 array: angles (radians) then angular velocities (radians/second).
    """
    a = _as_params(params)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    x = np.unwrap(a[:, N_ROOT:], axis=0)
    if len(x) >= 2:
        dx = np.gradient(x, axis=0) * float(fps)
    else:
        dx = np.zeros_like(x)
    return np.concatenate([x, dx], axis=1)


def resample_speed(params, speed: float) -> np.ndarray:
    """Play a sequence ``speed`` times faster, keeping the frame rate.

    Parameters
    ----------
    params : (T, D) float array.
    speed : float > 0; 1.1 gives about T / 1.1 frames of 10 % faster motion.

    Returns
    -------
    (T', D) float64 array, linearly interpolated (rotations unwrapped first),
    ``T' = floor((T - 1) / speed) + 1``.
    """
    a = _unwrap_rotations(_as_params(params))
    if not speed > 0:
        raise ValueError(f"speed must be positive, got {speed}")
    t_new = np.arange(0.0, len(a) - 1 + 1e-9, float(speed))
    t_old = np.arange(len(a), dtype=np.float64)
    return np.stack([np.interp(t_new, t_old, a[:, j]) for j in range(a.shape[1])], axis=1)


def smooth(params, sigma_frames: float) -> np.ndarray:
    """Gaussian smoothing along time (``sigma_frames`` in frames; 0 returns a copy)."""
    a = _unwrap_rotations(_as_params(params))
    if sigma_frames < 0:
        raise ValueError(f"sigma_frames must be >= 0, got {sigma_frames}")
    if sigma_frames == 0 or len(a) < 2:
        return a
    return gaussian_filter1d(a, float(sigma_frames), axis=0, mode="nearest")


def augment(params, speeds=(0.9, 1.0, 1.1), smoothing=(0.0, 1.0, 2.0)) -> list[np.ndarray]:
    """Augmented copies of one sequence: every (speed, smoothing) combination.

    Deterministic, so no random generator is needed.

    Parameters
    ----------
    params : (T, D) float array at some frame rate (unchanged by augmentation).
    speeds : sequence of float > 0, playback speed factors.
    smoothing : sequence of float >= 0, Gaussian sigmas in frames.

    Returns
    -------
    list of (T_i, D) float64 arrays, ``len(speeds) * len(smoothing)`` of them.
    """
    out = []
    for s in speeds:
        r = resample_speed(params, s)
        for g in smoothing:
            out.append(smooth(r, g))
    log.debug("augmented %d frames into %d sequences, %d frames", len(params), len(out),
              sum(len(o) for o in out))
    return out
