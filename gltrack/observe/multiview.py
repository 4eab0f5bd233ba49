"""The colour cameras as the multi-view trackers see them (Bandouch & Beetz 2009).

* :class:`MultiviewObservation` reads a frame's colour images and foreground masks, undistorted
  (masks from the dataset, or background subtraction on its empty-scene frames);
* :class:`SilhouetteLikelihood` uploads them to the scoring engine, with the blocking layer of
  :class:`~gltrack.observe.environment.EnvironmentLayers` and the HLS colour bits of an
  :class:`~gltrack.observe.appearance.AppearanceModel` when asked, and scores N poses: the
  silhouette XOR count ``e_S`` and the colour-consistent pixel count ``c_A``, summed over cameras.

How the two channels become particle weights is the tracker's choice (Bandouch's eq. 2, or
:func:`gltrack.sample.weights.cost_weights`).
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from gltrack.render.engine import ScoringEngine, silhouette_overlap

from . import hls
from .appearance import AppearanceModel
from .background import BackgroundModel
from .environment import EnvironmentLayers
from .model_masks import refine_view

log = logging.getLogger(__name__)

FOREGROUNDS = ("auto", "dataset", "background")
#: pixels the costs ignore: Bandouch's environment layers, the occluder polygons only, or none
BLOCKING = ("layers", "polygons", "none")
#: GrabCut's pixels at most when :attr:`MultiviewObservation.model` refines a mask: the bound
#: ``gltrack ingest``'s GrabCut works within (its ``grabcut_max_pixels``), which keeps a frame
#: of four cameras at 640 px to a fraction of a second instead of 1-2 s a camera
REFINE_PIXELS = 30000


def undistort_mask(cam, mask) -> np.ndarray:
    """(H, W) bool ``mask`` of camera ``cam`` undistorted with nearest neighbour."""
    m = np.asarray(mask).astype(np.uint8)
    return (cam.undistort_image(m, cv2.INTER_NEAREST) if np.any(cam.dist) else m) != 0


class MultiviewObservation:
    """Per-frame colour images and foreground masks of a dataset's colour cameras, undistorted.

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset
    foreground : "auto" (the dataset's masks when every camera has them, else background
        subtraction), "dataset" or "background"
    rng : numpy.random.Generator, optional, picks background training frames

    Attributes
    ----------
    index : list of int, dataset camera index of each colour camera
    cameras : list of Camera, as calibrated; pinholes : their undistorted twins
    polygons : list of (H, W) bool, occluder polygons (undistorted), all False without any
    mode : "dataset" or "background", where the masks come from
    model : None, or ((V, 3) posed vertices in metres, (F, 3) faces) of the tracked body near
        the frames about to be read: each mask is then refined with it
        (:func:`~gltrack.observe.model_masks.refine_view`: GrabCut seeded by its silhouette,
        the mask kept within reach of it) before it is undistorted. The tracker sets it (its
        ``mask_refine`` option) to the last frame's estimate, so segmentation follows tracking
        frame by frame.
    sequence : None, or list (C) of (H, W) bool: the masks of the last frame read with a
        ``model``, as they were before it refined them (distorted, like the images)
    """

    def __init__(self, dataset, foreground: str = "auto", rng=None):
        if foreground not in FOREGROUNDS:
            raise ValueError(f"foreground must be one of {', '.join(FOREGROUNDS)}, got "
                             f"{foreground!r}")
        self.dataset = dataset
        self.index = [i for i, c in enumerate(dataset.cameras) if c.kind == "colour"]
        if not self.index:
            raise ValueError(f"{dataset.path}: the multi-view trackers need colour cameras")
        self.cameras = [dataset.cameras[i] for i in self.index]
        self.pinholes = [c.undistorted() for c in self.cameras]
        self.polygons = [undistort_mask(c, dataset.blocking_mask(i))
                         for c, i in zip(self.cameras, self.index)]
        has_masks = [dataset.mask(0, i) is not None for i in self.index] if dataset.frames else []
        mode = foreground
        if mode == "auto":
            mode = "dataset" if has_masks and all(has_masks) else "background"
        if mode == "dataset" and not all(has_masks):
            missing = [c.name for c, h in zip(self.cameras, has_masks) if not h]
            raise ValueError(f"{dataset.path}: no foreground masks for cameras {missing} "
                             "(use foreground = \"background\")")
        self.mode = mode
        self.rng = rng
        self.model = None
        self.sequence = None
        self._bg = {}

    def _background_model(self, k):
        if k not in self._bg:
            frames = self.dataset.backgrounds(self.index[k])
            if not frames:
                raise ValueError(f"{self.dataset.path}: camera {self.cameras[k].name} has neither "
                                 "foreground masks nor empty-scene frames for background subtraction")
            self._bg[k] = BackgroundModel().fit(frames, rng=self.rng)
        return self._bg[k]

    def __call__(self, frame: int) -> tuple[list, list]:
        """Undistorted colour images (C of (H, W, 3) uint8 BGR) and foreground masks ((H, W) bool)."""
        images, masks = [], []
        self.sequence = [] if self.model is not None else None
        for k, (cam, i) in enumerate(zip(self.cameras, self.index)):
            bgr = self.dataset.colour(frame, i)
            fg = self.dataset.mask(frame, i) if self.mode == "dataset" else \
                self._background_model(k).foreground(bgr)
            if self.model is not None:
                self.sequence.append(np.asarray(fg, bool))
                fg = refine_view(cam, bgr, fg, *self.model, max_pixels=REFINE_PIXELS)
            images.append(cam.undistort_image(bgr, cv2.INTER_LINEAR) if np.any(cam.dist) else bgr)
            masks.append(undistort_mask(cam, fg))
        return images, masks


class SilhouetteLikelihood:
    """Silhouette XOR and colour-consistency counts of N poses in every colour camera.

    Parameters
    ----------
    ctx : moderngl.Context
    body : gltrack.body.model.BodyModel
    observation : MultiviewObservation
    tile : int, engine tile side in pixels (power of two)
    blocking : "layers" (occluder polygons and Bandouch's non-human foreground removal),
        "polygons" (the occluder polygons only) or "none"
    appearance : bool, score the colour channel once :meth:`init_appearance` has run
    coarse : BodyModel, optional, the same body with a coarser mesh
        (:meth:`~gltrack.body.model.BodyModel.with_lod`): a second engine scores it
        (:meth:`scores` with ``coarse=True``), with this frame's masks and the colour clusters
        of its nearest triangles of ``body``

    Attributes
    ----------
    engine : ScoringEngine
    coarse_engine : ScoringEngine or None
    appearance : AppearanceModel or None
    area : float, unblocked foreground pixels of the current frame at tile resolution, summed
        over the cameras (at least 1): the scale of ``e_S``
    areas : (C,) float, the same per camera (may be 0)
    raw_area : float, the frame's foreground pixels at tile resolution before the environment
        layers removed anything (occluder polygons only), summed over the cameras
    """

    def __init__(self, ctx, body, observation: MultiviewObservation, *, tile: int = 64,
                 blocking: str = "layers", appearance: bool = True, coarse=None):
        if blocking not in BLOCKING:
            raise ValueError(f"blocking must be one of {', '.join(BLOCKING)}, got {blocking!r}")
        self.body, self.obs = body, observation
        self.engine = ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, observation.pinholes,
                                    tile=tile)
        self.engine.set_kinematics(body.kin)
        self.coarse_engine = self._coarse_faces = None
        if coarse is not None:
            self.coarse_engine = ScoringEngine(ctx, coarse.mesh, coarse.skeleton.n_joints,
                                               observation.pinholes, tile=tile,
                                               programs=self.engine.programs)
            self.coarse_engine.set_kinematics(coarse.kin)
            self._coarse_faces = body.mesh.nearest_faces(coarse.mesh)
        self.blocking = blocking
        self.env = (EnvironmentLayers(ctx, observation.pinholes, programs=self.engine.programs)
                    if blocking == "layers" else None)
        self.use_appearance = bool(appearance)
        self.appearance = None
        self.area = 1.0
        self.areas = np.zeros(len(observation.pinholes))
        self.raw_area = 0.0
        self.frame = None
        self._fgs = self._blocks = None
        self._iou_eng, self._iou_frame, self._iou_areas = None, None, None

    @property
    def channels(self) -> list[str]:
        """Engine channels scored: the colour channel once the appearance model exists."""
        return ["silhouette", "appearance"] if self.appearance is not None else ["silhouette"]

    def init_appearance(self, params, images, masks, full: bool = True, rng=None) -> None:
        """Build the colour model from the body posed at ``params`` (D,) over ``images`` and
        ``masks`` (the observation of one frame): at full camera resolution (``full``) or at
        the engine's tile resolution."""
        if not self.use_appearance:
            return
        self.appearance = AppearanceModel.from_first_frame(
            self.body.mesh, self.body.skinning(np.asarray(params)[None])[0], self.obs.pinholes,
            images, masks, engine=None if full else self.engine, rng=rng)

    def refine_appearance(self, params, images, masks) -> None:
        """Add the colours seen at ``params`` (D,) in ``images`` / ``masks``."""
        if self.appearance is not None:
            self.appearance.refine(self.body.skinning(np.asarray(params)[None])[0],
                                   self.obs.pinholes, images, masks, engine=self.engine)

    def _human_lut(self):
        if self.appearance is not None:
            return self.appearance.human_lut()
        return np.ones(hls.N_VOXELS, bool)

    def observe(self, frame: int):
        """Read frame ``frame`` and upload its masks (and colour bits) to the engine.

        Returns
        -------
        images : list of (H, W, 3) uint8; fg : list of (H, W) bool, the foreground as scored;
        block : list of (H, W) bool, pixels the costs ignore
        """
        images, masks = self.obs(frame)
        fgs, blocks, raws = [], [], []
        lut = self._human_lut() if self.env is not None else None
        for c, (img, fg) in enumerate(zip(images, masks)):
            raws.append(fg & ~self.obs.polygons[c])
            if self.env is not None:
                fg, block = self.env.apply(c, fg, img, self.obs.polygons[c], lut)
            elif self.blocking == "polygons":
                block = self.obs.polygons[c]
            else:
                block = np.zeros_like(fg)
            self.engine.set_masks(c, fg, block)
            if self.coarse_engine is not None:
                self.coarse_engine.set_masks(c, fg, block)
            if self.appearance is not None:
                bits, tri = hls.observed_bits(img), self.appearance.tri_bits()
                self.engine.set_appearance(c, bits, tri)
                if self.coarse_engine is not None:
                    self.coarse_engine.set_appearance(c, bits, tri[self._coarse_faces])
            fgs.append(fg)
            blocks.append(block)
        T = self.engine.tile

        def count(m):
            return np.count_nonzero(cv2.resize(m.astype(np.uint8), (T, T),
                                               interpolation=cv2.INTER_NEAREST_EXACT))
        self.areas = np.array([count(f & ~b) for f, b in zip(fgs, blocks)], dtype=np.float64)
        self.area = max(1.0, float(self.areas.sum()))
        self.raw_area = float(sum(count(r) for r in raws))
        self.frame = frame
        self._fgs, self._blocks = fgs, blocks
        self._iou_frame = None  # a re-read frame (same number, other masks) is uploaded again
        return images, fgs, blocks

    def scores(self, X: np.ndarray, coarse: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """Silhouette error e_S (N,) and appearance count c_A (N,) or None, summed over cameras;
        of the coarse mesh with ``coarse`` (when there is one)."""
        eng = self.coarse_engine if coarse and self.coarse_engine is not None else self.engine
        r = eng.score_poses(np.atleast_2d(X), self.channels)
        e_s = r[:, :, 1].sum(axis=1)
        c_a = r[:, :, 2].sum(axis=1) if self.appearance is not None else None
        return e_s, c_a

    def silhouette_iou(self, x: np.ndarray, tile: int | None = None) -> np.ndarray:
        """Per-camera silhouette IoU of one pose against the current frame's foreground:
        the first row of :meth:`silhouette_overlap` (same parameters)."""
        return self.silhouette_overlap(x, tile)[0]

    def silhouette_overlap(self, x: np.ndarray, tile: int | None = None) -> np.ndarray:
        """Per-camera silhouette IoU of one pose against the current frame's foreground, and
        the shares of model and foreground that overlap.

        ``|M & F| / |M | F|``, ``|M & F| / |M|`` and ``|M & F| / |F|`` over the unblocked
        pixels (those ``e_S`` counts), from the engine's ``model`` channel M, the XOR count X
        and the foreground area F of each camera
        (:func:`gltrack.render.engine.silhouette_overlap`): one engine call.

        Parameters
        ----------
        x : (D,) pose parameters
        tile : int (power of two), optional
            Resolution the IoU is counted at (each camera resampled to ``tile`` x ``tile``).
            None or the tracking tile: the tracking engine and the masks already uploaded;
            another: a second engine of that tile (made on first use, sharing the programs)
            gets this frame's masks. A finer tile than the tracking one measures the fit, not
            the tile: at 64 px a limb is 2-3 pixels wide and one pixel of rounding costs a third.

        Returns
        -------
        (3, C) float in 0..1: IoU, model on foreground, foreground covered, per camera; NaN
        where a denominator is empty (no model or no foreground in that camera)
        """
        eng, areas = self.engine, self.areas
        if tile is not None and int(tile) != self.engine.tile:
            eng = self._iou_engine(int(tile))
            if self._iou_frame != self.frame:
                T = eng.tile
                areas = []
                for c, (f, b) in enumerate(zip(self._fgs, self._blocks)):
                    eng.set_masks(c, f, b)
                    areas.append(np.count_nonzero(eng.to_tile((f & ~b).astype(np.uint8))))
                self._iou_areas, self._iou_frame = np.asarray(areas, np.float64), self.frame
                log.debug("IoU masks of frame %s uploaded at %d px", self.frame, T)
            areas = self._iou_areas
        r = eng.score(self.body.skinning(np.asarray(x, dtype=np.float64)[None]),
                      ["silhouette", "model"])[0]
        return np.stack(silhouette_overlap(r[:, 0], areas, r[:, 1]))

    def _iou_engine(self, tile):
        if self._iou_eng is None or self._iou_eng.tile != tile:
            if self._iou_eng is not None:
                self._iou_eng.release()
            self._iou_eng = ScoringEngine(self.engine.ctx, self.body.mesh,
                                          self.body.skeleton.n_joints, self.obs.pinholes,
                                          tile=tile, programs=self.engine.programs)
            self._iou_frame = None
        return self._iou_eng

    @property
    def kept_fraction(self) -> float:
        """Share of the frame's foreground (occluder polygons aside) that the environment
        layers left to be scored (1.0 with nothing observed or nothing removed)."""
        return min(1.0, self.area / self.raw_area) if self.raw_area > 0 else 1.0

    def release(self) -> None:
        if self._iou_eng is not None:
            self._iou_eng.release()
            self._iou_eng = None
        if self.env is not None:
            self.env.release()
            self.env = None
        if self.coarse_engine is not None:
            self.coarse_engine.release()
            self.coarse_engine = None
        self.engine.release()
