"""Foreground masks of a synchronised multi-camera sequence that has no empty-scene frames.

Real recordings rarely start with the scene empty, and a subject who barely moves stays in any
per-pixel temporal median of the sequence. :func:`estimate_foreground` (and the
:class:`SequenceForeground` behind it) combines cues that can each be switched off and measured
on their own (``cues=``):

1. **Temporal background** (always on): per camera, the per-channel median of the frames with
   the pixels where a *person mask* says the subject is left out (a masked median). Pixels
   excluded in almost every frame have no observed background ("unknown", ``known`` False,
   filled by inpainting so the later steps have a value). Every frame is blurred a little and
   its exposure matched to the background (a robust affine fit per YUV channel). The candidate
   foreground of a frame is its normalised YUV distance to that background above ``threshold``
   noise standard deviations (a global sensor noise, raised per pixel by a robust temporal
   spread), cleaned by :func:`~.background.clean_mask`.
2. **shadows**: a candidate pixel that is dimmer than the background with the same chromaticity
   (:func:`~.background.shadow_test`) is "shadow". The hull is carved from all candidates, but a
   voxel must also be foreground in at least 2 views' shadow-free candidates: a cast shadow is
   shadow in every view and goes, while dark or grey clothes that pass the shadow test in some
   views (a lighter background of the same hue behind them) stay; without the hull cue shadow
   pixels are simply dropped. After the colour refinement the test vetoes pixels outside the
   hull's reprojection.
3. **hull** (multi-view consistency): the candidate masks of a frame are carved into a visual
   hull (:func:`~.voxels.carve`) over the volume the cameras share (:func:`shared_volume`),
   allowing ``hull_tolerance`` cameras to miss a voxel; only the hull's largest 26-connected
   component is kept, and each camera keeps only the candidate pixels near that component's
   reprojection. A blob that one camera (or two, with 4 cameras) sees alone - a person walking
   behind, a desk, a chart - has no hull and goes.
4. **grabcut** (colour refinement seeded by a silhouette): OpenCV's GrabCut, per camera and frame,
   on a crop around the seed: the hull-consistent candidate (eroded) is sure foreground, the rest
   of it "probably foreground"; the hull's
   reprojection, the 2-D convex hull of the seed and a band of ``body_margin`` metres (projected
   at the subject's depth) around them "probably background"; everything farther sure
   background. Its colour models fill holes where clothes match the
   background and grow the mask over still parts the temporal background missed.

5. **ghosts** (the subject's ghost in the temporal background): where the subject stood in
   most frames, the median is the subject, so the true background there is a candidate in
   the frames it moved away in (a door behind someone who stood in front of it most of the
   time), in every view (the hull keeps it), and GrabCut, seeded with it, learns the
   background's colours as the subject's and grows over it. A candidate pixel whose colour
   the pixel shows in at least ``ghost_recurrence`` of the background frames (away from the
   frame itself) is the scene: it is dropped before the hull. A moving part covers a pixel in a
   few frames only. Measured on the Pose2Sim take (body estimate from ``ingest``'s masks): a
   2.28 m body without this cue, 1.96 m with it.

6. **support** (the subject's support, with the floor given as ``floor=``): a leg that stands
   still for the whole take is in the temporal background, so the cues above miss it, and
   GrabCut's colour model of the whole crop holds the room too (on the Pose2Sim take,
   skin-coloured walls: the bare standing leg stays background). In static balance the centre
   of mass is above the support, so :func:`support_column` gives a column from the floor to
   the hull's centroid; per camera a column pixel is the subject's when its colour is
   ``support_odds`` times likelier under the subject's colours (the hull-consistent candidates
   of every frame) than under those of a ring of scene around the column
   (:meth:`SequenceForeground.support_colours`); a pixel is kept where the visual hull of the
   frame's masks inside the column's box (:meth:`SequenceForeground.consistent`) reprojects.
   A support pixel in the column's lower half also keeps its 2-D component when that does not
   touch the hull's reprojection: a bare standing shank is cut off from the body by still
   clothes (the Pose2Sim take's dark shorts against the dark force plate) that neither the
   temporal background nor the colour test takes; in the upper half, bits of the scene that
   the column's carve let through (the legs of the person behind) go.

7. **prior** (a person segmentation, given as ``person_prior=``; ``gltrack ingest`` passes the
   segmentation that the pose landmark model computes with its landmarks,
   :mod:`gltrack.observe.keypoints`): its pixels are left out of the background like person
   masks, and the final masks are the prior's multi-view consistent pixels
   (:meth:`SequenceForeground.consistent_prior`) plus the other cues' pixels next to them
   (:meth:`SequenceForeground.with_prior`). Where the prior is
   missing (the person not found) the other cues stand alone. Measured on the Pose2Sim take
   (docs/measurements.md): the GrabCut spill onto the skin-coloured cupboards goes and the
   still torso's holes fill. The segmentation is coarse (256-pixel logits) and fills the
   body's concavities too; with ``scene_trim`` (off by default) a region of the prior's masks
   that shows the scene as observed (stage ``"scene"``), where the subject looked different
   from it when there (``scene_contrast``), and reaches the mask's outside goes; an enclosed
   one stays.

``passes`` (default 2) repeats the chain (GrabCut in the last pass only) with the previous pass's
masks (dilated) added to the person masks, so the background estimate no longer averages the subject in; a tracker can
pass the projected silhouettes of its model as ``person_masks`` for the same effect.

Every image is processed at a reduced working resolution (long side ``work_size`` pixels) with the
cameras scaled to it (:meth:`~gltrack.camera.Camera.scaled`); masks come back at that resolution
(:meth:`ForegroundResult.mask_at` resizes them). Distortion is kept: masks belong to the raw
(distorted) images.

Limits (measured, see the foreground section of docs/ARCHITECTURE.md):

* a part of the subject that never moves *and* is not bounded by the hull (the torso of someone
  seated when only the hands move) is recovered only as far as GrabCut's colour models reach in
  the seed's convex hull and ``body_margin`` band; a tracker's silhouettes (``person_masks``)
  are the cure;
* the "ghost" of the subject in the temporal background (where the body was in most frames) is
  a multi-view consistent shape, so the hull keeps it too; the ghost test drops it only where
  the background shows in a quarter of the frames or more (a spot the subject covers in more
  than three quarters of the take keeps its ghost), and a part that rests on the same pixels
  for a quarter of the take is dropped with it (then it is as good as still);
* GrabCut grows the mask by colour alone: a background of the subject's colours next to the
  body (skin-coloured doors and cupboards on the Pose2Sim take) is taken in, in every view
  (a visual hull of GrabCut's masks did not remove it: measured, no change). The still torso it
  recovers is why it stays;
* the chromaticity shadow test cannot tell grey or dark neutral clothes on a lighter neutral
  floor from a shadow; the hull keeps such parts only where at least 2 views do not call them
  shadow;
* a moving object that all cameras see (a box carried past, a held board) is a legitimate hull
  component; the largest component within ``body_reach`` is kept, whatever it is.
"""
from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from gltrack.render.workers import core_budget

from .background import bgr_to_yuv, check_bgr, clean_mask, shadow_test
from .voxels import carve, centre_pixels, pixel_boxes

log = logging.getLogger(__name__)

CUES = ("hull", "grabcut", "shadows", "ghosts", "support", "prior")
#: first quartile of |x| for x ~ N(0, 1)
_Q25 = 0.31864


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------
def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 1)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


#: from this radius (pixels) on, :func:`dilate_mask` and :func:`erode_mask` threshold the
#: exact Euclidean distance transform instead of running the morphology: its cost does not
#: grow with the radius (0.4 s against 1 ms for a 300-pixel disk on a 640x360 mask, the reach
#: of :mod:`.model_masks` at 1 m; the morphology takes 44 ms at 96 px), and the two differ only
#: on the disk's rounded rim (under 1 % of the grown mask's pixels, measured at radii 30-300).
#: The foreground estimate's own radii stay below it (its GrabCut band is 0.15 m: 50-70 px
#: for a person 0.7-1 m from the caliscope take's nearest camera at the 480-pixel working
#: size), so its masks are as before.
DISTANCE_RADIUS = 96


def _within(mask, radius: int) -> np.ndarray:
    """Pixels within ``radius`` (Euclidean) of a pixel of ``mask``."""
    m = np.asarray(mask, bool)
    if not m.any():
        return np.zeros(m.shape, bool)
    d = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return d <= radius


def dilate_mask(mask, radius: int) -> np.ndarray:
    """(H, W) bool ``mask`` grown by a disk of ``radius`` pixels (unchanged for radius <= 0);
    shared with :mod:`.model_masks` and :mod:`gltrack.data.refine_masks`."""
    if radius <= 0:
        return np.asarray(mask, bool)
    if radius >= DISTANCE_RADIUS:
        return _within(mask, radius)
    return cv2.dilate(np.asarray(mask, np.uint8), _disk(radius)).astype(bool)


def erode_mask(mask, radius: int) -> np.ndarray:
    """(H, W) bool ``mask`` shrunk by a disk of ``radius`` pixels (unchanged for radius <= 0)."""
    if radius <= 0:
        return np.asarray(mask, bool)
    if radius >= DISTANCE_RADIUS:
        m = np.asarray(mask, bool)
        # eroding keeps what is farther than radius from the outside; the image border counts
        # as inside, as cv2.erode's default border does
        return m & ~_within(~m, radius)
    return cv2.erode(np.asarray(mask, np.uint8), _disk(radius)).astype(bool)


def _convex_fill(mask) -> np.ndarray:
    """(H, W) bool, the filled convex hull of a mask's pixels (all False for an empty mask)."""
    m = np.asarray(mask, bool)
    out = np.zeros(m.shape, np.uint8)
    ys, xs = np.nonzero(m)
    if len(xs):
        pts = cv2.convexHull(np.stack([xs, ys], 1).astype(np.int32))
        cv2.fillConvexPoly(out, pts, 1)
    return out.astype(bool) | m


def outside_reaching(region, mask) -> np.ndarray:
    """(h, w) bool: the 8-connected components of ``region`` (within ``mask``) that touch a
    pixel outside ``mask`` (the image's outside or a hole of it)."""
    region = np.asarray(region, bool)
    if not region.any():
        return region.copy()
    eight = np.ones((3, 3), bool)
    labels, _ = ndimage.label(region, eight)
    touching = ndimage.binary_dilation(~np.asarray(mask, bool), eight) & region
    keep = np.unique(labels[touching])
    return np.isin(labels, keep[keep > 0])


def fill_boxes(shape, lo_px, hi_px) -> np.ndarray:
    """(H, W) bool, the union of pixel boxes ``[lo, hi)`` (columns, rows), clipped to the image.

    Parameters
    ----------
    shape : (H, W), pixels
    lo_px, hi_px : (M, 2) int, first and one-past-last column / row of each box
    """
    H, W = shape
    c0 = np.clip(lo_px[:, 0], 0, W)
    c1 = np.clip(hi_px[:, 0], 0, W)
    r0 = np.clip(lo_px[:, 1], 0, H)
    r1 = np.clip(hi_px[:, 1], 0, H)
    ok = (c1 > c0) & (r1 > r0)
    c0, c1, r0, r1 = c0[ok], c1[ok], r0[ok], r1[ok]
    d = np.zeros((H + 1, W + 1), np.int32)
    np.add.at(d, (r0, c0), 1)
    np.add.at(d, (r0, c1), -1)
    np.add.at(d, (r1, c0), -1)
    np.add.at(d, (r1, c1), 1)
    return np.cumsum(np.cumsum(d, axis=0), axis=1)[:H, :W] > 0


def shared_volume(cameras, min_views: int | None = None, *, samples: int = 40) -> np.ndarray:
    """Axis-aligned box around the space at least ``min_views`` cameras see.

    The cameras' optical axes are intersected in the least-squares sense; a cube around that
    point, as large as the farthest camera is from it, is sampled on a ``samples^3`` grid and
    the box of the points in front of and inside the image of ``min_views`` cameras is returned.
    Scale-free: it follows the rig, whatever its units or size.

    Parameters
    ----------
    cameras : list of gltrack.camera.Camera, at least 2
    min_views : int, optional, default all cameras
    samples : int, grid points along each side of the sampled cube

    Returns
    -------
    (6,) float64, ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the cameras' world units
    """
    if len(cameras) < 2:
        raise ValueError(f"shared_volume needs at least 2 cameras, got {len(cameras)}")
    n = len(cameras) if min_views is None else int(min_views)
    if not 1 <= n <= len(cameras):
        raise ValueError(f"min_views must be in 1..{len(cameras)}, got {min_views}")
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        d = c.R[2]  # optical axis in the world
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    p0 = np.linalg.lstsq(A, b, rcond=None)[0]
    radius = max(float(np.linalg.norm(c.center - p0)) for c in cameras)
    g = np.linspace(-radius, radius, int(samples))
    pts = p0 + np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    seen = np.zeros(len(pts), np.int32)
    for c in cameras:
        z = c.depth_of(pts)
        front = z > 1e-6 * radius
        uv = np.full((len(pts), 2), -1.0)
        uv[front] = c.project(pts[front], distort=False)
        seen += front & (uv[:, 0] >= -0.5) & (uv[:, 0] <= c.width - 0.5) & \
            (uv[:, 1] >= -0.5) & (uv[:, 1] <= c.height - 0.5)
    keep = pts[seen >= n]
    if len(keep) == 0:
        raise ValueError(f"no point of space is seen by {n} of the {len(cameras)} cameras")
    step = g[1] - g[0]
    return np.concatenate([keep.min(axis=0) - step, keep.max(axis=0) + step])


def colour_density(colours, bins: int) -> np.ndarray:
    """Smoothed colour histogram: (bins, bins, bins) float that sums to 1.

    ``colours`` (N, 3) uint8 are quantised to ``bins`` levels per channel, the counts blurred by
    a Gaussian of one bin (a kernel density estimate: a few thousand samples leave most of the
    bins of a raw histogram empty, and an empty bin would make any colour "unlike" the scene)
    plus 1e-3 of a count per bin, so no colour has zero density.
    """
    B = int(bins)
    q = (np.asarray(colours, np.int32).reshape(-1, 3) * B) >> 8
    hist = np.zeros((B, B, B))
    np.add.at(hist, (q[:, 0], q[:, 1], q[:, 2]), 1.0)
    hist = ndimage.gaussian_filter(hist, 1.0, mode="constant") + 1e-3
    return hist / hist.sum()


def check_floor(floor):
    """``(normal, height)`` validated: a finite (3,) float unit normal and a float."""
    try:
        n, h = floor
        n = np.asarray(n, float).reshape(3)
        h = float(h)
    except (TypeError, ValueError) as e:
        raise ValueError(f"floor must be (normal (3,), height), got {floor!r}") from e
    norm = float(np.linalg.norm(n))
    if not (np.isfinite(n).all() and np.isfinite(h) and norm > 0):
        raise ValueError(f"floor must have a finite, non-zero normal and a finite height, "
                         f"got {floor!r}")
    return n / norm, h


def level_floor(height):
    """The ``floor`` argument (``(normal, height)``) for a horizontal floor of gltrack's
    internal +Y-up frame at ``height`` metres, or None when ``height`` is None (unknown)."""
    return None if height is None else ((0.0, 1.0, 0.0), float(height))


def support_column(lo, size, floor, *, reach: float, step: float):
    """Where a subject's support is: a vertical column from the floor up to the hull's centroid.

    A standing person's support reaches down to the floor, and in static balance the centre of
    mass is above it: the legs lie in a column under the hull's centroid. A leg that stood
    still for the whole take stays in the temporal background and is missing from the hull
    (the Pose2Sim take: the standing leg, in every view); the column says where to look for it.
    Whether the hull reaches the floor says nothing (the other foot may touch it), so the
    column is given for every frame.

    Parameters
    ----------
    lo : (M, 3) float, world corner of each hull voxel (the cameras' world units)
    size : (M,) float, edge of each voxel
    floor : tuple (normal, height): ``normal`` (3,) float, the world's unit up direction;
        floor points ``x`` satisfy ``normal @ x == height``
    reach : float, half the column's width (horizontal distance from the centroid's foot)
    step : float, the largest edge of the boxes the column is made of

    Returns
    -------
    (lo, size) : (N, 3) float and (N,) float, the column as axis-aligned boxes from the floor
        to the centroid's height; None when the hull is empty or its centroid is not above
        the floor
    """
    lo = np.asarray(lo, float).reshape(-1, 3)
    size = np.asarray(size, float).reshape(-1)
    if len(lo) == 0:
        return None
    n = np.asarray(floor[0], float)
    n = n / np.linalg.norm(n)
    centres = lo + 0.5 * size[:, None]
    w = size ** 3
    centroid = centres.T @ w / w.sum()
    top = float(centroid @ n - float(floor[1]))
    if top <= 0:
        return None
    foot = centroid - top * n
    # two horizontal directions
    u = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    k = max(int(np.ceil(reach / step)), 1)
    off = (np.arange(-k, k) + 0.5) * (reach / k)
    m = max(int(np.ceil(top / step)), 1)
    up = (np.arange(m) + 0.5) * (top / m)
    A, B, Z = np.meshgrid(off, off, up, indexing="ij")
    pts = foot + A.reshape(-1, 1) * u + B.reshape(-1, 1) * v + Z.reshape(-1, 1) * n
    # cubes as wide as the larger spacing cover the column
    edge = float(max(reach / k, top / m))
    return pts - 0.5 * edge, np.full(len(pts), edge)


def _robust_affine(x, y, keep=None, rounds: int = 3):
    """``(a, b)`` with ``y ~ a x + b`` fitted by least squares, refitted on the inliers
    (residual within 3 robust standard deviations) ``rounds`` times; ``(1, 0)`` if degenerate."""
    x = np.asarray(x, np.float64).ravel()
    y = np.asarray(y, np.float64).ravel()
    sel = np.ones(x.size, bool) if keep is None else np.asarray(keep).ravel().copy()
    a, b = 1.0, 0.0
    for _ in range(rounds):
        if sel.sum() < 10 or np.ptp(x[sel]) < 1e-6:
            return 1.0, 0.0
        a, b = np.polyfit(x[sel], y[sel], 1)
        r = np.abs(y - (a * x + b))
        sel &= r <= 3.0 * max(1.4826 * np.median(r[sel]), 1.0)
    if not 0.5 < a < 2.0:  # not an exposure change: leave the frame alone
        return 1.0, 0.0
    return float(a), float(b)


def masked_median(stack, exclude=None, min_count: int = 1):
    """Per-pixel median over frames, leaving out excluded samples.

    Parameters
    ----------
    stack : (T, H, W, K) uint8, T frames of K channels
    exclude : (T, H, W) bool, optional, samples to leave out (True = subject there)
    min_count : int, fewest samples a pixel needs to count as observed

    Returns
    -------
    median : (H, W, K) uint8, the lower median of the kept samples (of all samples where fewer
        than ``min_count`` are kept)
    spread : (H, W, K) float32, grey levels, a robust standard deviation: the first quartile of
        the kept samples' absolute deviations from the median over its Gaussian value 0.3186
        sigma. The quartile, not the median deviation: a subject who covers a pixel in a third of
        the frames inflates the MAD several-fold, the quartile stays at the noise (up to 75 %
        contamination on one side)
    known : (H, W) bool, at least ``min_count`` samples kept
    """
    s = np.asarray(stack)
    T = s.shape[0]
    if exclude is None:
        exclude = np.zeros(s.shape[:3], bool)
    count = T - exclude.sum(axis=0)
    known = count >= max(int(min_count), 1)
    ex = exclude & known[None]  # where too few samples are kept, use them all
    n = np.where(known, count, T)
    big = np.int16(1000)
    v = np.where(ex[..., None], big, s.astype(np.int16))
    v.sort(axis=0)
    k = ((n - 1) // 2)[None, :, :, None]
    med = np.take_along_axis(v, np.broadcast_to(k, (1,) + v.shape[1:]), axis=0)[0]
    dev = np.where(ex[..., None], big, np.abs(s.astype(np.int16) - med[None]))
    dev.sort(axis=0)
    k25 = ((n - 1) // 4)[None, :, :, None]
    q25 = np.take_along_axis(dev, np.broadcast_to(k25, (1,) + v.shape[1:]), axis=0)[0]
    return med.astype(np.uint8), (q25 / _Q25).astype(np.float32), known


# --------------------------------------------------------------------------------------------
# parameters and results
# --------------------------------------------------------------------------------------------
@dataclass
class ForegroundParams:
    """Settings of :func:`estimate_foreground`; every default is chosen to hold for any rig.

    Attributes
    ----------
    work_size : int, pixels
        Long side of the working images (480: a person a few metres away is still ~200 px tall;
        the trackers score downscaled images anyway; 4 x 100 frames take well under a minute).
    max_background_frames : int
        Frames used for the temporal background (evenly spaced, or drawn by ``rng``); 50 samples
        give a stable median and MAD while keeping the sort small.
    threshold : float, noise standard deviations
        A pixel is a candidate when its YUV distance to the background, normalised per channel,
        exceeds this (4: P(chi^2_3 > 16) ~ 0.1 % for Gaussian noise).
    min_sigma : float, grey levels
        Floor of the global sensor noise (8-bit quantisation and video compression).
    blur : float, pixels at ``work_size``
        Gaussian sigma applied to every frame before the background statistics and the
        difference test: averages independent pixel noise over ~3 x 3 pixels (a third of its
        standard deviation) while no limb at ``work_size`` is thinner than a few pixels.
    min_observed : float
        Fraction of the background frames in which a pixel must be free of the subject for its
        background to count as observed (10 %: a median over fewer samples is mostly noise).
    morph_size : int, pixels at ``work_size``; opening / closing kernel of the candidates.
    min_area : float
        Smallest kept 2-D component as a fraction of the image area (1e-4: ~20 px at 480x270).
    hull_levels : int
        The visual hull's finest voxel is the shared volume's longest side / (16 * 2**levels)
        (2: 64 voxels across, finer than a limb is thick in any room-sized volume).
    hull_tolerance : int, optional
        Cameras that may miss a hull voxel (occlusion, a colour match); default 1 with 4 or more
        cameras, 0 with fewer (a voxel must always be seen by at least 2 cameras... or 3 of 4).
    hull_margin : int, pixels
        Candidate pixels within this distance of the hull's reprojection are kept (the
        reprojection of voxel boxes is only as fine as the voxels).
    body_margin : float, metres (the cameras' world units)
        Width of GrabCut's "probably background" band around the seed, projected at the
        subject's depth: about a limb's thickness, the largest part of a body a seed from
        masks that agree in 3 views can miss.
    body_reach : float, metres
        Hull components within this distance of the largest are parts of the same body: a
        torso that did not move leaves a gap of at most its length, ~0.6-0.7 m from the hips
        (legs) to the neck (head, arms), between the moving parts; farther ones (another
        person, furniture) are dropped.
    grabcut_iterations : int
        GrabCut iterations (2: its colour models settle after one or two).
    grabcut_max_pixels : int
        A larger GrabCut crop is downscaled to this many pixels (its cost is linear in pixels;
        30000 is ~120 x 250, a standing person at ``work_size`` 480 with its band).
    shadow_low, shadow_high, shadow_chroma :
        The shadow test (:func:`~.background.shadow_test`): luminance ratio range, chroma
        tolerance in grey levels.
    exclude_margin : int, pixels
        Person masks (given, or the previous pass's) are dilated by this much before they are
        left out of the background (mask edges are never exact).
    passes : int
        Runs of the whole chain; each pass after the first leaves the previous pass's masks out
        of the background estimate.
    ghost_recurrence : float
        The ghost test (cue ``"ghosts"``): a candidate pixel whose colour the pixel also shows
        in at least this fraction of the background frames is the scene, not the subject. A
        ghost pixel shows the true background, seen whenever the subject is elsewhere; a
        moving part passes a pixel in a few frames. 0.25: a part would have to rest on the same
        pixel for a quarter of the take (then it is as good as still, which GrabCut and the
        tracker's silhouettes handle) to be dropped.
    ghost_gap : float
        Background frames within this fraction of the take of the tested frame do not count
        for the ghost test (a part moving slowly looks the same in the next few frames).
    prior_margin : int, pixels
        The other cues' pixels within this distance of the person prior's stay (cue
        ``"prior"``, :meth:`SequenceForeground.with_prior`): about one pixel of the landmark
        model's 256-pixel segmentation, whose crop is 1.25 times a standing person's height
        (at ``work_size`` 480, 1.5-2 pixels); the prior's edge is uncertain by that much.
    scene_trim : bool
        Drop the pixels of the prior's masks that show the scene as observed (the frame
        within ``threshold`` of a background seen in at least ``min_observed`` of the frames)
        where they reach the mask's outside (:meth:`SequenceForeground.with_prior`), at
        pixels that looked different in at least ``scene_contrast`` of the frames the prior
        claimed them: the segmentation's 256-pixel logits fill a body's concavities. Off by
        default (``gltrack ingest --scene-trim``). Measured (docs/measurements.md): on the
        Pose2Sim take 3.5-4.9 % of the masks go and the track's IoU moves by -0.006 to +0.017
        per camera (the seated caliscope take: 0.003-0.018 under the default); without the
        contrast test the trim raised the Pose2Sim IoU in two cameras but took a quarter of
        the caliscope frontal camera's masks (the still lower torso, which the segmentation
        misses in some frames: the background there is the person's ghost). Asking instead
        for the background to be seen in half the frames kept the torso but also the
        concavities.
    scene_contrast : float
        The share of the prior's frames that must have differed from the background for
        ``scene_trim`` to trust it (:meth:`SequenceForeground.contrasted`); a quarter, as
        ``ghost_recurrence``: a part would have to rest on the pixel for three quarters of the
        frames it is there to look like its own background.
    support_reach : float, metres
        Half the width of the support column (cue ``"support"``, :func:`support_column`) under
        the hull's centroid: in static balance the centre of mass is above the support, and a
        wide stance puts the feet up to ~0.3 m from it.
    support_bins : int
        Colour levels per YUV channel of the support cue's colour densities (16: 4096 bins,
        finer than skin, clothes and floor differ, coarse enough for a few thousand samples).
    support_odds : float
        A column pixel is the subject's when its colour is this many times likelier under the
        subject's colours than under the scene's around the column: the prior odds of the
        scene, as two legs (~0.25 m) fill about a third of the 0.8 m column.
    support_limb : float, metres
        The support cue's result is opened with a disk of this diameter (projected at the
        subject's depth): narrower than an ankle (6-7 cm), wider than a rail or a seam in the
        floor.
    """

    work_size: int = 480
    max_background_frames: int = 50
    threshold: float = 4.0
    min_sigma: float = 2.0
    blur: float = 1.0
    min_observed: float = 0.1
    morph_size: int = 3
    min_area: float = 1e-4
    hull_levels: int = 2
    hull_tolerance: int | None = None
    hull_margin: int = 3
    body_margin: float = 0.15
    body_reach: float = 0.8
    grabcut_iterations: int = 2
    grabcut_max_pixels: int = 30000
    shadow_low: float = 0.4
    shadow_high: float = 0.95
    shadow_chroma: float = 8.0
    exclude_margin: int = 5
    support_reach: float = 0.4
    support_bins: int = 16
    support_odds: float = 2.0
    support_limb: float = 0.05
    passes: int = 2
    ghost_recurrence: float = 0.25
    ghost_gap: float = 0.05
    prior_margin: int = 2
    scene_trim: bool = False
    scene_contrast: float = 0.25

    def __post_init__(self):
        if int(self.work_size) < 32:
            raise ValueError(f"ForegroundParams.work_size must be >= 32, got {self.work_size}")
        if not self.threshold > 0:
            raise ValueError(f"ForegroundParams.threshold must be positive, got {self.threshold}")
        if not 0 < self.ghost_recurrence <= 1:
            raise ValueError(f"ForegroundParams.ghost_recurrence must be in (0, 1], got "
                             f"{self.ghost_recurrence}")
        if not 0 <= self.ghost_gap < 1:
            raise ValueError(f"ForegroundParams.ghost_gap must be in [0, 1), got {self.ghost_gap}")
        if not 0 <= self.min_observed < 1:
            raise ValueError(f"ForegroundParams.min_observed must be in [0, 1), got "
                             f"{self.min_observed}")
        if not 0 <= self.scene_contrast <= 1:
            raise ValueError(f"ForegroundParams.scene_contrast must be in [0, 1], got "
                             f"{self.scene_contrast}")
        if not self.body_margin >= 0:
            raise ValueError(f"ForegroundParams.body_margin must be >= 0, got {self.body_margin}")
        if int(self.prior_margin) < 0:
            raise ValueError(f"ForegroundParams.prior_margin must be >= 0, got "
                             f"{self.prior_margin}")
        if int(self.passes) < 1:
            raise ValueError(f"ForegroundParams.passes must be >= 1, got {self.passes}")
        if int(self.max_background_frames) < 1:
            raise ValueError("ForegroundParams.max_background_frames must be >= 1, got "
                             f"{self.max_background_frames}")


@dataclass
class ForegroundResult:
    """What :func:`estimate_foreground` found; C cameras, T frames, images ``h x w`` (working).

    Attributes
    ----------
    masks : list (C) of (T, h, w) bool, the final foreground
    cameras : list (C) of Camera, scaled to the working images
    backgrounds : list (C) of (h, w, 3) uint8 BGR, the temporal background of the last pass
    known : list (C) of (h, w) bool, background observed (not inpainted)
    stages : dict, name -> list (C) of (T, h, w) bool masks of the last pass after each cue:
        ``"candidate"`` (temporal background, with shadows removed when that cue is on),
        with ``scene_trim`` ``"scene"`` (where the frame shows the background as observed:
        known there and no candidate, shadows and ghosts included), ``"hull"`` (multi-view consistent
        candidate), ``"grabcut"`` (refined, before the final shadow veto),
        ``"hull_silhouette"`` (reprojection of the hull's main component), and with the
        support cue ``"support_column"`` (the column's reprojection) and ``"support"`` (the
        pixels it added or confirmed)
    full_size : list (C) of (W, H), pixels, size of the input images
    """

    masks: list
    cameras: list
    backgrounds: list
    known: list
    stages: dict = field(default_factory=dict)
    full_size: list = field(default_factory=list)

    def mask_at(self, camera: int, frame: int, size=None) -> np.ndarray:
        """(H, W) bool mask of one camera and frame at ``size`` (W, H) (default: the input's)."""
        m = self.masks[camera][frame]
        W, H = self.full_size[camera] if size is None else size
        if (H, W) == m.shape:
            return m.copy()
        return cv2.resize(m.astype(np.uint8), (int(W), int(H)),
                          interpolation=cv2.INTER_NEAREST).astype(bool)

    def foreground_fraction(self) -> np.ndarray:
        """(C,) float, mean fraction of each camera's image that is foreground."""
        return np.array([float(np.mean(m)) for m in self.masks])


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------
class SequenceForeground:
    """Foreground estimation over one synchronised sequence (state kept between passes).

    Parameters
    ----------
    frames_by_camera : sequence (C) of iterables of (H_c, W_c, 3) uint8 BGR images, T frames
        each (generators are fine: every frame is downscaled as it arrives)
    cameras : sequence (C) of gltrack.camera.Camera; each image must be the camera's size or a
        uniform scaling of it (within 1 %)
    params : ForegroundParams, optional
    rng : numpy.random.Generator, optional; picks the background frames when there are more
        than ``params.max_background_frames`` and seeds GrabCut (default: evenly spaced frames,
        seed 0)
    floor : (normal (3,), height), optional; the floor plane ``normal @ x == height`` in the
        cameras' world, ``normal`` pointing up (cue ``"support"``; without it that cue is off)
    threads : int, optional; the cameras' steps (background, candidates, ghost test, GrabCut,
        support colours) run side by side on this many threads (default
        :func:`gltrack.render.workers.core_budget`, at most one per camera); the masks do not
        depend on it. On the Pose2Sim take (2 cores) the masks take 99 s instead of 139.
    """

    def __init__(self, frames_by_camera, cameras, params: ForegroundParams | None = None,
                 rng=None, floor=None, threads: int | None = None):
        self.params = params or ForegroundParams()
        # the per-camera work is OpenCV and NumPy calls that release the GIL; the cores are
        # those the process may use, within the share ``gltrack batch`` gives each job
        self.threads = core_budget() if threads is None else int(threads)
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.floor = None if floor is None else check_floor(floor)
        cameras = list(cameras)
        feeds = list(frames_by_camera)
        if len(feeds) != len(cameras):
            raise ValueError(f"frames_by_camera has {len(feeds)} cameras, cameras has "
                             f"{len(cameras)}")
        if len(cameras) < 2:
            raise ValueError("foreground estimation needs at least 2 cameras")
        self.images, self.cameras, self.full_size = [], [], []
        for cam, feed in zip(cameras, feeds):
            imgs, cw = self._downscale(cam, feed)
            self.images.append(imgs)
            self.cameras.append(cw)
        counts = {len(i) for i in self.images}
        if len(counts) != 1 or 0 in counts:
            raise ValueError(f"frames_by_camera: every camera needs the same, non-zero number of "
                             f"frames, got {[len(i) for i in self.images]}")
        self.T = counts.pop()
        self.rng = rng
        p = self.params
        C = len(self.cameras)
        self.tolerance = (1 if C >= 4 else 0) if p.hull_tolerance is None else int(p.hull_tolerance)
        if not 0 <= self.tolerance <= C - 2:
            raise ValueError(f"ForegroundParams.hull_tolerance must be in 0..{C - 2} with {C} "
                             f"cameras, got {p.hull_tolerance}")
        self.bounds = shared_volume(self.cameras, C - self.tolerance)
        n = min(self.T, int(p.max_background_frames))
        if rng is None:
            self.bg_frames = np.unique(np.linspace(0, self.T - 1, n).round().astype(int))
        else:
            self.bg_frames = np.sort(rng.choice(self.T, n, replace=False))
        self._seed = int(rng.integers(2 ** 31)) if rng is not None else 0
        self._raw, self._corrected = {}, {}
        log.debug("foreground: %d cameras x %d frames, work size %s, bounds %s", C, self.T,
                  [(c.width, c.height) for c in self.cameras], np.round(self.bounds, 3))

    def _downscale(self, cam, feed):
        imgs, cw = [], None
        for t, img in enumerate(feed):
            img = check_bgr(img, f"frames_by_camera[{cam.name}][{t}]")
            H, W = img.shape[:2]
            if cw is None:
                sx, sy = W / cam.width, H / cam.height
                if abs(sx - sy) > 0.01 * max(sx, sy):
                    raise ValueError(f"frames_by_camera[{cam.name}]: image {W}x{H} is not a "
                                     f"uniform scaling of the camera's {cam.width}x{cam.height}")
                s = min(1.0, self.params.work_size / max(W, H))
                w, h = max(int(round(W * s)), 1), max(int(round(H * s)), 1)
                cw = cam.scaled(w, h)
                self.full_size.append((W, H))
            elif (W, H) != self.full_size[-1]:
                raise ValueError(f"frames_by_camera[{cam.name}][{t}]: image {W}x{H}, frame 0 "
                                 f"was {self.full_size[-1][0]}x{self.full_size[-1][1]}")
            if (cw.width, cw.height) != (W, H):
                img = cv2.resize(img, (cw.width, cw.height), interpolation=cv2.INTER_AREA)
            imgs.append(img)
        if cw is None:
            raise ValueError(f"frames_by_camera[{cam.name}]: no frames")
        return np.stack(imgs), cw

    def per_camera(self, fn) -> list:
        """``[fn(c) for c in cameras]``, the cameras spread over ``threads`` threads.

        A camera's steps touch only that camera's images, caches and output arrays, so they
        may run side by side. GrabCut draws its initial colour clusters from OpenCV's random
        generator, which is per thread: a camera's work seeds it first (``cv2.setRNGSeed``), so
        its masks do not depend on which thread ran it or in which order.
        """
        n = min(len(self.cameras), self.threads)
        if n <= 1:
            return [fn(c) for c in range(len(self.cameras))]
        with ThreadPoolExecutor(n, thread_name_prefix="foreground") as pool:
            return list(pool.map(fn, range(len(self.cameras))))

    # ------------------------------------------------------------------------ person masks
    def _working_stack(self, c, given, name, probability=False):
        """(T, h, w) bool: camera c's given images at the working size, or None.

        ``given[c]`` holds T masks (nonzero: the person) or, with ``probability``, T person
        probabilities (uint8: times 255; floats as they are) that are true from one half on.
        """
        if given is None or given[c] is None:
            return None
        stack = given[c]
        if len(stack) != self.T:
            raise ValueError(f"{name}[{c}] has {len(stack)} frames, the sequence {self.T}")
        cam = self.cameras[c]
        out = np.zeros((self.T, cam.height, cam.width), bool)
        for t, m in enumerate(stack):
            m = np.asarray(m)
            if m.ndim != 2:
                raise ValueError(f"{name}[{c}][{t}] must be (H, W), got {m.shape}")
            if probability:
                m = m.astype(np.float32) / (255.0 if m.dtype == np.uint8 else 1.0)
                if m.shape != (cam.height, cam.width):
                    m = cv2.resize(m, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
                out[t] = m >= 0.5
            else:
                if m.shape != (cam.height, cam.width):
                    m = cv2.resize(m.astype(np.uint8), (cam.width, cam.height),
                                   interpolation=cv2.INTER_NEAREST)
                out[t] = m.astype(bool)
        return out

    # ------------------------------------------------------------------------ cue 1: background
    def background(self, c, exclude=None):
        """Temporal background of camera c, with every frame's exposure matched to it.

        Parameters
        ----------
        c : int, camera index
        exclude : (T, h, w) bool, optional, where the subject is (left out of the statistics)

        Returns
        -------
        bg : (h, w, 3) uint8 BGR (inpainted where not known)
        spread : (h, w, 3) float32, grey levels, per-pixel robust temporal standard deviation
            (YUV)
        known : (h, w) bool, background observed in enough frames

        Every frame's YUV channels are mapped by a robust affine fit onto a first median
        (auto-exposure and white-balance drift scale and shift the whole frame); the corrected
        frames (kept for :meth:`candidates`) give the final median.
        """
        p = self.params
        idx = self.bg_frames
        raw = self._yuv(c)
        ex = None if exclude is None else exclude[idx]
        min_count = max(1, int(np.ceil(p.min_observed * len(idx))))
        ref, _, _ = masked_median(raw[idx], ex, min_count)
        corr = np.empty_like(raw)
        sub = (slice(None, None, 4), slice(None, None, 4))
        for t in range(self.T):
            keep = None if exclude is None else ~exclude[t][sub]
            out = raw[t].astype(np.float32)
            for k in range(3):
                a, b = _robust_affine(ref[sub + (k,)], raw[t][sub + (k,)], keep)
                out[..., k] = (out[..., k] - b) / a
            corr[t] = np.clip(np.round(out), 0, 255).astype(np.uint8)
        self._corrected[c] = corr
        med, spread, known = masked_median(corr[idx], ex, min_count)
        bg = cv2.cvtColor(med, cv2.COLOR_YUV2BGR)
        if not known.all():
            bg = cv2.inpaint(bg, (~known).astype(np.uint8), 5, cv2.INPAINT_TELEA)
        return bg, spread, known

    def _yuv(self, c):
        """(T, h, w, 3) uint8, camera c's frames blurred by ``params.blur`` in YUV (cached)."""
        if c not in self._raw:
            s = float(self.params.blur)
            self._raw[c] = np.stack([cv2.cvtColor(cv2.GaussianBlur(img, (0, 0), s) if s > 0
                                                  else img, cv2.COLOR_BGR2YUV)
                                     for img in self.images[c]])
        return self._raw[c]

    def frame_yuv(self, c, t):
        """(h, w, 3) float32 YUV of frame t, camera c: blurred, exposure matched to the last
        :meth:`background` of that camera."""
        src = self._corrected.get(c)
        return (self._yuv(c) if src is None else src)[t].astype(np.float32)

    def noise_var(self, c, bgy, spread, known):
        """(h, w, 3) float, (grey levels)^2: the YUV noise variance of camera c's background."""
        p = self.params
        # global sensor noise: a robust spread of frame - background over all pixels (most are
        # background) of the background frames
        sample = np.stack([self.frame_yuv(c, t) - bgy for t in self.bg_frames[:10]])
        sigma = np.maximum(1.4826 * np.median(np.abs(sample.reshape(-1, 3)), axis=0), p.min_sigma)
        # the global noise is the floor; the per-pixel spread raises it where a pixel is noisier
        # (flicker, edges that shimmer under compression)
        return np.maximum(sigma ** 2, np.where(known[..., None], spread, 0.0) ** 2)

    def candidates(self, c, bg, var, shadows: bool = True):
        """Candidate foreground of camera c against background ``bg`` (BGR) with noise variance
        ``var`` (:meth:`noise_var`).

        Returns
        -------
        cand : (T, h, w) bool, without the pixels the shadow test calls shadow (if ``shadows``)
        raw : (T, h, w) bool, before the shadow test (the same array when not ``shadows``)
        shadow : (T, h, w) bool, the shadow test's verdict (all False when not ``shadows``)
        """
        p = self.params
        bgy = bgr_to_yuv(bg)
        inv = (1.0 / var).astype(np.float32)
        h, w = bg.shape[:2]
        min_area = max(int(p.min_area * h * w), 1)
        out = np.zeros((self.T, h, w), bool)
        raw = np.zeros((self.T, h, w), bool) if shadows else out
        shadow = np.zeros((self.T, h, w), bool)
        for t in range(self.T):
            yuv = self.frame_yuv(c, t)
            d = yuv - bgy
            fg = np.einsum("hwk,hwk,hwk->hw", d, d, inv) > p.threshold ** 2
            if shadows:
                raw[t] = clean_mask(fg, p.morph_size, min_area)
                shadow[t] = shadow_test(yuv, bgy, var, p.shadow_low, p.shadow_high,
                                        p.shadow_chroma)
                fg &= ~shadow[t]
            out[t] = clean_mask(fg, p.morph_size, min_area)
        return out, raw, shadow

    def ghosts(self, c, masks, var):
        """The ghost test (:attr:`ForegroundParams.ghost_recurrence`) of camera c.

        Parameters
        ----------
        masks : (T, h, w) bool, candidate pixels to test
        var : (h, w, 3) float, noise variance (:meth:`noise_var`)

        Returns
        -------
        (T, h, w) bool, the candidate pixels whose colour recurs: within ``threshold`` noise
        standard deviations (the candidate test's distance) in at least ``ghost_recurrence``
        of the background frames farther than ``ghost_gap`` of the take from the frame
        """
        p = self.params
        corr = self._corrected.get(c)
        yuv = self._yuv(c) if corr is None else corr
        inv = (1.0 / var).astype(np.float32)
        gap = p.ghost_gap * self.T
        out = np.zeros_like(masks)
        for t in range(self.T):
            m = masks[t]
            far = self.bg_frames[np.abs(self.bg_frames - t) > gap]
            if not m.any() or len(far) == 0:
                continue
            cur = yuv[t][m].astype(np.float32)
            d = yuv[:, m][far].astype(np.float32) - cur[None]
            near = np.einsum("snk,snk,nk->sn", d, d, inv[m]) <= p.threshold ** 2
            out[t][m] = near.mean(axis=0) >= p.ghost_recurrence
        return out

    def scene_pixels(self, c, masks):
        """Where camera c shows the static scene: (T, h, w) bool.

        A pixel is scene in frame t when its background is known (observed in enough frames
        with ``masks`` left out of the statistics, not inpainted), frame t matches that
        background (it is no candidate of the background test, shadows included) and the ghost
        test never fired there (the background is not a subject who stood still, seen away in
        other frames). A part of the subject that never moves matches this too: the caller must
        keep what it knows to be the subject (``gltrack refine-masks --method scene`` keeps the
        tracked model's silhouette).

        Parameters
        ----------
        c : int, camera index
        masks : (T, h, w) bool, the sequence's foreground (left out of the background
            statistics, dilated by ``exclude_margin``)
        """
        if masks.shape[0] != self.T:
            raise ValueError(f"masks of camera {c} have {masks.shape[0]} frames, the sequence "
                             f"{self.T}")
        bg, spread, known = self.background(c, self._dilate_stack(masks))
        var = self.noise_var(c, bgr_to_yuv(bg), spread, known)
        _, raw, _ = self.candidates(c, bg, var, shadows=True)
        ghost = self.ghosts(c, raw, var).any(axis=0)
        return ~raw & (known & ~ghost)[None]

    # ------------------------------------------------------------------------ cue 2: the hull
    def hull(self, masks_t, strong_t=None):
        """Main component of the visual hull of one frame's masks and its reprojections.

        Parameters
        ----------
        masks_t : list (C) of (h, w) bool
        strong_t : list (C) of (h, w) bool, optional
            Stricter masks (the candidates without shadow pixels): a hull voxel must also be
            foreground in at least 2 of them. A cast shadow is called shadow in every view and
            goes; dark clothes called shadow in some views stay.

        Returns
        -------
        silhouettes : list (C) of (h, w) bool, reprojection of the hull's largest component
        depth : (C,) float, depth of that component's centroid in each camera (nan if empty)
        voxels : (lo (M, 3), size (M,)) of the kept component (empty arrays if none)
        """
        p = self.params
        C = len(self.cameras)
        empty = [np.zeros((c.height, c.width), bool) for c in self.cameras]
        none = (np.zeros((0, 3)), np.zeros(0))
        if sum(bool(m.any()) for m in masks_t) < C - self.tolerance:
            return empty, np.full(C, np.nan), none
        # voxels far outside a camera's view can overflow its distortion polynomial; they are
        # classified "background" there either way (the box falls off the image)
        with np.errstate(invalid="ignore", over="ignore"):
            vox = carve(self.cameras, masks_t, self.bounds, base=16, max_depth=p.hull_levels,
                        tolerance=self.tolerance)
        if len(vox) == 0:
            return empty, np.full(C, np.nan), none
        L = int(p.hull_levels)
        fine = vox.at_level(L)
        shape = fine.max(axis=0) + 1
        grid = np.zeros(shape, bool)
        grid[tuple(fine.T)] = True
        if strong_t is not None:
            # the pixel under each cell's centre must be a strong candidate in 2 views
            cells = np.argwhere(grid)
            centres = vox.origin + (cells + 0.5) * (vox.size0 / (1 << L))
            votes = np.zeros(len(cells), np.int32)
            for cam, m in zip(self.cameras, strong_t):
                with np.errstate(invalid="ignore", over="ignore"):
                    ok, px = centre_pixels(cam, centres, True)
                votes[ok] += m[px[ok, 1], px[ok, 0]]
            grid[tuple(cells[votes < 2].T)] = False
            if not grid.any():
                return empty, np.full(C, np.nan), none
        labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3)))
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        main = int(np.argmax(sizes))
        # parts of the same body the candidates did not join (a still torso between moving
        # limbs): components within body_reach of the largest one
        parts = [main]
        if n > 1 and p.body_reach > 0:
            fine_size = vox.size0 / (1 << L)
            dist = ndimage.distance_transform_edt(labels != main) * fine_size
            near = ndimage.minimum(dist, labels, np.arange(1, n + 1))
            parts = [i + 1 for i in range(n) if near[i] <= p.body_reach]
        if strong_t is None:
            # a kept voxel belongs to the component of its first finest cell
            first = vox.ijk * (1 << (L - vox.level))[:, None]
            keep = np.isin(labels[tuple(first.T)], parts)
            lo = vox.origin + vox.ijk[keep] * vox.size[keep][:, None]
            size = vox.size[keep]
        else:  # the intersection cut coarse voxels: use the finest cells
            cells = np.argwhere(np.isin(labels, parts))
            fine_size = vox.size0 / (1 << L)
            lo = vox.origin + cells * fine_size
            size = np.full(len(cells), fine_size)
        centroid = (lo + 0.5 * size[:, None]).T @ size ** 3 / np.sum(size ** 3)
        sil, depth = [], np.zeros(C)
        for cam in self.cameras:
            with np.errstate(invalid="ignore", over="ignore"):
                front, lo_px, hi_px = pixel_boxes(cam, lo, size, True)
            sil.append(fill_boxes((cam.height, cam.width), lo_px[front], hi_px[front]))
            depth[self.cameras.index(cam)] = float(cam.depth_of(centroid[None])[0])
        return sil, depth, (lo, size)

    def consistent(self, masks_t, bounds):
        """Reprojection of the visual hull of one frame's masks inside ``bounds``.

        Parameters
        ----------
        masks_t : list (C) of (h, w) bool
        bounds : (6,) float, the box to carve

        Returns
        -------
        list (C) of (h, w) bool, the hull's reprojection dilated by ``hull_margin`` (all False
        where no voxel is kept)
        """
        p = self.params
        # 4 coarse voxels along the box's longest side, refined ``hull_levels`` times: for the
        # support column (about 0.8 x 0.8 x 1 m) a 5-6 cm voxel, finer than a shin is thick
        with np.errstate(invalid="ignore", over="ignore"):
            vox = carve(self.cameras, masks_t, bounds, base=4, max_depth=p.hull_levels,
                        tolerance=self.tolerance)
        out = []
        for cam, m in zip(self.cameras, masks_t):
            if len(vox) == 0:
                out.append(np.zeros_like(m))
                continue
            with np.errstate(invalid="ignore", over="ignore"):
                front, lo_px, hi_px = pixel_boxes(cam, vox.origin + vox.ijk * vox.size[:, None],
                                                  vox.size, True)
            out.append(dilate_mask(fill_boxes(m.shape, lo_px[front], hi_px[front]),
                                   p.hull_margin))
        return out

    # ------------------------------------------------------------------------ cue 3: GrabCut
    def grabcut(self, c, t, seed_sure, seed_probable, band_px, region=None):
        """GrabCut of camera c, frame t: (h, w) bool foreground, or None when not applicable.

        Parameters
        ----------
        seed_sure : (h, w) bool, sure foreground
        seed_probable : (h, w) bool, probable foreground
        band_px : int, width of the probable-background band, pixels
        region : (h, w) bool, optional, more "probably background" (the band goes around it)
        """
        fgish = seed_sure | seed_probable
        if not fgish.any():
            return None
        band = dilate_mask(fgish if region is None else (fgish | region), band_px)
        rows = np.flatnonzero(band.any(axis=1))
        cols = np.flatnonzero(band.any(axis=0))
        h, w = fgish.shape
        m = max(band_px, 4)
        r0, r1 = max(rows[0] - m, 0), min(rows[-1] + m + 1, h)
        c0, c1 = max(cols[0] - m, 0), min(cols[-1] + m + 1, w)
        gc = np.full((r1 - r0, c1 - c0), cv2.GC_BGD, np.uint8)
        gc[band[r0:r1, c0:c1]] = cv2.GC_PR_BGD
        gc[seed_probable[r0:r1, c0:c1]] = cv2.GC_PR_FGD
        gc[seed_sure[r0:r1, c0:c1]] = cv2.GC_FGD
        fg = self._grabcut_crop(c, t, gc, r0, c0)
        if fg is None:
            return None
        out = np.zeros((h, w), bool)
        out[r0:r1, c0:c1] = fg
        out |= seed_sure
        return out

    def person_colours(self, c, masks):
        """Colour density of the subject in camera c: (B, B, B) float, sums to 1.

        ``masks`` (T, h, w) bool are pixels known to be the subject (the hull-consistent
        candidates of every frame); the frames are the blurred YUV ones, quantised to
        ``support_bins`` levels per channel (:func:`colour_density`).
        """
        B = int(self.params.support_bins)
        yuv = self._yuv(c)
        samples = [yuv[t][masks[t]] for t in range(self.T) if masks[t].any()]
        return colour_density(np.concatenate(samples) if samples else np.zeros((0, 3), np.uint8),
                              B)

    def support_colours(self, c, t, body, column, person, limb_px: int = 1):
        """Pixels of the support column of camera c, frame t whose colour is the subject's.

        The scene's colours are learnt from a ring around the column (a quarter of its size
        wide, outside ``body``), where what lies around the support is (floor, mats); a column
        pixel is the subject when its colour is ``support_odds`` times likelier under ``person``
        (:meth:`person_colours`) than under the ring's density. A colour model of the whole
        crop (GrabCut's) holds the room's walls too, which on the Pose2Sim take are the colour
        of skin: a bare standing leg stayed background. The result is opened with a disk of
        ``limb_px`` radius: a strip thinner than a limb (a rail in the floor) goes.

        Returns
        -------
        (h, w) bool, inside ``column``; None when the ring is empty
        """
        p = self.params
        rows = np.flatnonzero(column.any(axis=1))
        cols = np.flatnonzero(column.any(axis=0))
        m = max(4, (max(rows[-1] - rows[0], cols[-1] - cols[0]) + 1) // 4)
        ring = dilate_mask(column, m) & ~column & ~body
        if not ring.any():
            return None
        yuv = self._yuv(c)[t]
        scene = colour_density(yuv[ring], int(p.support_bins))
        q = (yuv[column].astype(np.int32) * int(p.support_bins)) >> 8
        i = (q[:, 0], q[:, 1], q[:, 2])
        out = np.zeros_like(column)
        out[column] = person[i] > p.support_odds * scene[i]
        if limb_px > 1:
            out = dilate_mask(erode_mask(out, limb_px), limb_px) & out
        return clean_mask(out, p.morph_size, 1)

    def _grabcut_crop(self, c, t, gc, r0, c0):
        """cv2.grabCut on the crop of camera c, frame t at (r0, c0) with initial labels ``gc``
        (downscaled to ``grabcut_max_pixels``): (rows, cols) bool foreground, or None when a
        label set is too small or the colour models degenerate."""
        bgish = (gc == cv2.GC_BGD) | (gc == cv2.GC_PR_BGD)
        if bgish.sum() < 16 or (~bgish).sum() < 16:
            return None
        bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
        full = gc.shape
        crop = np.ascontiguousarray(self.images[c][t][r0:r0 + full[0], c0:c0 + full[1]])
        area = full[0] * full[1]
        cap = int(self.params.grabcut_max_pixels)
        if cap > 0 and area > cap:  # bound the cost: GrabCut is linear in pixels
            s = np.sqrt(cap / area)
            size = (max(int(full[1] * s), 1), max(int(full[0] * s), 1))
            crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
            gc = cv2.resize(gc, size, interpolation=cv2.INTER_NEAREST)
        try:
            cv2.grabCut(crop, gc, None, bgd, fgd, int(self.params.grabcut_iterations),
                        cv2.GC_INIT_WITH_MASK)
        except cv2.error as e:  # degenerate colour models (e.g. a flat crop)
            log.debug("grabCut failed on camera %d frame %d: %s", c, t, e)
            return None
        fg = ((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)).astype(np.uint8)
        if fg.shape != full:
            fg = cv2.resize(fg, (full[1], full[0]), interpolation=cv2.INTER_NEAREST)
        return fg.astype(bool)

    # ------------------------------------------------------------------------ one pass
    def run_pass(self, exclude=None, cues=CUES, known_person=None):
        """One pass of the chain (see the module docstring).

        Parameters
        ----------
        exclude : list (C) of (T, h, w) bool or None, where the subject is
        cues : iterable of str, subset of :data:`CUES`
        known_person : list (C) of (T, h, w) bool or None (per camera), optional
            Where the subject is known to be (the given person masks): never a ghost there (a
            subject that stood still shows its own colour in most frames)

        Returns
        -------
        masks : list (C) of (T, h, w) bool
        stages : dict (see :class:`ForegroundResult`)
        backgrounds : list (C) of (h, w, 3) uint8; known : list (C) of (h, w) bool
        """
        cues = set(cues)
        bad = cues - set(CUES)
        if bad:
            raise ValueError(f"cues must be a subset of {CUES}, got {sorted(bad)}")
        p = self.params
        C, T = len(self.cameras), self.T

        def background_and_candidates(c):
            ex = None if exclude is None else exclude[c]
            bg, spread, known = self.background(c, ex)
            bgy = bgr_to_yuv(bg)
            var = self.noise_var(c, bgy, spread, known)
            cs, cr, sh = self.candidates(c, bg, var, "shadows" in cues)
            # where the frame shows the scene as observed: no change from a background seen
            # in enough frames (before the ghost test, which finds more scene among changes);
            # kept only for the trim (a stack of the whole take per camera)
            scene = known[None] & ~cr if p.scene_trim else None
            ghost = None
            if "ghosts" in cues:
                ghost = self.ghosts(c, cr, var)
                if known_person is not None and known_person[c] is not None:
                    ghost &= ~known_person[c]
                cs, cr = cs & ~ghost, cr & ~ghost
            return bg, known, cs, cr, sh, ghost, scene

        bgs, knowns, cand, raw, shadow, ghosts, scene = (list(x) for x in zip(
            *self.per_camera(background_and_candidates)))
        stages = {"candidate": cand}
        if p.scene_trim:
            stages["scene"] = scene
        if "ghosts" in cues:
            stages["ghost"] = ghosts
        if "hull" not in cues and "grabcut" not in cues:
            return [m.copy() for m in cand], stages, bgs, knowns
        hullm = [np.zeros_like(m) for m in cand]
        sils = [np.zeros_like(m) for m in cand]
        columns = [np.zeros_like(m) for m in cand]
        # the column's lower half (up to about the knees), where a support stands on the floor
        lows = [np.zeros_like(m) for m in cand]
        column_boxes = {}
        depths = np.full((T, C), np.nan)
        for t in range(T):
            if "hull" in cues:
                strong = [cand[c][t] for c in range(C)] if "shadows" in cues else None
                sil, depths[t], (lo, size) = self.hull([raw[c][t] for c in range(C)], strong)
                col = None
                if "support" in cues and self.floor is not None:
                    col = support_column(lo, size, self.floor, reach=p.support_reach,
                                         step=p.support_reach / 4)
                if col is not None:
                    column_boxes[t] = np.concatenate([col[0].min(axis=0),
                                                      (col[0] + col[1][:, None]).max(axis=0)])
                    n_up = np.asarray(self.floor[0], float)
                    rise = (col[0] + 0.5 * col[1][:, None]) @ n_up - float(self.floor[1])
                    low = rise < 0.5 * rise.max()
                    for c in range(C):
                        with np.errstate(invalid="ignore", over="ignore"):
                            front, lo_px, hi_px = pixel_boxes(self.cameras[c], col[0], col[1],
                                                              True)
                        columns[c][t] = fill_boxes(sils[c][t].shape, lo_px[front],
                                                   hi_px[front])
                        lows[c][t] = fill_boxes(sils[c][t].shape, lo_px[front & low],
                                                hi_px[front & low])
                for c in range(C):
                    sils[c][t] = sil[c]
                    # the hull is carved from shadow-free candidates; a pixel the shadow test
                    # took (dark clothes on a lighter wall of the same hue) comes back where
                    # the other views put the body
                    hullm[c][t] = raw[c][t] & dilate_mask(sil[c], p.hull_margin)
            else:
                for c in range(C):
                    hullm[c][t] = cand[c][t]
        stages["hull"], stages["hull_silhouette"] = hullm, sils
        if column_boxes:
            stages["support_column"] = columns
        if "grabcut" not in cues:
            return [m.copy() for m in hullm], stages, bgs, knowns
        out = [np.zeros_like(m) for m in cand]
        support = [np.zeros_like(m) for m in cand]

        def grabcut_and_support(c):
            cv2.setRNGSeed((self._seed + c) % 2 ** 31)
            cam = self.cameras[c]
            f = 0.5 * (cam.fx + cam.fy)
            person = None
            for t in range(T):
                sure = erode_mask(hullm[c][t], 1)
                seed = sils[c][t] | hullm[c][t]
                # the hull's reprojection (voxel boxes) is blocky: it bounds the body, so it is
                # "probably background" like the seed's convex hull (the body between its
                # parts, e.g. a still torso between moving limbs), unless GrabCut's colours
                # claim it; only the hull-consistent candidates are "probably foreground"
                prob = hullm[c][t] & ~sure
                region = _convex_fill(seed)
                d = depths[t, c]
                if not np.isfinite(d) or d <= 0:
                    band = int(round(0.05 * max(cam.width, cam.height)))
                else:
                    band = int(round(p.body_margin * f / d))
                g = self.grabcut(c, t, sure, prob, max(band, 2), region)
                out[c][t] = hullm[c][t] if g is None else g
                if columns[c][t].any():
                    # the body's support, by colour (cue "support")
                    if person is None:
                        person = self.person_colours(c, hullm[c])
                    limb = (1 if not np.isfinite(d) or d <= 0
                            else int(round(0.5 * p.support_limb * f / d)))
                    s = self.support_colours(c, t, out[c][t], columns[c][t], person, limb)
                    if s is not None:
                        support[c][t] = s

        self.per_camera(grabcut_and_support)
        stages["grabcut"] = [m.copy() for m in out]
        supported = [np.zeros_like(m) for m in cand]
        for t, box in column_boxes.items():
            # a support pixel must be multi-view consistent: carved with the other views'
            # masks in the column's box (floor and mats a camera's colours took go)
            keep = self.consistent([out[c][t] | support[c][t] for c in range(C)], box)
            for c in range(C):
                supported[c][t] = support[c][t] & keep[c]
                out[c][t] |= supported[c][t]
        if column_boxes:
            stages["support"] = supported
        if "shadows" in cues:
            for c in range(C):
                out[c] &= ~(shadow[c] & ~sils[c])
        h_min = [max(int(p.min_area * m.shape[1] * m.shape[2]), 1) for m in out]
        for c in range(C):
            for t in range(T):
                m = clean_mask(out[c][t], p.morph_size, h_min[c])
                if "hull" in cues and m.any():
                    # keep only 2-D components that touch the hull's reprojection, or hold
                    # support pixels in the column's lower half: a standing shank, cut off
                    # from the body by still clothes that the colour test did not take (and
                    # not a bit of the scene higher up that the column's carve let through)
                    n, lab = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
                    touch = np.unique(lab[m & (sils[c][t] | (supported[c][t] & lows[c][t]))])
                    m = np.isin(lab, touch[touch > 0])
                out[c][t] = m
        return out, stages, bgs, knowns

    def run(self, person_masks=None, cues=CUES, passes: int | None = None,
            person_prior=None) -> ForegroundResult:
        """All passes; see :func:`estimate_foreground` for the parameters."""
        p = self.params
        passes = int(p.passes if passes is None else passes)
        given = [self._working_stack(c, person_masks, "person_masks")
                 for c in range(len(self.cameras))]
        prior = None
        if "prior" in cues and person_prior is not None:
            prior = [self._working_stack(c, person_prior, "person_prior", probability=True)
                     for c in range(len(self.cameras))]
            # where the prior says "person", the subject is left out of the background and is
            # never a ghost, as for given person masks
            given = [g if q is None else (q if g is None else g | q)
                     for g, q in zip(given, prior)]
            # the prior does not change between passes, nor its visual hull
            prior = self.consistent_prior(prior)
        given = [None if g is None else self._dilate_stack(g) for g in given]
        exclude = given if any(g is not None for g in given) else None
        for k in range(passes):
            # GrabCut refines the last pass only: an earlier pass just has to say which region
            # to leave out of the next background, which the hull-consistent masks do
            use = cues if k + 1 == passes else [q for q in cues if q != "grabcut"]
            masks, stages, bgs, knowns = self.run_pass(exclude, use, given)
            if prior is not None:
                masks = self.with_prior(masks, prior, stages.get("scene"))
                stages["prior"] = prior
            log.debug("foreground pass %d: fractions %s", k,
                      [round(float(m.mean()), 4) for m in masks])
            # the next background leaves out this pass's masks (dilated). Their convex hull
            # would also take out a still torso between moving limbs, but leaves so much
            # background unobserved (inpainted) that the masks overgrow into it (caliscope take)
            exclude = [self._dilate_stack(m)
                       | (False if g is None else g) for m, g in zip(masks, given)]
        return ForegroundResult(masks, list(self.cameras), bgs, knowns, stages,
                                list(self.full_size))

    def consistent_prior(self, prior):
        """The person prior's multi-view consistent pixels (cue ``"prior"``).

        Per frame, the prior's own visual hull is carved (:meth:`hull`); each camera keeps the
        prior's pixels near that hull's reprojection: a view whose prior took another person,
        or a poster, loses them. A frame whose prior has no hull (the person not found in
        enough views) keeps none.

        Parameters
        ----------
        prior : list (C) of (T, h, w) bool or None (per camera)

        Returns
        -------
        list (C) of (T, h, w) bool
        """
        C = len(self.cameras)
        used = [np.zeros((self.T, cam.height, cam.width), bool) for cam in self.cameras]
        for t in range(self.T):
            frame = [used[c][t] if prior[c] is None else prior[c][t] for c in range(C)]
            if sum(bool(m.any()) for m in frame) < C - self.tolerance:
                continue
            sil, _, (lo, _) = self.hull(frame)
            if len(lo) == 0:
                continue
            for c in range(C):
                used[c][t] = frame[c] & dilate_mask(sil[c], self.params.hull_margin)
        return used

    def with_prior(self, masks, used, scene=None):
        """Combine the cues' masks with the prior's consistent pixels (cue ``"prior"``).

        Each camera keeps the prior's consistent pixels (:meth:`consistent_prior`) and the
        cues' pixels within ``prior_margin`` of them. The prior fills what the cues miss
        (clothes the colour of the background, a part that never moved) and bounds what they
        spill (GrabCut taking in a cupboard of the skin's colour); the cues keep the edge where
        the prior is a few pixels short. A camera and frame without consistent prior pixels
        keeps the cues' mask.

        With ``scene`` (and ``params.scene_trim``) the pixels of that union that show the
        scene as observed, where :meth:`contrasted` trusts the background, are then dropped
        where they reach the mask's outside (:func:`outside_reaching`): the prior's coarse logits fill the concavities of a body
        (the gap between a hanging arm and the trunk, between the legs), whose background
        the other frames show. A scene-coloured region enclosed by the mask (dark shorts in
        front of a dark chair) stays, as filling such holes is what the prior is for.

        Parameters
        ----------
        masks : list (C) of (T, h, w) bool, the cues' masks
        used : list (C) of (T, h, w) bool, the prior's consistent pixels
        scene : list (C) of (T, h, w) bool, optional, where each frame shows the scene as
            observed (stage ``"scene"`` of :meth:`run_pass`)

        Returns
        -------
        list (C) of (T, h, w) bool
        """
        r = self.params.prior_margin
        trim = scene is not None and self.params.scene_trim
        out = [m.copy() for m in masks]
        for c, (m, u) in enumerate(zip(masks, used)):
            if trim:
                trusted = self.contrasted(u, scene[c])
            for t in np.flatnonzero(u.any(axis=(1, 2))):
                out[c][t] = (m[t] & dilate_mask(u[t], r)) | u[t]
                if trim:
                    out[c][t] &= ~outside_reaching(out[c][t] & scene[c][t] & trusted,
                                                   out[c][t])
        return out

    def contrasted(self, claimed, scene):
        """(h, w) bool: pixels whose background ``scene_trim`` may trust: in at least
        ``scene_contrast`` of the frames the prior ``claimed`` (T, h, w) them, the frame did
        not show the ``scene`` (T, h, w) there. A still part of the subject that the prior
        misses in some frames becomes the background (its own ghost) and then matches it
        whenever it is claimed; where the subject did pass, it looked different."""
        n = claimed.sum(axis=0)
        differs = (claimed & ~scene).sum(axis=0)
        return (n > 0) & (differs >= self.params.scene_contrast * n)

    def _dilate_stack(self, stack):
        return np.stack([dilate_mask(m, self.params.exclude_margin) for m in stack])


def estimate_foreground(frames_by_camera, cameras, *, person_masks=None, rng=None,
                        cues=CUES, params: ForegroundParams | None = None,
                        passes: int | None = None, floor=None,
                        person_prior=None) -> ForegroundResult:
    """Foreground masks of a synchronised multi-camera sequence without empty-scene frames.

    Parameters
    ----------
    frames_by_camera : sequence (C) of iterables of (H_c, W_c, 3) uint8 BGR images
        T synchronised frames per camera (lists, arrays or generators; each frame is downscaled
        to ``params.work_size`` as it arrives, so a full-resolution take never sits in memory).
    cameras : sequence (C) of gltrack.camera.Camera
        The calibrated cameras (world->camera, any world units and up axis); an image may be a
        uniform scaling of its camera's size.
    person_masks : sequence (C) of (T, H, W) bool (or None per camera), optional
        Where the subject is known to be (e.g. the tracked model's projected silhouettes), at any
        uniform scaling of the images; these pixels are left out of the background statistics.
    rng : numpy.random.Generator, optional
        Picks the background frames and seeds GrabCut; without it the frames are evenly spaced
        and the seed is 0 (deterministic either way).
    cues : iterable of str
        Cues to use, a subset of :data:`CUES` (``"hull", "grabcut", "shadows", "ghosts",
        "support", "prior"``); the temporal background is always used, ``"support"`` needs
        ``floor`` and ``"hull"`` and ``"grabcut"`` (it runs beside GrabCut), ``"prior"`` needs
        ``person_prior``. Leave cues out to measure
        what each contributes.
    params : ForegroundParams, optional
    passes : int, optional, overrides ``params.passes``
    floor : (normal (3,), height), optional
        The floor plane ``normal @ x == height`` (``normal`` a unit up vector in the cameras'
        world); the ``"support"`` cue needs it and is off without it.
    person_prior : sequence (C) of (T, H, W) person probabilities (or None per camera), optional
        A person segmentation (uint8: probability times 255; floats: probability), at any
        uniform scaling of the images: the ``"prior"`` cue
        (:meth:`SequenceForeground.with_prior`); off without it.

    Returns
    -------
    ForegroundResult, masks at the working resolution (``result.mask_at`` resizes them)
    """
    est = SequenceForeground(frames_by_camera, cameras, params, rng, floor)
    return est.run(person_masks, cues, passes, person_prior)
