"""Background models: foreground masks from colour frames of a static camera.

Every model is trained on frames of the empty scene and then frozen (a subject standing still is
never absorbed into the background).

:class:`BackgroundModel` gives a cleaned-up boolean mask per frame, with one of two methods:

* ``"mog2"``: OpenCV's adaptive Gaussian mixture (``cv2.createBackgroundSubtractorMOG2``,
  Zivkovic 2004) with its own shadow detection (a pixel darker than the background by a factor
  within ``[mog2_shadow_tau, 1]`` and of the same chromaticity is a shadow), applied with
  learning rate 0. The multi-view tracker uses it on datasets without masks, the sensor
  simulator (:func:`gltrack.data.sim_multiview.mask_model`) to make a dataset's masks.
* ``"gaussian_yuv"``: one Gaussian per pixel and YUV channel (mean and variance over the
  training frames). A pixel is foreground when its normalised squared distance to the mean,
  ``sum_c (x_c - mu_c)^2 / (var_c + noise_var)``, exceeds ``threshold^2``, unless it is a shadow.

:class:`YuvBackground` (Caillette et al. 2008) gives the per-pixel squared Mahalanobis distance
instead of a mask, for the chi-square tests of colour voxel carving
(:mod:`gltrack.observe.colour_carve`).

Shadow test (``gaussian_yuv``)
------------------------------
A cast shadow dims the light on a surface: every RGB channel scales by roughly the same factor
``r < 1``. YUV is linear in RGB with U and V offset by 128, so then ``Y = r mu_Y`` and
``U - 128 = r (mu_U - 128)`` (same for V): the luminance drops and the chromaticity
``(U - 128, V - 128) / Y`` stays. A pixel is a shadow (background) when
``shadow_low <= Y / mu_Y <= shadow_high`` and ``|(U - 128) - r (mu_U - 128)|`` and the same for V
stay within ``shadow_chroma`` levels (plus 3 background standard deviations).

Clean-up (:func:`clean_mask`)
-----------------------------
A morphological opening (removes isolated noise pixels) with an elliptic kernel of
``morph_size`` pixels, then a closing (fills pin holes) with one of ``close_size`` pixels
(default ``morph_size``), then connected components smaller than ``min_area`` pixels are dropped.

YUV Gaussian with a shadow twin (:class:`YuvBackground`)
--------------------------------------------------------
Every pixel has a full Gaussian in YUV (mean and 3x3 covariance over the empty-scene frames, plus
``noise_var`` on the diagonal so a static training set or 8-bit quantisation does not give a
singular covariance). The covariance is full, not diagonal, because YUV channels of a real sensor
are correlated (Bayer demosaicing and the RGB->YUV mix put the same photon noise into all three);
with a diagonal model the d_M of plain noise is no longer chi-square with 3 dof, so the alpha of
colour carving's thresholds would no longer mean what it says.
A second "shadow" Gaussian has the mean's luminance lowered by ``shadow_drop`` (10 %) and the
same covariance. By default its chroma offsets ``U - 128`` and ``V - 128`` shrink by the same
factor: that is the same surface under 10 % less light (YUV is linear in RGB), identical to the
paper's Y-only shift for a grey surface, while on a saturated one (chroma offset 60 levels) a
Y-only shift leaves a 6-level chroma error, several noise standard deviations, and calls the
shadow foreground. ``shadow_chroma=False`` gives the literal Y-only shift.
Per pixel the model with the smaller distance is used. The paper selects "by a simple test on
the luminance channel"; the smaller distance is that test made exact: the difference of the two
squared distances is affine in the pixel, so the choice is one linear test, which for a diagonal
covariance and a Y-only shift is exactly "Y nearer the shadow mean". A plain
``Y < (1 - shadow_drop / 2) mu_Y`` test would, with the chroma shift or correlated noise, send
ordinary noise dips of 5 % in Y to the wrong Gaussian.
``d_M`` is the squared Mahalanobis distance, chi-square with 3 dof for a background pixel.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

log = logging.getLogger(__name__)

METHODS = ("mog2", "gaussian_yuv")


def check_bgr(img, where: str, shape=None) -> np.ndarray:
    """``img`` as a C-contiguous (H, W, 3) uint8 BGR array, or a ValueError naming ``where``.

    Parameters
    ----------
    img : array_like, the image to check
    where : str, what the image is, for messages
    shape : (H, W), optional, the size the image must have, pixels
    """
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise ValueError(f"{where}: expected a BGR image (H, W, 3) uint8, got {a.shape} {a.dtype}")
    if shape is not None and a.shape[:2] != tuple(shape):
        raise ValueError(f"{where}: image is {a.shape[1]}x{a.shape[0]}, expected "
                         f"{shape[1]}x{shape[0]}")
    return np.ascontiguousarray(a)


def bgr_to_yuv(img) -> np.ndarray:
    """(H, W, 3) float32 YUV (OpenCV ``COLOR_BGR2YUV``, 0..255) of a uint8 BGR image."""
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2YUV).astype(np.float32)


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
        Kernel size of the opening, and of the closing unless ``close_size`` is given (0 or 1:
        no morphology).
    close_size : int, pixels, optional
        Kernel size of the closing (default ``morph_size``).
    min_area : int, pixels
        Connected foreground components smaller than this are removed (0 or 1: none).
    mog2_shadow_tau : float
        ``mog2``: MOG2's shadow threshold: a pixel darker than the background by a factor
        within ``[tau, 1]`` and of the same chromaticity is a shadow (OpenCV's default 0.5).
    max_train_frames : int
        Training uses at most this many frames (a random subset when an rng is given to
        :meth:`fit`, evenly spaced otherwise).
    """

    def __init__(self, *, threshold: float = 4.0, noise_var: float = 9.0, shadows: bool = True,
                 shadow_low: float = 0.4, shadow_high: float = 0.95, shadow_chroma: float = 8.0,
                 morph_size: int = 3, close_size: int | None = None, min_area: int = 20,
                 mog2_shadow_tau: float = 0.5, max_train_frames: int = 100):
        if not threshold > 0 or not noise_var >= 0:
            raise ValueError("threshold must be positive and noise_var non-negative")
        if not 0 < shadow_low < shadow_high <= 1:
            raise ValueError(f"need 0 < shadow_low < shadow_high <= 1, got {shadow_low}, {shadow_high}")
        if not 0 < mog2_shadow_tau <= 1:
            raise ValueError(f"mog2_shadow_tau must be in (0, 1], got {mog2_shadow_tau}")
        self.threshold = float(threshold)
        self.noise_var = float(noise_var)
        self.shadows = bool(shadows)
        self.shadow_low, self.shadow_high = float(shadow_low), float(shadow_high)
        self.shadow_chroma = float(shadow_chroma)
        self.morph_size = int(morph_size)
        self.close_size = self.morph_size if close_size is None else int(close_size)
        self.min_area = int(min_area)
        self.mog2_shadow_tau = float(mog2_shadow_tau)
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
        shape = check_bgr(frames[0], "background frame 0").shape[:2]
        imgs = [check_bgr(f, f"background frame {i}", shape) for i, f in enumerate(frames)]
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
            self._mog.setShadowThreshold(self.mog2_shadow_tau)
            for img in imgs:
                self._mog.apply(img, learningRate=-1)
        else:
            yuv = np.stack([bgr_to_yuv(i) for i in imgs])
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
        img = check_bgr(frame, "frame", self.shape)
        if self.method == "mog2":
            out = self._mog.apply(img, learningRate=0)
            # 127 marks MOG2's shadows, 255 foreground
            return out == 255 if self.shadows else out > 0
        yuv = bgr_to_yuv(img)
        var = self._var + self.noise_var
        diff = yuv - self._mean
        fg = (diff * diff / var).sum(axis=2) > self.threshold ** 2
        if self.shadows:
            fg &= ~self._shadow(yuv, var)
        return fg

    def _shadow(self, yuv, var):
        return shadow_test(yuv, self._mean, var, self.shadow_low, self.shadow_high,
                           self.shadow_chroma)

    def foreground(self, frame) -> np.ndarray:
        """Foreground mask I_F of a frame.

        Parameters
        ----------
        frame : (H, W, 3) uint8 BGR, the size of the training frames

        Returns
        -------
        (H, W) bool, True = foreground
        """
        return clean_mask(self.raw_foreground(frame), self.morph_size, self.min_area,
                          self.close_size)


def shadow_test(yuv, mean, var, low: float = 0.4, high: float = 0.95,
                chroma: float = 8.0) -> np.ndarray:
    """Pixels that are the background in a cast shadow: dimmer, same chromaticity.

    Parameters
    ----------
    yuv : (H, W, 3) float, the frame in YUV (:func:`bgr_to_yuv`, 0..255)
    mean : (H, W, 3) float, the background in YUV
    var : (H, W, 3) float, (grey levels)^2, the background's variance per channel
    low, high : float, range of the luminance ratio ``Y / mean_Y`` of a shadow
    chroma : float, grey levels, allowed change of ``(U - 128, V - 128)`` beyond the ratio's
        scaling (plus 3 background standard deviations)

    Returns
    -------
    (H, W) bool, True = shadow (see the module docstring)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        r = yuv[..., 0] / mean[..., 0]
        darker = (r >= low) & (r <= high)
        tol = chroma + 3.0 * np.sqrt(var[..., 1:])
        dc = np.abs((yuv[..., 1:] - 128.0) - r[..., None] * (mean[..., 1:] - 128.0))
        return darker & np.all(dc <= tol, axis=2)


def clean_mask(mask, morph_size: int = 3, min_area: int = 20,
               close_size: int | None = None) -> np.ndarray:
    """Opening, closing and small-component removal of a binary mask.

    Parameters
    ----------
    mask : (H, W) bool
    morph_size : int, pixels, elliptic kernel size of the opening, and of the closing unless
        ``close_size`` is given (<= 1: skip that operation)
    min_area : int, pixels, smallest component kept (<= 1: keep all)
    close_size : int, pixels, optional, elliptic kernel size of the closing

    Returns
    -------
    (H, W) bool
    """
    m = np.asarray(mask).astype(np.uint8)
    close_size = morph_size if close_size is None else close_size
    for op, size in ((cv2.MORPH_OPEN, morph_size), (cv2.MORPH_CLOSE, close_size)):
        if size > 1:
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
            m = cv2.morphologyEx(m, op, k)
    if min_area > 1 and m.any():
        n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_area
        keep[0] = False
        m = keep[labels].astype(np.uint8)
    return m.astype(bool)


@dataclass
class YuvBackground:
    """Per-pixel Gaussian background model in YUV with a shadow twin (see the module docstring).

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
        # the quadratic form's six distinct entries as contiguous planes (off-diagonals doubled):
        # a three-operand einsum over (H, W, 3, 3) ran unoptimised loops, 2 ms per 320x240 view
        p = self.inv_cov
        self._planes = [np.ascontiguousarray(p[..., 0, 0]), np.ascontiguousarray(p[..., 1, 1]),
                        np.ascontiguousarray(p[..., 2, 2]),
                        np.ascontiguousarray(p[..., 0, 1] + p[..., 1, 0]),
                        np.ascontiguousarray(p[..., 0, 2] + p[..., 2, 0]),
                        np.ascontiguousarray(p[..., 1, 2] + p[..., 2, 1])]
        self._shadow_mean = None

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) image size in pixels."""
        return self.mean.shape[:2]

    @property
    def shadow_mean(self) -> np.ndarray:
        """(H, W, 3) float32, YUV mean of the shadow Gaussian (computed once)."""
        if self._shadow_mean is None:
            s = self.mean.copy()
            r = np.float32(1.0 - self.shadow_drop)
            s[..., 0] *= r
            if self.shadow_chroma:
                s[..., 1:] = 128.0 + r * (s[..., 1:] - 128.0)
            self._shadow_mean = s
        return self._shadow_mean

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
        shadow_chroma : bool, shrink the shadow mean's chroma offsets too (see the module docstring)

        Returns
        -------
        YuvBackground
        """
        frames = list(frames)
        if not frames:
            raise ValueError("YuvBackground.fit: at least one background frame is needed")
        if not noise_var > 0:
            raise ValueError(f"YuvBackground.fit: noise_var must be positive, got {noise_var}")
        shape = check_bgr(frames[0], "background frame 0").shape[:2]
        mean = np.zeros(shape + (3,), np.float64)
        second = np.zeros(shape + (3, 3), np.float64)
        # streamed sums keep memory at one frame however many frames a dataset has
        for i, f in enumerate(frames):
            y = bgr_to_yuv(check_bgr(f, f"background frame {i}", shape)).astype(np.float64)
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
        yuv = bgr_to_yuv(check_bgr(image, "image", self.shape))
        dm = self._mahalanobis(yuv, self.mean)
        if self.shadow_drop > 0:
            np.minimum(dm, self._mahalanobis(yuv, self.shadow_mean), out=dm)
        return dm

    def _mahalanobis(self, yuv, mu):
        d = yuv - mu
        x, y, z = (np.ascontiguousarray(d[..., i]) for i in range(3))
        a, b, c, ab, ac, bc = self._planes
        return x * (a * x + ab * y + ac * z) + y * (b * y + bc * z) + c * z * z
