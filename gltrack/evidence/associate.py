"""Data association for evidence propagation: the greedy loop of Ganapathi et al. (2010, fig. 4).

Given the current best pose (already refined by hill climbing) and classified part detections:

1. prune detections near any part of ``x_best`` (already explained; the detector is most useful
   exactly when the tracker has lost a part, and then the detection is far from it);
2. expand the rest into candidate correspondences (body part, detection) of matching class,
   e.g. left hand and right hand with every "hand" detection;
3. for each candidate: propose a pose by UT inverse kinematics from ``x_best``
   (:func:`.ik.ut_ik`), refine it by local hill climbing, and keep it when its cost beats
   ``x_best``'s.

The paper makes one pass; here the pass is repeated while it improves anything (a greedy loop),
pruning again after every accepted correspondence. Pure function of callables: no GL here.
"""
from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from .ik import ut_ik
from .parts import Detections

log = logging.getLogger(__name__)


class EPResult(NamedTuple):
    """Outcome of :func:`evidence_propagation` (unpacks as a 4-tuple).

    Attributes
    ----------
    x : (D,) float64, best pose
    cost : float, its cost
    evaluations : int, poses scored by ``cost_fn`` and ``hill_climb_fn``
    accepted : list of dict, one per accepted correspondence: ``part``, ``detection`` (index
        into the detections), ``class``, ``cost_before``, ``cost_after``, ``ik_residual``
        (metres)
    """

    x: np.ndarray
    cost: float
    evaluations: int
    accepted: list


def _as_detections(detections) -> Detections:
    if isinstance(detections, Detections):
        return detections
    pairs = list(detections)
    if not pairs:
        return Detections(np.zeros((0, 3)), ())
    return Detections(np.array([p for p, _ in pairs], dtype=np.float64), [c for _, c in pairs])


def prune_explained(points: np.ndarray, part_positions: np.ndarray, radius: float) -> np.ndarray:
    """Mask of detections farther than ``radius`` from every part position.

    Parameters
    ----------
    points : (J, 3) float, detections, metres
    part_positions : (P, 3) float, metres
    radius : float, metres

    Returns
    -------
    (J,) bool, True = still unexplained
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    parts = np.asarray(part_positions, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0 or len(parts) == 0:
        return np.ones(len(pts), dtype=bool)
    d = np.linalg.norm(pts[:, None] - parts[None], axis=2)
    return d.min(1) > radius


def evidence_propagation(x_best, detections, part_fns: dict, classes: dict, cost_fn,
                         hill_climb_fn, *, sigma, chains: dict | None = None,
                         meas_std: float = 0.03, prune_radius: float = 0.10,
                         cost_best: float | None = None, lower=None, upper=None,
                         max_passes: int = 3, ik_kwargs: dict | None = None,
                         margin: float = 0.0, control: bool = False,
                         reach: dict | None = None, nearest: bool = False,
                         refine_many=None, speculate: bool = False,
                         screen: float | None = None) -> EPResult:
    """Greedy evidence propagation from classified part detections.

    Parameters
    ----------
    x_best : (D,) float, current best pose (after hill climbing)
    detections : Detections, or iterable of ``(point (3,), class str)``
    part_fns : dict part name -> callable ``X (N, D) -> (N, 3)``, world part position, metres
    classes : dict part name -> class str (e.g. ``PART_CLASSES``); parts without a class are
        never matched
    cost_fn : callable ``X (N, D) -> (N,)``, lower is better
    hill_climb_fn : callable ``(x (D,), part) -> (x (D,), cost float, evaluations int)``,
        refines a proposal for ``part`` (a name of ``part_fns``; None when ``control`` refines
        ``x_best`` itself), e.g. over that part's kinematic chain only
    sigma : (D,) float, prior standard deviation of the pose change for the IK (e.g. a multiple
        of ``DofSet.sigma_at(fps)``: evidence matters most after fast motion)
    chains : dict part name -> (d,) int DOFs the IK may move (e.g. :func:`.ik.part_chains`);
        default: every DOF with ``sigma > 0``
    meas_std : float, metres, detection noise (isotropic)
    prune_radius : float, metres, detections this close to any part of ``x_best`` are ignored
    cost_best : float, optional, ``cost_fn(x_best)`` if known (saves one evaluation)
    lower, upper : (D,) float, optional, pose limits for the IK
    max_passes : int, passes over the candidate correspondences at most
    ik_kwargs : dict, extra arguments for :func:`.ik.ut_ik`
    margin : float, a proposal replaces ``x_best`` only when its cost is lower by more than this
        (in ``cost_fn``'s units): a wrong correspondence whose refined pose is merely as good
        as ``x_best`` must not win on noise
    control : bool, before the first proposal, refine ``x_best`` itself with ``hill_climb_fn``
        (kept when better). Every proposal gets that extra climb; without the control, the
        extra climb alone, not the evidence, can make a wrong proposal beat ``x_best``.
    reach : dict part name -> ``(anchor_fn, radius)``, optional: a detection is matched to the
        part only when it lies within ``radius`` metres of ``anchor_fn(x_best[None])[0]`` (e.g. a
        hand within arm's length of its shoulder). The IK moves the part's chain only, so a
        farther detection cannot be reached; its proposal is an outstretched limb that the
        following climb bends into some other local optimum, and it only costs time and risk.
    nearest : bool, match a detection only to the part of its class nearest to it in
        ``x_best``. A foot detection that the right foot is nearer to is that foot's; moving the
        left foot onto it swaps the legs, which the depth cost hardly penalises and hill
        climbing cannot undo (walk clip: one such move took the error from 0.08 to 0.22 m).
        A part the tracker has really lost is still matched when its sibling is tracked, since
        the sibling's own detection is then explained and pruned.
    refine_many : callable ``(X (K, D), parts) -> (X (K, D), costs (K,), evaluations,
        calls)``, ``parts`` the K proposals' part names, optional: refines all proposals of a
        pass together (one batch of engine calls for all,
        e.g. :func:`gltrack.sample.hillclimb.stage_climb`) instead of ``hill_climb_fn`` one by
        one. Every proposal of a pass then starts from the same best pose, so a pass accepts
        only the best of them (the others were proposed from a pose that is no longer the
        best); the next pass proposes again from the new one.
    speculate : bool, with ``refine_many``: keep the one-by-one greedy order instead. The
        pass's remaining proposals are refined together from the current best pose and taken
        in order; when one is accepted, those after it are proposed and refined again from the
        new best pose. With ``refine_many`` the batched twin of ``hill_climb_fn`` (e.g.
        :func:`gltrack.sample.hillclimb.hill_climb_lanes`) the result is the one-by-one
        loop's, in one batch of engine calls per acceptance instead of one per proposal
        (acceptances are rare: most proposals are refused).
    screen : float, optional, in ``cost_fn``'s units: a proposal whose IK pose costs more than
        the best pose's cost plus this is not refined (the proposals of a pass are scored
        together first, one batch). Refining takes most of evidence propagation's time and
        most proposals are refused; a short climb takes off part of how far a proposal
        starts above the best (typically three quarters), so one that starts far above it
        seldom wins. None: every proposal is refined.

    Returns
    -------
    EPResult
    """
    x_best = np.array(x_best, dtype=np.float64).ravel()
    det = _as_detections(detections)
    evals = 0
    if cost_best is None:
        cost_best = float(np.asarray(cost_fn(x_best[None]), dtype=np.float64).ravel()[0])
        evals += 1
    accepted = []
    names = [n for n in part_fns if n in classes]
    R = np.eye(3) * float(meas_std) ** 2
    ik_kwargs = dict(ik_kwargs or {})
    used = np.zeros(len(det), dtype=bool)

    def reachable(name, x):
        if reach is None or name not in reach or len(det) == 0:
            return np.ones(len(det), dtype=bool)
        fn, radius = reach[name]
        a = np.asarray(fn(x[None]), dtype=np.float64).reshape(-1, 3)[0]
        return np.linalg.norm(det.points - a, axis=1) <= float(radius)

    def parts_of(x):
        return np.concatenate([np.asarray(part_fns[n](x[None]), dtype=np.float64).reshape(1, 3)
                               for n in names]) if names else np.zeros((0, 3))

    def propose(name, j):
        return ut_ik(x_best, part_fns[name], det.points[j], R, sigma,
                     dofs=None if chains is None else chains[name], lower=lower, upper=upper,
                     **ik_kwargs)

    def screened(pending, iks):
        """The proposals (and their IK results) worth refining (see ``screen``)."""
        nonlocal evals
        if screen is None or not pending:
            return pending, iks
        c0 = np.asarray(cost_fn(np.stack([ik.x for ik in iks])), dtype=np.float64).ravel()
        evals += len(iks)
        keep = c0 <= cost_best + float(screen)
        log.debug("EP screen: %d of %d proposals refined", int(keep.sum()), len(keep))
        return ([c for c, k in zip(pending, keep) if k], [ik for ik, k in zip(iks, keep) if k])

    def accept(name, j, ik, x_new, c_new):
        """``x_new`` (cost ``c_new``) replaces the best pose: detection ``j`` is ``name``."""
        nonlocal x_best, cost_best, used
        c_new = float(c_new)
        log.debug("EP: %s <- detection %d (%s): cost %.4g -> %.4g", name, j, det.classes[j],
                  cost_best, c_new)
        accepted.append({"part": name, "detection": int(j), "class": det.classes[j],
                         "cost_before": cost_best, "cost_after": c_new,
                         "ik_residual": float(np.linalg.norm(ik.residual))})
        x_best, cost_best = np.asarray(x_new, dtype=np.float64).ravel(), c_new
        used[j] = True
        # the new pose may explain other detections too
        used |= ~prune_explained(det.points, parts_of(x_best), prune_radius)

    for _ in range(int(max_passes)):
        improved = False
        open_ = ~used & prune_explained(det.points, parts_of(x_best), prune_radius)
        ok = {n: reachable(n, x_best) for n in names}
        if nearest and len(det):
            P = parts_of(x_best)
            dist = np.linalg.norm(det.points[:, None] - P[None], axis=2)  # (J, parts)
            for j in range(len(det)):
                same = [k for k, n in enumerate(names) if classes[n] == det.classes[j]]
                if same:
                    keep = same[int(np.argmin(dist[j, same]))]
                    for k in same:
                        ok[names[k]][j] &= k == keep
        cands = [(n, j) for n in names for j in np.nonzero(open_)[0]
                 if det.classes[j] == classes[n] and ok[n][j]]
        log.debug("EP pass: %d open detections, %d correspondences", int(open_.sum()), len(cands))
        if control and cands:
            control = False
            x_c, c_c, e = hill_climb_fn(x_best, None)
            evals += int(e)
            if float(c_c) < cost_best:
                x_best, cost_best = np.asarray(x_c, dtype=np.float64).ravel(), float(c_c)
        if refine_many is not None and speculate:
            pending = cands
            while pending:
                pending = [(n, j) for n, j in pending if not used[j]]
                if not pending:
                    break
                pending, iks = screened(pending, [propose(name, j) for name, j in pending])
                if not pending:
                    break
                X_new, c_new, e, _ = refine_many(np.stack([ik.x for ik in iks]),
                                                 [name for name, _ in pending])
                evals += int(e)
                won = next((i for i, c in enumerate(c_new) if float(c) < cost_best - margin),
                           None)
                if won is None:
                    break
                name, j = pending[won]
                accept(name, j, iks[won], X_new[won], c_new[won])
                improved = True
                pending = pending[won + 1:]
            cands = []
        if refine_many is not None and cands:
            cands, iks = screened(cands, [propose(name, j) for name, j in cands])
        if refine_many is not None and cands:
            X_new, c_new, e, _ = refine_many(np.stack([ik.x for ik in iks]),
                                             [name for name, _ in cands])
            evals += int(e)
            c_new = np.asarray(c_new, dtype=np.float64)
            b = int(np.argmin(c_new))  # the first of equal costs: the detector's order
            if c_new[b] < cost_best - margin:
                name, j = cands[b]
                accept(name, j, iks[b], X_new[b], c_new[b])
                improved = True
            cands = []
        for name, j in cands:
            if used[j]:
                continue
            ik = propose(name, j)
            if not screened([(name, j)], [ik])[0]:
                continue
            x_new, c_new, e = hill_climb_fn(ik.x, name)
            evals += int(e)
            if float(c_new) < cost_best - margin:
                accept(name, j, ik, x_new, c_new)
                improved = True
        if not improved:
            break
    return EPResult(x_best, cost_best, evals, accepted)
