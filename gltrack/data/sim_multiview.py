"""Colour camera sensor noise and the background subtraction that turns frames into masks.

Sensor model (:func:`sensor_image`), per frame and camera: a global gain ``1 + N(0, gain_sigma)``
and offset ``N(0, offset_sigma)`` grey levels per channel (auto-exposure and white-balance
flicker), then independent per-pixel Gaussian noise of ``pixel_sigma`` grey levels, rounding to
8 bits. Every term is multiplied by the noise level (:data:`gltrack.data.sim_depth.NOISE_LEVELS`).

Masks come from a real background-subtraction algorithm (:func:`mask_model`, a
:class:`gltrack.observe.background.BackgroundModel`): OpenCV's Gaussian-mixture subtractor
(MOG2, Zivkovic 2004) trained on empty-scene frames that carry the same sensor noise, applied
with a frozen model (learning rate 0, so a subject standing still is not absorbed into the
background), shadow pixels counted as background, then a morphological opening (speckle) and
closing (holes). The masks therefore have the errors trackers meet on real
data: holes where clothing matches the background, shadows at the feet, and any moving object
that is not the subject.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from gltrack.observe.background import BackgroundModel

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


def mask_model(backgrounds) -> BackgroundModel:
    """The simulator's background subtraction, fitted on a camera's empty-scene frames.

    MOG2 (:class:`gltrack.observe.background.BackgroundModel`, method ``"mog2"``) on all the
    frames, with a squared Mahalanobis distance of 12 for "matches the background" and a shadow
    threshold tau of 0.75: OpenCV's default 0.5 also swallows dark clothing in front of a light
    floor; 0.75 keeps the soft shadows of the simulated lighting out and the legs in. The
    opening and closing kernels are 3 and 5 pixels at 240 image rows, scaled with the image
    height (limbs get thinner); no small components are removed.

    Parameters
    ----------
    backgrounds : sequence of (H, W, 3) uint8 BGR empty-scene frames (at least 1)

    Returns
    -------
    BackgroundModel, fitted; ``.foreground(frame)`` gives (H, W) bool masks
    """
    frames = list(backgrounds)
    if not frames:
        raise ValueError("the simulator's background model needs at least one background frame")
    scale = np.asarray(frames[0]).shape[0] / 240.0
    open_px = max(1, 2 * int(round(1.5 * scale - 0.5)) + 1)   # 3 at 240 rows
    close_px = max(1, 2 * int(round(2.5 * scale - 0.5)) + 1)  # 5 at 240 rows
    model = BackgroundModel(threshold=math.sqrt(12.0), mog2_shadow_tau=0.75, morph_size=open_px,
                            close_size=close_px, min_area=0, max_train_frames=len(frames))
    return model.fit(frames, "mog2")


def iou(a, b) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union
