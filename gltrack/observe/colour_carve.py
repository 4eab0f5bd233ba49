"""Voxel carving straight from colour images (Caillette et al. 2008, sec. 6.1).

:func:`gltrack.observe.voxels.carve` classifies voxels from ready-made foreground masks. The paper
merges segmentation into the reconstruction instead, and this module does that:

Background model (:class:`gltrack.observe.background.YuvBackground`)
    A full-covariance Gaussian per pixel in YUV with a shadow twin; its squared Mahalanobis
    distance ``d_M`` is chi-square with 3 dof for a background pixel.

Per voxel and camera (eq. 6)
    The voxel's 8 corners are projected; the pixel bounding box of their hull, clipped to the
    image, is sampled at ``k = round(sqrt(box area))`` pixels by a fixed 2-D low-discrepancy
    pattern (the R2 sequence; deterministic, no generator needed, and evenly spread for any k).
    With ``S = sum_i d_M(s_i)``:

    * ``S <= T_k``                       -> background,
    * else every ``d_M(s_i) > T_1``      -> foreground,
    * else                               -> edge,

    where ``T_k = chi2.ppf(alpha, 3 k)`` is approximated at run time by a second-order polynomial
    in ``k`` (:func:`chi2_threshold_poly`, minimax relative error over the k range of the
    cameras). ``T_1`` itself is the exact constant. As in ``carve``, a box with a corner behind
    the camera is an edge, a box wholly outside the image is background (the camera does not see
    the voxel), and a box cut by the image border is never foreground (not all of it was seen).

    ``d_M`` is evaluated once per pixel of each image, not per sample: every pixel is sampled by
    several voxels and levels, and one vectorised pass over a 320x240 image is cheaper than
    gathering 3x3 matrices per sample. The values are identical.

Hierarchy
    A voxel is discarded when more than ``tolerance`` cameras say background, kept when all the
    others say foreground, and split into its 8 octants otherwise, down to ``max_depth``. At the
    finest level an edge camera is decided, as in ``carve``, by the pixel under the voxel centre
    (foreground when its ``d_M > T_1``).

Colour
    Each kept voxel gets, per camera, the mean BGR of its samples with ``d_M > T_1`` (for a
    foreground voxel: all of them; for a finest-level edge voxel this leaves out the background
    pixels its box overlaps), averaged over the cameras that have such samples. A voxel with no
    such sample anywhere (only possible at the finest level) takes the mean of all its samples in
    the cameras that did not call it background.
"""
from __future__ import annotations

import functools
import logging
import math
import time

import numpy as np
from scipy.optimize import linprog
from scipy.stats import chi2

from gltrack.observe.background import YuvBackground, check_bgr
from gltrack.observe.voxels import (BACKGROUND, EDGE, FOREGROUND, Voxels, _decide, _first_block,
                                    _grid, _octants, centre_pixels, classify_level)

log = logging.getLogger(__name__)

#: 1 / g and 1 / g^2 with g the plastic number: the R2 low-discrepancy sequence (M. Roberts 2018).
_R2 = (0.7548776662466927, 0.5698402909980532)


def _r2_fractions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) x and y fractions in [0, 1) of the first n points of the R2 sequence, from 0.5."""
    j = np.arange(n)
    return (0.5 + j * _R2[0]) % 1.0, (0.5 + j * _R2[1]) % 1.0


@functools.lru_cache(maxsize=32)
def chi2_threshold_poly(alpha: float = 0.99, k_max: int = 300) -> np.poly1d:
    """Second-order polynomial ``T(k) ~ chi2.ppf(alpha, 3 k)`` for ``k = 1..k_max``.

    The coefficients minimise the largest *relative* error over the integers ``1..k_max`` (a
    small linear programme): an absolute least-squares fit is dominated by the large thresholds
    and is off by tens of percent at small ``k``, where most voxels are.

    Parameters
    ----------
    alpha : float, confidence level in (0, 1)
    k_max : int, largest sample count the polynomial is used for (>= 3)

    Returns
    -------
    numpy.poly1d, callable on k (any shape), returns float64 thresholds
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if int(k_max) < 3:
        raise ValueError(f"k_max must be >= 3, got {k_max}")
    k = np.arange(1, int(k_max) + 1, dtype=np.float64)
    T = chi2.ppf(alpha, 3.0 * k)
    A = np.stack([k ** 2, k, np.ones_like(k)], axis=1) / T[:, None]
    one = np.ones((len(k), 1))
    # variables (a, b, c, e): minimise e subject to |A p - 1| <= e
    res = linprog([0, 0, 0, 1], A_ub=np.block([[A, -one], [-A, -one]]),
                  b_ub=np.concatenate([np.ones(len(k)), -np.ones(len(k))]),
                  bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    if not res.success:  # pragma: no cover - HiGHS solves this 4-variable LP
        raise RuntimeError(f"threshold fit failed: {res.message}")
    log.debug("chi2 threshold polynomial alpha=%g k<=%d: max rel. error %.4f", alpha, k_max,
              res.x[3])
    return np.poly1d(res.x[:3])


@functools.lru_cache(maxsize=32)
def _poly_error(alpha: float, k_max: int) -> float:
    k = np.arange(1, k_max + 1)
    return float(np.max(np.abs(chi2_threshold_poly(alpha, k_max)(k) / chi2.ppf(alpha, 3 * k) - 1)))


class _ColourView:
    """One camera's image, reduced to its per-pixel d_M, classifying voxels by pixel samples."""

    def __init__(self, camera, image, background, t1, poly, distort):
        where = f"image for camera {camera.name}"
        self.img = check_bgr(image, where, (camera.height, camera.width))
        if not isinstance(background, YuvBackground):
            raise ValueError(f"background for camera {camera.name} must be a YuvBackground, got "
                             f"{type(background).__name__}")
        if background.shape != (camera.height, camera.width):
            raise ValueError(f"background for camera {camera.name} is {background.shape[1]}x"
                             f"{background.shape[0]}, the camera is {camera.width}x{camera.height}")
        self.cam, self.distort, self.t1, self.poly = camera, distort, t1, poly
        self.dm = background.distance(self.img)

    def classify_boxes(self, front, lo_px, hi_px, colours: bool = True):
        """Classify voxels from their pixel boxes (``front``, ``lo_px``, ``hi_px`` of
        :func:`gltrack.observe.voxels.pixel_boxes`, M of them); without ``colours`` the three
        colour sums are None.

        Returns
        -------
        state : (M,) int8, BACKGROUND / EDGE / FOREGROUND
        fg_sum : (M, 3) float64, BGR sum of the samples with ``d_M > T_1``
        fg_n : (M,) int64, their count
        all_sum : (M, 3) float64, BGR sum of all samples
        all_n : (M,) int64, samples drawn (``k``; 0 for an unseen voxel)
        """
        M = len(front)
        W, H = self.cam.width, self.cam.height
        c0, c1 = np.clip(lo_px[:, 0], 0, W), np.clip(hi_px[:, 0], 0, W)
        r0, r1 = np.clip(lo_px[:, 1], 0, H), np.clip(hi_px[:, 1], 0, H)
        w, h = np.maximum(c1 - c0, 0), np.maximum(r1 - r0, 0)
        inside = front & (c0 == lo_px[:, 0]) & (r0 == lo_px[:, 1]) & (c1 == hi_px[:, 0]) \
            & (r1 == hi_px[:, 1])
        area = np.where(front, w * h, 0)
        k = np.where(area > 0, np.maximum(np.rint(np.sqrt(area)), 1), 0).astype(np.int64)

        vox = np.repeat(np.arange(M), k)
        start = np.cumsum(k) - k  # each voxel's first sample
        j = np.arange(len(vox)) - np.repeat(start, k)
        # sample j of every voxel sits at the same fractions of its box: look them up
        fx, fy = _r2_fractions(int(k.max()) if M else 0)
        px = np.repeat(c0, k) + (fx[j] * np.repeat(w, k)).astype(np.int64)
        py = np.repeat(r0, k) + (fy[j] * np.repeat(h, k)).astype(np.int64)
        d = self.dm.ravel()[py * W + px]
        fg = d > self.t1
        # per-voxel sums over the voxels' consecutive runs of samples (4x bincount's speed)
        seen = k > 0
        first = start[seen]
        total = np.zeros(M)
        fg_n = np.zeros(M, np.int64)
        if len(first):
            total[seen] = np.add.reduceat(d, first)
            fg_n[seen] = np.add.reduceat(fg.astype(np.int64), first)

        state = np.full(M, EDGE, np.int8)
        state[front & ~seen] = BACKGROUND
        state[seen & (fg_n == k) & inside] = FOREGROUND
        state[seen & (total <= self.poly(k))] = BACKGROUND

        if not colours:
            return state, None, None, None, k
        bgr = self.img.reshape(-1, 3)[py * W + px].astype(np.float64)
        fg_sum = np.stack([np.bincount(vox, weights=bgr[:, c] * fg, minlength=M)
                           for c in range(3)], axis=1)
        all_sum = np.stack([np.bincount(vox, weights=bgr[:, c], minlength=M)
                            for c in range(3)], axis=1)
        return state, fg_sum, fg_n, all_sum, k

    def centre_state(self, centres):
        """(M,) FOREGROUND/BACKGROUND from the d_M of the pixel under each centre (M, 3)."""
        ok, px = centre_pixels(self.cam, centres, self.distort)
        fg = np.zeros(len(centres), bool)
        fg[ok] = self.dm[px[ok, 1], px[ok, 0]] > self.t1
        return np.where(fg, FOREGROUND, BACKGROUND).astype(np.int8)


def _scatter(M, looked, parts):
    """(C, M, ...) per-camera values of M voxels from each camera's values (m_c, ...) for the
    voxels it looked at (``looked``), zeros elsewhere."""
    out = np.zeros((len(parts), M) + parts[0].shape[1:], parts[0].dtype)
    for c, (idx, v) in enumerate(zip(looked, parts)):
        out[c, idx] = v
    return out


def _colours(states, fg_sum, fg_n, all_sum, all_n):
    """(M, 3) float32 mean BGR per voxel from per-camera sums (C, M, ...)."""
    has_fg = fg_n > 0
    per_fg = fg_sum / np.maximum(fg_n, 1)[..., None]
    n_fg = has_fg.sum(axis=0)
    col = (per_fg * has_fg[..., None]).sum(axis=0) / np.maximum(n_fg, 1)[:, None]
    use = (all_n > 0) & (states != BACKGROUND)
    per_all = all_sum / np.maximum(all_n, 1)[..., None]
    fallback = (per_all * use[..., None]).sum(axis=0) / np.maximum(use.sum(axis=0), 1)[:, None]
    return np.where((n_fg > 0)[:, None], col, fallback).astype(np.float32)


def carve_colour(cameras, images, backgrounds, bounds, *, base: int = 16, max_depth: int = 3,
                 alpha: float = 0.99, tolerance: int = 0, distort: bool = True,
                 colours: bool = True) -> Voxels:
    """Coarse-to-fine voxel reconstruction classified from colour samples (paper eq. 5-6).

    Parameters
    ----------
    cameras : list of gltrack.camera.Camera, C of them
    images : list of (H, W, 3) uint8 BGR, the current frame of each camera (its own size)
    backgrounds : list of YuvBackground, one per camera, fitted on that camera's empty scene
    bounds : (6,) float, metres, tracking volume ``(xmin, ymin, zmin, xmax, ymax, zmax)``
    base : int, coarse voxels along the longest side of ``bounds`` (the paper's 16)
    max_depth : int, subdivision levels below the coarse grid (3 with base 16 is the paper's
        128^3-equivalent finest grid)
    alpha : float, confidence level of the background test
    tolerance : int, a voxel survives up to this many "background" cameras
    distort : bool, project with the lens distortion (raw images); False for undistorted ones
    colours : bool, also average each kept voxel's colour (False: ``colour`` is None, which
        saves a sixth of the time when the caller samples colours its own way)

    Returns
    -------
    Voxels with ``colour`` (M, 3) float32 BGR 0..255 (None with ``colours=False``).
    ``carve_colour.last_stats`` holds ``classifications`` (voxel-camera tests made: a camera
    skips the voxels the cameras before it dropped, see
    :func:`gltrack.observe.voxels.classify_level`), ``samples`` (pixel samples drawn),
    ``levels`` (per level: voxels, kept, split, and the states those tests gave, counted as
    background / edge / foreground), ``k_max`` and ``threshold_max_rel_error`` (polynomial vs
    chi2.ppf) and ``seconds``.
    """
    t_start = time.perf_counter()
    cameras, images, backgrounds = list(cameras), list(images), list(backgrounds)
    if not cameras or len(images) != len(cameras) or len(backgrounds) != len(cameras):
        raise ValueError(f"need one image and one background per camera, got {len(images)} "
                         f"images and {len(backgrounds)} backgrounds for {len(cameras)} cameras")
    if not 0 <= int(tolerance) < len(cameras):
        raise ValueError(f"tolerance must be in [0, {len(cameras) - 1}], got {tolerance}")
    if not 0 <= int(max_depth) <= 8:
        raise ValueError(f"max_depth must be in 0..8, got {max_depth}")
    if not 0.0 < float(alpha) < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    alpha = float(alpha)
    k_max = max(3, max(math.ceil(math.sqrt(c.width * c.height)) for c in cameras))
    poly = chi2_threshold_poly(alpha, k_max)
    t1 = float(chi2.ppf(alpha, 3))
    views = [_ColourView(c, im, bg, t1, poly, distort)
             for c, im, bg in zip(cameras, images, backgrounds)]

    origin, size0, ijk = _grid(bounds, base)
    blocks, extent = _first_block(ijk)
    kept_ijk, kept_lv, kept_col, levels = [], [], [], []
    tests = samples = 0
    for level in range(int(max_depth) + 1):
        if len(ijk) == 0:
            break
        size = size0 / 2.0 ** level
        lo = origin + ijk * size
        states, looked, out = classify_level(
            views, origin, size, ijk, blocks, extent, tolerance, distort,
            lambda v, *boxes: v.classify_boxes(*boxes, colours))
        counts = {name: int(sum(np.sum(o[0] == s) for o in out)) for name, s in
                  (("background", BACKGROUND), ("edge", EDGE), ("foreground", FOREGROUND))}
        all_n = _scatter(len(ijk), looked, [o[4] for o in out])
        tests += sum(len(i) for i in looked)
        samples += int(all_n.sum())
        keep, split = _decide(states, tolerance, level == max_depth, views, lo + 0.5 * size)
        if colours and np.any(keep):
            # a kept voxel was alive in every camera, so every camera looked at it
            fg_sum, fg_n, all_sum = (_scatter(len(ijk), looked, [o[i] for o in out])
                                     for i in (1, 2, 3))
            kept_col.append(_colours(states[:, keep], fg_sum[:, keep], fg_n[:, keep],
                                     all_sum[:, keep], all_n[:, keep]))
        kept_ijk.append(ijk[keep])
        kept_lv.append(np.full(int(keep.sum()), level, np.int64))
        levels.append({"voxels": len(ijk), "kept": int(keep.sum()), "split": int(split.sum()),
                       **counts})
        ijk, blocks, extent = _octants(ijk[split])

    vox = Voxels(np.concatenate(kept_ijk) if kept_ijk else np.zeros((0, 3), np.int64),
                 np.concatenate(kept_lv) if kept_lv else np.zeros(0, np.int64), origin, size0,
                 None if not colours else
                 np.concatenate(kept_col) if kept_col else np.zeros((0, 3), np.float32))
    seconds = time.perf_counter() - t_start
    carve_colour.last_stats = {
        "classifications": int(tests), "samples": samples, "levels": levels, "k_max": k_max,
        "threshold_max_rel_error": _poly_error(alpha, k_max),
        "seconds": seconds}
    log.debug("colour-carved %d voxels, %.4f m^3, %d classifications, %d samples, %.3f s",
              len(vox), vox.volume, tests, samples, seconds)
    return vox


carve_colour.last_stats = {}
