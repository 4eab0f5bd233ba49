"""The voxel / blob / KL likelihood of Caillette, Galata & Howard (2008, sec. 6), per frame.

One :class:`BlobEvidence` serves every tracker that scores particles the paper's way (``vlmm``
with ``evaluation = "blobs"``, ``condensation``, ``apf-blobs``; their options are
:class:`gltrack.track.blobfilter.BlobEvidenceOptions`), so those methods differ in their motion
model only:

1. **voxels** - hierarchical shape-from-silhouette reconstruction of the tracking volume,
   either from the dataset's foreground masks (:func:`gltrack.observe.voxels.carve`,
   ``segmentation = "masks"``) or by the paper's per-voxel chi-square test of pixel samples
   against a YUV background model learnt from the dataset's empty-scene frames
   (:func:`gltrack.observe.colour_carve.carve_colour`, ``segmentation = "colour"``);
2. **blob fit** - EM of the body-part Gaussian mixture onto the voxels from a few predicted
   poses, all at once (:func:`gltrack.observe.blobs.fit_blobs_from`); the most likely fit is
   the frame's image evidence (:meth:`BlobEvidence.fit`), its likelihood a failure signal;
3. **evaluation** - each particle's part blobs against the evidence by the closed-form KL
   divergence of eq. 9 (:meth:`BlobEvidence.costs`), vectorised over particles.

Every stage's wall time is accumulated in :attr:`BlobEvidence.seconds` (reset per frame by
:meth:`BlobEvidence.set_frame`), so the trackers report where time goes. While a frame is
fitted and weighed, the next frame is reconstructed on a worker thread, and the one after it
is read from disk in the background (:meth:`gltrack.data.dataset.Dataset.prefetch`); the
``voxels`` stage is then the time the tracker waited for its voxels.
"""
from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from .blobs import (BlobModel, Blobs, bgr_to_yuv, fit_blobs, fit_blobs_from, kl_translation,
                    mixture_kl, mixture_loglik, part_colours, place_on_centroid)
from .voxels import carve, point_colours

log = logging.getLogger(__name__)

SEGMENTATIONS = ("masks", "colour")
#: a best-particle KL above this (nats) flags a lost frame by default
LOST_KL = 25.0
#: where the blob fit starts: the trackers' predicted poses (the system), or the true pose of
#: the frame (an oracle: the paper's protocol comparing motion models only, Fig. 12)
FIT_FROM = ("predictions", "groundtruth")
#: timed stages, keys of :attr:`BlobEvidence.seconds`
STAGES = ("voxels", "blob_fit", "evaluation")


_worker_pool = None
_worker_lock = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """The thread that reconstructs the next frame (:meth:`BlobEvidence.set_frame`)."""
    global _worker_pool
    with _worker_lock:
        if _worker_pool is None:
            _worker_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gltrack-voxels")
        return _worker_pool


def default_volume(cameras, floor: float | None = 0.0) -> np.ndarray:
    """(6,) tracking volume, metres: 3 m x 3 m around the least-squares meeting point of the
    cameras' optical axes, from 0.1 m below the floor to 2.5 m above it.

    Parameters
    ----------
    cameras : list of gltrack.camera.Camera
    floor : float or None, the floor's height along +Y (:meth:`Dataset.assumed_floor
        <gltrack.data.dataset.Dataset.assumed_floor>`); None (unknown): a 3 m cube centred on
        the meeting point. Why: a calibration's origin need not lie on the floor (caliscope
        puts it where the board lay: on the seated take, at the subject's head height), and a
        volume that starts there held only the top of the head.
    """
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cameras:
        d = c.R[2] / np.linalg.norm(c.R[2])
        M = np.eye(3) - np.outer(d, d)
        A += M
        b += M @ c.center
    p = np.linalg.lstsq(A, b, rcond=None)[0]
    lo, hi = (p[1] - 1.5, p[1] + 1.5) if floor is None else (floor - 0.1, floor + 2.5)
    return np.array([p[0] - 1.5, lo, p[2] - 1.5, p[0] + 1.5, hi, p[2] + 1.5])


class BlobEvidence:
    """Per-frame voxel reconstruction, blob fit and KL scoring of a multi-view dataset.

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset (multiview rig)
    body : gltrack.body.model.BodyModel
    volume : (6,) float or empty, tracking volume ``(xmin, ymin, zmin, xmax, ymax, zmax)``,
        metres; empty = :func:`default_volume`
    base : int, coarse voxels along the longest side of the volume (the paper's 16)
    max_depth : int, subdivision levels below the coarse grid (3 = the paper's "depth 7",
        a 128^3-equivalent finest grid)
    tolerance : int, cameras allowed to call a voxel background (occlusions, bad masks)
    segmentation : "masks" (the dataset's camN_mask) or "colour" (chi-square pixel-sample test
        against a YUV background learnt from the dataset's background frames)
    fit_iterations : EM iterations of the blob fit
    point_size : metres; voxels bigger than this are split into points of this size for the
        fit, so a big interior voxel does not count as a single point
    colour : bool, coloured blobs: each voxel point takes the mean colour of the pixels under it,
        each blob a YUV colour Gaussian acquired from the first tracked frames
        (:meth:`acquire`), and the fit weighs colour with position (off: shape only)
    """

    def __init__(self, dataset, body, *, volume=(), base: int = 16, max_depth: int = 3,
                 tolerance: int = 0, segmentation: str = "masks", fit_iterations: int = 4,
                 point_size: float = 0.06, colour: bool = True, fit_from: str = "predictions"):
        if segmentation not in SEGMENTATIONS:
            raise ValueError(f"option segmentation must be one of {SEGMENTATIONS}, got "
                             f"{segmentation!r}")
        self.ds, self.body = dataset, body
        self.cameras = list(dataset.cameras)
        if not self.cameras:
            raise ValueError(f"{dataset.path}: no cameras")
        self.volume = (np.asarray(volume, dtype=np.float64) if len(volume)
                       else default_volume(self.cameras, dataset.assumed_floor()))
        if self.volume.shape != (6,) or np.any(self.volume[3:] <= self.volume[:3]):
            raise ValueError(f"option volume must be [xmin, ymin, zmin, xmax, ymax, zmax] with "
                             f"max > min, got {list(volume)}")
        self.base, self.max_depth, self.tolerance = int(base), int(max_depth), int(tolerance)
        self.segmentation = segmentation
        self.fit_iterations = int(fit_iterations)
        self.point_size = float(point_size)
        self.use_colour = bool(colour)
        self.part_colour = None
        self._colours = None
        self.model = BlobModel(body.mesh, body.skeleton)
        self._backgrounds = None
        self.frame = None
        self.voxels = None
        self.observed = None
        self.fit_loglik = -np.inf
        self._points = None
        self._ahead = None  # (frame, Future of _reconstruct) of the next frame
        self.seconds = dict.fromkeys(STAGES, 0.0)
        if fit_from not in FIT_FROM:
            raise ValueError(f"option fit_from must be one of {FIT_FROM}, got {fit_from!r}")
        self.fit_from = fit_from
        self._true_params = None
        if fit_from == "groundtruth":
            # the labelled oracle of Caillette et al.'s Fig. 12 protocol (motion models only)
            gt = dataset.groundtruth()
            if gt is None or "params" not in gt:
                raise ValueError(f"{dataset.path}/groundtruth.npz: field 'params' is needed by "
                                 "fit_from = 'groundtruth'")
            tp = np.asarray(gt["params"], dtype=np.float64)
            if tp.ndim != 2 or tp.shape[1] != body.dofs.size:
                raise ValueError(f"{dataset.path}/groundtruth.npz: field 'params' has shape "
                                 f"{tp.shape}, the body has {body.dofs.size} DOF")
            self._true_params = tp

    @contextmanager
    def _timed(self, stage):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - t

    # -- reconstruction -------------------------------------------------------------------
    def _background_models(self):
        from .background import YuvBackground

        if self._backgrounds is None:
            models = []
            for i, c in enumerate(self.cameras):
                frames = self.ds.backgrounds(i)
                if not frames:
                    raise ValueError(f"{self.ds.path}: camera {c.name} has no background frames "
                                     "(camN_background); segmentation = 'colour' needs them")
                models.append(YuvBackground.fit(frames))
            self._backgrounds = models
        return self._backgrounds

    def _carve_colour(self, images):
        from gltrack.observe.colour_carve import carve_colour

        # the blobs sample the colours of their own (split) points: no voxel colours
        return carve_colour(self.cameras, images, self._background_models(), self.volume,
                            base=self.base, max_depth=self.max_depth,
                            tolerance=self.tolerance, colours=False)

    def _carve_masks(self, masks):
        for c, m in zip(self.cameras, masks):
            if m is None:
                raise ValueError(f"{self.ds.path}: camera {c.name} has no foreground masks "
                                 "(camN_mask); use segmentation = 'colour'")
        return carve(self.cameras, [np.asarray(m, bool) for m in masks], self.volume,
                     base=self.base, max_depth=self.max_depth, tolerance=self.tolerance)

    def _read(self, frame):
        """``frame``'s images (None unless the colour test or the voxels' colours need them)
        and masks (None with the colour test), read on the calling thread."""
        cams = range(len(self.cameras))
        by_colour = self.segmentation == "colour"
        images = [self.ds.colour(frame, i) for i in cams] \
            if self.use_colour or by_colour else None
        masks = None if by_colour else [self.ds.mask(frame, i) for i in cams]
        return images, masks

    def _reconstruct(self, images, masks):
        """Voxels, their points (or None) and the points' YUV colours (or None) of one frame's
        images and masks. Touches no state, so that it can run on the worker thread."""
        voxels = self._carve_colour(images) if masks is None else self._carve_masks(masks)
        points = voxels.points(max_size=self.point_size) if len(voxels) else None
        colours = None
        if self.use_colour and points is not None:
            colours = bgr_to_yuv(point_colours(points[0], self.cameras, images))
        return voxels, points, colours

    def set_frame(self, frame: int) -> None:
        """Reconstruct ``frame``'s voxels (timed as ``voxels``: the time the caller waits for
        them); resets the stage timers.

        The next frame is reconstructed on a worker thread while the caller fits and weighs
        this one (the reconstruction depends on the images alone; it runs beside the tracker
        where numpy releases the GIL, and the tracker's BLAS keeps to one thread, see
        :data:`gltrack.track.runner.TRACK_BLAS_THREADS`): a tracker stepping through the
        frames in order finds each frame's voxels ready or under way. The result is the same
        as reconstructing on the calling thread."""
        if self.frame == frame:
            return
        self.seconds = dict.fromkeys(STAGES, 0.0)
        by_colour = self.segmentation == "colour"
        with self._timed("voxels"):
            if by_colour:
                self._background_models()  # fitted once, here: the worker only reads them
            ahead, self._ahead = self._ahead, None
            if ahead is not None and ahead[0] == frame:
                result = ahead[1].result()
            else:  # a jump: what is under way is for another frame
                if ahead is not None:
                    ahead[1].cancel()
                result = self._reconstruct(*self._read(frame))
            self.voxels, self._points, self._colours = result
            nxt = frame + 1
            if nxt < self.ds.frames:
                # read here (the dataset is not shared with the worker): its files were
                # prefetched a frame ago, so this costs no decoding. A file that cannot be
                # read is left to raise when its frame is asked for, after this one is done.
                try:
                    data = self._read(nxt)
                except (OSError, ValueError):
                    data = None
                if data is not None:
                    self._ahead = (nxt, _worker().submit(self._reconstruct, *data))
                self.ds.prefetch(nxt + 1, colour=self.use_colour or by_colour,
                                 masks=not by_colour)
        self.frame, self.observed, self.fit_loglik = frame, None, -np.inf
        if self._points is None:
            log.warning("frame %d: no voxels reconstructed inside the tracking volume %s",
                        frame, self.volume.round(2).tolist())

    @property
    def empty(self) -> bool:
        """True when the current frame's reconstruction has no voxels."""
        return self._points is None

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The current frame's voxel points (M, 3) metres and their volumes (M,) m^3."""
        if self._points is None:
            raise ValueError(f"frame {self.frame}: no voxels reconstructed inside the tracking "
                             f"volume {self.volume.round(2).tolist()}")
        return self._points

    def centroid(self) -> np.ndarray:
        """(3,) volume-weighted centre of the current frame's voxels, metres."""
        pts, vol = self.points()
        return (pts * vol[:, None]).sum(axis=0) / vol.sum()

    # -- evidence ---------------------------------------------------------------------------
    def blobs(self, params):
        """Part blobs (N, P) of N poses (N, D)."""
        return self.model.blobs(self.body.skinning(np.atleast_2d(params)))

    def rank(self, params, keep: int) -> np.ndarray:
        """Indices of the ``keep`` poses (N, D) whose unfitted blobs explain the voxels best
        (cheap pre-selection before fitting from many candidates)."""
        pts, vol = self.points()
        with self._timed("blob_fit"):
            # every point counts: ranking on a subset of 512 or 1024 of them lost the dancer in
            # protocol 2 (cmu_60_10, 3 seeds: 152-162 mm against 139); float32 sums are enough
            ll = mixture_loglik(pts, self.blobs(params), point_weights=vol, dtype=np.float32)
        return np.argsort(-np.atleast_1d(ll))[: max(int(keep), 1)]

    def fit(self, init_poses) -> float:
        """Fit the blobs from each of K poses (K, D) and keep the most likely as the evidence.

        Returns the kept fit's mean log-likelihood per unit volume (nats); ``-inf`` when the
        frame has no voxels (the evidence is then left unset and :meth:`costs` raises). With
        ``fit_from = "groundtruth"`` the given poses are ignored and the fit starts from the
        frame's true pose alone (the oracle protocol).
        """
        if self._true_params is not None:
            init_poses = self._true_params[min(int(self.frame), len(self._true_params) - 1)][None]
        if self._points is None:
            self.observed, self.fit_loglik = None, -np.inf
            return -np.inf
        pts, vol = self._points
        with self._timed("blob_fit"):
            # Starting also from last frame's fit was tried: it lets the evidence drift away
            # from body-shaped blobs over time (salsa, 1000 particles: 62 mm instead of 47 mm)
            fitted, ll = fit_blobs_from(pts, self.blobs(init_poses), point_weights=vol,
                                        iterations=self.fit_iterations, colours=self._colours,
                                        part_colour=self.part_colour)
            # the first of equal likelihoods, as a loop over the starts kept it
            best = int(np.argmax(np.where(np.isnan(ll), -np.inf, ll)))
        if not ll[best] > -np.inf:  # no start gave a finite fit: no evidence
            self.observed, self.fit_loglik = None, -np.inf
        else:
            self.observed, self.fit_loglik = fitted[best], float(ll[best])
        return self.fit_loglik

    def acquire(self, params, rate: float = 1.0) -> None:
        """Learn the blobs' colours from the current frame, the body posed at ``params`` (D,):
        the blobs are fitted by shape from that pose and each takes the colour statistics of
        the points it owns. ``rate`` < 1 blends into the colours acquired before (running
        average over the first frames, as the paper acquires its blobs)."""
        if not self.use_colour or self._points is None:
            return
        pts, vol = self._points
        with self._timed("blob_fit"):
            fitted, _ = fit_blobs(pts, self.blobs(params)[0], point_weights=vol,
                                  iterations=self.fit_iterations)
            new = part_colours(pts, self._colours, fitted, point_weights=vol)
        self.part_colour = new if self.part_colour is None or rate >= 1 else \
            self.part_colour.blend(new, rate)

    def costs(self, params, align_root: bool = False) -> np.ndarray:
        """(N,) KL divergence (nats) of N poses' blobs from the fitted evidence (eq. 9).

        With ``align_root`` the root translation of each pose (``params[:, :3]``, changed in
        place) first moves to where its KL is least (:func:`kl_translation`)."""
        if self.observed is None:
            raise ValueError(f"frame {self.frame}: no blob evidence fitted (empty "
                             "reconstruction?)")
        with self._timed("evaluation"):
            b = self.blobs(params)
            if align_root:
                t = kl_translation(b, self.observed)
                params[:, :3] += t
                b = Blobs(b.means + t[:, None, :], b.covs, b.weights)
            return mixture_kl(b, self.observed)


class ColourAcquisition:
    """Acquire the blobs' colours at the start pose, then average them over the estimates of
    the next ``frames - 1`` frames (sec. 6.2: "incrementally learnt during the first frames").

    Parameters
    ----------
    evidence : BlobEvidence
    frame : int, the start frame
    params : (D,) float, the start pose
    frames : int, frames that contribute (0 = no colours)
    """

    def __init__(self, evidence: BlobEvidence, frame: int, params, frames: int):
        self.evidence, self.first, self.frames = evidence, int(frame), int(frames)
        evidence.part_colour = None
        if self.frames > 0 and evidence.use_colour:
            evidence.set_frame(frame)
            evidence.acquire(params)

    def get_state(self) -> dict:
        """The acquisition's progress and the colours acquired so far (for a checkpoint)."""
        pc = self.evidence.part_colour
        return {"first": self.first, "frames": self.frames,
                "part_colour": None if pc is None else {"means": pc.means.copy(),
                                                        "covs": pc.covs.copy()}}

    @classmethod
    def from_state(cls, evidence: BlobEvidence, state: dict) -> "ColourAcquisition":
        """The acquisition of :meth:`get_state`, its colours put back into ``evidence``."""
        from .blobs import PartColours

        self = cls.__new__(cls)
        self.evidence, self.first, self.frames = evidence, int(state["first"]), int(state["frames"])
        pc = state["part_colour"]
        evidence.part_colour = None if pc is None else PartColours(
            np.asarray(pc["means"], dtype=np.float64), np.asarray(pc["covs"], dtype=np.float64))
        return self

    def update(self, frame: int, params) -> None:
        """Blend in the colours seen at ``frame`` under the estimate ``params`` (D,)."""
        k = int(frame) - self.first
        if 0 < k < self.frames:
            self.evidence.acquire(params, rate=1.0 / (k + 1))


def stage_seconds(evidence: BlobEvidence, total: float) -> dict:
    """The frame's wall time split into ``voxels``, ``blob_fit`` and ``particle_filter`` (the
    rest: prediction, KL evaluation - also given alone as ``evaluation`` - and resampling)."""
    s = dict(evidence.seconds)
    s["particle_filter"] = max(total - s["voxels"] - s["blob_fit"], 0.0)
    return s


def placed_candidates(evidence: BlobEvidence, body, prototypes, headings: int) -> np.ndarray:
    """Prototype poses at ``headings`` headings, each moved so its volume centroid sits on the
    centroid of the current frame's voxels (automatic initialisation and recovery, sec. 6.3).

    Parameters
    ----------
    evidence : BlobEvidence with the frame set
    body : BodyModel
    prototypes : (K, D) float, poses whose root translation and heading are replaced
    headings : int >= 1, headings spread evenly over a full turn

    Returns
    -------
    (K * H, D) float64, prototype k at heading h in row ``k * H + h``.
    """
    return place_on_centroid(body, evidence.model, prototypes, headings, evidence.centroid())
