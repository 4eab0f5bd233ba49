"""Estimate the subject's body from the first frames of a dataset (``--body estimate``).

What is estimated: the skeleton's segment lengths, as a stature plus proportions
(:class:`Proportions`: hip and shoulder heights, thigh/shank and upper-arm/forearm splits, arm,
hand and foot lengths, ankle height, shoulder and hip widths) and the mesh's ``girth_scale``.
The skeleton keeps the canonical topology and axis-aligned rest pose of
:func:`gltrack.body.skeleton.default_skeleton` (which is :class:`Proportions` at its defaults),
so the estimated body drops into every tracker. :data:`SEARCH` lists the proportions searched;
the others keep the anthropometric defaults.

How (both rigs, the same search; only the per-frame cost differs):

1. Frames: ``n_frames`` frames spread over the first ``span`` seconds (the subject may move
   and need not stand in a T-pose). Each frame gets its own scoring engine holding its
   observation: multi-view, every camera framed on the body (``tile`` pixels for a window
   0.3 m larger than the body, about 1.6 cm per pixel); depth, the depth tracker's crop.
2. Start: a stature guess from the observation (the visual hull's height for multi-view, the
   foreground points' height for depth), then the rig's own automatic start
   (:meth:`gltrack.track.multiview.MultiviewTracker.auto_init`,
   :meth:`gltrack.track.depth.HillClimbDepthTracker.auto_init`) with the default body of that
   stature finds the first frame's pose, which is settled (:meth:`_Search.settle`: either
   heading, legs either way, limbs swept through the pose library, hill-climbed).
3. Girth and stature on the first frame, then every later frame's pose: the previous one
   moved by the observation's centroid shift, limbs swept, hill-climbed with wide steps.
4. Shape search, one proportion at a time (:data:`SEARCH`, coarse to fine over ``rounds``):
   a step up or down is kept when its *profile* cost beats the current cost: the frames'
   poses carried over to the candidate body (same angles, feet kept on their spot) and
   hill-climbed once, the cost summed over the frames (multi-view: silhouette XOR pixels over
   all cameras, plus :data:`FLOOR_PENALTY` for a sole more than :data:`FLOOR_TOLERANCE`
   below the floor: the dataset's recorded one, ``world.floor`` from ``gltrack ingest``, else
   the visual hulls' bottom; depth: the smoothstep depth cost). Judging a candidate at the current poses
   instead never moves: those poses make up for the current body's errors. After every sweep
   the poses are hill-climbed again (:func:`gltrack.sample.hillclimb.hill_climb`).
5. The result: the skeleton of the best proportions, the procedural mesh of it
   (:class:`gltrack.body.model.BodyModel`), the per-stage costs and the frames' poses.

Why one template mesh stands in for every candidate body (speed): the procedural mesh of any
proportions has the same vertices, faces and skin bones as the template's (only positions
differ), so the candidate's rest mesh is approximated by one affine map per bone applied to the
template's vertices (a least-squares fit, ~4 mm RMS / 15 mm worst vertex off on the CMU walk
subject's skeleton). The maps fold into the skinning matrices, so candidate bodies need no
mesh upload: any batch may mix bodies and poses. The returned body has the exact mesh.

Measured (``gltrack synth`` of CMU clips, 60 frames at 30 fps, default noise, 4 cameras of
320 x 240 or one 176 x 144 depth camera; defaults, seed 0; :func:`gltrack.body.measure.body_error` against
meta.json's skeleton; mean / max bone error, height error, mm; 2-core llvmpipe)::

    clip (subject)          multi-view                     depth
    walk  cmu_02_01 @8      31 / 91 (hand),   -14   56 s   42 / 87 (hand),  -46   28 s
    hop   cmu_131_03 @160   36 / 80 (hand),  -100   55 s   41 / 92 (hand),  +14   31 s
    salsa cmu_60_10 @400    30 / 82 (sh.w.),   +8   47 s   32 / 149 (sh.w.), -10  29 s

against 51 / 68 / 110 mm for the default 1.75 m body and 39 / 38 / 30 mm for the default
proportions at the true height: the stature is most of what is won. Why the 20 mm target is
missed: the estimate is only as good as the first frames' poses (silhouettes and one depth
view leave limbs ambiguous: legs either way in a stride, arms against the torso, the hop's
lifted leg turned; a pose in the wrong basin is made up for by wrong proportions; started
from the true poses, an earlier variant of this search put the walk's stature within 2 mm);
and the CMU skeletons' conventions
lie outside what is measured (hands 0.046 H from wrist to end site against the default
0.108 H: 80-90 mm on each hand; ankle joints 1.5-2.4 % H above the sole; the salsa's shoulder
joints 9 cm from the midline). On rendered bodies of the default proportions (the tests,
clean masks) the height came within 13 mm (multi-view, tile 128) and 7 mm (depth) and the
mean bone error within 7 mm.

Units: metres, radians; costs are silhouette XOR pixels at tile resolution summed over cameras
and frames (multi-view) or depth-cost area units (``area_unit`` patches, see
:class:`gltrack.observe.depth_view.DepthLikelihood`) summed over frames (depth).

Plugging it in (``gltrack track --body estimate``)::

    est = estimate_body(dataset, ctx, preset=preset or "auto", rng=np.random.default_rng(seed))
    body = est.body          # est.frames / est.poses: where the body was found
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np

from gltrack.body.dofs import HIDDEN_PARTS
from gltrack.body.kinematics import Kinematics
from gltrack.body.measure import bone_lengths, lowest_sole
from gltrack.body.mesh import make_body_mesh
from gltrack.body.model import BodyModel
from gltrack.body.poses import canonical_poses
from gltrack.body.skeleton import EULER_ORDER, JOINT_NAMES, PARENTS, Skeleton, default_skeleton
from gltrack.gl.programs import ProgramCache
from gltrack.observe.blob_evidence import default_volume
from gltrack.observe.depth import foreground_points
from gltrack.observe.depth_view import (DepthLikelihood, DepthObservation, crop_camera,
                                         resample_depth)
from gltrack.observe.keypoints import keypoint_distance
from gltrack.observe.multiview import MultiviewObservation
from gltrack.observe.voxels import carve
from gltrack.render.engine import DepthCostParams, ScoringEngine
from gltrack.sample.hillclimb import hill_climb
from gltrack.sample.partitions import (LIMBS, default_partitions, exchange_limbs,
                                      hill_climb_order, limb_pairs)

from .base import NoPersonError

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------------------
# The body family
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Proportions:
    """A body shape: stature plus segment proportions (fractions of the stature) and girth.

    The defaults are :func:`gltrack.body.skeleton.default_skeleton`'s anthropometric ratios,
    so ``Proportions(height=H).skeleton()`` equals ``default_skeleton(H)``.

    Attributes
    ----------
    height : float, metres, rest standing height (lowest foot tip to head top)
    hip : hip-joint height over the floor / height
    shoulder : shoulder-joint height / height
    knee : thigh length / (thigh + shank)
    arm : (upper arm + forearm) / height
    elbow : upper arm / (upper arm + forearm)
    hand : wrist to hand tip / height
    shoulder_width : distance between the shoulder joints / height
    hip_width : distance between the hip joints / height
    ankle : ankle-joint height over the sole / height
    foot : toe tip ahead of the ankle / height
    girth : ``girth_scale`` of :func:`gltrack.body.mesh.make_body_mesh` (1 = the ANSUR means)
    """

    height: float = 1.75
    hip: float = 0.53
    shoulder: float = 0.82
    knee: float = 0.245 / 0.491
    arm: float = 0.332
    elbow: float = 0.186 / 0.332
    hand: float = 0.108
    shoulder_width: float = 0.259
    hip_width: float = 0.191 * 0.55
    ankle: float = 0.039
    foot: float = 0.11
    girth: float = 1.0

    #: (low, high) of each parameter: adult human ranges, wide enough for unusual builds;
    #: the search never leaves them.
    BOUNDS = {
        "height": (0.9, 2.3), "hip": (0.44, 0.64), "shoulder": (0.74, 0.90),
        "knee": (0.40, 0.60), "arm": (0.26, 0.42), "elbow": (0.44, 0.66),
        "hand": (0.03, 0.14), "shoulder_width": (0.12, 0.33), "hip_width": (0.05, 0.17),
        "ankle": (0.008, 0.07), "foot": (0.06, 0.16), "girth": (0.6, 1.6),
    }

    def clipped(self) -> "Proportions":
        """A copy with every parameter inside :attr:`BOUNDS`."""
        return replace(self, **{k: float(np.clip(getattr(self, k), *self.BOUNDS[k]))
                                for k in self.BOUNDS})

    def as_dict(self) -> dict:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def of_skeleton(cls, skeleton: Skeleton, girth: float = 1.0) -> "Proportions":
        """The proportions measured on a canonical skeleton's rest pose (left and right
        averaged; not clipped to :attr:`BOUNDS`): the closest member of the family."""
        L = bone_lengths(skeleton)
        pos = skeleton.rest_positions()
        P = {n: pos[i] for i, n in enumerate(skeleton.names)}
        H = skeleton.height()
        floor = min((pos + skeleton.ends)[:, 1].min(), pos[:, 1].min())

        def both(name):
            return 0.5 * (L[f"l_{name}"] + L[f"r_{name}"])

        def y(name):
            return 0.5 * (P[f"l_{name}"][1] + P[f"r_{name}"][1]) - floor

        tips = {n: pos[i] + skeleton.ends[i] for i, n in enumerate(skeleton.names)}
        foot = 0.5 * sum(tips[f"{s}_ankle"][2] - P[f"{s}_ankle"][2] for s in "lr")
        return cls(height=H, hip=y("hip") / H, shoulder=y("shoulder") / H,
                   knee=both("thigh") / (both("thigh") + both("shank")),
                   arm=(both("upper_arm") + both("forearm")) / H,
                   elbow=both("upper_arm") / (both("upper_arm") + both("forearm")),
                   hand=both("hand") / H, shoulder_width=L["shoulder_width"] / H,
                   hip_width=L["hip_width"] / H, ankle=y("ankle") / H, foot=foot / H,
                   girth=float(girth))

    def skeleton(self) -> Skeleton:
        """The canonical skeleton of these proportions (rest pose standing on y = 0).

        Layout as :func:`default_skeleton`: the hip joints 0.03 H below the pelvis joint; the
        trunk (pelvis joint to shoulder line) split 5 : 12 : 9 between lower spine, upper spine
        and clavicle height, the neck 1/26 of the trunk above the clavicles; the neck-to-head-top
        remainder split 5 : 12 between neck bone and head; clavicles start 0.03 H off the
        midline. Lengths in metres.
        """
        p = self.clipped()
        H = p.height
        hip_y, sh_y, ankle_h = p.hip * H, p.shoulder * H, p.ankle * H
        leg = hip_y - ankle_h
        thigh = p.knee * leg
        shank = leg - thigh
        pelvis_y = hip_y + 0.03 * H
        trunk = sh_y - pelvis_y
        neck_y = pelvis_y + trunk * 27.0 / 26.0
        head_neck = max(H - neck_y, 0.06 * H)
        half_sw, half_hw = 0.5 * p.shoulder_width * H, 0.5 * p.hip_width * H
        clav_x = min(0.03 * H, 0.7 * half_sw)
        upper = p.elbow * p.arm * H
        fore = p.arm * H - upper
        off = {
            "pelvis": (0, pelvis_y, 0),
            "spine_lower": (0, trunk * 5 / 26, 0),
            "spine_upper": (0, trunk * 12 / 26, 0),
            "neck": (0, trunk * 10 / 26, 0),
            "head": (0, head_neck * 5 / 17, 0),
            "l_clavicle": (clav_x, trunk * 9 / 26, 0), "l_shoulder": (half_sw - clav_x, 0, 0),
            "l_elbow": (upper, 0, 0), "l_wrist": (fore, 0, 0),
            "r_clavicle": (-clav_x, trunk * 9 / 26, 0), "r_shoulder": (clav_x - half_sw, 0, 0),
            "r_elbow": (-upper, 0, 0), "r_wrist": (-fore, 0, 0),
            "l_hip": (half_hw, -0.03 * H, 0), "l_knee": (0, -thigh, 0), "l_ankle": (0, -shank, 0),
            "r_hip": (-half_hw, -0.03 * H, 0), "r_knee": (0, -thigh, 0), "r_ankle": (0, -shank, 0),
        }
        ends = {
            "head": (0, head_neck * 12 / 17, 0),
            "l_wrist": (p.hand * H, 0, 0), "r_wrist": (-p.hand * H, 0, 0),
            "l_ankle": (0, -ankle_h, p.foot * H), "r_ankle": (0, -ankle_h, p.foot * H),
        }
        return Skeleton(JOINT_NAMES, np.array(PARENTS),
                        np.array([off[n] for n in JOINT_NAMES], dtype=np.float64),
                        np.array([ends.get(n, (0, 0, 0)) for n in JOINT_NAMES], dtype=np.float64),
                        tuple(EULER_ORDER[n] for n in JOINT_NAMES))


# ---------------------------------------------------------------------------------------------
# One template mesh for every candidate body
# ---------------------------------------------------------------------------------------------

class StretchedTemplate:
    """The procedural mesh of the default skeleton, re-shaped per candidate by per-bone affine
    maps folded into the skinning matrices.

    For a candidate body (skeleton, girth) the procedural mesh has the template's topology and
    skin bones; :meth:`maps` finds the B affine maps ``A_b`` (rest space to rest space) that
    minimise ``sum_v |sum_k w_vk A_{b_vk} [v, 1] - v'|^2`` over the template's vertices ``v``
    and the candidate's ``v'`` (one linear least-squares solve; the pseudo-inverse is computed
    once). :meth:`skinning` composes them with the candidate skeleton's skinning matrices.

    Parameters
    ----------
    lod : int, level of detail of the procedural mesh
    """

    def __init__(self, lod: int = 1):
        self.lod = int(lod)
        self.skeleton = default_skeleton()
        self.mesh = make_body_mesh(self.skeleton, lod=self.lod)
        m = self.mesh
        V, B = m.n_vertices, self.skeleton.n_joints
        vh = np.c_[m.vertices.astype(np.float64), np.ones(V)]
        A = np.zeros((V, B, 4))
        for k in range(4):
            A[np.arange(V), m.joints[:, k]] += m.weights[:, k, None].astype(np.float64) * vh
        self._pinv = np.linalg.pinv(A.reshape(V, 4 * B))
        self.n_bones = B

    def maps(self, skeleton: Skeleton, girth: float = 1.0) -> np.ndarray:
        """(B, 3, 4) affine maps from the template's rest mesh to ``skeleton``'s (metres)."""
        mesh = make_body_mesh(skeleton, lod=self.lod, girth_scale=girth)
        if mesh.vertices.shape != self.mesh.vertices.shape:
            raise ValueError("the candidate mesh does not share the template's topology")
        M = (self._pinv @ mesh.vertices.astype(np.float64)).reshape(self.n_bones, 4, 3)
        return np.ascontiguousarray(M.transpose(0, 2, 1))

    @staticmethod
    def skinning(kin: Kinematics, maps: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(N, B, 3, 4) float32 skinning matrices of poses ``X`` (N, D) of the candidate with
        kinematics ``kin`` and template maps ``maps`` (B, 3, 4)."""
        S = kin.skinning_matrices(X, dtype=np.float64)
        out = np.empty(S.shape, dtype=np.float32)
        out[..., :3] = S[..., :3] @ maps[None, :, :, :3]
        out[..., 3] = (S[..., :3] @ maps[None, :, :, 3:])[..., 0] + S[..., 3]
        return out


# ---------------------------------------------------------------------------------------------
# Per-frame costs of the two rigs
# ---------------------------------------------------------------------------------------------

class _SilhouetteFrames:
    """Silhouette XOR of each chosen frame: pixels summed over the colour cameras, each camera
    scored in a ``tile x tile`` window around the body, so that every camera sees the body at
    about the same resolution (a 2.3 m window is 3.6 cm per pixel on 64 pixels, 1.8 cm on 128;
    a whole 320 x 240 image on a 64-pixel tile is 4-5 cm per pixel, and a far camera's person
    only 20 pixels tall). One engine per frame holds its masks; pixels of a window outside the
    camera's image are blocked (not scored)."""

    unit = "px"
    margin = 0.3

    def __init__(self, dataset, ctx, template_body, tile: int, rng):
        self.dataset, self.ctx, self.rng = dataset, ctx, rng
        self.obs = MultiviewObservation(dataset, "auto", rng)
        self.tile = tile
        self.programs = ProgramCache(ctx)
        self.frames, self.engines = [], []
        #: the floor the dataset records (``gltrack ingest --floor``), or None
        self.known_floor = dataset.floor_height()
        #: metres (world y): the recorded floor, else the lowest bottom of the visual hulls
        #: measured so far
        self.floor = np.inf if self.known_floor is None else self.known_floor
        #: the dataset's triangulated keypoints (:func:`gltrack.track.keypoint_sites.keypoint_targets`)
        #: and, per added frame, its keypoints (K, 3) and foreground pixels
        self.kp_sites, self.kp_points = None, None
        self.kp_frames = []
        self.set_template(template_body)

    def set_template(self, body) -> None:
        """The template body of the search (its preset decides the keypoints' joints)."""
        from .keypoint_sites import keypoint_targets
        from .multiview import HpsOptions

        self.template_body = body
        opt = HpsOptions()
        self.kp_sites, self.kp_points = keypoint_targets(self.dataset, body, opt, sites=False)
        #: metres of mean distance that cost the whole area (the tracker's default scale)
        self.kp_scale = opt.keypoints

    def keypoint_cost(self, k: int, kin, X) -> np.ndarray | float:
        """(N,) pixels for frame ``k``: the tracker's keypoint cost
        (:meth:`gltrack.track.multiview.MultiviewTracker.keypoint_cost`, the same scale) of
        the poses ``X`` of the body ``kin``; 0 without keypoints."""
        target, area = self.kp_frames[k]
        if target is None:
            return 0.0
        d = keypoint_distance(self.kp_sites.positions(kin, X), target)
        if not np.isfinite(d).any():
            return 0.0
        return area * d / self.kp_scale

    def measure(self, frame: int) -> tuple[float, np.ndarray]:
        """Height (metres, top to bottom plus one voxel) and centroid (3,) of the frame's
        visual hull; NoPersonError without one. Lowers :attr:`floor` to the hull's bottom
        unless the dataset records the floor; then the height is measured from the floor when
        the hull reaches below it (masks that spill onto the floor round the feet: 8 cm on the
        Pose2Sim take)."""
        _, masks = self.obs(frame)
        volume = default_volume(self.obs.pinholes, self.dataset.assumed_floor())
        hull = carve(self.obs.pinholes, masks, volume, base=16, max_depth=3, distort=False)
        if len(hull) == 0:
            raise NoPersonError(f"frame {frame}: the cameras' foreground masks do not meet inside "
                                "the tracking volume: no person to estimate the body from")
        pts, vol = hull.points(max_size=0.05)
        size = float(np.cbrt(vol.min()))
        bottom = float(pts[:, 1].min() - 0.5 * size)
        if self.known_floor is None:
            self.floor = min(self.floor, bottom)
        else:
            bottom = max(bottom, self.known_floor)
        centroid = (pts * vol[:, None]).sum(axis=0) / vol.sum()
        return float(pts[:, 1].max() + 0.5 * size - bottom), centroid

    def initial_pose(self, frame: int, body) -> np.ndarray:
        from .multiview import HpsOptions, HPSTracker

        # Without the start's limb sweep: the settle sweeps the limbs through the pose library
        # itself, and with the sweep too the estimates' bones came out worse in 5 of 6 pairs
        # (the honest multi-view bench's hop, walk and salsa, rng seeds 1 and 2: mean bone
        # error 33.7 -> 38.6 mm on average)
        tr = HPSTracker(self.dataset, body, self.ctx,
                        HpsOptions(appearance=False, environment=False, init_limb_sweep=0),
                        self.rng)
        try:
            return tr.auto_init(frame)
        finally:
            tr.close()

    def add(self, frame: int, pose) -> None:
        """Frame ``frame``, every camera framed around ``pose`` (the template body's joints)."""
        _, masks = self.obs(frame)
        pts = self.template_body.joints(np.asarray(pose)[None])[0]
        cams, fg, block = [], [], []
        for pin, mask, poly in zip(self.obs.pinholes, masks, self.obs.polygons):
            cam, _ = crop_camera(pin, pts, self.tile, self.margin)
            inside = resample_depth(np.ones(mask.shape, np.float32), pin, cam) > 0
            cams.append(cam)
            fg.append(resample_depth(mask.astype(np.float32), pin, cam) > 0)
            block.append(~inside | (resample_depth(poly.astype(np.float32), pin, cam) > 0))
        eng = ScoringEngine(self.ctx, self.template_body.mesh, self.template_body.skeleton.n_joints,
                            cams, tile=self.tile, programs=self.programs)
        for c, (f, b) in enumerate(zip(fg, block)):
            eng.set_masks(c, f, b)
        self.frames.append(frame)
        self.engines.append(eng)
        area = float(sum((f & ~b).sum() for f, b in zip(fg, block)))
        self.kp_frames.append((None if self.kp_points is None else self.kp_points[frame], area))

    def cost(self, k: int, S: np.ndarray) -> np.ndarray:
        return self.engines[k].score(S, ["silhouette"])[:, :, 1].sum(axis=1)

    def release(self) -> None:
        for e in self.engines:
            e.release()
        self.engines = []
        self.programs.release()


class _DepthFrames:
    """Depth cost (area units, :class:`DepthLikelihood`) of each chosen frame, each scored in
    a window around the pose found for it (one engine per frame)."""

    unit = "area units"
    margin = 0.4
    #: no floor: background subtraction removes the floor and with it the soles that touch
    #: it, so the lowest foreground point lies above the floor, and a floor there would lift
    #: the body off the ground
    floor = np.inf

    def __init__(self, dataset, ctx, template_body, tile: int, rng):
        from .depth import DepthOptions

        # the settle tries the legs both ways itself (DepthOptions.init_exchange says why)
        o = DepthOptions(init_exchange=False)
        self.opt = o
        self.dataset, self.ctx, self.rng = dataset, ctx, rng
        self.obs = DepthObservation(dataset, bg_tolerance=o.bg_tolerance, bg_sigmas=o.bg_sigmas,
                                    range_noise_2m=o.range_noise_2m)
        self.programs = ProgramCache(ctx)
        self.template_body, self.tile = template_body, tile
        self.frames, self.lk = [], []

    def measure(self, frame: int) -> tuple[float, np.ndarray]:
        """Vertical extent (metres) and centroid (3,) of the frame's foreground points;
        NoPersonError with too few of them."""
        pts = foreground_points(self.obs(frame), self.obs.pinhole)
        if len(pts) < 50:
            raise NoPersonError(f"frame {frame}: too few foreground depth pixels ({len(pts)}) to "
                                "estimate the body from")
        lo, hi = np.percentile(pts[:, 1], [0.5, 99.5])
        return float(hi - lo), pts.mean(axis=0)

    def initial_pose(self, frame: int, body) -> np.ndarray:
        from .depth import HillClimbDepthTracker

        tr = HillClimbDepthTracker(self.dataset, body, self.ctx, self.opt, self.rng)
        try:
            return tr.auto_init(frame)
        finally:
            tr.close()

    def add(self, frame: int, pose) -> None:
        """Frame ``frame``, framed around ``pose`` (the template body's joints)."""
        o = self.opt
        lk = DepthLikelihood(self.ctx, self.template_body, self.obs.pinhole, tile=self.tile,
                             params=DepthCostParams(scale=o.scale, penalty=o.penalty,
                                                    smooth=o.smooth),
                             crop=True, area_unit=o.area_unit, programs=self.programs)
        lk.set_view(self.obs(frame), self.template_body.joints(np.asarray(pose)[None])[0],
                    self.margin)
        self.frames.append(frame)
        self.lk.append(lk)

    def set_template(self, body) -> None:
        self.template_body = body

    @staticmethod
    def keypoint_cost(k: int, kin, X) -> float:
        """0: a depth dataset has no keypoints."""
        return 0.0

    def cost(self, k: int, S: np.ndarray) -> np.ndarray:
        lk = self.lk[k]
        return lk.engine.score(S, ["depth"])[:, 0, 0] * lk.weight

    def release(self) -> None:
        for lk in self.lk:
            lk.release()
        self.lk = []
        self.programs.release()


# ---------------------------------------------------------------------------------------------
# The estimate
# ---------------------------------------------------------------------------------------------

@dataclass
class BodyEstimate:
    """What :func:`estimate_body` found.

    Attributes
    ----------
    skeleton : Skeleton, the estimated skeleton (metres)
    girth_scale : float, the estimated ``girth_scale`` of the procedural mesh
    body : BodyModel, the estimated body (procedural mesh of ``skeleton`` and ``girth_scale``,
        the requested DOF preset)
    proportions : Proportions, the estimated shape parameters
    frames : list of int, the dataset frames the estimate used
    poses : (K, D) float64, the pose found in each of them (with ``body``)
    costs : list of dict, one per stage: ``stage``, ``cost`` (summed over the frames, in
        ``unit``), ``seconds`` since the start
    unit : str, unit of the costs ("px": silhouette XOR pixels at tile resolution summed over
        cameras; "area units": depth cost, see :class:`DepthLikelihood`)
    seconds : float, wall time of the whole estimate
    evaluations : int, candidate (body, pose) pairs scored
    floor : float or None, metres (world y): the floor no sole was let more than
        :data:`FLOOR_TOLERANCE` below (multi-view: the lowest bottom of the frames' visual
        hulls; None for depth and where the feet are hidden)
    framing : dict or None, with ``preset="auto"``: the observation's height in each frame
        (``heights_m``), the threshold (``seated_below_m``, :data:`SEATED_HEIGHT`) and the
        preset chosen (:func:`framing_preset`)
    """

    skeleton: Skeleton
    girth_scale: float
    body: BodyModel
    proportions: Proportions
    frames: list
    poses: np.ndarray
    costs: list = field(default_factory=list)
    unit: str = ""
    seconds: float = 0.0
    evaluations: int = 0
    floor: float | None = None
    framing: dict | None = None

    def summary(self) -> dict:
        """JSON-able record: proportions, height (m), girth scale, frames, costs, seconds,
        floor (m or None), framing (dict or None)."""
        return {"height": self.skeleton.height(), "girth_scale": self.girth_scale,
                "proportions": self.proportions.as_dict(), "frames": list(self.frames),
                "costs": self.costs, "unit": self.unit, "seconds": self.seconds,
                "evaluations": self.evaluations, "floor": self.floor,
                "framing": self.framing}


#: Search schedule: (proportion, its first step). Order: the girth and the stature first (a
#: body too thin for its silhouette is made up for by longer segments: on a 1.62 m test subject
#: with girth 1.1 the hip height went from 0.53 to 0.57 before the girth was searched), then
#: the long segments (the largest silhouette changes), then the shoulder width. Steps
#: shrink by :data:`SHRINK` per round; rounds after the first search only the first
#: :data:`LATER_ROUNDS` proportions. The proportions not listed keep
#: :func:`~gltrack.body.skeleton.default_skeleton`'s ratios: the knee and elbow splits, the
#: hand, the ankle height, the foot and the hip width change a silhouette too little to be
#: measured reliably at this resolution (searched, the hand went to the longest allowed on the
#: CMU walk subject, whose true hand is the shortest).
SEARCH = (
    ("girth", 0.08), ("height", 0.04), ("hip", 0.02), ("shoulder", 0.015), ("arm", 0.02),
    ("shoulder_width", 0.02),
)
SHRINK = 0.6
LATER_ROUNDS = 2
#: Level of detail of the template mesh the search renders (lod 0: 542 vertices, about 1.5x
#: faster than lod 1 on llvmpipe); the returned body has the ``lod`` asked for.
TEMPLATE_LOD = 0
#: Steps of the stature search on the first frame alone (metres, each tried up to 3 times).
FIRST_STEPS = (0.08, 0.04, 0.02)

#: Silhouette XOR pixels per metre that a sole reaches more than :data:`FLOOR_TOLERANCE` below
#: the floor (the dataset's recorded one, else the lowest bottom of the frames' visual hulls;
#: multi-view only). Why: the
#: subject stands on something, and a hull holds the whole subject, so no sole lies below its
#: bottom. Without this, masks that spill into the background beside the person (GrabCut on
#: real footage) are covered best by a body too large for them that sinks through the floor:
#: the Pose2Sim take gave 2.07-2.20 m with the soles 0.2-0.4 m under the hulls' bottom, and
#: 1.89-1.90 m with this. 1000 pixels a centimetre outweighs any spill: in effect a limit, but one
#: with a slope that a start below the floor can climb back along.
FLOOR_PENALTY = 1.0e5
#: metres a sole may reach below the floor before :data:`FLOOR_PENALTY` applies: what the
#: procedural foot may differ from a real one (a mocap skeleton's ankle sits 1.5-2.4 % of the
#: stature above its sole, the procedural one's 3.9 %: up to 4 cm at 1.75 m), plus the
#: estimate of the lowest sole (within 1.6 cm of the mesh's lowest vertex)
FLOOR_TOLERANCE = 0.05

#: metres: a subject whose visual hull (or depth foreground) is shorter than this on the
#: estimate's frames (median) is seen from the waist up, and ``preset="auto"`` estimates and
#: tracks it with the ``"upper"`` preset. Whole bodies measure more: the simulated walk and hop
#: 1.4-1.7 m (multi-view and depth), the Pose2Sim take 1.4-1.7 m, and the shortest measured,
#: the simulated salsa dancer (MakeHuman subject), 1.22 m multi-view and 1.15-1.18 m depth.
#: Seen above a desk, an adult's trunk and head (sitting height 0.8-0.95 m) show less: the
#: seated caliscope take's hull is 0.84-0.87 m (the desk hides the legs from some cameras
#: only). 1.0 m lies between the two. Children under about 1 m would be taken for seated:
#: pass ``--dof full``.
SEATED_HEIGHT = 1.0

#: the presets :func:`framing_preset` chooses between
FRAMING_PRESETS = ("full", "upper")


def framing_preset(heights) -> str:
    """The DOF preset for a subject whose observation is ``heights`` (metres, one per frame)
    tall: ``"upper"`` when their median is under :data:`SEATED_HEIGHT` (seen from the waist
    up), else ``"full"``; ``"full"`` without any measurement."""
    h = np.asarray(heights, dtype=np.float64)
    if h.size == 0 or not np.all(np.isfinite(h)):
        return "full"
    return "upper" if float(np.median(h)) < SEATED_HEIGHT else "full"

#: DOFs a candidate body's pose re-fit leaves alone: twists about a limb's own axis and the
#: hands' and feet's small rotations barely change a silhouette or a depth surface.
FROZEN = ("l_shoulder_rx", "r_shoulder_rx", "l_elbow_rx", "r_elbow_rx", "l_hip_ry", "r_hip_ry",
          "neck_ry", "head_ry", "l_wrist_ry", "r_wrist_ry", "l_wrist_rz", "r_wrist_rz",
          "l_ankle_rz", "r_ankle_rz")


class _Search:
    """State of one estimate: the frames' scorers and poses, the current shape and its cost.

    A candidate shape is judged by its *profile* cost (:meth:`evaluate`): the frames' poses
    carried over to it and hill-climbed once. Why not at the current poses: those were fitted
    to the current body and compensate its errors (a body too short for its silhouette
    straightens its knees and leans less), so at them every other body looks worse and a
    coordinate search never leaves its start; with one re-fit per candidate, taller, longer-
    legged bodies won where they should (walk subject: 1.44 -> 1.478 m, true 1.476 m).
    """

    def __init__(self, views, template: StretchedTemplate, dofs, fps: float,
                 stands: bool = True):
        self.views, self.template, self.dofs = views, template, dofs
        #: whether the feet are scored, and so held above the views' floor
        self.stands = bool(stands)
        self.sigma = dofs.sigma_at(fps)
        self.order = hill_climb_order(dofs, group_limbs=True)
        frozen = {dofs.index(n) for n in FROZEN if n in dofs.names}
        self.profile_order = [g for g in (tuple(i for i in np.atleast_1d(e) if i not in frozen)
                                          for e in self.order) if g]
        self.parts = default_partitions(dofs)
        self.library = canonical_poses(dofs)[1]
        self.pairs = limb_pairs(dofs)
        self.evaluations = 0
        self.poses = []
        self.shape = None
        self.cost = np.inf
        self._direction = {}
        self._cache = {}

    def candidate(self, shape: Proportions):
        """(kinematics, template maps) of ``shape`` (cached)."""
        key = tuple(np.round(list(shape.as_dict().values()), 6))
        if key not in self._cache:
            sk = shape.skeleton()
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = (Kinematics(sk, self.dofs), self.template.maps(sk, shape.girth))
        return self._cache[key]

    def frame_cost(self, k, shape=None):
        """Cost function ``X (N, D) -> (N,)`` of frame ``k`` for ``shape`` (default current):
        the rig's cost, plus the joints' distance to the frame's triangulated keypoints where
        the dataset has them (the tracker's keypoint cost, on the same scale: a skeleton whose
        bones do not reach the keypoints pays for it), plus :data:`FLOOR_PENALTY` per metre a
        sole reaches more than :data:`FLOOR_TOLERANCE` below the views' floor (none where the
        feet are hidden)."""
        kin, maps = self.candidate(shape or self.shape)
        floor = self.views.floor if self.stands else np.inf

        def cost(X):
            X = np.atleast_2d(X)
            self.evaluations += len(X)
            c = self.views.cost(k, self.template.skinning(kin, maps, X)) + \
                self.views.keypoint_cost(k, kin, X)
            if np.isfinite(floor):
                below = floor - FLOOR_TOLERANCE - lowest_sole(kin, X)
                c = c + FLOOR_PENALTY * np.maximum(0.0, below)
            return c

        return cost

    def frame_costs(self) -> list:
        return [round(float(self.frame_cost(k)(x[None])[0]), 1) for k, x in enumerate(self.poses)]

    def climb(self, k, x, steps, levels=2, shape=None, order=None):
        d = self.dofs
        res = hill_climb(self.frame_cost(k, shape), x, order or self.order, steps,
                         levels=levels, grid=5, shrink=0.4, batch_independent=True,
                         lower=d.lower, upper=d.upper)
        return res.x, res.cost

    def limb_sweep(self, k: int, x, shape=None):
        """Try, for each limb on its own, the limb's angles of every library pose
        (:func:`gltrack.body.poses.canonical_poses`; all in one batch) and keep the best one
        that lowers the cost. Why: a hill climb keeps an arm stuck behind the torso or a leg
        on the wrong side once it got there; the library holds the limb placements a person
        commonly takes (down, out, forward, striding, lifted). Returns (pose, cost)."""
        cost = self.frame_cost(k, shape)
        x = np.array(x, dtype=np.float64)
        limbs = [self.parts[n] for n in LIMBS if n in self.parts]
        C = [x[None]]
        for idx in limbs:
            c = np.repeat(x[None], len(self.library), axis=0)
            c[:, idx] = self.library[:, idx]
            C.append(c)
        c = cost(np.concatenate(C))
        base, rest = c[0], c[1:].reshape(len(limbs), len(self.library))
        for idx, row in zip(limbs, rest):
            j = int(np.argmin(row))
            if row[j] < base:
                x[idx] = self.library[j, idx]
        return x, float(cost(x[None])[0])

    def _swapped(self, x, pair):
        """``x`` with the DOFs of limbs ``pair`` (left indices, right indices) exchanged and
        mirrored (rotations about y and z change sign), clamped to the limits."""
        return self.dofs.validate(exchange_limbs(x, [pair]))[0]

    def settle(self, k: int, x) -> np.ndarray:
        """The best of pose ``x``, ``x`` turned by half a turn (a silhouette or a depth surface
        fits about as well either way round) and each of these with the legs exchanged (a
        stride seen from the side fits either way): each with its limbs swept through the
        library (:meth:`limb_sweep`) and hill-climbed with wide steps; the best is climbed
        again with finer steps."""
        yaw = self.dofs.index("pelvis_ry")
        steps = 3.0 * self.sigma
        steps[:3] = 0.1
        steps[yaw] = 0.5  # the automatic start's headings are 30 degrees apart
        starts = []
        for turn in (0.0, np.pi):
            y = np.array(x, dtype=np.float64)
            y[yaw] += turn
            starts += [y] + [self._swapped(y, pair) for pair in self.pairs[:1]]
        best, best_cost = None, np.inf
        for y in starts:
            y, _ = self.limb_sweep(k, y)
            y, c = self.climb(k, y, steps)
            if c < best_cost:
                best, best_cost = y, c
        best, _ = self.limb_sweep(k, best)
        return self.climb(k, best, 0.4 * steps)[0]

    def refit(self, scale: float) -> float:
        """Hill-climb every frame's pose (all DOFs) with steps of ``scale`` inter-frame sigmas;
        returns and keeps the new summed cost."""
        total = 0.0
        for k, x in enumerate(self.poses):
            self.poses[k], c = self.climb(k, x, scale * self.sigma)
            total += c
        self.cost = total
        return total

    @staticmethod
    def _anchored(kin_old, kin_new, X):
        """Poses ``X`` for the new body: the same angles, the root moved by the change of its
        rest position turned by the pelvis rotation. Both rest poses stand on y = 0, so an
        upright body keeps its feet where they were."""
        X = np.array(X, dtype=np.float64)
        d = kin_new.skeleton.offsets[0] - kin_old.skeleton.offsets[0]
        R = kin_old.local_rotations(X)[:, 0]
        X[:, :3] += R @ d
        return X

    def evaluate(self, shape: Proportions, scale: float = 1.0):
        """Profile cost of ``shape``: every frame's pose anchored to it (:meth:`_anchored`)
        and hill-climbed once (DOFs but :data:`FROZEN`, steps of ``scale`` inter-frame
        sigmas). Returns the summed cost and the poses (list of K (D,) arrays)."""
        kin0 = self.candidate(self.shape)[0]
        kin = self.candidate(shape)[0]
        total, poses = 0.0, []
        for k, x in enumerate(self.poses):
            y = self._anchored(kin0, kin, x[None])[0]
            y, c = self.climb(k, y, scale * self.sigma, shape=shape, order=self.profile_order)
            total += c
            poses.append(y)
        return total, poses

    def line_search(self, name: str, h: float, scale: float = 1.0) -> bool:
        """Try proportion ``name`` at the current value +-``h`` (the direction that last
        succeeded first); keep the first whose profile cost (:meth:`evaluate`) beats the
        current cost. Returns whether the shape changed."""
        lo, hi = Proportions.BOUNDS[name]
        cur = getattr(self.shape, name)
        first = self._direction.get(name, 1.0)
        # the current body gets the same one climb first: a climb from poses carried over
        # also finds better poses by the way, which must not count for the candidate (without
        # this the first-frame stature of the hop clip drifted 2 cm down on such gains)
        c, poses = self.evaluate(self.shape, scale)
        if c < self.cost:
            self.poses, self.cost = poses, c
        for sign in (first, -first):
            v = float(np.clip(cur + sign * h, lo, hi))
            if v == cur:
                continue
            sh = replace(self.shape, **{name: v})
            c, poses = self.evaluate(sh, scale)
            log.debug("body estimate: %s %.4f -> %.4f: cost %.1f (current %.1f)", name, cur, v,
                      c, self.cost)
            if c < self.cost:
                self.shape, self.poses, self.cost = sh, poses, c
                self._direction[name] = sign
                return True
        return False


def _pick_frames(dataset, frames, n_frames: int, span: float) -> list[int]:
    if frames is not None:
        out = sorted({int(f) for f in frames})
        if not out or out[0] < 0 or out[-1] >= dataset.frames:
            raise ValueError(f"{dataset.path}: frames {frames} outside 0..{dataset.frames - 1}")
        return out
    last = min(dataset.frames - 1, int(round(span * dataset.fps)))
    return sorted({int(round(f)) for f in np.linspace(0, last, max(int(n_frames), 1))})


def estimate_body(dataset, ctx, *, preset: str = "full", frames=None, rng=None,
                  n_frames: int = 3, span: float = 0.4, tile: int = 64, rounds: int = 2,
                  lod: int = 1, report=None) -> BodyEstimate:
    """Estimate the subject's skeleton and girth from the first frames of ``dataset``.

    Needs no body record and no ground truth. See the module docstring for the method.

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset, a multiview (colour cameras, masks or empty-scene
        frames) or depth dataset
    ctx : moderngl.Context
    preset : str, DOF preset of the returned body (the search uses "full": a body is measured
        better with all its joints free; except a preset that hides parts,
        :data:`gltrack.body.dofs.HIDDEN_PARTS`, whose hidden surface must stay out of the cost);
        "auto": "upper" for a subject seen from the waist up (its observation under
        :data:`SEATED_HEIGHT` tall on the chosen frames, :func:`framing_preset`), else "full"
    frames : sequence of int, optional, the frames to use; default ``n_frames`` frames spread
        over the first ``span`` seconds. A first frame without a person is skipped (the next
        frames are tried, up to 30).
    rng : numpy.random.Generator, for the automatic start (multi-view sampler)
    n_frames : int, frames used when ``frames`` is not given
    span : float, seconds from the first frame that ``frames`` spreads over by default
    tile : int, engine tile side in pixels
    rounds : int, sweeps over the shape parameters (each followed by a pose re-fit)
    lod : int, level of detail of the returned body's procedural mesh
    report : callable ``report(text)``, optional, told after each stage what was done (e.g. a
        progress bar's status; the stages take 5-30 s each on software GL)

    Returns
    -------
    BodyEstimate

    Raises
    ------
    NoPersonError
        No person in any of the frames tried for the start.
    ValueError
        The dataset has neither a depth camera nor colour cameras.
    """
    t0 = time.perf_counter()
    rng = rng if rng is not None else np.random.default_rng(0)
    template = StretchedTemplate(lod=TEMPLATE_LOD)
    auto = preset == "auto"
    # the search's preset: "full", or a preset that hides parts (their DOFs fixed, their
    # surface not scored: hidden legs must not be fitted to the desk that hides them)
    search_preset = preset if preset in HIDDEN_PARTS else "full"
    tbody = BodyModel.build(template.skeleton, search_preset, template.lod, mesh=template.mesh)
    if dataset.rig == "depth":
        views = _DepthFrames(dataset, ctx, tbody, tile, rng)
    elif dataset.rig == "multiview":
        views = _SilhouetteFrames(dataset, ctx, tbody, tile, rng)
    else:
        raise ValueError(f"{dataset.path}: no body estimate for rig {dataset.rig!r}")
    chosen = _pick_frames(dataset, frames, n_frames, span)
    costs = []

    def stage(name, cost):
        costs.append({"stage": name, "cost": float(cost),
                      "seconds": round(time.perf_counter() - t0, 2)})
        log.info("body estimate: %-22s cost %10.1f %s  height %.3f m  (%.1f s)", name, cost,
                 views.unit, search.shape.height if search.shape else float("nan"),
                 time.perf_counter() - t0)
        log.debug("body estimate: per-frame costs %s", search.frame_costs())
        if report is not None:
            report(f"body estimate: {name} done, {search.shape.height:.2f} m")

    try:
        # the first frame with a person starts; later frames keep their spacing after it
        first = None
        for f in range(chosen[0], min(dataset.frames, chosen[0] + 30)):
            try:
                h_guess, c_prev = views.measure(f)
                first = f
                break
            except NoPersonError as exc:
                log.warning("%s; trying frame %d", exc, f + 1)
        if first is None:
            raise NoPersonError(f"{dataset.path}: no person in frames {chosen[0]}.."
                                f"{min(dataset.frames, chosen[0] + 30) - 1} to estimate the "
                                "body from")
        chosen = sorted({first, *[f + first - chosen[0] for f in chosen
                                  if f + first - chosen[0] < dataset.frames]})
        framing = None
        if auto:
            heights = [h_guess]
            # measured here only to decide; the floor (multi-view: the lowest hull bottom so
            # far) stays as it was, so a full-body estimate is the one without the decision
            floor = getattr(views, "floor", None)
            for f in chosen[1:]:
                try:
                    heights.append(views.measure(f)[0])
                except NoPersonError:
                    pass
            if floor is not None:
                views.floor = floor
            preset = framing_preset(heights)
            framing = {"heights_m": [round(float(h), 3) for h in heights],
                       "seated_below_m": SEATED_HEIGHT, "preset": preset}
            if preset == "upper":
                log.warning("%s: the subject is %.2f m tall in frames %s (median; under %.1f m): "
                            "seen from the waist up, so tracked with the 'upper' DOF preset "
                            "(legs fixed, out of the fit); pass --dof full to fit the legs",
                            dataset.path, float(np.median(heights)), chosen, SEATED_HEIGHT)
            if preset in HIDDEN_PARTS:
                search_preset = preset
                tbody = BodyModel.build(template.skeleton, search_preset, template.lod,
                                        mesh=template.mesh)
                views.set_template(tbody)
        # hidden feet are not held above the floor: the hull's bottom is then the desk's edge
        feet_hidden = any("foot" in p for p in HIDDEN_PARTS.get(search_preset, ()))
        search = _Search(views, template, tbody.dofs, dataset.fps, stands=not feet_hidden)
        # the search starts from the observed height; with the feet hidden that is only a
        # lower bound of the stature (the part above the desk), so it starts from the default
        # adult's unless the observation is taller. Why: the stature search below moves at
        # most ~0.45 m; from the clipped 1.0 m it stopped at 1.44 m on the seated caliscope
        # take, with the head 8 cm short on an adult's trunk and arms.
        start_height = float(np.clip(h_guess, 1.0, 2.2))
        if feet_hidden:
            start_height = max(start_height, Proportions().height)
        search.shape = Proportions(height=start_height)
        x = views.initial_pose(chosen[0], BodyModel.build(search.shape.skeleton(), search_preset))
        views.add(chosen[0], x)
        search.poses.append(search.settle(0, x))
        stage(f"start (frame {chosen[0]})", search.refit(0.5))
        # the stature on the first frame alone, so that the later frames are found with it
        for h in FIRST_STEPS:
            for _ in range(3):
                if not search.line_search("height", h, scale=1.5):
                    break
        stage("height (first frame)", search.refit(1.0))
        # later frames: the previous pose moved by the observation's centroid shift, then
        # hill-climbed with wide steps
        used = [chosen[0]]
        for f in chosen[1:]:
            try:
                _, c = views.measure(f)
            except NoPersonError as exc:
                log.warning("%s; frame left out of the body estimate", exc)
                continue
            x = search.poses[-1].copy()
            x[:3] += c - c_prev
            c_prev = c
            views.add(f, x)
            k = len(search.poses)
            wide = 1.5 * np.sqrt(f - used[-1]) * search.sigma
            wide[:3] = 0.1
            for scale in (1.0, 0.5, 0.25):
                x, _ = search.limb_sweep(k, x)
                x, _ = search.climb(k, x, scale * wide)
            search.poses.append(x)
            used.append(f)
        chosen = used
        stage(f"poses ({len(chosen)} frames)", search.refit(0.5))
        # the shape, one proportion at a time (each step judged by its profile cost); the
        # poses re-fitted after every sweep
        for r in range(int(rounds)):
            shrink = SHRINK ** r
            for name, h in SEARCH if r == 0 else SEARCH[:LATER_ROUNDS]:
                for _ in range(2):
                    if not search.line_search(name, h * shrink):
                        break
            stage(f"round {r + 1}", search.refit(shrink))
        shape = search.shape.clipped()
        skeleton = shape.skeleton()
        body = BodyModel.build(skeleton, preset, lod, girth_scale=shape.girth)
        poses = np.stack(search.poses)
        if preset != search_preset:
            full = np.asarray(search.dofs.names)
            poses = np.stack([[p[list(full).index(n)] if n in full else 0.0
                               for n in body.dofs.names] for p in poses])
        seconds = time.perf_counter() - t0
        floor = float(views.floor) if search.stands and np.isfinite(views.floor) else None
        log.info("body estimate: height %.3f m, girth %.2f from frames %s in %.1f s (%d "
                 "evaluations; floor %s)", skeleton.height(), shape.girth, chosen, seconds,
                 search.evaluations, "none" if floor is None else f"y = {floor:.3f} m")
        return BodyEstimate(skeleton, float(shape.girth), body, shape, chosen, poses, costs,
                            views.unit, seconds, search.evaluations, floor, framing)
    finally:
        views.release()
