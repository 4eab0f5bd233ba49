"""Probabilistic inverse kinematics linearised by the unscented transform.

Ganapathi et al. (2010, "Probabilistic inverse kinematics"): given the previous pose ``x_prev``,
a Gaussian prior on the change of the pose, ``x ~ N(x_prev, Sigma)`` (over the DOFs of the
kinematic chain that carries the part), and an observation that body part ``i`` is at ``y``,
``y ~ N(p_i(x), R)``, find the posterior mode of ``x``. ``p_i`` is non-linear, so it is replaced
by a linear-Gaussian fit obtained with sigma points (statistical linear regression), the
linear-Gaussian posterior is computed in closed form, and the fit is repeated about the new
estimate until it stops moving: an iterated posterior-linearisation (iterated UKF) update.

Iteration ``i`` with linearisation density ``N(m_i, P_i)`` (``m_0 = x_prev``, ``P_0 = Sigma``)::

    sigma points X_k of N(m_i, P_i), Y_k = p(X_k)
    y_bar, P_yy = UT(Y);  P_xy = cross-covariance(X, Y)
    A = P_xy^T P_i^-1,  b = y_bar - A m_i,  Omega = P_yy - A P_i A^T
        (so that p(x) ~ A x + b + N(0, Omega) near the linearisation density)
    S = A Sigma A^T + R + Omega;  K = Sigma A^T S^-1
    m_{i+1} = x_prev + K (y - A x_prev - b);  P_{i+1} = Sigma - K S K^T

A step that would raise the negative log posterior is halved until it does not (a safeguard
against overshooting near joint limits or for unreachable targets). Because the sigma points
span the posterior spread rather than the tangent at the mode, the fixed point lies close to,
not exactly at, the MAP pose (the mean shift ``y_bar - p(m_i)`` of a curved ``p`` is kept).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .ut import MerweScaledSigmaPoints, cross_covariance, unscented_transform

log = logging.getLogger(__name__)


#: Joints shared by several limbs: moving them to place one part displaces the others.
TORSO = ("spine_lower", "spine_upper")


def chain_dofs(skeleton, dofs, joint, *, include_root: bool = False,
               include_torso: bool = True, include_joint: bool = True) -> np.ndarray:
    """DOFs that move ``joint``'s bone: its own and its ancestors'.

    Parameters
    ----------
    skeleton : Skeleton; dofs : DofSet
    joint : str or int, the bone that carries the part (e.g. ``"l_wrist"`` for the left hand)
    include_root : bool, also the six root DOFs (moving them moves every limb)
    include_torso : bool, also the spine joints of :data:`TORSO` (they move the other arm and
        the head too)
    include_joint : bool, the joint's own DOFs (e.g. the wrist's for a hand tip)

    Returns
    -------
    (d,) int64, sorted indices into the pose vector
    """
    j = skeleton.index(joint) if isinstance(joint, str) else int(joint)
    chain = []
    k = j if include_joint else int(skeleton.parents[j])
    while k > 0:
        if include_torso or skeleton.names[k] not in TORSO:
            chain.append(k)
        k = int(skeleton.parents[k])
    idx = [i for i in range(dofs.size) if dofs.joint[i] in chain and dofs.slot[i] >= 0]
    if include_root:
        idx = list(range(6)) + idx
    return np.array(sorted(set(idx)), dtype=np.int64)


def part_chains(skeleton, dofs, *, include_torso: bool = False) -> dict:
    """Chain DOFs of every part in :data:`gltrack.evidence.parts.PART_NAMES` (no root DOFs).

    Without the torso (the default) a proposal for one part leaves every other limb exactly
    where it was; the hill climb that follows adjusts the torso.
    """
    from .parts import PART_BONES, PART_NAMES

    return {n: chain_dofs(skeleton, dofs, b, include_torso=include_torso)
            for n, b in zip(PART_NAMES, PART_BONES)}


@dataclass
class IKResult:
    """Outcome of :func:`ut_ik`.

    Attributes
    ----------
    x : (D,) float64, posterior mode (DOFs outside the chain are ``x_prev``'s)
    cov : (d, d) float64, posterior covariance of the chain DOFs
    dofs : (d,) int64, the chain DOFs
    iterations : int
    converged : bool
    residual : (m,) float64, ``y - part_fn(x)``
    """

    x: np.ndarray
    cov: np.ndarray
    dofs: np.ndarray
    iterations: int
    converged: bool
    residual: np.ndarray


def ut_ik(x_prev, part_fn, y, R, sigma, *, dofs=None, lower=None, upper=None,
          alpha: float = 0.5, beta: float = 2.0, kappa: float = 0.0, max_iter: int = 30,
          tol: float = 1e-4) -> IKResult:
    """Posterior mode of the pose given that a body part is observed at ``y``.

    Parameters
    ----------
    x_prev : (D,) float, prior mean (previous or current best pose)
    part_fn : callable, ``X (N, D) -> (N, m)``, part location of N poses (e.g. metres)
    y : (m,) float, observed location
    R : (m, m) float or scalar, observation noise covariance (a scalar is a variance times I)
    sigma : (D,) float standard deviations or (D, D) covariance of the prior on the pose change
        (e.g. ``DofSet.sigma_at(fps)``); only the ``dofs`` rows/columns are used
    dofs : (d,) int, DOFs that may move (e.g. :func:`chain_dofs`); default all with sigma > 0
    lower, upper : (D,) float, optional, limits the estimate is clipped to
    alpha, beta, kappa : sigma-point parameters (:class:`.ut.MerweScaledSigmaPoints`)
    max_iter : int, re-linearisations at most
    tol : float, stop when no chain DOF moves more than this between iterations

    Returns
    -------
    IKResult
    """
    x_prev = np.asarray(x_prev, dtype=np.float64).ravel()
    D = x_prev.size
    y = np.asarray(y, dtype=np.float64).ravel()
    m = y.size
    R = np.asarray(R, dtype=np.float64)
    R = np.eye(m) * R if R.ndim == 0 else R
    if R.shape != (m, m):
        raise ValueError(f"R must be ({m}, {m}), got {R.shape}")
    sig = np.asarray(sigma, dtype=np.float64)
    Sfull = np.diag(sig ** 2) if sig.ndim == 1 else sig
    if Sfull.shape != (D, D):
        raise ValueError(f"sigma must be ({D},) or ({D}, {D}), got {sig.shape}")
    idx = (np.nonzero(np.diag(Sfull) > 0)[0] if dofs is None
           else np.asarray(dofs, dtype=np.int64).ravel())
    if idx.size == 0:
        raise ValueError("no DOFs to move (empty chain or zero prior)")
    lo = np.full(D, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(D, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    lo, hi = lo[idx], hi[idx]

    mu0 = x_prev[idx]
    S0 = Sfull[np.ix_(idx, idx)]
    pts = MerweScaledSigmaPoints(idx.size, alpha=alpha, beta=beta, kappa=kappa)

    def f(sub):
        X = np.repeat(x_prev[None], len(sub), axis=0)
        X[:, idx] = sub
        out = np.asarray(part_fn(X), dtype=np.float64).reshape(len(sub), m)
        if not np.all(np.isfinite(out)):
            raise ValueError("part_fn returned non-finite positions")
        return out

    S0_inv = np.linalg.inv(S0)
    R_inv = np.linalg.inv(R)

    def objective(sub, fx):  # negative log posterior (x2), up to a constant
        dx, dy = sub - mu0, y - fx
        return float(dx @ S0_inv @ dx + dy @ R_inv @ dy)

    mean, P = mu0.copy(), S0.copy()
    J = objective(mean, f(mean[None])[0])
    converged = False
    it = 0
    for it in range(1, int(max_iter) + 1):
        X = pts.sigma_points(mean, P)
        Y = f(X)
        y_bar, Pyy = unscented_transform(Y, pts.Wm, pts.Wc)
        Pxy = cross_covariance(X, mean, Y, y_bar, pts.Wc)
        # A = Pxy^T P^-1; lstsq copes with the near-singular P of converged directions
        A = np.linalg.lstsq(P, Pxy, rcond=1e-12)[0].T
        b = y_bar - A @ mean
        Omega = Pyy - A @ P @ A.T
        Omega = 0.5 * (Omega + Omega.T)
        S = A @ S0 @ A.T + R + Omega
        K = np.linalg.solve(S, A @ S0).T
        new = np.clip(mu0 + K @ (y - A @ mu0 - b), lo, hi)
        P = S0 - K @ S @ K.T
        P = 0.5 * (P + P.T)
        # Backtrack when the linearised update overshoots (strong curvature, joint limits):
        # the posterior must not get worse, which also stops two-point oscillations.
        J_new = objective(new, f(new[None])[0])
        for _ in range(8):
            if J_new <= J:
                break
            new = mean + 0.5 * (new - mean)
            J_new = objective(new, f(new[None])[0])
        if J_new > J:  # no descent along the linearised step: a stationary point
            converged = True
            break
        step = np.max(np.abs(new - mean))
        mean, J = new, J_new
        if step < tol:
            converged = True
            break
    x = x_prev.copy()
    x[idx] = mean
    res = y - f(mean[None])[0]
    log.debug("ut_ik: %d iterations, converged=%s, |residual|=%.4g", it, converged,
              np.linalg.norm(res))
    return IKResult(x, P, idx, it, converged, res)


def part_reach(kin, chains: dict, slack: float = 0.1) -> dict:
    """Where each part can be put by moving its chain: ``{part: (anchor_fn, radius)}``.

    The anchor is the joint of the chain's outermost bone (e.g. the clavicle joint for a hand
    when the torso is not in the chain), the radius the sum of the chain's bone lengths plus
    the part point's offset (the limb fully stretched) plus ``slack`` (detection noise, soft
    tissue). For :func:`gltrack.evidence.associate.evidence_propagation`'s ``reach``.

    Parameters
    ----------
    kin : gltrack.body.kinematics.Kinematics
    chains : dict part name -> (d,) int DOFs (e.g. :func:`part_chains`)
    slack : float, metres

    Returns
    -------
    dict part name -> (callable ``X (N, D) -> (N, 3)`` metres, radius float metres)
    """
    from .parts import PART_NAMES, part_points

    sk, dofs = kin.skeleton, kin.dofs
    bone, local = part_points(sk)
    out = {}
    for i, name in enumerate(PART_NAMES):
        if name not in chains or len(chains[name]) == 0:
            continue
        joints = {int(dofs.joint[k]) for k in chains[name]}
        path, k = [], int(bone[i])  # the part's bone up to the root
        while k >= 0:
            path.append(k)
            k = int(sk.parents[k])
        top = max((path.index(j) for j in joints if j in path), default=0)
        anchor = path[top]
        radius = float(np.linalg.norm(local[i]) + slack
                       + sum(np.linalg.norm(sk.offsets[j]) for j in path[:top]))

        def fn(X, a=anchor):
            return kin.forward(np.atleast_2d(X)).positions[:, a]

        out[name] = (fn, radius)
    return out
