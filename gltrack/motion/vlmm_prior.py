"""The learnt behaviour model (Caillette et al. 2008) as a particle motion prior.

:class:`VlmmPrior` keeps every particle's feature vector ``X = (angles, velocities)`` and VLMM
state and moves the modelled joint angles with :meth:`BehaviourModel.predict` (eq. 3: jump to a
cluster drawn from ``N(X | cluster) * gamma(q, k)``; eq. 4: local second-order dynamics with the
cluster's own covariance as noise, by default its full one, ``local="full"``). The six root
parameters, which the clusters do not describe, move with the root dynamics the model learnt
(``root="ar1"``: each particle keeps a root velocity that follows a stationary autoregression
with the training takes' spread and memory, :func:`gltrack.motion.behaviour.root_dynamics`) or,
as in the paper, with plain Gaussian diffusion (``root="walk"``); any joint angle of the body
that the model does not cover gets plain Gaussian diffusion.
Any particle sampler of :mod:`gltrack.sample` takes it as its ``predict_fn``.
"""
from __future__ import annotations

import logging

import numpy as np
from scipy.special import logsumexp

from .behaviour import BehaviourModel

log = logging.getLogger(__name__)


def _model_indices(model: BehaviourModel, dofs) -> np.ndarray:
    if model.dof_names:
        missing = [n for n in model.dof_names if n not in dofs.names]
        if missing:
            raise ValueError(f"behaviour model angles {missing[:3]} are not DOFs of the "
                             f"{dofs.preset!r} body; track with the preset the model was learnt "
                             f"with (--dof {model.info.get('preset', '25')})")
        return np.array([dofs.index(n) for n in model.dof_names], dtype=np.int64)
    if model.n_angles != dofs.size - 6:
        raise ValueError(f"behaviour model has {model.n_angles} angles, the {dofs.preset!r} "
                         f"body {dofs.size - 6}")
    return np.arange(6, dofs.size)


def _learnt_or_walk(option: str, value: str, learnt: bool, missing: str,
                    choices=("ar1", "walk")) -> str:
    """``value`` of an option whose choices but the last need something learnt ("ar1" |
    "walk", or ``choices``), or the last choice with a warning when the model lacks it
    (``missing`` says what and why)."""
    if value not in choices:
        raise ValueError(f"{option} must be one of {choices}, got {value!r}")
    if value != choices[-1] and not learnt:
        log.warning("the behaviour model has no learnt %s", missing)
        return choices[-1]
    return value


class VlmmPrior:
    """The behaviour model as a particle motion model, keeping each particle's VLMM state.

    Parameters
    ----------
    model : BehaviourModel
    dofs : gltrack.body.dofs.DofSet of the tracked body (the model's angles are found by name)
    fps : float, frame rate of the tracked data
    lam : float, attenuation of the angles' noise in the local dynamics (eq. 4)
    velocity : "ar1" (default): the velocities follow the model's learnt autoregression about
        the cluster's mean velocity (:mod:`gltrack.motion.behaviour`), so their spread stays
        the cluster's; "walk": the paper's eq. 4, a random walk with noise ``lam_dx``. With the
        blob fit from the true pose (``gltrack bench vlmm`` protocol 1, 200 particles, 150
        frames of cmu_60_10, 2 seeds) "ar1" gives 69-71 mm RMS against 85 with the walk and
        75 with ``lam_dx = 0``; models learnt before ``vel_rho`` existed fall back to "walk"
        with a warning
    lam_dx : float or None, attenuation of the velocities' noise in the random walk; None:
        ``lam`` (the paper's eq. 4 has one coefficient). 0 keeps the velocity a particle got
        when it entered its cluster instead of letting it random-walk: the likelihood sees
        poses, never velocities, so a few hundred particles cannot select velocities and their
        noise integrates into drift. With the blob fit from the true pose (``gltrack bench vlmm``
        protocol 1, 200 particles, frames 0-89, 2 seeds) ``lam_dx = 0`` gives 59.6 mm RMS
        against 86.6 with the paper's 0.5 on cmu_60_10, and 41.0 against 78.1 on cmu_60_13 held
        out of training instead (0.25: 76.4; 0.86, the maximum-likelihood scale of the training
        takes' velocity residuals: 116). It is not the default because a particle that keeps
        its velocity overshoots when its cluster lasts longer than the motion keeps its
        direction: on the periodic test motion of tests/test_track_vlmm.py (silhouette
        evaluation) it tracks worse than a fixed pose (119 against 95 mm)
    root : "ar1" (default): every particle carries a root velocity ``v`` (6 values, m/s and
        rad/s) that follows ``v' = rho v + sqrt(1 - rho^2) sd n`` with the model's learnt
        ``root_dyn`` (``sd``, ``rho``; ``n`` standard normal), and the root moves by ``v' dt``,
        so a particle that turns (a spin) or walks keeps doing so while the likelihood keeps
        it. On the salsa takes the heading's velocity has a spread of 3.1 rad/s (0.10 rad a
        frame at 30 fps, twice the DOF set's root sigma) and a memory of 0.76, the horizontal
        speed 0.54 m/s with 0.94. "walk": the paper's Gaussian diffusion with the DOF set's
        root sigmas. Models learnt before ``root_dyn`` existed fall back to "walk" with a
        warning
    root_scale : float, multiplier of the root's noise (the learnt velocity spread with
        ``root="ar1"``, the DOF set's root sigmas with "walk")
    other_scale : float, multiplier of the sigmas of body angles the model does not cover
    local : "full" (default): the local dynamics' noise comes from each cluster's full
        covariance (:attr:`BehaviourModel.local_covs`), so the angles move together as they do
        in the training takes (the paper's clusters are full: "particles are only propagated
        in valid directions"); "diag": the diagonal covariances the MML clustering fits, each
        angle's noise on its own (the default before); "regressed": "full", and the velocity's
        mean regressed on the angles inside the cluster. ``gltrack bench vlmm``'s two
        protocols over the whole unseen take, 4 seeds (protocol 2 on cmu_60_13: 2), RMS mm,
        diag / full / regressed: protocol 1 (vlmm 200, blob fit from the true pose) cmu_60_10
        83.7 / 81.7 / 77.9, cmu_60_13 82.2 / 82.4 / 90.7; protocol 2 (vlmm 1000, the whole
        system) cmu_60_10 93.9 / 83.1 / 86.1, cmu_60_13 88.4 / 84.1 / 78.1. "full" is never
        worse by more than the seeds' spread; the regression gains on one take and loses 8 mm
        on the other in protocol 1, so it is not the default. Models learnt before
        ``local_covs`` existed fall back to "diag" with a warning

    Use: :meth:`reset` with the start particles, then per frame ``x = prior.predict(x, rng)``;
    after resampling call :meth:`select` with the resampling's ancestor indices
    (``SampleResult.ancestors`` of a one-layer sampler), or, when annealing layers have moved
    the particles since the prediction, :meth:`follow` with the sampler's output so every row
    inherits the state of the predicted particle it came from.
    """

    def __init__(self, model: BehaviourModel, dofs, fps: float, *, lam: float = 0.5,
                 lam_dx: float | None = None, root_scale: float = 1.0,
                 other_scale: float = 1.0, velocity: str = "ar1", root: str = "ar1",
                 local: str = "full"):
        self.model, self.dofs, self.fps, self.lam = model, dofs, float(fps), float(lam)
        self.velocity = _learnt_or_walk(
            "velocity", velocity, model.vel_rho is not None,
            "velocity memory (it was learnt by an older gltrack): its velocities random-walk as "
            "in the paper; relearn it with gltrack learn for the learnt autoregression")
        self.root = _learnt_or_walk(
            "root", root, model.root_dyn is not None,
            "root dynamics (it was learnt by an older gltrack): the root diffuses as in the "
            "paper; relearn it with gltrack learn for the learnt root velocities")
        self.local = _learnt_or_walk(
            "local", local, model.local_covs is not None,
            "full cluster covariances (it was learnt by an older gltrack): the local dynamics' "
            "noise comes from the diagonal ones; relearn it with gltrack learn for the full "
            "ones", choices=("full", "regressed", "diag"))
        self.lam_dx = self.lam if lam_dx is None else float(lam_dx)
        if abs(model.fps - self.fps) > 1e-6 * self.fps:
            log.warning("behaviour model learnt at %g frames/s, data at %g: cluster transitions "
                        "will run at the wrong tempo (relearn with --fps %g)", model.fps,
                        self.fps, self.fps)
        self.idx = _model_indices(model, dofs)
        a = model.n_angles
        rest = np.setdiff1d(np.arange(6, dofs.size), self.idx)
        self.other = rest
        sig = dofs.sigma_at(self.fps)
        self.root_sigma = root_scale * sig[:6]
        if self.root == "ar1":
            # velocity spread per second; the memory is per model frame, so it is rescaled to
            # this data's frame interval
            self.root_sd = root_scale * model.root_dyn[0]
            self.root_rho = model.root_dyn[1] ** (model.fps / self.fps)
        self.other_sigma = other_scale * sig[rest]
        self._a = a
        self.X = None
        self.states = None
        self.V = None  # (N, 6) root velocities (root="ar1")

    # -- state bookkeeping -------------------------------------------------------------------
    def get_state(self) -> dict:
        """The particles' histories (``X``, VLMM ``states``, root velocities ``V``; None before
        any), for a checkpoint."""
        return {"X": None if self.X is None else self.X.copy(),
                "states": None if self.states is None else np.asarray(self.states).copy(),
                "V": None if self.V is None else self.V.copy()}

    def set_state(self, state: dict) -> None:
        """Take over histories from :meth:`get_state`."""
        self.X = None if state["X"] is None else np.array(state["X"], dtype=np.float64)
        self.states = None if state["states"] is None else np.array(state["states"])
        V = state.get("V")  # checkpoints written before the root dynamics lack it
        self.V = None if V is None else np.array(V, dtype=np.float64)

    def _angle_cluster_logpost(self, angles):
        """(N, K) log P(cluster | angles) from the clusters' angle marginals."""
        g, a = self.model.gmm, self._a
        mu, cov = g.means[:, :a], g.covs[:, :a, :a]
        diff = angles[:, None, :] - mu[None]
        L = np.linalg.cholesky(cov + 1e-9 * np.eye(a))
        y = np.linalg.solve(L[None], diff[..., None])[..., 0]
        logdet = 2 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)
        lp = -0.5 * (np.sum(y * y, axis=-1) + logdet) + np.log(g.weights)
        return lp - logsumexp(lp, axis=1, keepdims=True)

    def reset(self, particles, rng: np.random.Generator) -> None:
        """Start histories for ``particles`` (N, D): each gets a cluster drawn from the posterior
        of its joint angles, that cluster's mean velocity and the VLMM state of that cluster."""
        P = self.dofs.validate(particles)
        ang = P[:, self.idx]
        lp = self._angle_cluster_logpost(ang)
        k = self._draw(np.exp(lp), rng)
        self.X = np.concatenate([ang, self.model.gmm.means[k, self._a:]], axis=1)
        self.states = self._state_of(k)
        self.V = (rng.standard_normal((len(P), 6)) * self.root_sd if self.root == "ar1"
                  else None)

    def _state_of(self, clusters):
        table = np.array([self.model.state_for([c]) for c in range(self.model.gmm.n_components)])
        return table[np.asarray(clusters, dtype=np.int64)]

    @staticmethod
    def _draw(p, rng):
        cdf = np.cumsum(p, axis=1)
        u = rng.random(len(p))[:, None] * cdf[:, -1:]
        return np.minimum(np.sum(cdf <= u, axis=1), p.shape[1] - 1)

    def clusters(self) -> np.ndarray:
        """(N,) current cluster of each particle (-1 without history)."""
        return self.model.vlmm.last_symbol[self.states]

    def predict(self, particles, rng: np.random.Generator) -> np.ndarray:
        """Propagate (N, D) particles one frame; returns new (N, D) particles within the limits."""
        P = self.dofs.validate(particles, clamp=False)
        if self.X is None or len(self.X) != len(P):
            self.reset(P, rng)
        X = self.X.copy()
        X[:, :self._a] = P[:, self.idx]  # a sampler may have moved the angles since
        Xn, sn = self.model.predict(rng, X, self.states, lam=self.lam, lam_dx=self.lam_dx,
                                    dt=1.0 / self.fps, velocity=self.velocity,
                                    local=self.local)
        out = P.copy()
        out[:, self.idx] = Xn[:, :self._a]
        if self.root == "ar1":
            if self.V is None or len(self.V) != len(P):  # e.g. a checkpoint without them
                self.V = np.zeros((len(P), 6))
            rho = self.root_rho
            self.V = (rho * self.V
                      + np.sqrt(1.0 - rho ** 2) * self.root_sd * rng.standard_normal((len(P), 6)))
            out[:, :6] += self.V / self.fps
        else:
            out[:, :6] += rng.standard_normal((len(P), 6)) * self.root_sigma
        if self.other.size:
            out[:, self.other] += rng.standard_normal((len(P), self.other.size)) * self.other_sigma
        out = self.dofs.validate(out)
        Xn[:, :self._a] = out[:, self.idx]
        self.X, self.states = Xn, sn
        return out

    def select(self, idx) -> None:
        """Keep the histories of the rows ``idx`` (after resampling with these indices)."""
        idx = np.asarray(idx, dtype=np.int64)
        self.X, self.states = self.X[idx], self.states[idx]
        if self.V is not None:
            self.V = self.V[idx]

    def follow(self, particles) -> None:
        """Re-align histories with ``particles`` (N', D) that descend from the last prediction:
        each row takes the state and velocity of its nearest predicted particle (in the
        modelled angles; exact copies find themselves)."""
        P = np.asarray(particles, dtype=np.float64)
        ang = P[:, self.idx]
        ref = self.X[:, :self._a]
        nearest = np.empty(len(P), dtype=np.int64)
        for s in range(0, len(P), 512):
            d = np.sum((ang[s:s + 512, None, :] - ref[None]) ** 2, axis=-1)
            nearest[s:s + 512] = np.argmin(d, axis=1)
        self.select(nearest)
        self.X[:, :self._a] = ang

    def respawn(self, particles, clusters) -> None:
        """Set histories of ``particles`` (N, D) to fresh ones in ``clusters`` (N,) (recovery);
        their roots start at rest."""
        P = np.asarray(particles, dtype=np.float64)
        k = np.asarray(clusters, dtype=np.int64)
        self.X = np.concatenate([P[:, self.idx], self.model.gmm.means[k, self._a:]], axis=1)
        self.states = self._state_of(k)
        self.V = np.zeros((len(P), 6)) if self.root == "ar1" else None


def vlmm_prior(model, dofs, fps: float, **kwargs) -> VlmmPrior:
    """The behaviour prior for any particle tracker (the issue's ``--prior vlmm``).

    Parameters
    ----------
    model : BehaviourModel or path to a model .npz written by ``gltrack learn``
    dofs : DofSet of the tracked body
    fps : float, frame rate of the tracked data
    **kwargs : ``lam``, ``lam_dx``, ``root_scale``, ``other_scale``, ``velocity``, ``root``,
        ``local`` of :class:`VlmmPrior`

    The samplers of :mod:`gltrack.sample` take it directly:
    ``res = sampler.step(particles, weight_fn, rng, predict_fn=prior.predict)`` then
    ``prior.follow(res.particles)`` (what the multi-view trackers do with ``prior = "vlmm"``) or
    ``prior.select(res.ancestors)`` after a one-layer sampler (the ``vlmm`` tracker).
    """
    if not isinstance(model, BehaviourModel):
        model = BehaviourModel.load(model)
    return VlmmPrior(model, dofs, fps, **kwargs)
