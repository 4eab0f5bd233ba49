"""Multi-camera particle-filter trackers (Bandouch, Kirchlechner & Beetz 2009).

Methods (``gltrack track DATASET --method M``), all on the same observation model:

* ``sir``: sampling importance resampling (one weighting per frame);
* ``apf``: Deutscher's annealed particle filter (10 layers by default);
* ``ps``: partitioned sampling over :func:`gltrack.sample.partitions.fine_partitions`, in
  Bandouch's order (pose and lower torso, upper torso, thighs, shins, upper arms, forearms);
* ``hps``: Bandouch's hierarchical sampler: annealed torso, then parallel limb pipelines.

Motion model (``prior``): ``"diffusion"`` (default), each particle keeps its last state and is
diffused with zero-mean Gaussian noise of the body-part dependent inter-frame standard deviations
(``DofSet.sigma_at(fps)`` times ``sigma_scale``), clamped
to the joint limits; or ``"vlmm"``, the learnt behaviour model ``prior_model`` (``gltrack learn``,
:class:`gltrack.track.vlmm.VlmmPrior`) predicts every particle once per frame and replaces the
first diffusion layer of each sampler stage (``prior_diffusion`` sigmas of Gaussian noise remain
there; the annealing layers after it diffuse as usual). The resampled particle set of one
frame is the prior of the next; with ``"vlmm"`` each resampled particle inherits the VLMM history
of the predicted particle it descends from (``VlmmPrior.follow``).

Observation per frame and colour camera (all images undistorted first, masks with nearest
neighbour; the engine renders the undistorted pinhole cameras):

* I_F, the foreground mask: the dataset's ``CAM_mask`` (background subtraction done when the data
  was recorded) or, when the dataset has none, :class:`gltrack.observe.background.BackgroundModel`
  fitted on the dataset's empty-scene frames;
* the blocking layer (``environment`` on): the occluder polygons of ``environment.json`` and, with
  the appearance model, Bandouch's non-human foreground removal, eqs. 3-7, computed by
  :class:`gltrack.observe.environment.EnvironmentLayers` (without the appearance model the
  human-colour table is all True, which reduces eqs. 5-7 to "polygons minus foreground");
* the observed HLS bitmasks (``appearance`` on) scored against the per-triangle colour clusters of
  :class:`gltrack.observe.appearance.AppearanceModel`, initialised from the start pose.

Weights (``weights="bandouch"``, the default, eq. 2)::

    w = alpha (1 - NORM(e_S)) + beta NORM(c_A),   alpha = 0.7, beta = 0.3

with ``e_S`` the silhouette XOR pixel count summed over the cameras, ``c_A`` the count of
colour-consistent pixels and NORM a min-max scaling over the particles of one weighting batch;
without appearance ``w = 1 - NORM(e_S)``. The weights are relative to the batch, which is why the
hierarchical sampler re-scores its combined pipeline sets in one batch (``reweight="evaluate"``).

``weights="exp"`` is a sharper alternative: ``w = exp(-lambda (e_S - min e_S) / A)`` times
``exp(lambda_A (c_A - max c_A) / A)`` with ``A`` the unblocked foreground area of the frame (pixels
at tile resolution, all cameras). It is a proper likelihood up to a per-batch constant, so plain SIR
and PS (whose single-layer partitions weight with exponent 1) actually concentrate; the annealed
methods pick their own exponent and barely change with it.

Estimate (``estimate``): ``"mean"`` (default), the weighted mean of the final weighted particle set
(Deutscher's estimate: it averages out the Monte Carlo jitter of single particles, so trajectories
are smoother), or ``"best"``, the particle of highest weight.

Score of a frame: the summed silhouette XOR count of the estimate (one extra evaluation, included in
``FrameEstimate.evaluations``).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from gltrack.render.engine import ScoringEngine
from gltrack.sample import (AnnealedParticleFilter, HierarchicalSampler, PartitionedSampler,
                            SIRFilter, StateSpace, bandouch_weights, default_partitions,
                            default_pipelines, fine_partitions)
from gltrack.sample.diffusion import VARIANTS

from .base import FrameEstimate, Tracker
from .runner import register

log = logging.getLogger(__name__)

#: Per-method defaults: particles and layers (APF: annealing layers; HPS: maximum torso layers;
#: PS: layers per partition; SIR: always 1). APF 10 x 800 and PS 1600 are Bandouch's comparison;
#: HPS 200 is his low-particle run, which still beat both.
METHOD_DEFAULTS = {"sir": (800, 1), "apf": (800, 10), "ps": (1600, 1), "hps": (200, 6)}

ESTIMATES = ("mean", "best")
WEIGHTS = ("bandouch", "exp")
FOREGROUNDS = ("auto", "dataset", "background")
PRIORS = ("diffusion", "vlmm")
APPEARANCE_INITS = ("full", "tile")


@dataclass
class MultiviewOptions:
    """Options of the multi-view trackers (``--config`` keys; the DOF preset is ``--dof``).

    particles : particles per frame; 0 = the method's default (sir 800, apf 800, ps 1600, hps 200)
    layers : 0 = the method's default; apf: annealing layers (10); hps: most torso layers (6);
        ps: annealing layers per partition (1 = plain partitioned sampling); ignored by sir
    limb_layers, joint_layers : hps: layers per limb partition of the left-first / right-first
        pipelines, and per partition of the paired (both arms, both legs) pipeline
    survival : target survival rate ESS/N of every annealing layer; 0 = the sampler's default
        (0.5 for apf and ps, 0.3 for hps)
    min_spread : hps: stop torso annealing once every torso DOF's weighted standard deviation is
        below ``min_spread`` inter-frame sigmas (Bandouch's variance threshold); 0 = off
    diffusion : "covariance" (default), "layer_variance" or "constant" layer noise
    sigma_scale : multiplier of the motion model's inter-frame sigmas ``DofSet.sigma_at(fps)``
        (1, default: the 30 frames/s sigmas scaled by ``30 / fps``); 0 = ``sqrt(fps / 30)``, the
        random-walk scaling ``sqrt(30 / fps)``. On the 15 frames/s demo data 0.5, 0.7 and 1
        gave the same two-frame error from the truth (41-44 +- 5 mm); whole-run differences
        were within the seed-to-seed spread (84-158 mm for one setting)
    tile : engine tile side in pixels (power of two); observations are resampled to it
    appearance : use the colour appearance model (channel c_A) when the cameras are colour
    appearance_init : "full" samples the start pose's colours at full camera resolution (CPU
        rasteriser, every visible triangle), "tile" at the engine's tile resolution, where a
        64-pixel tile sees only a few dozen of the ~2000 triangles
    appearance_refine : add colours seen at the estimate every this many frames (0 = never)
    environment : use the blocking layer (occluder polygons, non-human foreground removal)
    foreground : "auto" (dataset masks when present, else background subtraction), "dataset",
        "background"
    weights : "bandouch" (eq. 2, default) or "exp" (sharper, see the module docstring)
    shape_weight, appearance_weight : alpha and beta of eq. 2
    sharpness : lambda of the "exp" weights (per unit of e_S / foreground area)
    estimate : "mean" (weighted mean, default) or "best" (highest-weight particle)
    velocity : fraction of the last frame's change of the estimate added to every particle before
        diffusion (0 = Bandouch's "last state + diffusion"; 1 = constant velocity)
    prior : motion model, "diffusion" (Gaussian, default) or "vlmm" (learnt behaviour model)
    prior_model : path of the behaviour model .npz (``gltrack learn``); required with "vlmm"
    prior_lam : noise attenuation of the behaviour model's local dynamics (eq. 4 of Caillette)
    prior_diffusion : Gaussian diffusion (in inter-frame sigmas) each sampler stage still adds in
        its first layer after the behaviour model's prediction
    """

    particles: int = 0
    layers: int = 0
    limb_layers: int = 2
    joint_layers: int = 4
    survival: float = 0.0
    min_spread: float = 0.0
    diffusion: str = "covariance"
    sigma_scale: float = 1.0
    tile: int = 64
    appearance: bool = True
    appearance_init: str = "full"
    appearance_refine: int = 0
    environment: bool = True
    foreground: str = "auto"
    weights: str = "bandouch"
    shape_weight: float = 0.7
    appearance_weight: float = 0.3
    sharpness: float = 20.0
    estimate: str = "mean"
    velocity: float = 0.0
    prior: str = "diffusion"
    prior_model: str = ""
    prior_lam: float = 0.5
    prior_diffusion: float = 0.5

    def __post_init__(self):
        def choice(name, allowed):
            if getattr(self, name) not in allowed:
                raise ValueError(f"option {name} must be one of {', '.join(allowed)}, "
                                 f"got {getattr(self, name)!r}")

        choice("diffusion", VARIANTS)
        choice("estimate", ESTIMATES)
        choice("weights", WEIGHTS)
        choice("foreground", FOREGROUNDS)
        choice("prior", PRIORS)
        choice("appearance_init", APPEARANCE_INITS)
        if self.prior == "vlmm" and not self.prior_model:
            raise ValueError("option prior = \"vlmm\" needs prior_model = \"MODEL.npz\" (a behaviour "
                             "model written by gltrack learn)")
        if self.prior_lam < 0 or self.prior_diffusion < 0:
            raise ValueError("options prior_lam and prior_diffusion must be >= 0")
        for name in ("particles", "layers", "appearance_refine"):
            if getattr(self, name) < 0:
                raise ValueError(f"option {name} must be >= 0, got {getattr(self, name)}")
        for name in ("limb_layers", "joint_layers"):
            if getattr(self, name) < 1:
                raise ValueError(f"option {name} must be >= 1, got {getattr(self, name)}")
        if not 0.0 <= self.survival < 1.0:
            raise ValueError(f"option survival must be in [0, 1), got {self.survival}")
        if not self.sigma_scale >= 0:
            raise ValueError(f"option sigma_scale must be >= 0, got {self.sigma_scale}")
        if self.min_spread < 0 or self.sharpness <= 0:
            raise ValueError("options min_spread must be >= 0 and sharpness > 0")
        if self.shape_weight < 0 or self.appearance_weight < 0 or \
                self.shape_weight + self.appearance_weight <= 0:
            raise ValueError("options shape_weight and appearance_weight must be >= 0, not both 0")
        t = self.tile
        if t < 16 or t > 512 or t & (t - 1):
            raise ValueError(f"option tile must be a power of two in 16..512, got {t}")


# ---------------------------------------------------------------------------------------------
# observation


class MultiviewObservation:
    """Per-frame colour images and foreground masks of a dataset's colour cameras, undistorted.

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset
    options : MultiviewOptions
    rng : numpy.random.Generator, optional, picks background training frames

    Attributes
    ----------
    index : list of int, dataset camera index of each colour camera
    cameras : list of Camera, as calibrated; pinholes : their undistorted twins
    polygons : list of (H, W) bool, occluder polygons (undistorted), all False without any
    """

    def __init__(self, dataset, options: MultiviewOptions, rng=None):
        self.dataset = dataset
        self.index = [i for i, c in enumerate(dataset.cameras) if c.kind == "colour"]
        if not self.index:
            raise ValueError(f"{dataset.path}: the multi-view trackers need colour cameras")
        self.cameras = [dataset.cameras[i] for i in self.index]
        self.pinholes = [c.undistorted() for c in self.cameras]
        self.polygons = [self._undistort(c, dataset.blocking_mask(i).astype(np.uint8)) != 0
                         for c, i in zip(self.cameras, self.index)]
        has_masks = [dataset.mask(0, i) is not None for i in self.index] if dataset.frames else []
        mode = options.foreground
        if mode == "auto":
            mode = "dataset" if has_masks and all(has_masks) else "background"
        if mode == "dataset" and not all(has_masks):
            missing = [c.name for c, h in zip(self.cameras, has_masks) if not h]
            raise ValueError(f"{dataset.path}: no foreground masks for cameras {missing} "
                             "(use foreground = \"background\")")
        self.mode = mode
        self.rng = rng
        self._bg = {}

    @staticmethod
    def _undistort(cam, img, interpolation=cv2.INTER_NEAREST):
        return cam.undistort_image(img, interpolation) if np.any(cam.dist) else img

    def _background_model(self, k):
        if k not in self._bg:
            from gltrack.observe.background import BackgroundModel

            frames = self.dataset.backgrounds(self.index[k])
            if not frames:
                raise ValueError(f"{self.dataset.path}: camera {self.cameras[k].name} has neither "
                                 "foreground masks nor empty-scene frames for background subtraction")
            self._bg[k] = BackgroundModel().fit(frames, rng=self.rng)
        return self._bg[k]

    def __call__(self, frame: int) -> tuple[list, list]:
        """Undistorted colour images (C of (H, W, 3) uint8 BGR) and foreground masks ((H, W) bool)."""
        images, masks = [], []
        for k, (cam, i) in enumerate(zip(self.cameras, self.index)):
            bgr = self.dataset.colour(frame, i)
            fg = self.dataset.mask(frame, i) if self.mode == "dataset" else \
                self._background_model(k).foreground(bgr)
            images.append(self._undistort(cam, bgr, cv2.INTER_LINEAR))
            masks.append(self._undistort(cam, fg.astype(np.uint8)) != 0)
        return images, masks


# ---------------------------------------------------------------------------------------------
# the tracker


def make_sampler(method: str, dofs, fps: float, opt: MultiviewOptions):
    """The sampler of ``method`` for a ``DofSet`` at ``fps``, and its particle count.

    Returns
    -------
    (sampler, n_particles)
    """
    if method not in METHOD_DEFAULTS:
        raise ValueError(f"unknown multi-view method {method!r}; choose one of "
                         f"{', '.join(METHOD_DEFAULTS)}")
    n_def, l_def = METHOD_DEFAULTS[method]
    n, layers = opt.particles or n_def, opt.layers or l_def
    scale = opt.sigma_scale or float(np.sqrt(fps / 30.0))
    space = StateSpace(dofs.lower, dofs.upper, scale * dofs.sigma_at(fps))
    kw = {"alpha": opt.survival} if opt.survival else {}
    if method == "sir":
        return SIRFilter(space), n
    if method == "apf":
        return AnnealedParticleFilter(space, layers=layers, diffusion=opt.diffusion, **kw), n
    if method == "ps":
        return PartitionedSampler(space, fine_partitions(dofs), layers=layers,
                                  diffusion=opt.diffusion, **kw), n
    spread = opt.min_spread or None
    pipes = default_pipelines(dofs, limb_layers=opt.limb_layers, joint_layers=opt.joint_layers)
    return HierarchicalSampler(space, default_partitions(dofs)["torso"], pipes,
                               torso_layers=layers, min_spread=spread, diffusion=opt.diffusion,
                               **kw), n


class MultiviewTracker(Tracker):
    """Bandouch's multi-camera tracker; subclasses fix the sampler (``method``).

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset, a multiview dataset with colour cameras
    body : gltrack.body.model.BodyModel
    ctx : moderngl.Context
    options : MultiviewOptions
    rng : numpy.random.Generator
    """

    method = "hps"

    def __init__(self, dataset, body, ctx, options: MultiviewOptions | None = None, rng=None):
        self.opt = options or MultiviewOptions()
        self.body = body
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.obs = MultiviewObservation(dataset, self.opt, self.rng)
        self.fps = dataset.fps
        self.engine = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, self.obs.pinholes,
                                    tile=self.opt.tile)
        self.env = None
        if self.opt.environment:
            from gltrack.observe.environment import EnvironmentLayers

            self.env = EnvironmentLayers(ctx, self.obs.pinholes, programs=self.engine.programs)
        self.sampler, self.n = make_sampler(self.method, body.dofs, dataset.fps, self.opt)
        self.prior = None
        if self.opt.prior == "vlmm":
            from .vlmm import vlmm_prior

            self.prior = vlmm_prior(self.opt.prior_model, body.dofs, dataset.fps,
                                    lam=self.opt.prior_lam)
        self.use_appearance = bool(self.opt.appearance)
        self.channels = ["silhouette", "appearance"] if self.use_appearance else ["silhouette"]
        self.appearance = None
        self.particles = None
        self.area = 1.0
        self.frames_done = 0

    # -- observation ----------------------------------------------------------------------
    def _human_lut(self):
        if self.appearance is not None:
            return self.appearance.human_lut()
        from gltrack.observe.hls import N_VOXELS

        return np.ones(N_VOXELS, bool)

    def observe(self, frame: int):
        """Read frame ``frame`` and upload masks (and colour bits) to the engine.

        Returns
        -------
        images : list of (H, W, 3) uint8; fg : list of (H, W) bool, the foreground as scored;
        block : list of (H, W) bool, pixels the costs ignore
        """
        images, masks = self.obs(frame)
        fgs, blocks = [], []
        lut = self._human_lut() if self.env is not None else None
        for c, (img, fg) in enumerate(zip(images, masks)):
            if self.env is not None:
                fg, block = self.env.apply(c, fg, img, self.obs.polygons[c], lut)
            else:
                block = np.zeros_like(fg)
            self.engine.set_masks(c, fg, block)
            if self.appearance is not None:
                from gltrack.observe.hls import observed_bits

                self.engine.set_appearance(c, observed_bits(img), self.appearance.tri_bits())
            fgs.append(fg)
            blocks.append(block)
        T = self.engine.tile
        self.area = max(1.0, float(sum(
            np.count_nonzero(cv2.resize((f & ~b).astype(np.uint8), (T, T),
                                        interpolation=cv2.INTER_NEAREST_EXACT)) for f, b in zip(fgs, blocks))))
        return images, fgs, blocks

    # -- weights --------------------------------------------------------------------------
    def scores(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Silhouette error e_S (N,) and appearance count c_A (N,) or None, summed over cameras."""
        r = self.engine.score(self.body.skinning(np.atleast_2d(X)), self.channels)
        e_s = r[:, :, 1].sum(axis=1)
        c_a = r[:, :, 2].sum(axis=1) if self.appearance is not None else None
        return e_s, c_a

    def weights(self, X: np.ndarray) -> np.ndarray:
        """(N,) non-negative particle weights, larger = better (see the module docstring)."""
        e_s, c_a = self.scores(X)
        o = self.opt
        if o.weights == "bandouch":
            # Without c_A, alpha only scales every weight: use 1 so shape_weight = 0 stays valid.
            alpha = o.shape_weight if c_a is not None else 1.0
            return bandouch_weights(e_s, c_a, alpha, o.appearance_weight)
        z = -o.sharpness * (e_s - e_s.min()) / self.area
        if c_a is not None:
            total = o.shape_weight + o.appearance_weight
            z = (o.shape_weight * z + o.appearance_weight * o.sharpness
                 * (c_a - c_a.max()) / self.area) / total
        return np.exp(z)

    # -- tracking -------------------------------------------------------------------------
    def start(self, frame, params, velocity=None):
        x = self.body.dofs.validate(params)[0]
        self.particles = np.repeat(x[None], self.n, axis=0)
        if self.use_appearance:
            from gltrack.observe.appearance import AppearanceModel

            images, masks = self.obs(frame)
            self.appearance = AppearanceModel.from_first_frame(
                self.body.mesh, self.body.skinning(x[None])[0], self.obs.pinholes, images, masks,
                engine=self.engine if self.opt.appearance_init == "tile" else None, rng=self.rng)
        if self.prior is not None:
            self.prior.reset(self.particles, self.rng)
        self.frames_done = 0
        self.last = x
        self.velocity = np.zeros_like(x) if velocity is None else np.asarray(velocity, float)

    def step(self, frame):
        if self.particles is None:
            raise RuntimeError("start() the tracker first")
        images, fgs, _ = self.observe(frame)
        if self.opt.velocity:
            self.particles = self.body.dofs.validate(self.particles + self.opt.velocity * self.velocity)
        predict = self.prior.predict if self.prior is not None else None
        res = self.sampler.step(self.particles, self.weights, self.rng, predict_fn=predict,
                                predict_scale=self.opt.prior_diffusion)
        self.particles = res.particles
        if self.prior is not None:
            self.prior.follow(self.particles)
        x = res.estimate if self.opt.estimate == "mean" else res.best
        x = self.body.dofs.validate(x)[0]
        self.velocity, self.last = x - self.last, x
        e_s, c_a = self.scores(x[None])
        self.frames_done += 1
        k = self.opt.appearance_refine
        if self.appearance is not None and k and self.frames_done % k == 0:
            self.appearance.refine(self.body.skinning(x[None])[0], self.obs.pinholes, images, fgs,
                                   engine=self.engine)
        info = {"e_s": float(e_s[0]), "foreground_px": self.area,
                "ess": float(res.weights.ess), "weightings": len(res.layers)}
        if c_a is not None:
            info["c_a"] = float(c_a[0])
        if "pipeline_weight" in res.info:
            info["pipeline_weight"] = res.info["pipeline_weight"]
        return FrameEstimate(x, float(e_s[0]), int(res.evaluations) + 1, info)

    def close(self):
        if self.env is not None:
            self.env.release()
            self.env = None
        self.engine.release()


class SIRTracker(MultiviewTracker):
    """Sampling importance resampling (Condensation) on the multi-view observation."""

    method = "sir"


class APFTracker(MultiviewTracker):
    """Deutscher's annealed particle filter on the multi-view observation."""

    method = "apf"


class PSTracker(MultiviewTracker):
    """MacCormick & Isard's partitioned sampling on the multi-view observation."""

    method = "ps"


class HPSTracker(MultiviewTracker):
    """Bandouch's hierarchical sampling with parallel limb pipelines."""

    method = "hps"


for _name, _cls in (("sir", "SIRTracker"), ("apf", "APFTracker"), ("ps", "PSTracker"),
                    ("hps", "HPSTracker")):
    register(_name, "multiview", f"gltrack.track.multiview:{_cls}",
             "gltrack.track.multiview:MultiviewOptions")
