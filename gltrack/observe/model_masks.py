"""Foreground masks refined with a tracked model's silhouettes (``gltrack refine-masks``).

The sequence foreground of ``gltrack ingest`` (:mod:`gltrack.observe.foreground`) finds what
moves; a part of the subject that never moves (the torso of someone seated who gestures with
the hands) stays in the temporal background, and the "ghost" where the subject stood most of
the time, or another person, comes out as foreground. A tracked model knows where the body is.
Per frame and camera, :func:`refine_with_model` combines the two:

* GrabCut on the colour image, seeded by the model's projected silhouette M (distorted like the
  image, :func:`model_silhouette`): outside a band of ``band_m`` metres around M (projected at
  the model's depth) is sure background; inside M "probably foreground", and sure foreground
  where M, eroded by ``core_m``, and the sequence mask agree; the band "probably background";
  the sequence mask within reach (below) "probably foreground". GrabCut's colour models then
  grow the mask over the still torso the model covers, and keep it off background that the
  model overlaps;
* the sequence mask within ``reach_m`` metres of M is kept as it is: it holds the moving parts,
  including a raised hand the model missed (a mask made from the model alone copies the
  model's errors), while what lies farther from the body (the ghost, a second person, a
  blinking keyboard) is dropped.

What this cannot fix: a frame where the model is off the person (the refined mask then follows
the model's error within ``reach_m``; check the overlay before refining from a poor track).
Measured on the caliscope take (seated, frames 0-19): see docs/measurements.md, "Real footage"
(the caliscope paragraphs).
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from gltrack.render.reference import silhouette_overlap

from .foreground import dilate_mask, erode_mask

log = logging.getLogger(__name__)

#: supersampling of :func:`model_silhouette` (per axis)
SUPER = 4
#: metres around the model's silhouette where GrabCut decides (beyond: sure background). About
#: a limb's width: the model's limbs are within that of the person's where the track is good.
BAND_M = 0.15
#: metres the sequence mask is kept within, around the model's silhouette: an arm's length
#: (shoulder to fingertip is about 0.35 of the stature), so a raised hand stays even where the
#: model's arm hangs down (a track that does not follow the arms at all, as on the caliscope
#: take, whose hands a 0.3 m reach dropped), while the ghost and other people farther away go.
REACH_M = 0.6
#: metres by which the silhouette is eroded before it counts as sure foreground (where the
#: sequence mask agrees): the model's own fitting error at a limb's edge.
CORE_M = 0.04


def lens_radius_limit(dist, r_max: float = 10.0) -> float:
    """The normalised radius (``|(x, y)|`` on the plane z = 1) up to which the radial part of
    OpenCV's distortion ``dist`` = (k1, k2, p1, p2, k3) keeps growing with the radius, i.e.
    maps distinct radii to distinct ones; ``inf`` when it grows up to ``r_max``."""
    k1, k2, _, _, k3 = (list(np.ravel(dist)) + [0.0] * 5)[:5]
    r = np.linspace(0.0, r_max, 20001)
    grows = np.diff(r * (1 + k1 * r ** 2 + k2 * r ** 4 + k3 * r ** 6)) > 0
    stop = np.nonzero(~grows)[0]
    return float(r[stop[0]]) if len(stop) else np.inf


def model_silhouette(camera, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The pixels the posed mesh covers in ``camera``'s real (distorted) image.

    Every triangle with all three corners in front of the camera, within an image's width and
    height of the image and inside the lens model's valid radius (:func:`lens_radius_limit`)
    is projected through the lens model
    (:meth:`gltrack.camera.Camera.project`) and filled at :data:`SUPER` times the
    resolution; a pixel is covered when at least half of it is. The silhouette needs no
    visibility test.

    Parameters
    ----------
    camera : gltrack.camera.Camera
    vertices : (V, 3) float, posed vertices in the camera's world frame, metres
    faces : (F, 3) int

    Returns
    -------
    (H, W) bool
    """
    H, W = camera.height, camera.width
    v = np.asarray(vertices, dtype=np.float64)
    front = camera.depth_of(v) > 1e-3
    # the lens polynomial is fitted within the image: beyond the radius where it stops growing
    # it folds points back into the image, and far out it overflows; a triangle reaching there
    # (an image or more beside it) is dropped: it can only cover the image's edge
    with np.errstate(all="ignore"):
        pin = camera.project(v, distort=False)
        uv = camera.project(v, distort=True)
        r = np.hypot((pin[:, 0] - camera.cx) / camera.fx, (pin[:, 1] - camera.cy) / camera.fy)
    ok = front & np.isfinite(uv).all(axis=1) & (r < lens_radius_limit(camera.dist))
    ok &= (pin[:, 0] > -W) & (pin[:, 0] < 2 * W) & (pin[:, 1] > -H) & (pin[:, 1] < 2 * H)
    tri = faces[ok[faces].all(axis=1)]
    if len(tri) == 0:
        return np.zeros((H, W), bool)
    # filled at SUPER x the resolution, then a pixel is covered when half its area is: fillPoly
    # colours every pixel an edge touches (fillConvexPoly too), a 1-pixel rim at full resolution (30 % too many
    # pixels for a body 60 px tall). Pixel i spans [i - 0.5, i + 0.5], sub-pixels
    # SUPER i .. SUPER i + SUPER - 1, hence the offset.
    U = uv * SUPER + (SUPER - 1) / 2.0
    pts = np.round(U[tri] * 16).astype(np.int32)  # 4 fractional bits
    fine = np.zeros((H * SUPER, W * SUPER), np.uint8)
    for t in pts:  # one by one: fillPoly of many contours leaves their overlaps empty (even-odd)
        cv2.fillConvexPoly(fine, t, 1, lineType=cv2.LINE_8, shift=4)
    area = fine.reshape(H, SUPER, W, SUPER).mean(axis=(1, 3))
    return area >= 0.5


def mask_covered(camera, vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> float:
    """Share of ``mask``'s pixels inside the posed mesh's silhouette in ``camera``'s real image
    (:func:`model_silhouette`); NaN for an empty mask.

    Parameters
    ----------
    camera : gltrack.camera.Camera, as calibrated (``mask`` is distorted like the image)
    vertices : (V, 3) float, metres; faces : (F, 3) int
    mask : (H, W) bool

    Returns
    -------
    float in 0..1, or NaN
    """
    return silhouette_overlap(model_silhouette(camera, vertices, faces), mask)[2]


def metres_to_pixels(camera, metres: float, depth: float) -> int:
    """``metres`` seen at ``depth`` metres in ``camera``'s pixels (at least 1)."""
    return max(int(round(camera.fx * metres / max(depth, 0.1))), 1)


def refine_view(camera, image: np.ndarray, mask: np.ndarray, vertices: np.ndarray,
                faces: np.ndarray, *, band_m: float = BAND_M, reach_m: float = REACH_M,
                core_m: float = CORE_M, max_pixels: int = 0) -> np.ndarray:
    """:func:`refine_with_model` of one camera's real image for a posed mesh.

    Parameters
    ----------
    camera : gltrack.camera.Camera, as calibrated (the image and mask are distorted)
    image : (H, W, 3) uint8 BGR; mask : (H, W) bool, the sequence foreground
    vertices : (V, 3) float, the posed mesh in the camera's world frame, metres
    faces : (F, 3) int
    band_m, reach_m, core_m : float, metres (:data:`BAND_M`, :data:`REACH_M`, :data:`CORE_M`),
        turned into pixels at the mesh's median depth in this camera
    max_pixels : int, see :func:`refine_with_model`

    Returns
    -------
    (H, W) bool
    """
    sil = model_silhouette(camera, vertices, faces)
    depth = float(np.median(camera.depth_of(np.asarray(vertices, dtype=np.float64))))
    return refine_with_model(image, mask, sil, band_px=metres_to_pixels(camera, band_m, depth),
                             reach_px=metres_to_pixels(camera, reach_m, depth),
                             core_px=metres_to_pixels(camera, core_m, depth),
                             max_pixels=max_pixels)


def refine_with_model(image: np.ndarray, mask: np.ndarray, model: np.ndarray, *, band_px: int,
                      reach_px: int, core_px: int, iterations: int = 3,
                      max_pixels: int = 0) -> np.ndarray:
    """One camera's foreground from its sequence mask and the model's silhouette.

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR
    mask : (H, W) bool, the sequence foreground (``ingest``'s mask)
    model : (H, W) bool, the model's silhouette (:func:`model_silhouette`)
    band_px, reach_px, core_px : int, :data:`BAND_M`, :data:`REACH_M` and :data:`CORE_M` in
        pixels at the model's depth
    iterations : int, GrabCut iterations
    max_pixels : int, GrabCut runs on its box shrunk to at most this many pixels (its cost is
        linear in them) and its labels are scaled back; 0 = at full resolution

    Returns
    -------
    (H, W) bool; the sequence mask unchanged where the model has no pixel in the image
    (nothing to refine it with).
    """
    mask, model = np.asarray(mask, bool), np.asarray(model, bool)
    if image.shape[:2] != mask.shape or mask.shape != model.shape:
        raise ValueError(f"image {image.shape[:2]}, mask {mask.shape} and model {model.shape} "
                         "must have the same size")
    if not model.any():
        return mask.copy()
    band = dilate_mask(model, band_px)
    reach = mask & dilate_mask(model, reach_px)
    core = erode_mask(model, core_px)
    seed = np.full(mask.shape, cv2.GC_BGD, np.uint8)
    seed[band] = cv2.GC_PR_BGD
    seed[model | reach] = cv2.GC_PR_FGD
    seed[core & mask] = cv2.GC_FGD
    # GrabCut on the box around what it decides (and a margin of sure background for its
    # background colour model): the rest of the image is sure background anyway
    ys, xs = np.nonzero(band | reach)
    pad = max(band_px, 8)
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, mask.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, mask.shape[1])
    crop = seed[y0:y1, x0:x1].copy()
    img = np.ascontiguousarray(image[y0:y1, x0:x1])
    full = crop.shape
    if 0 < max_pixels < crop.size:
        s = np.sqrt(max_pixels / crop.size)
        size = (max(int(full[1] * s), 1), max(int(full[0] * s), 1))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_NEAREST)
    fg_model, bg_model = np.zeros((1, 65)), np.zeros((1, 65))
    if (crop == cv2.GC_BGD).any() and ((crop == cv2.GC_PR_FGD) | (crop == cv2.GC_FGD)).any():
        cv2.setRNGSeed(0)  # GrabCut's k-means starts from OpenCV's generator: reproducible
        cv2.grabCut(img, crop, None, bg_model, fg_model, int(iterations), cv2.GC_INIT_WITH_MASK)
    fg = ((crop == cv2.GC_FGD) | (crop == cv2.GC_PR_FGD)).astype(np.uint8)
    if fg.shape != full:
        fg = cv2.resize(fg, (full[1], full[0]), interpolation=cv2.INTER_NEAREST)
    out = np.zeros_like(mask)
    out[y0:y1, x0:x1] = fg.astype(bool)
    return out | reach
