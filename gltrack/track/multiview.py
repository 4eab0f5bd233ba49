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
:class:`gltrack.motion.vlmm_prior.VlmmPrior`) predicts every particle once per frame and replaces the
first diffusion layer of each sampler stage (``prior_diffusion`` sigmas of Gaussian noise remain
there; the annealing layers after it diffuse as usual). The resampled particle set of one
frame is the prior of the next; with ``"vlmm"`` each resampled particle inherits the VLMM history
of the predicted particle it descends from (``VlmmPrior.follow``).

The observation and the likelihood are :class:`gltrack.observe.multiview.MultiviewObservation`
and :class:`gltrack.observe.multiview.SilhouetteLikelihood`; the samplers are
:mod:`gltrack.sample`'s. Observation per frame and colour camera (all images undistorted first, masks with nearest
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
at tile resolution, all cameras), i.e. :func:`gltrack.sample.weights.cost_weights` of the cost
``lambda (e_S - lambda_A / lambda c_A) / A``. It is a proper likelihood up to a per-batch constant, so plain SIR
and PS (whose single-layer partitions weight with exponent 1) actually concentrate; the annealed
methods pick their own exponent and barely change with it.

Estimate (``estimate``): ``"mean"`` (default), the weighted mean of the final weighted particle set
(Deutscher's estimate: it averages out the Monte Carlo jitter of single particles, so trajectories
are smoother), or ``"best"``, the particle of highest weight.

Score of a frame: the summed silhouette XOR count of the estimate (one extra evaluation, included in
``FrameEstimate.evaluations``). One more engine call per frame, not counted as an evaluation
(it does not steer the filter), gives ``info["iou"]``: the per-camera silhouette IoU of the
estimate against the frame's foreground over the unblocked pixels, counted at ``iou_tile``
pixels (:meth:`SilhouetteLikelihood.silhouette_overlap`, channel ``model``), a quality figure that
needs no ground truth (``gltrack eval`` summarises it; None for a camera where neither model
nor foreground has a pixel). The same call gives ``info["model_on_fg"]``, the share of the
model's silhouette on the foreground, and ``info["fg_covered"]``, the share of the foreground
the model covers: which of the two is low says whether the model sticks out of the masks or the
masks hold what the model does not explain (None where the model, or the foreground, is
empty). ``info["quality"]`` (XOR over foreground pixels at the tracking
tile, at least the share of the foreground the environment layers removed when that is over
half: ``info["foreground_kept"]``) is what the runner's loss detection reads.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gltrack.body.mesh import MESH_LODS
from gltrack.body.poses import canonical_poses
from gltrack.motion.vlmm_prior import vlmm_prior
from gltrack.observe.blob_evidence import default_volume
from gltrack.observe.blobs import BlobModel, place_on_centroid
from gltrack.observe.keypoints import keypoint_distance
from gltrack.observe.people import pick_person
from gltrack.observe.model_masks import mask_covered
from gltrack.observe.multiview import FOREGROUNDS, MultiviewObservation, SilhouetteLikelihood
from gltrack.observe.voxels import carve
from gltrack.render.reference import skin_vertices
from gltrack.sample import (AnnealedParticleFilter, HierarchicalSampler, PartitionedSampler,
                            SIRFilter, StateSpace, bandouch_weights, cost_weights,
                            default_partitions, default_pipelines, fine_partitions)
from gltrack.sample.diffusion import VARIANTS
from gltrack.sample.partitions import exchange_limbs, limb_pairs
from gltrack.sample.sweep import LEGS, SweepResult, arm_grid, limb_grid, sweep_limbs

from .base import FrameEstimate, NoPersonError, Tracker, rng_state, set_rng_state, two_modes
from .keypoint_ik import limb_targets, propose_limbs
from .keypoint_sites import keypoint_targets
from .options import Options, at_least, choice, positive, within

log = logging.getLogger(__name__)

#: Per-method defaults: particles and layers (APF: annealing layers; HPS: maximum torso layers;
#: PS: layers per partition; SIR: always 1). APF 10 x 800 and PS 1600 are Bandouch's comparison;
#: HPS 200 is his low-particle run, which still beat both.
METHOD_DEFAULTS = {"sir": (800, 1), "apf": (800, 10), "ps": (1600, 1), "hps": (200, 6)}

ESTIMATES = ("mean", "best")
WEIGHTS = ("bandouch", "exp")
PRIORS = ("diffusion", "vlmm")
APPEARANCE_INITS = ("full", "tile")
MASK_REFINES = ("auto", "grabcut", "none")


def resolve_mask_refine(choice: str, preset: str, meta: dict, mode: str) -> str:
    """``mask_refine`` ("auto", "grabcut" or "none") as a run uses it: "auto" is "grabcut" for
    the upper-body preset on masks a dataset's ``meta.json`` says ``gltrack ingest`` estimated
    from the sequence (``"masks": {"method": "sequence-foreground"}``) and read from the
    dataset (``mode``), "none" otherwise (see :class:`MultiviewOptions`)."""
    if choice != "auto":
        return choice
    masks = meta.get("masks") if isinstance(meta.get("masks"), dict) else {}
    sequence = masks.get("method") == "sequence-foreground" and mode == "dataset"
    return "grabcut" if preset == "upper" and sequence else "none"


def near_home(X, cost, home, max_shift: float):
    """The poses of ``X`` (N, D) whose root (first 3 entries) lies within ``max_shift`` metres
    of ``home`` (3,), with their costs (N,); all of them when none or all do (nothing to
    prefer)."""
    near = np.linalg.norm(np.asarray(X)[:, :3] - home, axis=1) <= max_shift
    if near.any() and not near.all():
        log.info("auto init: %d refined poses moved more than %.1f m from the hull and are not "
                 "used", int((~near).sum()), max_shift)
        return X[near], cost[near]
    return X, cost


@dataclass
class MultiviewOptions(Options):
    """Options of the multi-view trackers (``--config`` keys; the DOF preset is ``--dof``);
    these are all of ``sir``'s, :class:`AnnealedOptions` and :class:`HpsOptions` add the
    annealing schedules.

    particles : particles per frame; 0 = the method's default (sir 800, apf 800, ps 1600, hps 200)
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
        (``--behaviour`` sets it and implies ``prior = "vlmm"``)
    prior_lam : noise attenuation of the behaviour model's local dynamics (eq. 4 of Caillette):
        the angles' noise is ``prior_lam`` times the cluster's spread. 0.25, half the paper's
        0.5 (which the ``vlmm`` tracker keeps), because here the sampler's own diffusion and
        annealing layers follow the prediction and do the exploring; with the MML's broad
        clusters half a cluster's spread a frame is twice the motion of a frame (salsa model,
        median angle spread 0.17 rad against 0.045 rad a frame of velocity spread at 30 fps).
        ``hps``, 90 frames of cmu_60_10 (held out of the model), true body and start, seeds
        0 / 1, mean joint error: 0.5 gave 62.8 / 61.2 mm, 0.25 43.1 / 44.7, the diffusion
        prior 43.4 / 39.5 (0.35: 49.6, 0.1: 52.3, seed 0)
    prior_diffusion : Gaussian diffusion (in inter-frame sigmas) each sampler stage still adds in
        its first layer after the behaviour model's prediction
    init_headings : ``--init auto``: headings (over a full turn) at which every library pose is
        placed on the visual hull's centroid and scored
    init_keep : ``--init auto``: best placed poses, each (and each turned round by 180
        degrees) refined on its own by a hierarchical sampler (``particles / (2 init_keep)``
        particles each, at least 50)
    init_rounds : ``--init auto``: steps of that sampler per refined pose
    init_limb_sweep : ``--init auto``: points per swing axis of a grid sweep of each limb
        (:func:`gltrack.sample.sweep.limb_grid`: shoulder and hip swing, elbow and knee flexion
        at 4 points) of the best refined pose of each heading; a pose the sweep improves is
        refined again the same way and competes with the others. 0 = off. A refinement from a
        library pose leaves a raised limb hanging where the silhouette does not pull it up
        (see :mod:`gltrack.sample.sweep`); 10 (default): 4 x 401 evaluations per heading
    iou_tile : resolution (power of two, pixels per side) at which ``info["iou"]`` is counted;
        0 = the tracking ``tile``. 256 by default: at 64 px a limb is 2-3 pixels wide, so the
        IoU would measure the tile more than the fit; 256 px costs one render of one pose
    mesh_lod : level of detail of the procedural mesh the engine scores with
        (:func:`gltrack.body.mesh.make_body_mesh`: 0 = 1008 triangles, 1 = 1968, 2 = 7872);
        the run's body record keeps its own. 1 by default: measured (apf 800 x 10, MakeHuman
        subject, true body and start, 12 frames of walk, hop and salsa, 8 seeds each,
        llvmpipe) 0 takes 4.3 s a frame instead of 6.9, but its mean joint error is 2.2 +- 1.2
        mm higher (47.7 against 45.5 mm; salsa +4.8 +- 2.5 mm)
    mask_refine : "auto" (default), "grabcut" or "none". With "grabcut" every tracked frame's
        masks are first refined with the last frame's estimate
        (:func:`gltrack.observe.model_masks.refine_view`: GrabCut seeded by its silhouette, the
        dataset's mask kept within 0.6 m of it), so segmentation and tracking alternate frame
        by frame; the dataset's masks are not changed. "auto" is "grabcut" for the upper-body
        preset (``--dof upper``) on masks that ``gltrack ingest`` estimated from the sequence
        (a seated person's still torso stays in the sequence's temporal background, so those
        masks hold the hands and face only), "none" otherwise. Measured on real footage
        (2026-11-26, llvmpipe): on the seated caliscope take the track stays on the person
        over all 111 frames with it and is lost from frame 4 without it; on the Pose2Sim take
        (full body, frames 20-49, scored against masks refined by the scene test, which this
        refinement does not see) the mean IoU is 0.638 with it against 0.663 without (GrabCut
        grows the masks into background of the subject's colours and the model follows), so
        not for full-body takes: a refinement seeded by a wrong model confirms it (hence
        :attr:`MultiviewTracker.min_sequence_covered`, which checks the estimate against the
        masks before the refinement). About 0.1 s a camera and frame at 640x360
        (:data:`~gltrack.observe.multiview.REFINE_PIXELS`)
    arm_sweep : 0 (default, off) or points per swing axis of the arm sweep
        (:mod:`gltrack.sample.sweep`): after the sampler, each arm's two shoulder swing angles
        (this many points each between the limits) and the elbow's flexion (4 points) are
        scored in one batch with the estimate; a better arm replaces the estimate's and the
        particles move with it (10: 2 x 401 more evaluations a frame). For raised arms that a
        silhouette sampler leaves hanging. Measured (2026-11-26, llvmpipe): on the Pose2Sim
        take's default track the sweep of single frames found better right arms in 13 of 15
        frames from 25 to 95 (mean IoU over the cameras +0.04 on frames 40-50); the whole take
        tracked with it (hps defaults otherwise): mean IoU per camera 0.620 / 0.648 / 0.669 /
        0.640 against 0.618 / 0.635 / 0.666 / 0.628, 73 frames under 0.6 against 94 (summed
        over the cameras), but joint jitter 52.8 against 44.7 mm/frame^2 and 3803 evaluations
        a frame against 3001; on the honest bench (hps, MakeHuman subject, seed 0) walk 53.9
        against 54.4 mm, salsa 82.9 against 86.0 mm (wrists better, elbows worse). Not enough
        to pay for 27-40 % more evaluations by default
    leg_sweep : 0 (default, off) or points per swing axis of the leg sweep: as ``arm_sweep``,
        for each leg's hip flexion and abduction and the knee's flexion (10: 2 x 401 more
        evaluations a frame). For a raised or swinging leg that the particles leave hanging
        beside the standing one. Measured (2026-11-27, llvmpipe, ``hps``): on six honest
        MakeHuman datasets (walk, hop, salsa at two synthesis seeds; 15 frames, each with its
        estimated body and start kept fixed, 133 particles, tracking seeds 0 / 1) the mean
        joint error fell by 6.9 mm on average over the 12 pairs and rose in none (hop 121.9 /
        131.0 -> 88.4 / 90.1 mm; 240 particles without it, the same evaluations: 119.8 /
        115.0); but on the Pose2Sim take (all 100 frames) it swapped legs back and forth in
        the bent-over frames: mean IoU per camera 0.547 / 0.606 / 0.624 / 0.603 against 0.553
        / 0.613 / 0.624 / 0.599, joint jitter 50.7 against 38.8 mm/frame^2 (95th percentile
        108.6 against 65.3), 1.16x the time; and the honest bench's 5-frame hop came out 3.4
        mm worse. Not a default while it makes a real track jumpier
    ground_contact : 0 (off) or metres: a prior against a body leaving the ground the
        cameras see it on. Each frame's visual hull (the scored masks, one camera allowed to
        miss a voxel with 4 or more cameras; the person's connected part) gives the lowest
        point of the person; a pose whose lowest joint is more than ``ground_contact`` plus a
        voxel edge above it is weighted as if its silhouette error were larger by
        ``area * (excess / GROUND_SCALE)`` pixels (:meth:`MultiviewTracker.ground_cost`), in
        every weighting (sampler layers, coarse layers, sweeps, the automatic start's
        refinement). A dataset that records its floor (``world.floor`` of ``gltrack ingest``)
        puts the reference down to the floor whenever the hull comes within that allowance of
        it: a foot that one camera's mask misses still stands on the floor. A jump lifts the
        hull and the reference with it. Off for ``--dof upper`` (the legs are not tracked).
        Why: on the Pose2Sim take the model floats (its lower ankle 0.3-0.4 m above the floor
        over frames 30-59 while the person stands on the force plate), and at a floating root
        no leg reaches the standing shank: a leg put down to the floor there costs 19-227 more
        pixels of e_S. Measured (2026-11-28, llvmpipe, ``hps`` defaults, the whole take from
        one fixed body and start, seed 0, 0.2 m from the recorded floor, before the hull
        reference): the lower ankle stays at 0.15-0.17 m over frames 20-59 instead of
        0.22-0.40, and in the overlays of frames 45 and 50 a leg stands on the shank in cam_03
        and cam_04; mean IoU per camera 0.546 / 0.583 / 0.631 / 0.597 against 0.545 / 0.608 /
        0.609 / 0.600, jitter 38.5 against 38.4 mm/frame^2: a better-looking pose, not a
        better fit. Off by default: with the hull reference (0.15 m) neither the honest
        synthetic clips (walk, hop, salsa; 3 seeds; 84.5 / 117.0 / 80.9 mm against 80.7 /
        100.0 / 79.6) nor the Pose2Sim take (IoU within 0.02 per camera) measured better
        (docs/measurements.md, "Ground contact from the visual hull")
    keypoints : 0 (off) or metres: how far the joints may be from the dataset's triangulated
        body keypoints (``keypoints.npz``, which ``gltrack ingest`` writes when the landmark
        model is installed; :mod:`gltrack.observe.keypoints`). Every weighting adds
        ``area * d / keypoints`` pixels to a pose's silhouette error, ``d`` the mean distance
        of its hips, knees, ankles, shoulders, elbows and wrists to their keypoints, and of
        the head's centre, heels and toe tips to the ears' midpoint, heels and toes where the
        preset turns the head and ankles (:mod:`gltrack.track.keypoint_sites`), each
        capped at :data:`~gltrack.observe.keypoints.DISTANCE_CAP` (knees and ankles left out
        with ``--dof upper``; points without a keypoint in a frame left out). Why 0.15 m: the
        keypoints are 4-6 cm from hand labels on a good frame, and at the right pose real
        masks still leave 0.3-0.5 of the foreground area unexplained (IoU 0.6-0.8), so one
        keypoint error (5 cm) costs about what the silhouette's own mismatch does: neither
        cue overrules the other. A dataset without keypoints tracks on silhouettes alone
    keypoint_ik : bool (default True). After the sampler (and the sweeps), each limb whose
        elbow or wrist (knee or ankle) has a keypoint and lies at least
        :data:`~gltrack.track.keypoint_ik.NEAR` from it (mean) is solved onto its keypoints by
        inverse kinematics (:mod:`gltrack.track.keypoint_ik`); the solved limbs are weighed
        with the estimate in one batch, those that weigh more replace the estimate's (all of
        them together when that weighs more still, else the best alone) and the particles
        move with the estimate. For a limb the track has lost out of the particles' reach,
        which the capped keypoint distance alone does not bring back (a few evaluations in
        the frames that have such a limb). A dataset without keypoints is not affected.
        Measured (2026-12-03, llvmpipe, ``hps`` defaults, docs/measurements.md "Limbs solved
        onto the keypoints"): three runs that had lost a limb (true body, automatic start,
        MakeHuman walk / hop / salsa, seed 1) came out 48.8 / 52.1 / 39.4 mm against 76.0 /
        63.0 / 78.9 (the salsa's left elbow 82 mm off against 461); the honest runs (3 clips
        x 3 seeds) 0.4 mm better on average (within their noise); the Pose2Sim take within
        its seeds' spread (seed 1 the same track to the bit)
    """

    FLAGS: ClassVar[dict] = {"behaviour": "prior_model"}
    IMPLIES: ClassVar[dict] = {"prior_model": {"prior": "vlmm"}}

    particles: int = 0
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
    prior_lam: float = 0.25
    prior_diffusion: float = 0.5
    init_headings: int = 12
    init_keep: int = 3
    init_rounds: int = 1
    init_limb_sweep: int = 10
    iou_tile: int = 256
    mesh_lod: int = 1
    mask_refine: str = "auto"
    arm_sweep: int = 0
    leg_sweep: int = 0
    ground_contact: float = 0.0
    keypoints: float = 0.15
    keypoint_ik: bool = True

    def problems(self):
        bad = super().problems() + [
            *choice(self, "mask_refine", MASK_REFINES),
            *at_least(self, 1, "init_headings", "init_keep", "init_rounds"),
            *choice(self, "mesh_lod", MESH_LODS),
            *choice(self, "estimate", ESTIMATES), *choice(self, "weights", WEIGHTS),
            *choice(self, "foreground", FOREGROUNDS), *choice(self, "prior", PRIORS),
            *choice(self, "appearance_init", APPEARANCE_INITS),
            *at_least(self, 0, "prior_lam", "prior_diffusion", "particles", "appearance_refine",
                      "sigma_scale", "shape_weight", "appearance_weight", "arm_sweep",
                      "leg_sweep", "init_limb_sweep", "ground_contact", "keypoints"),
            *positive(self, "sharpness")]
        if self.prior == "vlmm" and not self.prior_model:
            bad.append("prior = \"vlmm\" needs prior_model = \"MODEL.npz\" (a behaviour model "
                       "written by gltrack learn)")
        if self.shape_weight + self.appearance_weight <= 0:
            bad.append("shape_weight and appearance_weight are both 0")
        t = self.tile
        if t < 16 or t > 512 or t & (t - 1):
            bad.append(f"tile = {t} (a power of two in 16..512)")
        t = self.iou_tile
        if t and (t < 16 or t > 512 or t & (t - 1)):
            bad.append(f"iou_tile = {t} (0, or a power of two in 16..512)")
        for name in ("arm_sweep", "leg_sweep", "init_limb_sweep"):
            if getattr(self, name) == 1:
                bad.append(f"{name} = 1 (0 = off, or at least 2 points per swing axis)")
        return bad


@dataclass
class AnnealedOptions(MultiviewOptions):
    """Options of ``apf`` and ``ps``: those of :class:`MultiviewOptions` plus

    layers : 0 = the method's default; apf: annealing layers (10); ps: annealing layers per
        partition (1 = plain partitioned sampling); hps: most torso layers (6)
    survival : target survival rate ESS/N of every annealing layer; 0 = the sampler's default
        (0.5 for apf and ps, 0.3 for hps)
    diffusion : "covariance" (default), "layer_variance" or "constant" layer noise
    """

    layers: int = 0
    survival: float = 0.0
    diffusion: str = "covariance"

    def problems(self):
        return super().problems() + [*choice(self, "diffusion", VARIANTS),
                                     *at_least(self, 0, "layers"),
                                     *within(self, "survival", 0.0, 1.0, open_hi=True)]


@dataclass
class ApfOptions(AnnealedOptions):
    """Options of ``apf``: those of :class:`AnnealedOptions` plus

    fine_layers : the last ``fine_layers`` annealing layers of a frame score the mesh of
        ``mesh_lod``; the layers before them score the coarsest mesh (``mesh_lod`` 0, 1008
        triangles instead of 1968), which llvmpipe draws in about 0.7x the time. The early
        layers, flattened by small exponents, only move the set towards the mode; the last
        ones place it, and the estimate is theirs. 0 = every layer at ``mesh_lod``. 2 by
        default: measured against 0 (2026-11-27, llvmpipe, 800 particles x 10 layers, true
        body and start, paired runs): own-mesh subject, 5 frames of walk, hop and salsa with
        tracking seeds 0-2, 0.78x the time, mean joint error 27.3 against 28.7 mm (-1.4 +-
        1.0 paired); MakeHuman subject, 15 frames of walk and salsa, seeds 0-3, 0.78x the
        time, 49.9 against 52.4 mm (-2.4 +- 1.9). (With every layer on the coarse mesh,
        ``mesh_lod = 0``, the error grew by 2.2 +- 1.2 mm.)
    """

    fine_layers: int = 2

    def problems(self):
        return super().problems() + [*at_least(self, 0, "fine_layers")]


def uses_coarse_mesh(method: str, opt: MultiviewOptions) -> bool:
    """Whether some annealing layers of ``method`` score the coarse mesh (its options'
    ``fine_layers``): not for the methods without the option, with ``fine_layers = 0``, when
    ``mesh_lod`` is already the coarsest, or when every run has at most ``fine_layers``
    layers."""
    fine = getattr(opt, "fine_layers", 0)
    if not fine or opt.mesh_lod == 0 or method not in ("apf", "hps"):
        return False
    runs = [opt.layers or METHOD_DEFAULTS[method][1]]
    if method == "hps":
        runs += [opt.limb_layers, opt.joint_layers]
    return max(runs) > fine


@dataclass
class HpsOptions(AnnealedOptions):
    """Options of ``hps``: those of :class:`AnnealedOptions` plus

    limb_layers, joint_layers : layers per limb partition of the left-first / right-first
        pipelines, and per partition of the paired (both arms, both legs) pipeline
    min_spread : stop torso annealing once every torso DOF's weighted standard deviation is
        below ``min_spread`` inter-frame sigmas (Bandouch's variance threshold); 0 = off
    fine_layers : as :attr:`ApfOptions.fine_layers`, for every annealing run of a frame: the
        torso's and each limb partition's layers before their last ``fine_layers`` score the
        coarsest mesh; the final combination scores ``mesh_lod``'s. 0 (off) by default:
        measured against 0 with 1 (2026-11-27, llvmpipe, the default 200 particles, true
        body and start, paired runs) it took 0.81x the time, but the mean joint error was
        +0.7 +- 0.9 mm (own-mesh subject, 5 frames of walk, hop and salsa, seeds 0-2) and
        +0.7 +- 3.7 mm (MakeHuman subject, 15 frames of walk and salsa, seeds 0-7), worse
        in 16 of the 25 pairs: within the noise, but leaning the wrong way for a default
    """

    limb_layers: int = 2
    joint_layers: int = 4
    min_spread: float = 0.0
    fine_layers: int = 0

    def problems(self):
        return super().problems() + [*at_least(self, 1, "limb_layers", "joint_layers"),
                                     *at_least(self, 0, "min_spread", "fine_layers")]


def _child(rng: np.random.Generator) -> np.random.Generator:
    """An independent generator derived from ``rng`` without drawing from it (numpy >= 1.25;
    older numpy: seeded by one draw)."""
    try:
        return rng.spawn(1)[0]
    except (AttributeError, TypeError):  # older numpy, or a generator without a seed sequence
        return np.random.default_rng(int(rng.integers(2 ** 63)))


def make_sampler(method: str, dofs, fps: float, opt: MultiviewOptions):
    """The sampler of ``method`` for a ``DofSet`` at ``fps``, and its particle count.

    ``opt`` is the method's options class (:class:`MultiviewOptions` for sir,
    :class:`ApfOptions` for apf, :class:`AnnealedOptions` for ps, :class:`HpsOptions` for hps).

    Returns
    -------
    (sampler, n_particles)
    """
    if method not in METHOD_DEFAULTS:
        raise ValueError(f"unknown multi-view method {method!r}; choose one of "
                         f"{', '.join(METHOD_DEFAULTS)}")
    n_def, l_def = METHOD_DEFAULTS[method]
    n = opt.particles or n_def
    scale = opt.sigma_scale or float(np.sqrt(fps / 30.0))
    space = StateSpace(dofs.lower, dofs.upper, scale * dofs.sigma_at(fps))
    if method == "sir":
        return SIRFilter(space), n
    layers = opt.layers or l_def
    kw = {"alpha": opt.survival} if opt.survival else {}
    if method == "apf":
        return AnnealedParticleFilter(space, layers=layers, diffusion=opt.diffusion,
                                      fine_layers=max(1, opt.fine_layers), **kw), n
    if method == "ps":
        return PartitionedSampler(space, fine_partitions(dofs), layers=layers,
                                  diffusion=opt.diffusion, **kw), n
    spread = opt.min_spread or None
    pipes = default_pipelines(dofs, limb_layers=opt.limb_layers, joint_layers=opt.joint_layers)
    return HierarchicalSampler(space, default_partitions(dofs)["torso"], pipes,
                               torso_layers=layers, min_spread=spread, diffusion=opt.diffusion,
                               fine_layers=max(1, opt.fine_layers), **kw), n


class MultiviewTracker(Tracker):
    """Bandouch's multi-camera tracker; subclasses fix the sampler (``method``).

    The composition: :class:`~gltrack.observe.multiview.MultiviewObservation` and
    :class:`~gltrack.observe.multiview.SilhouetteLikelihood` (observation and likelihood),
    Gaussian diffusion or :class:`~gltrack.motion.vlmm_prior.VlmmPrior` (motion prior) and the
    method's sampler from :mod:`gltrack.sample` (:func:`make_sampler`).

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset, a multiview dataset with colour cameras
    body : gltrack.body.model.BodyModel
    ctx : moderngl.Context
    options : the method's options (see :func:`make_sampler`)
    rng : numpy.random.Generator
    """

    method = "hps"
    options_class = HpsOptions

    def __init__(self, dataset, body, ctx, options: MultiviewOptions | None = None, rng=None):
        self.opt = (options or self.options_class()).validate()
        self.body = body.with_lod(self.opt.mesh_lod)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        # the background models are fitted lazily, on the first frame read: their own generator
        # (its first state goes into checkpoints), so that a resumed run fits them the same
        obs_rng = _child(self.rng)
        self._obs_rng0 = rng_state(obs_rng)
        self.obs = MultiviewObservation(dataset, self.opt.foreground, obs_rng)
        self.fps = dataset.fps
        coarse = self.body.with_lod(0) if uses_coarse_mesh(self.method, self.opt) else None
        self.likelihood = SilhouetteLikelihood(
            ctx, self.body, self.obs, tile=self.opt.tile, appearance=self.opt.appearance,
            blocking="layers" if self.opt.environment else "none", coarse=coarse)
        self.engine = self.likelihood.engine
        self.sampler, self.n = make_sampler(self.method, body.dofs, dataset.fps, self.opt)
        self.prior = None
        if self.opt.prior == "vlmm":
            # the clusters' diagonal covariances, with which prior_lam was measured; the full
            # ones (the vlmm tracker's default) have not been measured in these trackers
            self.prior = vlmm_prior(self.opt.prior_model, body.dofs, dataset.fps,
                                    lam=self.opt.prior_lam, local="diag")
        self.particles = None
        self.frames_done = 0
        self.refines_masks = resolve_mask_refine(self.opt.mask_refine, body.dofs.preset,
                                                 dataset.meta, self.obs.mode) == "grabcut"
        #: the per-frame sweep's grids: the arms' (``arm_sweep``), then the legs' (``leg_sweep``)
        self._limb_grids = ((arm_grid(body.dofs, self.opt.arm_sweep) if self.opt.arm_sweep else [])
                            + (limb_grid(body.dofs, self.opt.leg_sweep, limbs=LEGS)
                               if self.opt.leg_sweep else []))
        #: the floor's height along +Y (metres) when the dataset records it (``ground_contact``)
        self.floor = dataset.floor_height()
        #: ``ground_contact`` in use (0 with ``--dof upper``: the legs are not tracked)
        self.contact = float(self.opt.ground_contact) if body.dofs.preset != "upper" else 0.0
        #: this frame's ground reference along +Y (metres; :meth:`observe_ground`), None = none
        self.ground = None
        self._volume = default_volume(self.obs.pinholes, dataset.assumed_floor())
        #: the body's points matched with keypoints (joints and sites) and their keypoints per
        #: frame (F, K, 3), or None without keypoints
        self._kp_sites, self._kp_points = keypoint_targets(dataset, self.body, self.opt)
        #: ``keypoint_ik``'s limbs: limb -> indices of its middle and end joints' keypoints
        self._ik_limbs = (limb_targets(self._kp_sites.names)
                          if self.opt.keypoint_ik and self._kp_sites is not None else {})
        #: this frame's keypoints (K, 3) (:meth:`observe_keypoints`), None = none
        self.kp_target = None

    @property
    def appearance(self):
        """The colour model (None before :meth:`start` or without appearance)."""
        return self.likelihood.appearance

    #: a frame is lost when the silhouette XOR of the estimate exceeds this share of the
    #: foreground pixels (``info["quality"]``; the depth trackers use the same figure). Measured
    #: on the CMU walk drawn with the MakeHuman mesh (4 cameras 320x240, hps 100 particles,
    #: true body): 0.21-0.29 while tracked, 0.46-0.74 in the first frames after the particle
    #: set was turned 90 degrees. Real masks are worse than simulated ones (a mask IoU of 0.8
    #: alone gives about 0.25), hence the margin.
    lost_quality = 0.45
    #: metres a refined start pose may move from where it was placed on the visual hull
    #: (:meth:`start_hypotheses`): a body stands within about half its height of its volume
    #: centroid, so a root further than this has left the person
    INIT_MAX_SHIFT = 1.0
    #: below this share of the foreground left by the environment layers
    #: (:attr:`SilhouetteLikelihood.kept_fraction`) a frame's quality is at least the share
    #: removed: the layers take out other people and clutter (a second person in the
    #: background of two of four views is well under half the foreground), not the subject.
    min_kept = 0.5
    #: with ``mask_refine``: a frame is lost when, in some camera, the estimate covers less than
    #: this share of the sequence mask (the masks before the refinement: what moved, e.g. the
    #: hands and face of a seated person). The refined masks follow the model, so its silhouette
    #: error cannot show a model that left the person; the sequence mask can. Measured on the
    #: caliscope take: the worst camera's share is 0.09-0.15 at its lowest in three runs that
    #: stayed on the person (median 0.42-0.49), and 0.0 once a track ran away (a model filling
    #: the nearest camera's view, beside the person in the others)
    min_sequence_covered = 0.05
    #: metres of excess height (``ground_contact``) that cost as much as the whole foreground
    #: area unexplained: a body floating half a metre too high is as bad as a body off the
    #: person, enough to outweigh the few hundred pixels a floating pose gains, soft enough
    #: for the tenths of a metre of a hop
    GROUND_SCALE = 0.5

    @property
    def area(self) -> float:
        return self.likelihood.area

    def observe(self, frame: int):
        """Read frame ``frame`` and upload it (see :meth:`SilhouetteLikelihood.observe`)."""
        return self.likelihood.observe(frame)

    def scores(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Silhouette error e_S (N,) and appearance count c_A (N,) or None, summed over cameras."""
        return self.likelihood.scores(X)

    def weights(self, X: np.ndarray) -> np.ndarray:
        """(N,) non-negative particle weights, larger = better (see the module docstring)."""
        e_s, c_a = self.scores(X)
        return self._weights(e_s + self.ground_cost(X) + self.keypoint_cost(X), c_a)

    def coarse_weights(self, X: np.ndarray) -> np.ndarray:
        """:meth:`weights` of the coarse mesh (``fine_layers``; the tracked mesh without one)."""
        e_s, c_a = self.likelihood.scores(X, coarse=True)
        return self._weights(e_s + self.ground_cost(X) + self.keypoint_cost(X), c_a)

    def observe_keypoints(self, frame: int) -> None:
        """Set :attr:`kp_target` to ``frame``'s keypoints (None without any)."""
        self.kp_target = None if self._kp_points is None else self._kp_points[frame]

    def keypoint_distance(self, X: np.ndarray) -> np.ndarray:
        """(N,) metres: mean capped distance of the matched joints and sites
        (:mod:`gltrack.track.keypoint_sites`) to this frame's keypoints
        (:func:`gltrack.observe.keypoints.keypoint_distance`; NaN without keypoints)."""
        if self.kp_target is None:
            return np.full(len(X), np.nan)
        return keypoint_distance(self._kp_sites.positions(self.body.kin, X), self.kp_target)

    def solve_limbs(self, x: np.ndarray) -> SweepResult:
        """``keypoint_ik``: the estimate ``x`` (D,) with the limbs solved onto this frame's
        keypoints that weigh more than its own (see the option); the result's ``improved``
        names the limbs replaced (:data:`gltrack.track.keypoint_ik.LIMBS` keys)."""
        props = propose_limbs(self.body.kin, x, self.kp_target, self._ik_limbs)
        if not props:
            return SweepResult(x, np.zeros_like(x), 0, ())
        w = self.weights(np.stack([x] + [p.pose for p in props]))
        evaluations = len(props) + 1
        if log.isEnabledFor(logging.DEBUG):  # the text only when it is shown
            log.debug("keypoint_ik: %s", ", ".join(
                f"{p.limb} {p.before:.3f} -> {p.after:.3f} m, weight {w[k + 1]:.3g} against "
                f"{w[0]:.3g}" for k, p in enumerate(props)))
        better = [k for k in range(len(props)) if w[k + 1] > w[0]]
        if not better:
            return SweepResult(x, np.zeros_like(x), evaluations, ())
        best = max(better, key=lambda k: w[k + 1])
        new, names = props[best].pose, (props[best].limb,)
        if len(better) > 1:  # the limbs are disjoint DOFs: all of them at once
            both = x + sum(props[k].pose - x for k in better)
            w2 = self.weights(np.stack([new, both]))
            evaluations += 2
            if w2[1] > w2[0]:
                new, names = both, tuple(props[k].limb for k in better)
        log.debug("keypoint_ik: %s solved onto the keypoints", ", ".join(names))
        return SweepResult(new, new - x, evaluations, names)

    def keypoint_cost(self, X: np.ndarray) -> np.ndarray | float:
        """(N,) silhouette-error pixels for the joints' distance to this frame's keypoints:
        ``area * distance / keypoints`` (0 without keypoints; see ``keypoints``)."""
        if self.kp_target is None:
            return 0.0
        d = self.keypoint_distance(X)
        if not np.isfinite(d).any():
            return 0.0
        return self.area * d / self.opt.keypoints

    def start_cost(self, X: np.ndarray) -> np.ndarray:
        """(N,) the automatic start's ranking: silhouette error plus :meth:`keypoint_cost`."""
        return self.likelihood.scores(X)[0] + self.keypoint_cost(X)

    def ground_cost(self, X: np.ndarray) -> np.ndarray | float:
        """(N,) silhouette-error pixels added for a lowest joint more than the allowance
        above this frame's ground reference (0 when the prior is off or has no reference)."""
        if self.ground is None:
            return 0.0
        ground, allowance = self.ground
        lowest = self.body.joints(X)[:, :, 1].min(axis=1)
        excess = np.clip(lowest - ground - allowance, 0.0, None)
        return self.area * excess / self.GROUND_SCALE

    def observe_ground(self, masks) -> None:
        """Set :attr:`ground` from a frame's masks: ``(reference height, allowance)`` in metres
        along +Y, or None when ``ground_contact`` is off or the masks do not meet.

        The reference is the bottom of the person's part of the masks' visual hull (a voxel
        survives one camera that misses it when there are 4 or more; the finest voxel edge is
        the tracking volume's longest side / 64, ~5 cm); the allowance ``ground_contact`` plus
        that voxel edge, as the hull is only as fine as its voxels. With the floor recorded, a
        hull that comes within the allowance of it puts the reference on the floor.
        """
        self.ground = None
        if not self.contact:
            return
        tolerance = 1 if len(masks) >= 4 else 0
        hull = carve(self.obs.pinholes, masks, self._volume, base=16, max_depth=2,
                     tolerance=tolerance, distort=False)
        if len(hull) == 0:
            return
        pts, vol = hull.points(max_size=0.06)
        person = pick_person(pts, vol)
        if person is None:
            return
        edge = float(np.cbrt(vol[person.index].min()))
        bottom = float(person.lo[1]) - 0.5 * edge
        allowance = self.contact + edge
        if self.floor is not None and bottom < self.floor + allowance:
            bottom = self.floor
        self.ground = (bottom, allowance)

    def _weights(self, e_s, c_a):
        o = self.opt
        if o.weights == "bandouch":
            # Without c_A, alpha only scales every weight: use 1 so shape_weight = 0 stays valid.
            alpha = o.shape_weight if c_a is not None else 1.0
            return bandouch_weights(e_s, c_a, alpha, o.appearance_weight)
        cost = e_s
        if c_a is not None:
            cost = (o.shape_weight * e_s - o.appearance_weight * c_a) / \
                (o.shape_weight + o.appearance_weight)
        return cost_weights(cost, self.area / o.sharpness).W

    # -- automatic start ----------------------------------------------------------------
    def start_hypotheses(self, frame):
        """Find the body in ``frame`` without any pose given.

        A global search, then the filter's own kind of search: every pose of the library
        (:func:`gltrack.body.poses.canonical_poses`, plus the behaviour model's cluster
        prototypes with ``prior = "vlmm"``) is placed at ``init_headings`` headings with its
        volume centroid on the centroid of the frame's visual hull and scored by its silhouette
        error; each of the ``init_keep`` best is refined on its own by Bandouch's hierarchical
        sampler (``init_rounds`` steps on the frame, whatever the method), and the refined pose
        (best particle or estimate) with the lowest silhouette error starts the tracker. The
        best refined pose of each heading is also tried with its legs and arms exchanged
        (mirrored), refined the same way, and with each limb swept over a grid
        (``init_limb_sweep``), refined again where a limb moved. Where the dataset has
        keypoints, every ranking here adds their cost (:meth:`start_cost`), so the heading
        and the sides whose joints meet the keypoints win.

        Why each on its own: a silhouette fits about as well turned by 180 degrees, and one
        particle set seeded at both headings often settled on the wrong one (3 of 6 runs on the
        test data, 270-290 mm); refined apart, the right heading ended lower in 9 of 9 runs
        (26-44 mm mean joint error, a plain, a turned and a shifted start).
        Why hierarchical for every method: refined by PS (40 particles) or SIR (200) the right
        heading ended at 290-295 px of silhouette error, no better than the mirror image (281,
        280 mm off), while HPS reached 225 px (35 mm; the truth scores 166 px).

        Raises
        ------
        NoPersonError
            The cameras' foreground masks do not meet in the tracking volume (no person).
        """
        o, d = self.opt, self.body.dofs
        yaw = d.index("pelvis_ry")
        images, masks = self.obs(frame)
        self.observe_ground(masks)
        self.observe_keypoints(frame)
        volume = self._volume
        hull = carve(self.obs.pinholes, masks, volume, base=16, max_depth=2, distort=False)
        if len(hull) == 0:
            raise NoPersonError(f"frame {frame}: the cameras' foreground masks do not meet inside "
                                f"the tracking volume {volume.round(2).tolist()}: no person to "
                                "start from")
        pts, vol = hull.points(max_size=0.06)
        # the largest connected part of the hull: a second person is not averaged in
        centroid = pick_person(pts, vol, where=f"frame {frame}").centroid
        _, library = canonical_poses(d, self.body.skeleton)
        if self.prior is not None:
            protos = np.repeat(d.zero(self.body.skeleton)[None], len(self.prior.model.gmm.means), 0)
            protos[:, self.prior.idx] = self.prior.model.gmm.means[:, :self.prior.model.n_angles]
            library = np.concatenate([library, d.validate(protos)])
        P = place_on_centroid(self.body, BlobModel(self.body.mesh, self.body.skeleton), library,
                              o.init_headings, centroid)
        self.likelihood.observe(frame)
        e_s = self.start_cost(P)
        seeds = P[np.argsort(e_s)[:o.init_keep]]
        # each seed also turned round: a silhouette fits about as well either way
        twins = seeds.copy()
        twins[:, yaw] += np.pi
        seeds = np.concatenate([seeds, d.validate(twins)])
        n = max(self.n // len(seeds), 50)
        refiner, _ = make_sampler("hps", d, self.fps, HpsOptions(sigma_scale=o.sigma_scale))

        def refine(seed):  # the best particle and the estimate after init_rounds steps
            X = np.repeat(seed[None], n, axis=0)
            for _ in range(o.init_rounds):
                res = refiner.step(X, self.weights, self.rng)
                X = res.particles
            return [res.best, res.estimate]

        final = [seeds[0]]
        for seed in seeds:
            final += refine(seed)
        final = d.validate(np.stack(final))
        e_final = self.start_cost(final)
        # The best refined pose of each heading (and its turned-round twin) with the legs and
        # arms exchanged (mirrored), refined the same way: a refinement from a standing library
        # pose settles a stride with either leg forward, a silhouette fits either about as
        # well, and a local search seldom goes from one to the other.
        pairs = limb_pairs(d)
        if pairs:
            mirrors = d.validate(exchange_limbs(np.stack(two_modes(final, e_final, yaw)), pairs))
            more = np.concatenate([mirrors, d.validate(np.stack([p for m in mirrors for p in refine(m)]))])
            final = np.concatenate([final, more])
            e_final = np.concatenate([e_final, self.start_cost(more)])
        # The best refined pose of each heading with each limb swept over a grid, refined again
        # where a limb moved: a limb the refinement left hanging beside the body (a raised leg,
        # a raised arm) is in a narrow basin that the sampler's diffusion seldom reaches.
        if o.init_limb_sweep:
            grids = limb_grid(d, o.init_limb_sweep)
            swept = []
            for m in two_modes(final, e_final, yaw):
                sw = sweep_limbs(m, lambda X: -self.start_cost(X), grids)
                if sw.improved:
                    swept += [sw.estimate, *refine(sw.estimate)]
            if swept:
                more = d.validate(np.stack(swept))
                final = np.concatenate([final, more])
                e_final = np.concatenate([e_final, self.start_cost(more)])
        # a refined pose that left the hull has explained the person away (masks that miss
        # much of the person, e.g. a still torso, make a model out of view score well): it may
        # not start the tracker while one near the person does
        final, e_final = near_home(final, e_final, seeds[:, :3].mean(axis=0), self.INIT_MAX_SHIFT)
        log.info("auto init: %d placed poses (best silhouette error %.0f px), refined to %.0f px",
                 len(P), e_s.min(), e_final.min())
        return two_modes(final, e_final, yaw)

    # -- tracking -------------------------------------------------------------------------
    def start(self, frame, params, velocity=None):
        x = self.body.dofs.validate(params)[0]
        self.particles = np.repeat(x[None], self.n, axis=0)
        if self.opt.appearance:
            images, masks = self.obs(frame)
            self.likelihood.init_appearance(x, images, masks, rng=self.rng,
                                            full=self.opt.appearance_init == "full")
        if self.prior is not None:
            self.prior.reset(self.particles, self.rng)
        self.frames_done = 0
        self.last = x
        self.velocity = np.zeros_like(x) if velocity is None else np.asarray(velocity, float)

    def transform_state(self, fn):
        if self.particles is None:
            raise RuntimeError("start() the tracker first")
        self.particles = self.body.dofs.validate(fn(self.particles))

    def get_state(self):
        """Particles, last estimate and velocity, frame count, appearance model, behaviour
        prior histories and the generators."""
        if self.particles is None:
            return None
        app = self.likelihood.appearance
        return {"particles": self.particles.copy(), "last": np.array(self.last, dtype=np.float64),
                "velocity": np.array(self.velocity, dtype=np.float64),
                "frames_done": int(self.frames_done), "rng": rng_state(self.rng),
                "obs_rng": self._obs_rng0,
                "appearance": None if app is None else app.get_state(),
                "prior": None if self.prior is None else self.prior.get_state()}

    def set_state(self, state):
        from gltrack.observe.appearance import AppearanceModel

        self.particles = np.array(state["particles"], dtype=np.float64)
        self.last = np.array(state["last"], dtype=np.float64)
        self.velocity = np.array(state["velocity"], dtype=np.float64)
        self.frames_done = int(state["frames_done"])
        self._obs_rng0 = state["obs_rng"]
        set_rng_state(self.obs.rng, self._obs_rng0)
        self.obs._bg.clear()  # re-fitted from the first state, as the original run fitted them
        app = state.get("appearance")
        self.likelihood.appearance = None if app is None or not self.likelihood.use_appearance \
            else AppearanceModel.from_state(self.body.mesh, app, rng=self.rng)
        if self.prior is not None and state.get("prior") is not None:
            self.prior.set_state(state["prior"])
        set_rng_state(self.rng, state["rng"])

    def step(self, frame):
        if self.particles is None:
            raise RuntimeError("start() the tracker first")
        if self.refines_masks:
            # the masks of this frame refined with the last estimate's silhouette; only here:
            # a start or re-start must not see masks shaped by a track it may replace
            S = self.body.skinning(self.last[None])
            self.obs.model = (skin_vertices(self.body.mesh, S)[0], self.body.mesh.faces)
        try:
            images, fgs, blocks = self.observe(frame)
        finally:
            self.obs.model = None
        # blocked pixels (occluders) may hide the person: they do not carve the hull away
        self.observe_ground([f | b for f, b in zip(fgs, blocks)])
        self.observe_keypoints(frame)
        if self.opt.velocity:
            self.particles = self.body.dofs.validate(self.particles + self.opt.velocity * self.velocity)
        predict = self.prior.predict if self.prior is not None else None
        coarse = ({"coarse_fn": self.coarse_weights}
                  if self.likelihood.coarse_engine is not None else {})
        res = self.sampler.step(self.particles, self.weights, self.rng, predict_fn=predict,
                                predict_scale=self.opt.prior_diffusion, **coarse)
        self.particles = res.particles
        x = res.estimate if self.opt.estimate == "mean" else res.best
        x = self.body.dofs.validate(x)[0]
        evaluations = int(res.evaluations)
        swept = ()
        if self._limb_grids:
            sw = sweep_limbs(x, self.weights, self._limb_grids)
            evaluations += sw.evaluations
            swept = sw.improved
            if swept:  # the particles follow the estimate's limbs
                x = sw.estimate
                self.particles = self.body.dofs.validate(self.particles + sw.delta)
        solved = ()
        if self._ik_limbs and self.kp_target is not None:
            ik = self.solve_limbs(x)
            evaluations += ik.evaluations
            solved = ik.improved
            if solved:
                x = ik.estimate
                self.particles = self.body.dofs.validate(self.particles + ik.delta)
        if self.prior is not None:  # the particles as they go on to the next frame
            self.prior.follow(self.particles)
        self.velocity, self.last = x - self.last, x
        e_s, c_a = self.scores(x[None])
        e_s, c_a = float(e_s[0]), None if c_a is None else float(c_a[0])
        overlap = self.likelihood.silhouette_overlap(x, self.opt.iou_tile or None)
        self.frames_done += 1
        k = self.opt.appearance_refine
        if self.appearance is not None and k and self.frames_done % k == 0:
            self.likelihood.refine_appearance(x, images, fgs)
        kept = self.likelihood.kept_fraction
        quality = e_s / max(self.area, 1.0)
        covered = None
        if self.refines_masks and self.obs.sequence is not None:
            verts = skin_vertices(self.body.mesh, self.body.skinning(x[None]))[0]
            covered = np.array([mask_covered(cam, verts, self.body.mesh.faces, m)
                                for cam, m in zip(self.obs.cameras, self.obs.sequence)])
            if np.isfinite(covered).any() and np.nanmin(covered) < self.min_sequence_covered:
                quality = max(quality, 1.0)  # off what moved, whatever the refined masks say
        if kept < self.min_kept:
            # the colour model removed most of what the cameras see: the fit is to a mask the
            # tracker made itself (after a bad start it learnt the background's colours and
            # then explained the person away: e_S near 0 with the model off the person)
            quality = max(quality, 1.0 - kept)
        info = {"e_s": e_s, "foreground_px": self.area, "foreground_kept": round(kept, 4),
                "quality": quality,
                **{key: [None if not np.isfinite(v) else round(float(v), 4) for v in row]
                   for key, row in zip(("iou", "model_on_fg", "fg_covered"), overlap)},
                "ess": float(res.weights.ess), "weightings": len(res.layers)}
        if self._limb_grids:
            info["limb_sweep"] = list(swept)
        if self._ik_limbs:
            info["keypoint_ik"] = list(solved)
        if self.kp_target is not None:
            d = float(self.keypoint_distance(x[None])[0])
            info["keypoint_m"] = None if not np.isfinite(d) else round(d, 4)
        if c_a is not None:
            info["c_a"] = c_a
        if self.refines_masks:
            info["masks_refined"] = True  # the IoU above is against masks this track refined
        if covered is not None:
            info["sequence_covered"] = [None if not np.isfinite(v) else round(float(v), 4)
                                        for v in covered]
        if "pipeline_weight" in res.info:
            info["pipeline_weight"] = res.info["pipeline_weight"]
        return FrameEstimate(x, e_s, evaluations + 1, info)

    def close(self):
        self.likelihood.release()


class SIRTracker(MultiviewTracker):
    """Sampling importance resampling (Condensation) on the multi-view observation."""

    method = "sir"
    options_class = MultiviewOptions


class APFTracker(MultiviewTracker):
    """Deutscher's annealed particle filter on the multi-view observation."""

    method = "apf"
    options_class = ApfOptions


class PSTracker(MultiviewTracker):
    """MacCormick & Isard's partitioned sampling on the multi-view observation."""

    method = "ps"
    options_class = AnnealedOptions


class HPSTracker(MultiviewTracker):
    """Bandouch's hierarchical sampling with parallel limb pipelines."""

    method = "hps"
    options_class = HpsOptions
