"""Behaviour-model tracker of Caillette, Galata & Howard (2008), method ``vlmm`` (multi-view).

A particle filter whose motion prior is a learnt behaviour model (``gltrack learn``):

* prediction: every particle carries its feature vector ``X = (angles, velocities)`` and its
  VLMM state; :meth:`BehaviourModel.predict` moves the modelled joint angles (eq. 3: jump to a
  cluster drawn from ``N(X | cluster) * gamma(q, k)``; eq. 4: local second-order dynamics with
  the cluster's own covariance as noise). The six root parameters, which the model does not
  describe, and any joint angle of the body that the model does not cover, get plain Gaussian
  diffusion (:class:`VlmmPrior`);
* weighting: either the GPU silhouette XOR count against every camera's foreground mask
  (``evaluation = "silhouette"``), or the paper's fast evaluation (``"blobs"``): voxels carved
  from the masks (:mod:`gltrack.observe.voxels`), Gaussian blobs fitted to them by EM from the
  predicted poses of the best-supported clusters, and the KL divergence between each particle's
  part blobs and the fitted ones (:mod:`gltrack.observe.blobs`). Costs become weights
  ``exp(-beta * cost)`` with ``beta`` set so the effective sample size is ``survival * N``
  (cost scales differ by orders of magnitude between the two evaluations);
* SIR resampling; the estimate is the weighted mean (option estimate; "best" is the paper's
  maximum of the posterior).

Initialisation (``--init auto``) and recovery follow the paper: the body is placed at the
centroid of the voxels carved from the masks and every cluster mean is tried at ``headings``
headings; the best-scoring candidate starts the tracker. When the frame's best fit is worse
than ``lost_threshold`` for ``lost_frames`` frames in a row the particles are re-drawn from
those candidates over all clusters (VLMM histories reset).

Other trackers can use the behaviour prior through :func:`vlmm_prior` (see
:class:`VlmmPrior`).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import logsumexp

from gltrack.motion.behaviour import BehaviourModel
from gltrack.sample.resampling import systematic_resample
from gltrack.sample.weights import Weights, annealing_exponent

from .base import FrameEstimate, Tracker
from .blob_evidence import (BlobEvidenceOptions, ColourAcquisition, placed_candidates,
                            stage_seconds)
from .blobfilter import LOST_KL, inject_failure
from .runner import register

log = logging.getLogger(__name__)

EVALUATIONS = ("silhouette", "blobs")
#: Default "lost" thresholds: silhouette XOR pixels per foreground pixel; blob KL in nats.
LOST_DEFAULT = {"silhouette": 0.8, "blobs": LOST_KL}


# ------------------------------------------------------------------------------- the prior
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


class VlmmPrior:
    """The behaviour model as a particle motion model, keeping each particle's VLMM state.

    Parameters
    ----------
    model : BehaviourModel
    dofs : gltrack.body.dofs.DofSet of the tracked body (the model's angles are found by name)
    fps : float, frame rate of the tracked data
    lam : float, noise attenuation of the local dynamics (eq. 4)
    root_scale : float, multiplier of the DOF set's root sigmas for the root diffusion
    other_scale : float, multiplier of the sigmas of body angles the model does not cover

    Use: :meth:`reset` with the start particles, then per frame ``x = prior.predict(x, rng)``;
    after resampling with indices call :meth:`select`, or, when a sampler resamples internally
    (``SIRFilter.step`` returns copies of predicted rows, annealing layers move them a little),
    :meth:`follow` with the sampler's output so every row inherits the state of the predicted
    particle it came from.
    """

    def __init__(self, model: BehaviourModel, dofs, fps: float, *, lam: float = 0.5,
                 root_scale: float = 1.0, other_scale: float = 1.0):
        self.model, self.dofs, self.fps, self.lam = model, dofs, float(fps), float(lam)
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
        self.other_sigma = other_scale * sig[rest]
        self._a = a
        self.X = None
        self.states = None

    # -- state bookkeeping -------------------------------------------------------------------
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
        Xn, sn = self.model.predict(rng, X, self.states, lam=self.lam, dt=1.0 / self.fps)
        out = P.copy()
        out[:, self.idx] = Xn[:, :self._a]
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
        """Set histories of ``particles`` (N, D) to fresh ones in ``clusters`` (N,) (recovery)."""
        P = np.asarray(particles, dtype=np.float64)
        k = np.asarray(clusters, dtype=np.int64)
        self.X = np.concatenate([P[:, self.idx], self.model.gmm.means[k, self._a:]], axis=1)
        self.states = self._state_of(k)


def vlmm_prior(model, dofs, fps: float, **kwargs) -> VlmmPrior:
    """The behaviour prior for any particle tracker (the issue's ``--prior vlmm``).

    Parameters
    ----------
    model : BehaviourModel or path to a model .npz written by ``gltrack learn``
    dofs : DofSet of the tracked body
    fps : float, frame rate of the tracked data
    **kwargs : ``lam``, ``root_scale``, ``other_scale`` of :class:`VlmmPrior`

    Hook: replace the tracker's ``diffuse(particles)`` by ``prior.predict(particles, rng)``
    before weighting, and after the sampler's resampling call ``prior.select(indices)`` or
    ``prior.follow(result.particles)``. The samplers of :mod:`gltrack.sample` take it directly:
    ``res = sampler.step(particles, weight_fn, rng, predict_fn=prior.predict)`` then
    ``prior.follow(res.particles)`` (what the multi-view trackers do with ``prior = "vlmm"``).
    """
    if not isinstance(model, BehaviourModel):
        model = BehaviourModel.load(model)
    return VlmmPrior(model, dofs, fps, **kwargs)


# ----------------------------------------------------------------------------- the tracker
@dataclass
class VlmmOptions(BlobEvidenceOptions):
    """Options of the behaviour-model tracker (``--config`` keys): those of the blob likelihood
    (:class:`~gltrack.track.blob_evidence.BlobEvidenceOptions`; its voxels also place the
    candidates of initialisation and recovery with the silhouette evaluation) plus

    model : path of the behaviour model .npz (``gltrack learn``); required
    particles : particles per frame (= evaluations per frame outside recovery)
    evaluation : "blobs" (voxels + blob KL, the paper's) or "silhouette" (GPU XOR against the
        masks)
    lam : attenuation of the local-dynamics noise (eq. 4)
    root_scale, other_scale : multipliers of the DOF sigmas diffusing the root and the angles
        the model does not cover
    survival : target effective sample size / N that sets the weight exponent
    estimate : weighted "mean" (default: steadier under a noisy likelihood; salsa, condensation
        1000: 47 mm against 80 mm) or "best" particle (the paper's maximum of the posterior)
    tile : silhouette tile side, pixels (power of two)
    fit_inits : clusters (by particle support) whose predicted poses initialise the blob fit
    headings : headings tried per cluster at initialisation and recovery
    lost_threshold : worst acceptable best-fit (silhouette: XOR pixels per foreground pixel,
        blobs: KL nats); 0 = the evaluation's default
    lost_frames : consecutive bad frames before recovery; 0 disables recovery
    """

    model: str = ""
    particles: int = 200
    evaluation: str = "blobs"
    lam: float = 0.5
    root_scale: float = 1.0
    other_scale: float = 1.0
    survival: float = 0.3
    estimate: str = "mean"
    tile: int = 64
    fit_inits: int = 3
    headings: int = 12
    lost_threshold: float = 0.0
    lost_frames: int = 3


class VlmmTracker(Tracker):
    """Particle filter with the learnt behaviour prior (see module docstring)."""

    method = "vlmm"

    def __init__(self, dataset, body, ctx, options: VlmmOptions | None = None, rng=None):
        opt = self.opt = options or VlmmOptions()
        if not opt.model:
            raise ValueError("method vlmm needs a behaviour model: --behaviour MODEL.npz (or "
                             "model = 'MODEL.npz' in --config), learnt by gltrack learn")
        if opt.evaluation not in EVALUATIONS:
            raise ValueError(f"option evaluation must be one of {EVALUATIONS}, got "
                             f"{opt.evaluation!r}")
        if opt.estimate not in ("best", "mean"):
            raise ValueError(f"option estimate must be best or mean, got {opt.estimate!r}")
        if opt.particles < 2:
            raise ValueError(f"option particles must be >= 2, got {opt.particles}")
        if not 0 < opt.survival < 1:
            raise ValueError(f"option survival must be in (0, 1), got {opt.survival}")
        self.ds, self.body = dataset, body
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.model = BehaviourModel.load(opt.model)
        self.prior = VlmmPrior(self.model, body.dofs, dataset.fps, lam=opt.lam,
                               root_scale=opt.root_scale, other_scale=opt.other_scale)
        # the voxels place the candidates of initialisation and recovery in both evaluations
        self.evidence = opt.evidence(dataset, body)
        self.cameras = self.evidence.cameras
        self.lost_threshold = opt.lost_threshold or LOST_DEFAULT[opt.evaluation]
        self.engine = None
        if opt.evaluation == "silhouette":
            from gltrack.render.engine import ScoringEngine

            self.engine = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints,
                                        [c.undistorted() for c in self.cameras], tile=opt.tile)
        self.P = None
        self.est = None
        self._frame = None
        self._fg_pixels = 1.0
        self._bad = 0

    # -- observation ----------------------------------------------------------------------------
    def _load(self, frame):
        """Set the frame: voxels (lazily) and, for the silhouette evaluation, the GPU masks."""
        self.evidence.set_frame(frame)
        if self._frame == frame or self.engine is None:
            self._frame = frame
            return
        self._frame = frame
        fg_total = 0
        t = self.opt.tile
        for i, c in enumerate(self.cameras):
            m = self.ds.mask(frame, i)
            if m is None:
                raise ValueError(f"{self.ds.path}: camera {c.name} has no foreground masks "
                                 f"(camN_mask); evaluation = 'silhouette' needs them")
            block = self.ds.blocking_mask(i)
            if np.any(c.dist):
                m = c.undistort_image(m.astype(np.uint8), cv2.INTER_NEAREST) > 0
                block = c.undistort_image(block.astype(np.uint8), cv2.INTER_NEAREST) > 0
            self.engine.set_masks(i, m, block)
            small = cv2.resize((m & ~block).astype(np.uint8), (t, t),
                               interpolation=cv2.INTER_NEAREST)
            fg_total += int(small.sum())
        self._fg_pixels = max(fg_total, 1)

    # -- evaluation ---------------------------------------------------------------------------
    def costs(self, frame, params) -> np.ndarray:
        """(N,) cost of N poses against frame ``frame`` (lower is better)."""
        self._load(frame)
        if self.engine is not None:
            S = self.body.skinning(params)
            return self.engine.score(S, ["silhouette"])[:, :, 1].sum(axis=1)
        if self.evidence.observed is None:
            self.evidence.fit(np.atleast_2d(params)[:1])
        return self.evidence.costs(params)

    def quality(self, best_cost: float) -> float:
        """The frame's fit figure compared with ``lost_threshold`` (lower is better)."""
        if self.engine is not None:
            return float(best_cost) / self._fg_pixels
        return float(best_cost)

    def _weights(self, cost):
        lw = -(cost - cost.min())
        beta = annealing_exponent(lw, self.opt.survival)
        return Weights(beta * lw)

    # -- initialisation and recovery ---------------------------------------------------------------
    def candidates(self, frame) -> tuple[np.ndarray, np.ndarray]:
        """Every cluster mean at ``headings`` headings, placed so its volume centroid sits on
        the reconstructed voxels' centroid.

        Returns
        -------
        poses : (K * H, D) float64
        clusters : (K * H,) int64
        """
        self._load(frame)
        d, g = self.body.dofs, self.model.gmm
        K, H = g.n_components, max(int(self.opt.headings), 1)
        proto = np.repeat(d.zero(self.body.skeleton)[None], K, axis=0)
        proto[:, self.prior.idx] = g.means[:, :self.model.n_angles]
        return placed_candidates(self.evidence, self.body, proto, H), np.repeat(np.arange(K), H)

    def _search(self, frame):
        P, k = self.candidates(frame)
        if self.engine is None:
            # fitting from every candidate is too slow: fit from the few that explain the
            # voxels best before any fitting
            self.evidence.fit(P[self.evidence.rank(P, self.opt.fit_inits)])
        return P, k, self.costs(frame, P)

    def auto_init(self, frame):
        P, _, c = self._search(frame)
        log.info("auto init: best of %d cluster/heading candidates, cost %.3g", len(P), c.min())
        return P[int(np.argmin(c))]

    def _recover(self, frame):
        P, k, c = self._search(frame)
        w = self._weights(c)
        idx = systematic_resample(w.W, self.rng, self.opt.particles)
        self.P = P[idx].copy()
        self.prior.respawn(self.P, k[idx])
        log.info("frame %d: lost for %d frames, re-initialised from %d clusters", frame,
                 self._bad, self.model.gmm.n_components)
        return len(P)

    # -- tracking -----------------------------------------------------------------------------
    def start(self, frame, params, velocity=None):
        p = self.body.dofs.validate(params)[0]
        self.P = np.repeat(p[None], self.opt.particles, axis=0)
        self.prior.reset(self.P, self.rng)
        self.est = p
        self._bad = 0
        self.colours = ColourAcquisition(self.evidence, frame, p, self.opt.colour_frames
                                         if self.engine is None else 0)

    def step(self, frame):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        t0 = time.perf_counter()
        self._load(frame)
        if frame == self.opt.perturb_frame:
            self.P = inject_failure(self.P, self.body.dofs, self.opt.perturb_rad,
                                    self.opt.perturb_shift)
            log.info("frame %d: failure injected", frame)
        if self.engine is None and self.evidence.empty:
            # no reconstruction: nothing to weigh against or to recover from
            return FrameEstimate(self.est.copy(), float("nan"), 0, {
                "empty": True, "stage_seconds": stage_seconds(self.evidence,
                                                              time.perf_counter() - t0)})
        P = self.prior.predict(self.P, self.rng)
        evals = 0
        if self.engine is None:
            self._fit_from_clusters(P)
        cost = self.costs(frame, P)
        evals += len(P)
        best = int(np.argmin(cost))
        q = self.quality(cost[best])
        lost = q > self.lost_threshold
        self._bad = self._bad + 1 if lost else 0
        info = {"quality": q, "lost": bool(lost),
                "clusters": int(len(np.unique(self.prior.clusters())))}
        w = self._weights(cost)
        est = P[best].copy() if self.opt.estimate == "best" else w.mean(P)
        self.est = est
        self.colours.update(frame, est)
        score = float(cost[best])
        idx = systematic_resample(w.W, self.rng, len(P))
        self.P = P[idx]
        self.prior.select(idx)
        if self.opt.lost_frames > 0 and self._bad >= self.opt.lost_frames:
            evals += self._recover(frame)
            info["recovered"] = True
            self._bad = 0
        info["stage_seconds"] = stage_seconds(self.evidence, time.perf_counter() - t0)
        return FrameEstimate(est, score, evals, info)

    def _fit_from_clusters(self, P):
        """Blob-fit initialisations: the mean predicted pose of the best-supported clusters."""
        cl = self.prior.clusters()
        ks, counts = np.unique(cl, return_counts=True)
        top = ks[np.argsort(-counts)[: max(int(self.opt.fit_inits), 1)]]
        poses = np.stack([P[cl == k].mean(axis=0) for k in top])
        if self.est is not None:
            poses = np.concatenate([poses, self.est[None]])
        self.evidence.fit(poses)

    def close(self):
        if self.engine is not None:
            self.engine.release()
            self.engine = None


register("vlmm", "multiview", "gltrack.track.vlmm:VlmmTracker", "gltrack.track.vlmm:VlmmOptions")
