"""Degree-of-freedom presets, joint limits and per-part inter-frame standard deviations.

A pose is a parameter vector ``params`` of length D. The first six entries are always the root:
translation ``pelvis_tx, pelvis_ty, pelvis_tz`` (metres, world) and the pelvis rotation angles in
its Euler order (radians). The rest are joint angles named ``<joint>_r<axis>``.

Presets (counts are this implementation's, with the papers' intent in brackets):

* ``"full"`` (48 DOF) [Bandouch's ~51-DOF model]: root 6, lower and upper spine 3+3, neck 3,
  head 3, clavicles 2x2, shoulders 2x3, elbows 2x2 (flexion + forearm twist), wrists 2x2,
  hips 2x3, knees 2x1, ankles 2x2.
* ``"38"`` (37 DOF) [Bandouch's 38-DOF experiments]: ``full`` without lower spine, hands
  (wrists) and feet (ankles).
* ``"upper"`` (36 DOF): ``full`` without hips, knees and ankles; the legs stay in the rest
  pose and are left out of the surface (:data:`HIDDEN_PARTS`): for a subject seen from the
  waist up.
* ``"25"`` (25 DOF) [Caillette: 14 segments, at most 2 DOF per joint]: root 6, lower spine 1,
  upper spine 2, head 2, shoulders 2x2, elbows 2x1, hips 2x2, knees 2x1, ankles 2x1.

Limits are biomechanical ranges of motion for the T-pose rest frame (Kapandji; NASA-STD-3000
ranges, rounded and widened ~10 % so a tracker is not trapped at a limit by calibration error).
Sigmas are inter-frame standard deviations at 30 frames/s: about the largest angle change a
joint makes in 1/30 s during brisk everyday motion (walking, reaching), so that a diffusion or
a search grid of +-2 sigma covers most real frame-to-frame motion. :meth:`DofSet.sigma_at`
rescales them linearly with the frame interval.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .skeleton import Skeleton

INF = np.inf
_ROOT_T = (-50.0, 50.0, 0.03)
_ROOT_R = (-INF, INF, 0.05)

# joint -> {axis: (lower, upper, sigma@30fps)}; signs follow the T-pose frames of skeleton.py.
LIMITS = {
    "pelvis": {"x": _ROOT_R, "y": _ROOT_R, "z": _ROOT_R},
    "spine_lower": {"x": (-0.45, 0.9, 0.04), "y": (-0.55, 0.55, 0.04), "z": (-0.45, 0.45, 0.04)},
    "spine_upper": {"x": (-0.45, 0.9, 0.04), "y": (-0.55, 0.55, 0.04), "z": (-0.45, 0.45, 0.04)},
    "neck": {"x": (-0.7, 0.9, 0.06), "y": (-1.1, 1.1, 0.06), "z": (-0.7, 0.7, 0.05)},
    "head": {"x": (-0.6, 0.6, 0.06), "y": (-0.9, 0.9, 0.06), "z": (-0.45, 0.45, 0.05)},
    "l_clavicle": {"y": (-0.45, 0.35, 0.03), "z": (-0.35, 0.55, 0.03)},
    "r_clavicle": {"y": (-0.35, 0.45, 0.03), "z": (-0.55, 0.35, 0.03)},
    "l_shoulder": {"x": (-1.7, 1.7, 0.15), "y": (-1.8, 0.9, 0.15), "z": (-1.8, 1.6, 0.15)},
    "r_shoulder": {"x": (-1.7, 1.7, 0.15), "y": (-0.9, 1.8, 0.15), "z": (-1.6, 1.8, 0.15)},
    "l_elbow": {"x": (-1.6, 1.6, 0.15), "y": (-2.7, 0.1, 0.2)},
    "r_elbow": {"x": (-1.6, 1.6, 0.15), "y": (-0.1, 2.7, 0.2)},
    "l_wrist": {"y": (-0.6, 0.6, 0.15), "z": (-1.3, 1.3, 0.15)},
    "r_wrist": {"y": (-0.6, 0.6, 0.15), "z": (-1.3, 1.3, 0.15)},
    "l_hip": {"x": (-2.2, 0.6, 0.12), "y": (-0.9, 0.9, 0.08), "z": (-0.6, 1.1, 0.08)},
    "r_hip": {"x": (-2.2, 0.6, 0.12), "y": (-0.9, 0.9, 0.08), "z": (-1.1, 0.6, 0.08)},
    "l_knee": {"x": (-0.1, 2.6, 0.18)},
    "r_knee": {"x": (-0.1, 2.6, 0.18)},
    "l_ankle": {"x": (-0.9, 0.7, 0.1), "z": (-0.45, 0.45, 0.06)},
    "r_ankle": {"x": (-0.9, 0.7, 0.1), "z": (-0.45, 0.45, 0.06)},
}

_FULL = {
    "spine_lower": "xyz", "spine_upper": "xyz", "neck": "xyz", "head": "xyz",
    "l_clavicle": "yz", "r_clavicle": "yz", "l_shoulder": "xyz", "r_shoulder": "xyz",
    "l_elbow": "xy", "r_elbow": "xy", "l_wrist": "yz", "r_wrist": "yz",
    "l_hip": "xyz", "r_hip": "xyz", "l_knee": "x", "r_knee": "x", "l_ankle": "xz", "r_ankle": "xz",
}
PRESETS = {
    "full": _FULL,
    "38": {k: v for k, v in _FULL.items()
           if k not in ("spine_lower", "l_wrist", "r_wrist", "l_ankle", "r_ankle")},
    "25": {"spine_lower": "x", "spine_upper": "xz", "head": "xz",
           "l_shoulder": "yz", "r_shoulder": "yz", "l_elbow": "y", "r_elbow": "y",
           "l_hip": "xz", "r_hip": "xz", "l_knee": "x", "r_knee": "x",
           "l_ankle": "x", "r_ankle": "x"},
    "upper": {k: v for k, v in _FULL.items()
              if k not in ("l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle")},
}

#: Limits a preset sets instead of :data:`LIMITS`. ``"upper"`` is for a seated subject: the
#: pelvis rests on the seat, so it turns freely about the vertical but tilts (pitch and roll,
#: after the turn in its Euler order) by at most 0.5 rad (about 30 degrees: slouching, or
#: leaning forward from the hips); the spine adds up to 1.8 rad of forward bend. Without the
#: legs nothing else holds the pelvis upright: measured on the caliscope take (seated, hands
#: and face in the masks), the free pelvis started 1.1 rad pitched and 0.8 rolled, and the
#: track ended with the torso lying towards a camera.
PRESET_LIMITS = {"upper": {"pelvis": {"x": (-0.5, 0.5, _ROOT_R[2]),
                                      "z": (-0.5, 0.5, _ROOT_R[2])}}}

#: Mesh parts (:data:`gltrack.body.mesh.PARTS`) a preset leaves out of the body's surface, so
#: they are neither drawn nor scored: ``"upper"`` is for a subject whose legs the cameras do
#: not see (seated behind a desk); legs that are hidden must not be fitted to whatever hides
#: them.
HIDDEN_PARTS = {"upper": ("l_thigh", "l_shin", "l_foot", "r_thigh", "r_shin", "r_foot")}


@dataclass(frozen=True)
class DofSet:
    """The free parameters of a pose.

    Attributes
    ----------
    preset : str
    names : tuple of str, (D,)
    joint : (D,) int, joint index of each DOF (the root for its 6)
    axis : (D,) int, 0/1/2 for x/y/z; translation DOFs are the first three
    slot : (D,) int, position of the axis in the joint's Euler order (-1 for translations)
    lower, upper : (D,) float, limits (radians or metres)
    sigma30 : (D,) float, inter-frame standard deviation at 30 frames/s
    """

    preset: str
    names: tuple
    joint: np.ndarray
    axis: np.ndarray
    slot: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    sigma30: np.ndarray

    @property
    def size(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown DOF {name!r} in preset {self.preset!r}") from None

    def joint_dofs(self, joint: int) -> np.ndarray:
        """Indices of the DOFs that move ``joint`` itself (not its ancestors)."""
        return np.nonzero(self.joint == joint)[0]

    def sigma_at(self, fps: float) -> np.ndarray:
        """(D,) inter-frame standard deviations at ``fps`` frames per second."""
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        return self.sigma30 * (30.0 / float(fps))

    def zero(self, skeleton: Skeleton | None = None) -> np.ndarray:
        """(D,) rest pose (T-pose) standing with the root at its rest position."""
        p = np.zeros(self.size)
        if skeleton is not None:
            p[:3] = skeleton.offsets[0]
        return p

    def validate(self, params, *, name: str = "params", clamp: bool = True) -> np.ndarray:
        """Check shape and finiteness; clamp to the joint limits (documented policy).

        Poses outside the limits are *clamped*, not rejected: samplers diffuse freely and
        the limits are a projection, as in Deutscher's and Bandouch's filters. NaN/inf poses and
        wrong shapes raise ``ValueError``.

        Returns
        -------
        (N, D) float64 array (a copy).
        """
        a = np.array(params, dtype=np.float64, copy=True)
        if a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or a.shape[1] != self.size:
            raise ValueError(f"{name} must have shape (N, {self.size}) for preset "
                             f"{self.preset!r}, got {np.shape(params)}")
        if not np.all(np.isfinite(a)):
            bad = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"{name} has a non-finite value at row {bad[0]}, "
                             f"DOF {self.names[bad[1]]!r}")
        if clamp:
            np.clip(a, self.lower, self.upper, out=a)
        return a


def make_dofs(skeleton: Skeleton, preset: str = "full") -> DofSet:
    """Build the DOF set of ``preset`` for ``skeleton`` (which must use the canonical names)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown DOF preset {preset!r}; choose one of {', '.join(PRESETS)}")
    names, joint, axis, slot, lo, hi, sig = [], [], [], [], [], [], []
    for k, ax in enumerate("xyz"):
        names.append(f"pelvis_t{ax}")
        joint.append(0); axis.append(k); slot.append(-1)
        lo.append(_ROOT_T[0]); hi.append(_ROOT_T[1]); sig.append(_ROOT_T[2])
    spec = {"pelvis": "xyz", **PRESETS[preset]}
    own = PRESET_LIMITS.get(preset, {})
    for j, jname in enumerate(skeleton.names):
        axes = spec.get(jname, "")
        order = skeleton.orders[j].lower()
        for ax in order:  # keep Euler order so names read naturally
            if ax not in axes:
                continue
            lim = own.get(jname, {}).get(ax, LIMITS[jname][ax])
            names.append(f"{jname}_r{ax}")
            joint.append(j); axis.append("xyz".index(ax)); slot.append(order.index(ax))
            lo.append(lim[0]); hi.append(lim[1]); sig.append(lim[2])
    return DofSet(preset, tuple(names), np.array(joint), np.array(axis), np.array(slot),
                  np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64),
                  np.array(sig, dtype=np.float64))
