"""Colour camera sensor noise and the background subtraction that turns frames into masks.

Sensor model (:func:`sensor_image`), per frame and camera: a global gain ``1 + N(0, gain_sigma)``
and offset ``N(0, offset_sigma)`` grey levels per channel (auto-exposure and white-balance
flicker), then independent per-pixel Gaussian noise of ``pixel_sigma`` grey levels, rounding to
8 bits. Every term is multiplied by the noise level (:data:`gltrack.data.sim_depth.NOISE_LEVELS`).

Masks come from a real background-subtraction algorithm, :class:`BackgroundModel`: OpenCV's
Gaussian-mixture subtractor (MOG2, Zivkovic 2004) trained on empty-scene frames that carry the
same sensor noise, applied with a frozen model (learning rate 0, so a subject standing still is
not absorbed into the background), shadow pixels counted as background, then a morphological
opening (speckle) and closing (holes). The masks therefore have the errors trackers meet on real
data: holes where clothing matches the background, shadows at the feet, and any moving object
that is not the subject.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from .sim_depth import NoisePreset

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ColourNoise(NoisePreset):
    """Colour sensor noise parameters (see module docstring).

    Attributes
    ----------
    level : float, multiplier of every term (0 = clean)
    gain_sigma : float, relative standard deviation of the per-frame gain
    offset_sigma : float, grey levels, per-frame offset per channel
    pixel_sigma : float, grey levels, per-pixel noise
    """

    level: float = 1.0
    gain_sigma: float = 0.03
    offset_sigma: float = 2.0
    pixel_sigma: float = 2.5


def sensor_image(rgb, rng: np.random.Generator, model: ColourNoise | None = None) -> np.ndarray:
    """A clean render as the camera would deliver it.

    Parameters
    ----------
    rgb : (H, W, 3) uint8 or float in 0..255, RGB
    rng : numpy.random.Generator (the same number of values is drawn at every level)
    model : ColourNoise, default ``ColourNoise()``

    Returns
    -------
    (H, W, 3) uint8, **BGR** (OpenCV order, as the dataset stores it)
    """
    model = model or ColourNoise()
    img = np.asarray(rgb, dtype=np.float64)
    gain = 1.0 + model.level * model.gain_sigma * rng.standard_normal()
    offset = model.level * model.offset_sigma * rng.standard_normal(3)
    noise = model.level * model.pixel_sigma * rng.standard_normal(img.shape)
    out = img * gain + offset + noise
    return np.clip(np.round(out), 0, 255).astype(np.uint8)[..., ::-1].copy()


class BackgroundModel:
    """MOG2 background subtraction trained once on empty-scene frames, then frozen.

    Parameters
    ----------
    backgrounds : sequence of (H, W, 3) uint8 BGR empty-scene frames (at least 1)
    var_threshold : float, squared Mahalanobis distance for "matches the background"
    shadow_threshold : float
        MOG2's tau: a pixel darker than the background by a factor within ``[tau, 1]`` and of
        the same chromaticity is a shadow. OpenCV's default 0.5 also swallows dark clothing in
        front of a light floor; 0.75 keeps the soft shadows of the simulated lighting out and
        the legs in.
    open_px, close_px : int, sizes of the elliptic opening/closing kernels, pixels; default
        3 and 5 at 240 image rows, scaled with the image height (limbs get thinner)
    """

    def __init__(self, backgrounds, var_threshold: float = 12.0, shadow_threshold: float = 0.75,
                 open_px: int | None = None, close_px: int | None = None):
        frames = [np.asarray(b) for b in backgrounds]
        if not frames:
            raise ValueError("BackgroundModel needs at least one background frame")
        self.shape = frames[0].shape
        self._mog = cv2.createBackgroundSubtractorMOG2(history=max(len(frames), 2),
                                                       varThreshold=var_threshold,
                                                       detectShadows=True)
        self._mog.setShadowThreshold(float(shadow_threshold))
        for f in frames:
            if f.shape != self.shape or f.dtype != np.uint8:
                raise ValueError(f"background frames must all be {self.shape} uint8, got "
                                 f"{f.shape} {f.dtype}")
            self._mog.apply(f, learningRate=-1)
        scale = self.shape[0] / 240.0
        open_px = open_px or max(1, 2 * int(round(1.5 * scale - 0.5)) + 1)   # 3 at 240 rows
        close_px = close_px or max(1, 2 * int(round(2.5 * scale - 0.5)) + 1)  # 5 at 240 rows
        self._open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (open_px, open_px))
        self._close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))

    def foreground(self, frame) -> np.ndarray:
        """(H, W) bool foreground mask of a (H, W, 3) uint8 BGR frame."""
        frame = np.asarray(frame)
        if frame.shape != self.shape:
            raise ValueError(f"frame is {frame.shape}, the background model {self.shape}")
        raw = self._mog.apply(frame, learningRate=0)
        fg = np.where(raw == 255, 255, 0).astype(np.uint8)  # 127 = shadow: background
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self._open)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self._close)
        return fg > 0


def iou(a, b) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union
