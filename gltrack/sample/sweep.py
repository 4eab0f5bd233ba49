"""A grid sweep of each limb's direction: after a sampler's step, and in the automatic start.

A silhouette cost has a narrow basin for a raised limb: an arm hanging inside the torso's
silhouette, or a leg hanging beside the standing one, costs nothing extra, while a raised one
costs its whole area in every view unless its direction is right in all of them, so a sampler
that diffuses from a hanging limb seldom reaches it (measured on the Pose2Sim take: frames 40-55
of its default track, the right arm raised by the person, hanging in the model; on the honest
multi-view hop, the raised right leg hanging in the model from its automatic start on, knee
350-384 mm off, while a leg grid found poses 55-66 pixels of silhouette error better). A grid
over the limb's two swing angles (shoulder or hip) and its flexion (elbow or knee), scored in
one batch with the estimate, finds such limbs wherever the grid has a point inside the basin;
the particles then move with the estimate.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

#: (swing joint, its two swing axes, distal joint, its flexion axis) of each arm.
ARMS = (("l_shoulder", "yz", "l_elbow", "y"), ("r_shoulder", "yz", "r_elbow", "y"))
#: The same for each leg: the hip's flexion and abduction, the knee's flexion.
LEGS = (("l_hip", "xz", "l_knee", "x"), ("r_hip", "xz", "r_knee", "x"))


@dataclass(frozen=True)
class SweepResult:
    """What :func:`sweep_limbs` did.

    Attributes
    ----------
    estimate : (D,) float, the estimate with every improved limb replaced
    delta : (D,) float, ``estimate`` minus the estimate given
    evaluations : int, poses weighted
    improved : tuple of str, the swing joints whose grid point won
    """

    estimate: np.ndarray
    delta: np.ndarray
    evaluations: int
    improved: tuple


def arm_grid(dofs, swing: int = 10, flex: int = 4) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The grid of each arm a DOF set can move: :func:`limb_grid` of :data:`ARMS`."""
    return limb_grid(dofs, swing, flex, ARMS)


def limb_grid(dofs, swing: int = 10, flex: int = 4,
              limbs=ARMS + LEGS) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The grid of each limb a DOF set can move.

    Parameters
    ----------
    dofs : gltrack.body.dofs.DofSet (``names``, ``lower``, ``upper``)
    swing : int, points along each swing axis (between the joint limits, ends included)
    flex : int, points of the distal joint's flexion (elbow, knee)
    limbs : rows like :data:`ARMS` and :data:`LEGS`

    Returns
    -------
    list of (joint name, (K,) int DOF indices, (G, K) float grid values); a limb whose DOFs the
    preset lacks is left out, one without its flexion is swept without it
    """
    names = list(dofs.names)
    out = []
    for joint, axes, distal, flex_axis in limbs:
        idx = [names.index(f"{joint}_r{a}") for a in axes if f"{joint}_r{a}" in names]
        if len(idx) < 2:
            continue
        counts = [swing] * len(idx)
        fname = f"{distal}_r{flex_axis}"
        if fname in names and flex > 0:
            idx.append(names.index(fname))
            counts.append(flex)
        axes_values = [np.linspace(dofs.lower[i], dofs.upper[i], n) for i, n in zip(idx, counts)]
        grid = np.array(list(itertools.product(*axes_values)), dtype=np.float64)
        out.append((joint, np.asarray(idx), grid))
    return out


def sweep_limbs(x, weights_fn, grids, margin: float = 0.0) -> SweepResult:
    """Replace each limb of ``x`` by its best grid point when that weighs more than ``x``
    (by more than ``margin``).

    Parameters
    ----------
    x : (D,) float, the estimate
    weights_fn : callable, (N, D) poses -> (N,) weights (larger = better); the weights of one
        call must be comparable with each other (they may be normalised per call)
    grids : list from :func:`limb_grid` or :func:`arm_grid`
    margin : float, >= 0, in the weights' units

    Returns
    -------
    SweepResult; the limbs are swept one after the other, each from the pose the one before left
    """
    x0 = np.asarray(x, dtype=np.float64)
    best = x0.copy()
    evaluations = 0
    improved = []
    for joint, idx, grid in grids:
        X = np.repeat(best[None], len(grid) + 1, axis=0)
        X[1:, idx] = grid
        w = np.asarray(weights_fn(X), dtype=np.float64)
        evaluations += len(X)
        k = int(np.argmax(w))
        if k > 0 and w[k] > w[0] + margin:
            best = X[k].copy()
            improved.append(joint)
    return SweepResult(best, best - x0, evaluations, tuple(improved))
