"""Behaviour-model tracker of Caillette, Galata & Howard (2008), method ``vlmm`` (multi-view).

A particle filter whose motion prior is a learnt behaviour model (``gltrack learn``):

* prediction: :class:`gltrack.motion.vlmm_prior.VlmmPrior` (every particle carries its
  feature vector and VLMM state; eq. 3 cluster jumps, eq. 4 local dynamics; Gaussian diffusion
  of the root and of angles the model does not cover);
* weighting: either the GPU silhouette XOR count against every camera's foreground mask
  (``evaluation = "silhouette"``), or the paper's fast evaluation (``"blobs"``): voxels carved
  from the masks (:mod:`gltrack.observe.voxels`), Gaussian blobs fitted to them by EM from the
  predicted poses of the best-supported clusters, and the KL divergence between each particle's
  part blobs and the fitted ones (:mod:`gltrack.observe.blob_evidence`). Costs become weights
  ``exp(-beta * cost)`` (:func:`gltrack.sample.weights.cost_weights`) with ``beta`` set so the
  effective sample size is ``survival * N`` (cost scales differ by orders of magnitude between
  the two evaluations);
* :class:`gltrack.sample.SIRFilter` (tempered to that survival rate) predicts with the prior,
  weighs and resamples; the estimate is the weighted mean (option estimate; "best" is the
  paper's maximum of the posterior). With ``layers`` > 1 an annealed particle filter (Deutscher)
  takes its place: the prior's prediction is the first layer, the later layers re-weigh the
  same frame's evidence with their own diffusion. The paper's introduction speaks of integrating
  annealed particle filtering with the VLMM, its tracking section resamples once a frame (SIR):
  the default is one layer.

Initialisation (``--init auto``) and recovery follow the paper: the body is placed at the
centroid of the voxels carved from the masks and every cluster mean is tried at ``headings``
headings; the best-scoring candidate starts the tracker. When the frame's best fit is worse
than ``lost_threshold`` for ``lost_frames`` frames in a row the particles are re-drawn from
those candidates over all clusters (VLMM histories reset).

Other trackers use the behaviour prior through :func:`gltrack.motion.vlmm_prior.vlmm_prior`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gltrack.motion.behaviour import LOCAL_DYNAMICS, BehaviourModel
from gltrack.motion.vlmm_prior import VlmmPrior
from gltrack.observe.blob_evidence import ColourAcquisition, placed_candidates, stage_seconds
from gltrack.observe.multiview import MultiviewObservation, SilhouetteLikelihood
from gltrack.sample import (AnnealedParticleFilter, SIRFilter, StateSpace, cost_weights,
                            systematic_resample)
from gltrack.sample.weights import Weights, annealing_exponent

from .base import (FrameEstimate, NoPersonError, Tracker, rng_state, set_rng_state,
                   turned_round)
from .blobfilter import BlobEvidenceOptions
from .options import at_least, choice, within

log = logging.getLogger(__name__)

EVALUATIONS = ("silhouette", "blobs")
#: Default "lost" thresholds: silhouette XOR pixels per foreground pixel; blob KL in nats.
#: The blobs' is tighter than the diffusion filters' LOST_KL (25), because recovery here is the
#: filter's own cheap re-draw from the clusters, not a new automatic start: a set turned 1.5 rad
#: and moved 0.5 m scores 37-39 nats, but the evidence then follows it and its KL falls under
#: 25 within two frames, so 25 for three frames in a row never fired. Well-tracked frames score
#: 1-3 nats (90 % under 7-10). With 10 the failure is recovered from after 3 frames in 5 of 5
#: runs (two unseen salsa takes, against 3-57 frames or never) and protocol 2 gets better too
#: (cmu_60_10: 128 against 139 mm over 3 seeds; cmu_60_13: 181 against 191 over 2).
LOST_DEFAULT = {"silhouette": 0.8, "blobs": 10.0}


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
    lam : attenuation of the local dynamics' angle noise (eq. 4)
    velocity : "ar1" (the velocities' learnt autoregression about the cluster's mean
        velocity) or "walk" (the paper's eq. 4 random walk, noise ``lam_dx``); see
        :class:`~gltrack.motion.vlmm_prior.VlmmPrior`
    lam_dx : attenuation of the random walk's velocity noise (``velocity = "walk"`` only; the
        paper uses ``lam`` for both; 0 keeps a particle's cluster velocity)
    root : "ar1" (the root's learnt dynamics: every particle keeps a root velocity with the
        training takes' spread and memory) or "walk" (the paper's Gaussian diffusion with the
        DOF sigmas); see :class:`~gltrack.motion.vlmm_prior.VlmmPrior`
    local : "full" (each cluster's full covariance for the local dynamics' noise), "diag" (the
        clusters' diagonal covariances) or "regressed" ("full" and the velocity regressed on
        the angles); see :class:`~gltrack.motion.vlmm_prior.VlmmPrior`
    root_scale, other_scale : multipliers of the root's noise and of the DOF sigmas diffusing
        the angles the model does not cover
    survival : target effective sample size / N that sets the weight exponent (one layer)
    layers : 1 (default, the paper's SIR filter) or the annealing layers per frame:
        evaluations per frame = particles * layers; the behaviour prior predicts the first
        layer, every later one diffuses with the particles' own spread
    alpha : target survival rate of each annealing layer (``layers`` > 1; Deutscher's 0.5, as
        ``apf-blobs``)
    estimate : weighted "mean" (default: steadier under a noisy likelihood; salsa, condensation
        1000: 47 mm against 80 mm) or "best" particle (the paper's maximum of the posterior)
    tile : silhouette tile side, pixels (power of two)
    fit_inits : clusters (by particle support) whose predicted poses initialise the blob fit
    fit_prototypes : also fit from this many cluster prototypes (the model's cluster means
        placed on the voxels' centroid at ``headings`` headings), those whose unfitted blobs
        explain the voxels best; the fit with the best voxel likelihood is the evidence. Starts
        that do not come from the predictions keep the evidence from following them (the
        drift) and let a lost particle set show a high KL (bench vlmm, salsa: recovery
        after 3 frames instead of never in 80); 0 = predictions only
    headings : headings tried per cluster at initialisation and recovery
    lost_threshold : worst acceptable best-fit (silhouette: XOR pixels per foreground pixel,
        blobs: KL nats); 0 = the evaluation's default
    lost_frames : consecutive bad frames before recovery; 0 disables recovery
    """

    FLAGS: ClassVar[dict] = {"behaviour": "model"}

    model: str = ""
    particles: int = 200
    evaluation: str = "blobs"
    lam: float = 0.5
    velocity: str = "ar1"
    lam_dx: float = 0.5
    root: str = "ar1"
    local: str = "full"
    root_scale: float = 1.0
    other_scale: float = 1.0
    survival: float = 0.3
    layers: int = 1
    alpha: float = 0.5
    estimate: str = "mean"
    tile: int = 64
    fit_inits: int = 3
    fit_prototypes: int = 3
    headings: int = 12
    lost_threshold: float = 0.0
    lost_frames: int = 3

    def problems(self):
        bad = super().problems() + [
            *choice(self, "evaluation", EVALUATIONS), *choice(self, "estimate", ("best", "mean")),
            *choice(self, "velocity", ("ar1", "walk")), *choice(self, "root", ("ar1", "walk")),
            *choice(self, "local", LOCAL_DYNAMICS),
            *at_least(self, 2, "particles"),
            *within(self, "survival", 0, 1, open_lo=True, open_hi=True),
            *within(self, "alpha", 0, 1, open_lo=True, open_hi=True),
            *at_least(self, 0, "lam", "lam_dx", "root_scale", "other_scale", "lost_threshold",
                      "lost_frames", "fit_prototypes"),
            *at_least(self, 1, "fit_inits", "headings", "layers")]
        if not self.model:
            bad.append("model = \"\": method vlmm needs a behaviour model: --behaviour MODEL.npz "
                       "(or model = 'MODEL.npz' in --config), learnt by gltrack learn")
        return bad


class VlmmTracker(Tracker):
    """Particle filter with the learnt behaviour prior (see module docstring)."""

    method = "vlmm"
    recovers_itself = True  # the paper's recovery: particles re-drawn from the clusters

    def __init__(self, dataset, body, ctx, options: VlmmOptions | None = None, rng=None):
        opt = self.opt = (options or VlmmOptions()).validate()
        self.ds, self.body = dataset, body
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.model = BehaviourModel.load(opt.model)
        self.prior = VlmmPrior(self.model, body.dofs, dataset.fps, lam=opt.lam,
                               lam_dx=opt.lam_dx, root_scale=opt.root_scale, velocity=opt.velocity,
                               root=opt.root, other_scale=opt.other_scale, local=opt.local)
        # the prior is the whole motion step: the filter adds no diffusion of its own (the
        # annealing layers after the first diffuse by the particles' spread, not these sigmas)
        space = StateSpace.from_dofs(body.dofs, dataset.fps)
        self.sampler = (SIRFilter(space, alpha=opt.survival) if opt.layers == 1 else
                        AnnealedParticleFilter(space, layers=opt.layers, alpha=opt.alpha))
        # the voxels place the candidates of initialisation and recovery in both evaluations
        self.evidence = opt.evidence(dataset, body)
        self.cameras = self.evidence.cameras
        self.lost_limit = opt.lost_threshold or LOST_DEFAULT[opt.evaluation]
        self.silhouette = None
        if opt.evaluation == "silhouette":
            self.silhouette = SilhouetteLikelihood(
                ctx, body, MultiviewObservation(dataset, "dataset"), tile=opt.tile,
                blocking="polygons", appearance=False)
        self.P = None
        self.est = None
        self._bad = 0

    # -- observation ----------------------------------------------------------------------------
    def _load(self, frame):
        """Set the frame: voxels (lazily) and, for the silhouette evaluation, the GPU masks."""
        self.evidence.set_frame(frame)
        if self.silhouette is not None and self.silhouette.frame != frame:
            self.silhouette.observe(frame)

    # -- evaluation ---------------------------------------------------------------------------
    def costs(self, frame, params, align_root: bool = False) -> np.ndarray:
        """(N,) cost of N poses against frame ``frame`` (lower is better); ``align_root``
        moves the poses' root translations (in place) to their least KL first (the blob
        evaluation only, see :meth:`BlobEvidence.costs`)."""
        self._load(frame)
        if self.silhouette is not None:
            return self.silhouette.scores(params)[0]
        if self.evidence.observed is None:
            self.evidence.fit(np.atleast_2d(params)[:1])
        return self.evidence.costs(params, align_root=align_root)

    def quality(self, best_cost: float) -> float:
        """The frame's fit figure compared with ``lost_threshold`` (lower is better)."""
        if self.silhouette is not None:
            return float(best_cost) / self.silhouette.area
        return float(best_cost)

    def _weights(self, cost) -> Weights:
        """Weights of (N,) costs tempered to the target survival rate."""
        w = cost_weights(cost)
        return w.tempered(annealing_exponent(w.lw, self.opt.survival))

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
        if self.silhouette is None:
            # fitting from every candidate is too slow: fit from the few that explain the
            # voxels best before any fitting, and as many of the best turned round from the
            # first (more than 90 degrees). The fit with the best voxel likelihood is kept, so
            # the evidence does not just follow one heading: on cmu_60_10 the first frame's
            # start faced 148 degrees the wrong way with the chi-square segmentation and the
            # track stayed turned round (184 mm against 126 with the masks); with the twins it
            # is 2 degrees off, and 3 of 12 sampled frames are put right, none made worse.
            n = self.opt.fit_inits
            order = self.evidence.rank(P, len(P))
            yaw = P[:, self.body.dofs.index("pelvis_ry")]
            turned = turned_round(yaw[order], yaw[order[0]])
            self.evidence.fit(P[np.concatenate([order[:n], order[turned][:n]])])
        return P, k, self.costs(frame, P)

    def start_hypotheses(self, frame):
        return [self.auto_init(frame)]

    def auto_init(self, frame):
        self._load(frame)
        if self.evidence.empty:
            raise NoPersonError(f"frame {frame}: no voxels reconstructed inside the tracking "
                                f"volume {self.evidence.volume.round(2).tolist()}: no person to "
                                "start from")
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
                                         if self.silhouette is None else 0)

    def transform_state(self, fn):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        self.P = self.body.dofs.validate(fn(self.P))

    def get_state(self):
        """Particles, estimate, bad-frame count, VLMM histories, blob colours, generator."""
        if self.P is None:
            return None
        return {"P": self.P.copy(), "est": np.array(self.est, dtype=np.float64),
                "bad": int(self._bad), "prior": self.prior.get_state(),
                "colours": self.colours.get_state(), "rng": rng_state(self.rng)}

    def set_state(self, state):
        self.P = np.array(state["P"], dtype=np.float64)
        self.est = np.array(state["est"], dtype=np.float64)
        self._bad = int(state["bad"])
        self.prior.set_state(state["prior"])
        self.colours = ColourAcquisition.from_state(self.evidence, state["colours"])
        set_rng_state(self.rng, state["rng"])

    def step(self, frame):
        if self.P is None:
            raise RuntimeError("start() the tracker first")
        t0 = time.perf_counter()
        self._load(frame)
        if self.silhouette is None and self.evidence.empty:
            # no reconstruction: nothing to weigh against or to recover from
            return FrameEstimate(self.est.copy(), float("nan"), 0, {
                "empty": True, "stage_seconds": stage_seconds(self.evidence,
                                                              time.perf_counter() - t0)})
        costs = []

        def weigh(P):
            if self.silhouette is None and not costs:
                # one blob fit a frame, from the predicted particles (the first call): the
                # annealing layers that follow weigh against the same evidence
                self._fit_from_clusters(P)
            costs.append(self.costs(frame, P, align_root=self.opt.root_align))
            return cost_weights(costs[-1])

        res = self.sampler.step(self.P, weigh, self.rng, predict_fn=self.prior.predict)
        evals = res.evaluations
        best_cost = float(costs[-1].min())
        q = self.quality(best_cost)
        lost = q > self.lost_limit
        self._bad = self._bad + 1 if lost else 0
        info = {"quality": q, "lost": bool(lost),
                "clusters": int(len(np.unique(self.prior.clusters())))}
        est = res.best if self.opt.estimate == "best" else res.estimate
        self.est = est
        self.colours.update(frame, est)
        self.P = res.particles
        if self.opt.layers == 1:
            self.prior.select(res.ancestors)
        else:  # the layers moved the particles since the prediction
            self.prior.follow(res.particles)
        if self.opt.lost_frames > 0 and self._bad >= self.opt.lost_frames:
            evals += self._recover(frame)
            info["recovered"] = True
            self._bad = 0
        info["stage_seconds"] = stage_seconds(self.evidence, time.perf_counter() - t0)
        return FrameEstimate(est, best_cost, evals, info)

    def _fit_from_clusters(self, P):
        """Blob-fit initialisations: the mean predicted pose of the best-supported clusters."""
        cl = self.prior.clusters()
        ks, counts = np.unique(cl, return_counts=True)
        top = ks[np.argsort(-counts)[: max(int(self.opt.fit_inits), 1)]]
        poses = np.stack([P[cl == k].mean(axis=0) for k in top])
        if self.est is not None:
            poses = np.concatenate([poses, self.est[None]])
            # (the oracle fit of protocol 1 ignores every start: no prototypes to rank)
            n = int(self.opt.fit_prototypes) if self.evidence.fit_from == "predictions" else 0
            if n > 0:
                # cluster means placed on the voxels' centroid at ``headings`` headings: starts
                # the predictions did not choose, so a fit that followed wrong particles (even
                # a metre off) loses to one on the body, and their KL then flags the failure
                g = self.model.gmm
                proto = np.repeat(self.est[None], g.n_components, axis=0)
                proto[:, self.prior.idx] = g.means[:, :self.model.n_angles]
                cand = placed_candidates(self.evidence, self.body, proto, self.opt.headings)
                poses = np.concatenate([poses, cand[self.evidence.rank(cand, n)]])
        self.evidence.fit(poses)

    def close(self):
        if self.silhouette is not None:
            self.silhouette.release()
            self.silhouette = None
