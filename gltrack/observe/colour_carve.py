"""Voxel carving straight from colour images (Caillette et al. 2008, sec. 6.1).

:func:`gltrack.observe.voxels.carve` classifies voxels from ready-made foreground masks. The paper
merges segmentation into the reconstruction instead, and this module does that:

Background model (:class:`YuvBackground`)
    Every pixel has a full Gaussian in YUV (mean and 3x3 covariance over the empty-scene frames,
    plus ``noise_var`` on the diagonal so a static training set or 8-bit quantisation does not
    give a singular covariance). The covariance is full, not diagonal, because YUV channels of a
    real sensor are correlated (Bayer demosaicing and the RGB->YUV mix put the same photon noise
    into all three); with a diagonal model the d_M of plain noise is no longer chi-square with 3
    dof, so the alpha of the thresholds below would no longer mean what it says.
    A second "shadow" Gaussian has the mean's luminance lowered by ``shadow_drop`` (10 %) and the
    same covariance. By default its chroma offsets ``U - 128`` and ``V - 128`` shrink by the same
    factor: that is the same surface under 10 % less light (YUV is linear in RGB), identical to
    the paper's Y-only shift for a grey surface, while on a saturated one (chroma offset 60
    levels) a Y-only shift leaves a 6-level chroma error, several noise standard deviations, and
    calls the shadow foreground. ``shadow_chroma=False`` gives the literal Y-only shift.
    Per pixel the model with the smaller distance is used. The paper selects "by a simple test
    on the luminance channel"; the smaller distance is that test made exact: the difference of
    the two squared distances is affine in the pixel, so the choice is one linear test, which for
    a diagonal covariance and a Y-only shift is exactly "Y nearer the shadow mean". A plain
    ``Y < (1 - shadow_drop / 2) mu_Y`` test would, with the chroma shift or correlated noise,
    send ordinary noise dips of 5 % in Y to the wrong Gaussian.
    ``d_M`` is the squared Mahalanobis distance, chi-square with 3 dof for a background pixel.

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
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linprog
from scipy.stats import chi2

from gltrack.observe.voxels import (_CORNERS, BACKGROUND, EDGE, FOREGROUND, Voxels, _decide,
                                    _grid, centre_pixels, pixel_boxes)

log = logging.getLogger(__name__)

#: 1 / g and 1 / g^2 with g the plastic number: the R2 low-discrepancy sequence (M. Roberts 2018).
_R2 = (0.7548776662466927, 0.5698402909980532)


def _check_bgr(img, where, shape=None) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise ValueError(f"{where}: expected a BGR image (H, W, 3) uint8, got {a.shape} {a.dtype}")
    if shape is not None and a.shape[:2] != tuple(shape):
        raise ValueError(f"{where}: image is {a.shape[1]}x{a.shape[0]}, expected "
                         f"{shape[1]}x{shape[0]}")
    return a


def _yuv(img) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2YUV).astype(np.float32)


@dataclass
class YuvBackground:
    """Per-pixel Gaussian background model in YUV with a shadow twin (see module docstring).

    Attributes
    ----------
    mean : (H, W, 3) float32, YUV (OpenCV ``COLOR_BGR2YUV``, 0..255)
    inv_cov : (H, W, 3, 3) float32, inverse covariance, (grey levels)^-2
    shadow_drop : float, relative luminance drop of the shadow Gaussian (0 disables it)
    shadow_chroma : bool, the shadow mean's chroma offsets shrink with its luminance
    """

    mean: np.ndarray
    inv_cov: np.ndarray
    shadow_drop: float = 0.1
    shadow_chroma: bool = True

    def __post_init__(self):
        m, p = np.asarray(self.mean), np.asarray(self.inv_cov)
        if m.ndim != 3 or m.shape[2] != 3:
            raise ValueError(f"YuvBackground.mean must be (H, W, 3), got {m.shape}")
        if p.shape != m.shape + (3,):
            raise ValueError(f"YuvBackground.inv_cov must be {m.shape + (3,)}, got {p.shape}")
        if not 0.0 <= float(self.shadow_drop) < 1.0:
            raise ValueError(f"YuvBackground.shadow_drop must be in [0, 1), got {self.shadow_drop}")
        self.mean = m.astype(np.float32)
        self.inv_cov = p.astype(np.float32)
        self.shadow_drop = float(self.shadow_drop)
        self.shadow_chroma = bool(self.shadow_chroma)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) image size in pixels."""
        return self.mean.shape[:2]

    @property
    def shadow_mean(self) -> np.ndarray:
        """(H, W, 3) float32, YUV mean of the shadow Gaussian."""
        s = self.mean.copy()
        r = np.float32(1.0 - self.shadow_drop)
        s[..., 0] *= r
        if self.shadow_chroma:
            s[..., 1:] = 128.0 + r * (s[..., 1:] - 128.0)
        return s

    @classmethod
    def fit(cls, frames, *, noise_var: float = 4.0, shadow_drop: float = 0.1,
            shadow_chroma: bool = True) -> "YuvBackground":
        """Learn the model from frames of the empty scene.

        Parameters
        ----------
        frames : sequence of (H, W, 3) uint8 BGR images, all the same size (e.g.
            ``Dataset.backgrounds(cam)``); the covariance needs at least 2, one frame gives
            ``noise_var * I``
        noise_var : float, (grey levels)^2, added to the covariance diagonal
        shadow_drop : float, relative luminance drop of the shadow Gaussian (0 disables it)
        shadow_chroma : bool, shrink the shadow mean's chroma offsets too (see module docstring)

        Returns
        -------
        YuvBackground
        """
        frames = list(frames)
        if not frames:
            raise ValueError("YuvBackground.fit: at least one background frame is needed")
        if not noise_var > 0:
            raise ValueError(f"YuvBackground.fit: noise_var must be positive, got {noise_var}")
        shape = _check_bgr(frames[0], "background frame 0").shape[:2]
        mean = np.zeros(shape + (3,), np.float64)
        second = np.zeros(shape + (3, 3), np.float64)
        # streamed sums keep memory at one frame however many frames a dataset has
        for i, f in enumerate(frames):
            y = _yuv(_check_bgr(f, f"background frame {i}", shape)).astype(np.float64)
            mean += y
            second += y[..., :, None] * y[..., None, :]
        n = len(frames)
        mean /= n
        cov = (second - n * mean[..., :, None] * mean[..., None, :]) / max(n - 1, 1)
        if n == 1:
            cov[:] = 0.0
        cov += float(noise_var) * np.eye(3)
        log.debug("YUV background fitted on %d frames of %dx%d", n, shape[1], shape[0])
        return cls(mean.astype(np.float32), np.linalg.inv(cov).astype(np.float32),
                   float(shadow_drop), bool(shadow_chroma))

    def distance(self, image) -> np.ndarray:
        """Squared Mahalanobis distance of every pixel to its selected Gaussian.

        Parameters
        ----------
        image : (H, W, 3) uint8 BGR, the model's size

        Returns
        -------
        (H, W) float32, (grey levels / sigma)^2: chi-square with 3 dof where the pixel is
        background (slightly smaller with the shadow model, as the minimum of two distances)
        """
        yuv = _yuv(_check_bgr(image, "image", self.shape))
        dm = self._mahalanobis(yuv, self.mean)
        if self.shadow_drop > 0:
            np.minimum(dm, self._mahalanobis(yuv, self.shadow_mean), out=dm)
        return dm

    def _mahalanobis(self, yuv, mu):
        d = yuv - mu
        return np.einsum("hwi,hwij,hwj->hw", d, self.inv_cov, d, optimize=False)


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
        self.img = _check_bgr(image, where, (camera.height, camera.width))
        if not isinstance(background, YuvBackground):
            raise ValueError(f"background for camera {camera.name} must be a YuvBackground, got "
                             f"{type(background).__name__}")
        if background.shape != (camera.height, camera.width):
            raise ValueError(f"background for camera {camera.name} is {background.shape[1]}x"
                             f"{background.shape[0]}, the camera is {camera.width}x{camera.height}")
        self.cam, self.distort, self.t1, self.poly = camera, distort, t1, poly
        self.dm = background.distance(self.img)

    def classify(self, lo, size):
        """Classify voxels with world corner ``lo`` (M, 3) and edge ``size`` (M,).

        Returns
        -------
        state : (M,) int8, BACKGROUND / EDGE / FOREGROUND
        fg_sum : (M, 3) float64, BGR sum of the samples with ``d_M > T_1``
        fg_n : (M,) int64, their count
        all_sum : (M, 3) float64, BGR sum of all samples
        all_n : (M,) int64, samples drawn (``k``; 0 for an unseen voxel)
        """
        M = len(lo)
        front, lo_px, hi_px = pixel_boxes(self.cam, lo, size, self.distort)
        W, H = self.cam.width, self.cam.height
        c0, c1 = np.clip(lo_px[:, 0], 0, W), np.clip(hi_px[:, 0], 0, W)
        r0, r1 = np.clip(lo_px[:, 1], 0, H), np.clip(hi_px[:, 1], 0, H)
        w, h = np.maximum(c1 - c0, 0), np.maximum(r1 - r0, 0)
        inside = front & (c0 == lo_px[:, 0]) & (r0 == lo_px[:, 1]) & (c1 == hi_px[:, 0]) \
            & (r1 == hi_px[:, 1])
        area = np.where(front, w * h, 0)
        k = np.where(area > 0, np.maximum(np.rint(np.sqrt(area)), 1), 0).astype(np.int64)

        vox = np.repeat(np.arange(M), k)
        j = np.arange(len(vox)) - np.repeat(np.cumsum(k) - k, k)
        fx = (0.5 + j * _R2[0]) % 1.0
        fy = (0.5 + j * _R2[1]) % 1.0
        px = c0[vox] + (fx * w[vox]).astype(np.int64)
        py = r0[vox] + (fy * h[vox]).astype(np.int64)
        d = self.dm[py, px]
        fg = d > self.t1
        total = np.bincount(vox, weights=d, minlength=M)
        fg_n = np.bincount(vox, weights=fg, minlength=M).astype(np.int64)

        state = np.full(M, EDGE, np.int8)
        seen = area > 0
        state[front & ~seen] = BACKGROUND
        state[seen & (fg_n == k) & inside] = FOREGROUND
        state[seen & (total <= self.poly(k))] = BACKGROUND

        bgr = self.img[py, px].astype(np.float64)
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
                 alpha: float = 0.99, tolerance: int = 0, distort: bool = True) -> Voxels:
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

    Returns
    -------
    Voxels with ``colour`` (M, 3) float32 BGR 0..255. ``carve_colour.last_stats`` holds
    ``classifications`` (voxel-camera tests), ``samples`` (pixel samples drawn),
    ``levels`` (per level: voxels, kept, split, and camera states counted as background / edge /
    foreground), ``k_max`` and ``threshold_max_rel_error`` (polynomial vs chi2.ppf) and
    ``seconds``.
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
    kept_ijk, kept_lv, kept_col, levels = [], [], [], []
    tests = samples = 0
    for level in range(int(max_depth) + 1):
        if len(ijk) == 0:
            break
        size = size0 / 2.0 ** level
        lo = origin + ijk * size
        out = [v.classify(lo, np.full(len(ijk), size)) for v in views]
        states = np.stack([o[0] for o in out])
        counts = {name: int(np.sum(states == s)) for name, s in
                  (("background", BACKGROUND), ("edge", EDGE), ("foreground", FOREGROUND))}
        all_n = np.stack([o[4] for o in out])
        tests += states.size
        samples += int(all_n.sum())
        keep, split = _decide(states, tolerance, level == max_depth, views, lo + 0.5 * size)
        if np.any(keep):
            kept_col.append(_colours(states[:, keep], np.stack([o[1][keep] for o in out]),
                                     np.stack([o[2][keep] for o in out]),
                                     np.stack([o[3][keep] for o in out]), all_n[:, keep]))
        kept_ijk.append(ijk[keep])
        kept_lv.append(np.full(int(keep.sum()), level, np.int64))
        levels.append({"voxels": len(ijk), "kept": int(keep.sum()), "split": int(split.sum()),
                       **counts})
        ijk = (2 * ijk[split][:, None, :] + _CORNERS.astype(np.int64)[None]).reshape(-1, 3)

    vox = Voxels(np.concatenate(kept_ijk) if kept_ijk else np.zeros((0, 3), np.int64),
                 np.concatenate(kept_lv) if kept_lv else np.zeros(0, np.int64), origin, size0,
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
