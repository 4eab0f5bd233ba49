"""2-D body keypoints in each camera, and their triangulation: a cue silhouettes lack.

A silhouette says where the person is, not which limb is which: on the Pose2Sim take the
silhouette track put both legs on the raised leg and missed the standing one (137-165 mm
median joint error against hand labels), while MediaPipe's pose landmark model, run in each
view and triangulated, came within 41 mm (docs/notebook.md, 2026-11-29). This module runs
that model and triangulates its points; ``gltrack ingest`` stores them in the dataset
(``keypoints.npz``) and the multi-view tracker adds their distance to its cost.

The model
---------
BlazePose GHUM 3D's landmark network, ``pose_landmark_full.tflite`` (MediaPipe, Apache 2.0),
as the ``mediapipe`` pip wheel ships it; ``scripts/setup.sh`` copies it out of the wheel
(nothing is downloaded at run time). OpenCV's DNN module runs it, so mediapipe itself (and its
numpy < 2 pin) is not needed. Input: a 256 x 256 RGB crop in [0, 1] with the person upright in
its centre; outputs: 39 points (33 landmarks and 6 auxiliary) as x, y (crop pixels), z,
visibility and presence logits, and a person-presence score in [0, 1].

Crops follow MediaPipe's own tracking: the first crop of a camera is the foreground mask's
largest blob when masks are given (a square 1.25 times its longer side; ``gltrack ingest``
finds the keypoints before the masks and starts from the whole image), re-cropped twice on the
model's own alignment points (33: the hips' centre, 34: the top of the body's circle; side 2.5
times their distance, rotated so that 33 -> 34 points up); every later frame starts from the
last frame's alignment and is re-cropped once. A crop whose presence score falls below
:data:`MIN_PRESENCE` has lost the person: the frame starts again from the mask, then from
the whole image, each start with one more crop aligned on its own points; frames still
missed are searched again backwards from the next frame that found the person.

The same network segments the person in its crop (:meth:`Detection.person_probability`);
``gltrack ingest`` hands the segmentation of the views whose landmarks triangulate with the
others (:func:`confirmed_views`) to the foreground masks as their ``"prior"`` cue.

Triangulation
-------------
The model confuses left and right in a view now and then (27 of 100 frames of the Pose2Sim
take needed one view's sides exchanged): :func:`triangulate_keypoints` tries every view with
its sides kept or exchanged and keeps the combination with the lowest median reprojection
residual; then, for each point whose largest residual exceeds :data:`MAX_RESIDUAL` of the
image's long side (with three or more views), leaves out the one view whose absence leaves the
smallest largest residual.
"""
from __future__ import annotations

import itertools
import logging
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from gltrack.camera import triangulate

log = logging.getLogger(__name__)

#: file name of the landmark model (``scripts/setup.sh`` puts it in the environment)
MODEL_NAME = "pose_landmark_full.tflite"
#: environment variable naming the model file; otherwise ``<sys.prefix>/share/gltrack/models``
MODEL_ENV = "GLTRACK_POSE_MODEL"
#: the model's input side, pixels
INPUT = 256
#: MediaPipe's landmark indices of the joints gltrack tracks (of 33)
LANDMARKS = {"nose": 0, "l_shoulder": 11, "r_shoulder": 12, "l_elbow": 13, "r_elbow": 14,
             "l_wrist": 15, "r_wrist": 16, "l_hip": 23, "r_hip": 24, "l_knee": 25,
             "r_knee": 26, "l_ankle": 27, "r_ankle": 28, "l_heel": 29, "r_heel": 30,
             "l_toe": 31, "r_toe": 32}
#: the joints of a gltrack body that a landmark marks (its joint centre, within a few cm)
BODY_JOINTS = ("l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle", "l_shoulder",
               "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist")
#: points of the body that are no joint, each marked by one landmark or the midpoint of two
#: (all triangulated; :func:`site_points`): the ears' midpoint is the head's centre, then the
#: back of each heel and each foot's toe tip. They orient what the joints alone leave free:
#: the head on the neck, the feet on the ankles. Not the hands (the index and little finger
#: knuckles, 17-20): on the seated caliscope take, hands before the face and on the keyboard,
#: fitting them put the labelled arms 15-20 mm further off on both seeds measured
#: (docs/measurements.md, "The head and the feet from the landmarks").
SITE_LANDMARKS = {"head": (7, 8), "l_heel": (29,), "r_heel": (30,), "l_toe": (31,),
                  "r_toe": (32,)}
#: metres: a joint's distance to its keypoint counts up to this much
#: (:func:`keypoint_distance`): a triangulated keypoint is 4-6 cm off on a good frame (the
#: Pose2Sim take against hand labels), a wrong one (a limb confused with the other) is off
#: by a limb's separation, 0.2 m and more; capped, one wrong keypoint costs a pose no more
#: than a fifth of a metre however far it went
DISTANCE_CAP = 0.2
#: the 33 landmarks' names, "" for those gltrack does not name (eyes, ears, mouth, hands)
NAMES = tuple(next((k for k, v in LANDMARKS.items() if v == i), "") for i in range(33))
#: the 33 landmarks' left/right exchange (a permutation of 0..32)
MIRROR = np.array([0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15, 18, 17, 20, 19,
                   22, 21, 24, 23, 26, 25, 28, 27, 30, 29, 32, 31])
#: below this person-presence score a crop has lost the person (MediaPipe's default, 0.5)
MIN_PRESENCE = 0.5
#: a view's landmarks confirm its person (:func:`confirmed_views`) when at least this many of
#: them went into the triangulation: a median of fewer says little (a quarter of the 33; the
#: seated caliscope take, legs hidden, has 7-25 a view, 22 median)
MIN_CONFIRMED = 8
#: frames without the person that :func:`detect_sequence` keeps to search backwards once it
#: finds the person again (their images are held meanwhile: 100 dataset frames of 640 x 360
#: are 70 MB)
MAX_BACKTRACK = 100
#: pixels: a crop smaller than this holds no person the model could find (a quarter of its
#: input)
MIN_CROP = INPUT / 4
#: a crop's side over the size that the alignment points give (MediaPipe: 1.25)
CROP_MARGIN = 1.25
#: a view's residual above this fraction of its image's long side marks that view's point as
#: an outlier: 30 px of a 1920-pixel frame, where the take's good detections reproject within
#: 13 px (median); a wrong-limb detection is off by a limb's image length, 100 px or more
MAX_RESIDUAL = 30 / 1920


def find_model(path=None) -> Path | None:
    """The landmark model file: ``path``, else ``$GLTRACK_POSE_MODEL``, else the
    environment's ``share/gltrack/models``; None when there is none (keypoints are then off).

    Raises
    ------
    FileNotFoundError
        ``path`` or ``$GLTRACK_POSE_MODEL`` is given and names no file.
    """
    given = path or os.environ.get(MODEL_ENV)
    if given:
        p = Path(given)
        if not p.is_file():
            where = "" if path else f" (${MODEL_ENV})"
            raise FileNotFoundError(f"{p}: no pose landmark model file here{where}")
        return p
    p = Path(sys.prefix) / "share" / "gltrack" / "models" / MODEL_NAME
    return p if p.is_file() else None


@dataclass
class Detection:
    """One view's landmarks.

    Attributes
    ----------
    uv : (33, 2) float64, image pixels (NaN when nothing was found)
    visibility : (33,) float64 in [0, 1], the model's belief that each point is in view
    presence : float in [0, 1], the model's belief that the crop holds a person
    segmentation : (256, 256) float32 logits of the crop's person segmentation, or None
    crop : (2, 3) float64, the affine map from image pixels to crop pixels, or None
    """
    uv: np.ndarray
    visibility: np.ndarray
    presence: float
    segmentation: np.ndarray | None = None
    crop: np.ndarray | None = None

    @classmethod
    def empty(cls) -> "Detection":
        return cls(np.full((33, 2), np.nan), np.zeros(33), 0.0)

    def person_probability(self, shape, size=None) -> np.ndarray:
        """The model's person segmentation mapped back to the image, in [0, 1].

        The landmark network also segments its crop (what MediaPipe's ``enable_segmentation``
        returns); pixels outside the crop, and every pixel when nothing was found, are 0.

        Parameters
        ----------
        shape : (H, W), pixels, the image the detection ran on
        size : (w, h), pixels, optional: the output's size (a scaling of the image)

        Returns
        -------
        (H, W) or (h, w) float32
        """
        H, W = int(shape[0]), int(shape[1])
        w, h = (W, H) if size is None else (int(size[0]), int(size[1]))
        if self.segmentation is None or self.crop is None:
            return np.zeros((h, w), np.float32)
        # output pixel q is image pixel p = (q + 0.5) / s - 0.5 per axis (pixel centres)
        s = np.array([w / W, h / H])
        A = self.crop[:, :2] / s
        b = self.crop[:, :2] @ (0.5 / s - 0.5) + self.crop[:, 2]
        p = _sigmoid(self.segmentation).astype(np.float32)
        return cv2.warpAffine(p, np.hstack([A, b[:, None]]), (w, h),
                              flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.clip(x, -50, 50)))


class PoseLandmarker:
    """MediaPipe's pose landmark network run by OpenCV's DNN module.

    Parameters
    ----------
    model : path, the ``.tflite`` file (:func:`find_model`)
    """

    def __init__(self, model):
        self.model = Path(model)
        try:
            self.net = cv2.dnn.readNetFromTFLite(str(self.model), engine=cv2.dnn.ENGINE_CLASSIC)
        except cv2.error as e:
            raise ValueError(f"{self.model}: OpenCV cannot read this pose landmark model "
                             f"({str(e).strip().splitlines()[-1]})") from None

    def run(self, image, centre, side, angle=0.0) -> tuple[Detection, np.ndarray]:
        """The landmarks in one square crop of ``image``.

        Parameters
        ----------
        image : (H, W, 3) uint8 BGR
        centre : (2,) pixels, the crop's centre
        side : float, pixels, the crop's side
        angle : float, radians, the crop's rotation (the person's up direction turned to the
            crop's up)

        Returns
        -------
        Detection, and the (39, 2) image pixels of all 39 points (the 6 auxiliary ones align
        the next crop)
        """
        s = INPUT / float(side)
        c, n = np.cos(angle), np.sin(angle)
        A = s * np.array([[c, n], [-n, c]])
        M = np.hstack([A, (np.array([INPUT / 2, INPUT / 2]) - A @ np.asarray(centre, float))[:, None]])
        crop = cv2.warpAffine(image, M, (INPUT, INPUT), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        blob = cv2.cvtColor(crop, cv2.COLOR_BGR2RGB).astype(np.float32).transpose(2, 0, 1)[None]
        self.net.setInput(blob / np.float32(255.0))
        # the segmentation comes with the same forward pass (kept as logits; mapped back to the
        # image only when asked, by Detection.person_probability)
        points, flag, seg = self.net.forward(["Identity", "Identity_1", "Identity_2"])
        points = points.reshape(-1, 5)[:39].astype(np.float64)
        inv = cv2.invertAffineTransform(M)
        xy = points[:, :2] @ inv[:, :2].T + inv[:, 2]
        det = Detection(xy[:33].copy(), _sigmoid(points[:33, 3]), float(np.ravel(flag)[0]),
                        seg.reshape(INPUT, INPUT).astype(np.float32), M)
        return det, xy

    @staticmethod
    def aligned(xy) -> tuple[np.ndarray, float, float]:
        """MediaPipe's next crop from 39 points: centre (2,), side and angle (radians)."""
        hips, top = xy[33], xy[34]
        v = top - hips
        angle = np.pi / 2 - np.arctan2(-v[1], v[0])
        return hips, 2.0 * CROP_MARGIN * float(np.hypot(*v)), float(angle)

    def detect(self, image, box=None, previous=None, passes: int = 2):
        """Landmarks of the person in ``image``.

        The first crop is the last frame's alignment (``previous``); when it has lost the
        person (or there is none), the ``box``, then the whole image. A start that misses the
        person gets one more try, aligned on its own points; each found crop is re-cropped
        ``passes`` times on the model's own alignment.

        Parameters
        ----------
        image : (H, W, 3) uint8 BGR
        box : (x0, y0, x1, y1) pixels, the person's box, optional
        previous : (39, 2) pixels of the last frame's points, optional
        passes : int, re-crops on the model's own alignment after the first crop

        Returns
        -------
        Detection, and the (39, 2) points that align the next frame's crop (None when the
        person was not found)
        """
        starts = []
        if previous is not None:
            starts.append(self.aligned(previous))
        if box is not None:
            x0, y0, x1, y1 = (float(v) for v in box)
            starts.append((np.array([x0 + x1, y0 + y1]) / 2,
                           CROP_MARGIN * max(x1 - x0, y1 - y0, 1.0), 0.0))
        # last, the whole image: a mask's blob may be a moving hand, or nothing at all (the
        # sequence's masks of a person who stands still), while the person fills the frame
        h, w = image.shape[:2]
        starts.append((np.array([w / 2, h / 2]), float(max(w, h)), 0.0))
        for centre, side, angle in starts:
            det, xy = self.run(image, centre, side, angle)
            if det.presence < MIN_PRESENCE:
                # an upright box round a person who leans 20-40 degrees scores near the
                # threshold (0.42 or 0.59 for boxes one pixel apart); its points still align
                # a rotated crop, which holds the person when there is one
                centre, side, angle = self.aligned(xy)
                if not (np.isfinite(side) and side >= MIN_CROP and np.isfinite(centre).all()):
                    continue
                det, xy = self.run(image, centre, side, angle)
                if det.presence < MIN_PRESENCE:
                    continue
            for _ in range(passes):
                # a re-crop aligned on a poor first guess (a box that cut off the head or
                # feet) can lose the person: the last crop that held the person stands then
                again, xy_again = self.run(image, *self.aligned(xy))
                if again.presence < MIN_PRESENCE:
                    break
                det, xy = again, xy_again
            return det, xy
        return Detection.empty(), None


def person_box(mask) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) of the largest connected blob of a foreground mask (None if empty)."""
    m = np.asarray(mask).astype(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h = stats[k, :4]
    return int(x), int(y), int(x + w), int(y + h)


def segmentation_size(width: int, height: int, long_side: int | None) -> tuple[int, int]:
    """(w, h) of an image scaled down to ``long_side`` pixels (never up; None: unchanged)."""
    s = 1.0 if long_side is None else min(1.0, long_side / max(width, height))
    return max(int(round(width * s)), 1), max(int(round(height * s)), 1)


def detect_sequence(landmarker: PoseLandmarker, images, masks=None, progress=None,
                    segment: int | None = None):
    """Landmarks of one camera's frames, each crop started from the last frame's points.

    Frames where the person was not found are searched again backwards, from the crop of the
    next frame that found them (at most :data:`MAX_BACKTRACK` frames back).

    Parameters
    ----------
    landmarker : PoseLandmarker
    images : iterable of (H, W, 3) uint8 BGR
    masks : iterable of (H', W') bool, optional: the foreground, for the first crop and after
        the person was lost (any size; scaled to the image); None: the whole image
    progress : callable, optional, called once per frame
    segment : int, optional: also return the model's person segmentation of every frame,
        scaled down to this long side in pixels (:func:`segmentation_size`)

    Returns
    -------
    uv : (F, 33, 2) float64 pixels (NaN where the person was not found)
    visibility : (F, 33) float64
    presence : (F,) float64
    segmentation : (F, h, w) uint8, the person's probability times 255 (0 where the person
        was not found); only with ``segment``
    """
    uv, vis, pres, seg = [], [], [], []

    def keep(i, img, det):
        row = (det.uv, det.visibility, det.presence)
        if segment is not None:
            H, W = img.shape[:2]
            prob = det.person_probability((H, W), segmentation_size(W, H, segment))
            row += (np.round(prob * 255).astype(np.uint8),)
        for store, value in zip((uv, vis, pres, seg), row):
            if i == len(store):
                store.append(value)
            else:
                store[i] = value

    previous = None
    # the frames of the current run without the person (image kept): when the person is found
    # again, the run is searched backwards from there (a person too small in the whole image
    # to be found at the start of the take is found from the next frames' crops)
    lost = []
    masks = iter(masks) if masks is not None else None
    for i, img in enumerate(images):
        box = None
        mask = next(masks) if masks is not None else None
        if mask is not None:
            box = person_box(mask)
            if box is not None and mask.shape[:2] != img.shape[:2]:
                sx, sy = img.shape[1] / mask.shape[1], img.shape[0] / mask.shape[0]
                box = (box[0] * sx, box[1] * sy, box[2] * sx, box[3] * sy)
        det, previous = landmarker.detect(img, box=box, previous=previous,
                                          passes=2 if previous is None else 1)
        keep(i, img, det)
        if previous is None:
            lost = (lost + [(i, img)])[-MAX_BACKTRACK:]
        elif lost:
            back = previous
            for j, old in reversed(lost):
                again, back = landmarker.detect(old, previous=back, passes=1)
                if back is None:
                    break
                keep(j, old, again)
            lost = []
        if progress is not None:
            progress()
    out = (np.array(uv).reshape(-1, 33, 2), np.array(vis).reshape(-1, 33), np.array(pres))
    return out + (np.array(seg),) if segment is not None else out


def triangulate_keypoints(cameras, uv, visibility=None, *, min_visibility: float = 0.5):
    """3-D landmarks of one frame from the views' 2-D landmarks, robust to exchanged sides.

    Parameters
    ----------
    cameras : sequence (C) of Camera, the views' calibration (distorted image pixels)
    uv : (C, 33, 2) pixels, NaN where a view found nothing
    visibility : (C, 33), optional: observations below ``min_visibility`` are left out
    min_visibility : float

    Returns
    -------
    points : (33, 3) float64, the cameras' world frame (NaN: seen by fewer than two views)
    residual : (C, 33) float64 pixels, each used observation's reprojection distance (NaN
        where left out)
    swapped : (C,) bool, the views whose left and right were exchanged
    """
    uv = np.array(uv, dtype=np.float64)
    if uv.shape != (len(cameras), 33, 2):
        raise ValueError(f"uv must be ({len(cameras)}, 33, 2), got {uv.shape}")
    if visibility is not None:
        uv[np.asarray(visibility) < min_visibility] = np.nan
    found = np.isfinite(uv).any(axis=(1, 2))
    best = None
    for combo in itertools.product((False, True), repeat=int(found.sum())):
        swapped = np.zeros(len(cameras), bool)
        swapped[found] = combo
        trial = np.where(swapped[:, None, None], uv[:, MIRROR], uv)
        pts, res = triangulate(cameras, trial)
        score = np.nanmedian(res) if np.isfinite(res).any() else np.inf
        # ties (a symmetric pose) keep the fewest exchanges
        key = (score, int(swapped.sum()))
        if best is None or key < best[0]:
            best = (key, trial, pts, res, swapped)
    _, trial, pts, res, swapped = best
    long_side = np.array([max(c.width, c.height) for c in cameras], float)
    for j in range(33):
        r = res[:, j] / long_side
        if np.sum(np.isfinite(r)) <= 2 or np.nanmax(r) <= MAX_RESIDUAL:
            continue
        # leave each view out in turn and keep the one whose absence fits best: the linear
        # solution spreads one wrong view's error over the others, so the largest residual
        # need not be the wrong view's
        trials = []
        for drop in np.flatnonzero(np.isfinite(r)):
            t = trial[:, j:j + 1].copy()
            t[drop] = np.nan
            p, rr = triangulate(cameras, t)
            trials.append((np.nanmax(rr[:, 0] / long_side), drop, p[0], rr[:, 0]))
        worst, drop, p, rr = min(trials, key=lambda t: t[0])
        if worst < np.nanmax(r):
            trial[drop, j] = np.nan
            pts[j], res[:, j] = p, rr
    return pts, res, swapped


def confirmed_views(cameras, residual, min_points: int = MIN_CONFIRMED) -> np.ndarray:
    """Which views' landmarks are a person the other views see too.

    The landmark model also reports a person where there is none now and then (a coloured
    ball on a plain background, in ``gltrack ingest``'s tests): its points then do not
    triangulate with the other views'. A view is confirmed in a frame when at least
    ``min_points`` of its landmarks were used and their median reprojection residual is
    within :data:`MAX_RESIDUAL` of its image's long side.

    Parameters
    ----------
    cameras : sequence (C) of Camera
    residual : (N, C, 33) pixels, NaN where left out (:func:`triangulate_keypoints`)
    min_points : int

    Returns
    -------
    (N, C) bool
    """
    residual = np.asarray(residual, dtype=np.float64)
    long_side = np.array([max(c.width, c.height) for c in cameras], float)
    used = np.isfinite(residual).sum(axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: not confirmed
        median = np.nanmedian(residual, axis=2)
    return (used >= min_points) & (median <= MAX_RESIDUAL * long_side)


def detect_keypoints(cameras, images, masks=None, model=None, progress=None,
                     segment: int | None = None) -> dict:
    """Landmarks of every camera's frames and their triangulation, frame by frame.

    Parameters
    ----------
    cameras : sequence (C) of Camera
    images : sequence (C) of iterables of (H, W, 3) uint8 BGR frames, one per camera
    masks : sequence (C) of iterables of foreground masks, optional (:func:`detect_sequence`)
    model : path, optional (:func:`find_model`)
    progress : callable, optional, called once per camera frame
    segment : int, optional, as for :func:`detect_sequence`

    Returns
    -------
    dict with the arrays :meth:`gltrack.data.dataset.Dataset.keypoints` describes (``uv``,
    ``visibility``, ``points``, ``residual``, ``names``) and ``presence`` (N, C), ``swapped``
    (N, C) bool, ``confirmed`` (N, C) bool (:func:`confirmed_views`); with ``segment`` also
    ``segmentation``, a list (C) of (N, h, w) uint8, zero in the views not confirmed

    Raises
    ------
    FileNotFoundError
        No model file (see :func:`find_model`).
    """
    path = find_model(model)
    if path is None:
        raise FileNotFoundError(f"no pose landmark model: set ${MODEL_ENV} or run "
                                "scripts/setup.sh, which copies it from the mediapipe wheel")
    landmarker = PoseLandmarker(path)
    per_cam = [detect_sequence(landmarker, imgs, None if masks is None else masks[c], progress,
                               segment) for c, imgs in enumerate(images)]
    uv = np.stack([p[0] for p in per_cam], axis=1)  # (N, C, 33, 2)
    vis = np.stack([p[1] for p in per_cam], axis=1)
    pres = np.stack([p[2] for p in per_cam], axis=1)
    points = np.full((len(uv), 33, 3), np.nan)
    residual = np.full(vis.shape, np.nan)
    swapped = np.zeros(pres.shape, bool)
    for n in range(len(uv)):
        points[n], residual[n], swapped[n] = triangulate_keypoints(cameras, uv[n], vis[n])
    confirmed = confirmed_views(cameras, residual)
    out = {"uv": uv, "visibility": vis, "points": points, "residual": residual,
           "names": list(NAMES), "presence": pres, "swapped": swapped, "confirmed": confirmed}
    if segment is not None:
        seg = [p[3] for p in per_cam]
        for c in range(len(seg)):
            seg[c][~confirmed[:, c]] = 0
        out["segmentation"] = seg
    return out


def site_points(points, name: str) -> np.ndarray:
    """The triangulated position of a body site of :data:`SITE_LANDMARKS`.

    Parameters
    ----------
    points : (..., 33, 3) float, metres, triangulated landmarks (NaN: not triangulated)
    name : str, a key of :data:`SITE_LANDMARKS`

    Returns
    -------
    (..., 3) float64 metres, the mean of the site's landmarks; NaN where any is
    """
    points = np.asarray(points, dtype=np.float64)
    return points[..., list(SITE_LANDMARKS[name]), :].mean(axis=-2)


def keypoint_distance(joints, targets, cap: float = DISTANCE_CAP) -> np.ndarray:
    """Mean capped distance of each pose's joints to their triangulated keypoints.

    Parameters
    ----------
    joints : (N, K, 3) float, metres, the K matched joints of N poses
    targets : (K, 3) float, metres, the keypoints (NaN rows are left out)
    cap : float, metres, the most one joint's distance counts

    Returns
    -------
    (N,) float64 metres; NaN when no target is finite
    """
    joints = np.asarray(joints, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    ok = np.isfinite(targets).all(axis=1)
    if not ok.any():
        return np.full(len(joints), np.nan)
    d = np.linalg.norm(joints[:, ok] - targets[ok], axis=-1)
    return np.minimum(d, cap).mean(axis=1)
