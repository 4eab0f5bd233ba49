"""Foreground masks I_F from colour frames by background subtraction.

Two models, both trained on frames of the empty scene:

* ``"mog2"``: OpenCV's adaptive Gaussian mixture (``cv2.createBackgroundSubtractorMOG2``) with its
  own shadow detection; while tracking it is applied with learning rate 0, so a subject standing
  still is never absorbed into the background.
* ``"gaussian_yuv"``: one Gaussian per pixel and YUV channel (mean and variance over the
  training frames). A pixel is foreground when its normalised squared distance to the mean,
  ``sum_c (x_c - mu_c)^2 / (var_c + noise_var)``, exceeds ``threshold^2``, unless it is a shadow.

Shadow test (``gaussian_yuv``)
------------------------------
A cast shadow dims the light on a surface: every RGB channel scales by roughly the same factor
``r < 1``. YUV is linear in RGB with U and V offset by 128, so then ``Y = r mu_Y`` and
``U - 128 = r (mu_U - 128)`` (same for V): the luminance drops and the chromaticity
``(U - 128, V - 128) / Y`` stays. A pixel is a shadow (background) when
``shadow_low <= Y / mu_Y <= shadow_high`` and ``|(U - 128) - r (mu_U - 128)|`` and the same for V
stay within ``shadow_chroma`` levels (plus 3 background standard deviations).

Clean-up: a morphological opening (removes isolated noise pixels) then a closing (fills pin
holes), both with an elliptic kernel of ``morph_size`` pixels, then connected components smaller
than ``min_area`` pixels are dropped.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

METHODS = ("mog2", "gaussian_yuv")


def _check_frame(frame, where, shape=None) -> np.ndarray:
    img = np.asarray(frame)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"{where}: expected a BGR image (H, W, 3) uint8, got {img.shape} {img.dtype}")
    if shape is not None and img.shape[:2] != shape:
        raise ValueError(f"{where}: image is {img.shape[1]}x{img.shape[0]}, the background model "
                         f"is {shape[1]}x{shape[0]}")
    return np.ascontiguousarray(img)


class BackgroundModel:
    """Background subtraction for one camera.

    Parameters
    ----------
    threshold : float
        ``gaussian_yuv``: foreground beyond this many (combined) standard deviations.
        ``mog2``: passed as ``varThreshold = threshold^2``.
    noise_var : float, (grey levels)^2
        ``gaussian_yuv``: added to each pixel's variance, so a perfectly static training set
        does not make every compression artefact foreground.
    shadows : bool
        Treat detected shadows as background (both methods).
    shadow_low, shadow_high : float
        Range of the luminance ratio ``Y / mu_Y`` of a shadow (``gaussian_yuv``).
    shadow_chroma : float, grey levels
        Allowed chromaticity change of a shadow (``gaussian_yuv``).
    morph_size : int, pixels
        Kernel size of the opening and closing (0 or 1: no morphology).
    min_area : int, pixels
        Connected foreground components smaller than this are removed.
    max_train_frames : int
        Training uses at most this many frames (a random subset when an rng is given to
        :meth:`fit`, evenly spaced otherwise).
    """

    def __init__(self, *, threshold: float = 4.0, noise_var: float = 9.0, shadows: bool = True,
                 shadow_low: float = 0.4, shadow_high: float = 0.95, shadow_chroma: float = 8.0,
                 morph_size: int = 3, min_area: int = 20, max_train_frames: int = 100):
        if not threshold > 0 or not noise_var >= 0:
            raise ValueError("threshold must be positive and noise_var non-negative")
        if not 0 < shadow_low < shadow_high <= 1:
            raise ValueError(f"need 0 < shadow_low < shadow_high <= 1, got {shadow_low}, {shadow_high}")
        self.threshold = float(threshold)
        self.noise_var = float(noise_var)
        self.shadows = bool(shadows)
        self.shadow_low, self.shadow_high = float(shadow_low), float(shadow_high)
        self.shadow_chroma = float(shadow_chroma)
        self.morph_size = int(morph_size)
        self.min_area = int(min_area)
        self.max_train_frames = int(max_train_frames)
        self.method = None
        self.shape = None
        self._mog = None
        self._mean = None
        self._var = None

    # ------------------------------------------------------------------------------- training
    def fit(self, frames, method: str = "mog2", rng=None) -> "BackgroundModel":
        """Learn the background from frames of the empty scene.

        Parameters
        ----------
        frames : list of (H, W, 3) uint8 BGR images, all the same size
        method : {"mog2", "gaussian_yuv"}
        rng : numpy.random.Generator, optional; picks the training subset when there are more
            than ``max_train_frames`` frames

        Returns
        -------
        self
        """
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        frames = list(frames)
        if not frames:
            raise ValueError("at least one background frame is needed")
        shape = _check_frame(frames[0], "background frame 0").shape[:2]
        imgs = [_check_frame(f, f"background frame {i}", shape) for i, f in enumerate(frames)]
        if len(imgs) > self.max_train_frames:
            if rng is None:
                pick = np.linspace(0, len(imgs) - 1, self.max_train_frames).round().astype(int)
            else:
                pick = np.sort(rng.choice(len(imgs), self.max_train_frames, replace=False))
            imgs = [imgs[i] for i in pick]
        self.method, self.shape = method, shape
        if method == "mog2":
            self._mog = cv2.createBackgroundSubtractorMOG2(
                history=max(len(imgs), 2), varThreshold=self.threshold ** 2, detectShadows=self.shadows)
            for img in imgs:
                self._mog.apply(img, learningRate=-1)
        else:
            yuv = np.stack([cv2.cvtColor(i, cv2.COLOR_BGR2YUV) for i in imgs]).astype(np.float32)
            self._mean = yuv.mean(axis=0)
            self._var = yuv.var(axis=0)
        log.debug("background model %s fitted on %d frames of %dx%d", method, len(imgs),
                  shape[1], shape[0])
        return self

    # ------------------------------------------------------------------------------- applying
    def raw_foreground(self, frame) -> np.ndarray:
        """(H, W) bool foreground before the morphological clean-up."""
        if self.method is None:
            raise RuntimeError("BackgroundModel.fit must be called first")
        img = _check_frame(frame, "frame", self.shape)
        if self.method == "mog2":
            out = self._mog.apply(img, learningRate=0)
            # 127 marks MOG2's shadows, 255 foreground
            return out == 255 if self.shadows else out > 0
        yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV).astype(np.float32)
        var = self._var + self.noise_var
        diff = yuv - self._mean
        fg = (diff * diff / var).sum(axis=2) > self.threshold ** 2
        if self.shadows:
            fg &= ~self._shadow(yuv, var)
        return fg

    def _shadow(self, yuv, var):
        mu = self._mean
        with np.errstate(divide="ignore", invalid="ignore"):
            r = yuv[..., 0] / mu[..., 0]
        darker = (r >= self.shadow_low) & (r <= self.shadow_high)
        tol = self.shadow_chroma + 3.0 * np.sqrt(var[..., 1:])
        chroma = np.abs((yuv[..., 1:] - 128.0) - r[..., None] * (mu[..., 1:] - 128.0))
        return darker & np.all(chroma <= tol, axis=2)

    def foreground(self, frame) -> np.ndarray:
        """Foreground mask I_F of a frame.

        Parameters
        ----------
        frame : (H, W, 3) uint8 BGR, the size of the training frames

        Returns
        -------
        (H, W) bool, True = foreground
        """
        return clean_mask(self.raw_foreground(frame), self.morph_size, self.min_area)


def clean_mask(mask, morph_size: int = 3, min_area: int = 20) -> np.ndarray:
    """Opening, closing and small-component removal of a binary mask.

    Parameters
    ----------
    mask : (H, W) bool
    morph_size : int, pixels, elliptic kernel size (<= 1: skip the morphology)
    min_area : int, pixels, smallest component kept (<= 1: keep all)

    Returns
    -------
    (H, W) bool
    """
    m = np.asarray(mask).astype(np.uint8)
    if morph_size > 1:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (morph_size, morph_size))
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, k)
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, k)
    if min_area > 1 and m.any():
        n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_area
        keep[0] = False
        m = keep[labels].astype(np.uint8)
    return m.astype(bool)
