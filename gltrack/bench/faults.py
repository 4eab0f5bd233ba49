"""Fault injection for the recovery benchmarks, as runner hooks.

A tracker never knows it is being tested: ``track(..., hooks=[FaultAt(frame, fault)])`` calls
the hook before every frame, and at ``frame`` it replaces the tracker's pose hypotheses ``X``
(N, D) by ``fault(X, dofs)`` through :meth:`gltrack.track.base.Tracker.transform_state`.
"""
from __future__ import annotations

import logging
from functools import partial

import numpy as np

from gltrack.sample.partitions import default_partitions

log = logging.getLogger(__name__)

#: Limbs a perturbation may target.
LIMBS = ("l_arm", "r_arm", "l_leg", "r_leg")


def perturb_limb(X, dofs, part: str, rad: float) -> np.ndarray:
    """(N, D) poses with every DOF of limb ``part`` shifted by ``rad`` radians (clamped).

    The depth benchmark's fault: the tracker has lost that limb.
    """
    parts = default_partitions(dofs)
    if part not in LIMBS or part not in parts:
        raise ValueError(f"perturb_part must be one of {', '.join(LIMBS)}, got {part!r}")
    X = np.array(X, dtype=np.float64)
    idx = parts[part]
    X[:, idx] = np.clip(X[:, idx] + rad, dofs.lower[idx], dofs.upper[idx])
    return X


def turn_and_shift(X, dofs, rad: float, shift: float) -> np.ndarray:
    """(N, D) poses turned by ``rad`` about the vertical and moved ``shift`` metres along x.

    The behaviour benchmark's fault: the whole particle set is thrown off the body.
    """
    X = np.array(X, dtype=np.float64)
    X[:, dofs.index("pelvis_ry")] += rad
    X[:, 0] += shift
    return dofs.validate(X)


class FaultAt:
    """Runner hook applying ``fault(X, dofs) -> X`` to the tracker's state at ``frame``.

    Parameters
    ----------
    frame : int, dataset frame before whose tracking the fault strikes
    fault : callable ``(X (N, D), dofs) -> (N, D)``, e.g.
        ``functools.partial(perturb_limb, part="r_arm", rad=0.5)``
    """

    def __init__(self, frame: int, fault):
        self.frame, self.fault = int(frame), fault

    def __call__(self, tracker, frame: int) -> None:
        if frame == self.frame:
            dofs = tracker.body.dofs
            tracker.transform_state(lambda X: self.fault(X, dofs))
            log.info("frame %d: fault injected (%s)", frame, self.fault)


def limb_fault(frame: int, part: str, rad: float) -> FaultAt:
    """The hook that throws limb ``part`` off by ``rad`` radians before ``frame``."""
    return FaultAt(frame, partial(perturb_limb, part=part, rad=rad))


def set_fault(frame: int, rad: float, shift: float) -> FaultAt:
    """The hook that turns the whole state by ``rad`` and moves it ``shift`` m before ``frame``."""
    return FaultAt(frame, partial(turn_and_shift, rad=rad, shift=shift))
