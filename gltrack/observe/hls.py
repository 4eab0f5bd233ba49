"""Bandouch's colour quantisation: HLS voxels and their per-channel bitmasks (sec. 3.3).

Colour space
------------
OpenCV's ``COLOR_BGR2HLS_FULL`` on 8-bit images: hue, lightness and saturation each in 0..255
(hue covers the full circle, 256 steps). Each channel is cut into 32 equal bins (``value >> 3``),
giving 32 x 32 x 32 = 32768 voxels. A voxel's index is ``(h << 10) | (l << 5) | s``.

Observed bitmasks
-----------------
An observed colour in voxel ``(h, l, s)`` is represented by three 32-bit masks
``(1 << h, 1 << l, 1 << s)``. A colour matches a colour cluster (three masks of allowed bins)
when all three ANDs are non-zero. Hue and saturation lose their meaning for very dark and very
bright colours, and hue also for unsaturated (grey) colours; a channel without meaning is given
all 32 bits so it matches any cluster. The thresholds, in bins (one bin = 8 of 256 levels):

* ``l < L_DARK = 3``   (L < 24, below ~9 % lightness): hue and saturation masked out;
* ``l >= L_BRIGHT = 29`` (L >= 232, above ~91 % lightness): hue and saturation masked out;
* ``s < S_GREY = 3``   (S < 24, below ~9 % saturation): hue masked out.

OpenCV's HLS saturation divides the chroma by ``1 - |2L - 1|``, so near black and white it
amplifies sensor noise into full saturation: that is why saturation is dropped there too.

OpenCV converts the SIMD-sized part of a row and its scalar tail with different rounding (pure
red gets L = 128 in a wide image but 127 as a single pixel), so convert whole images, never single
pixels, wherever results must agree.

All of this is precomputed once into :data:`HLS_BITS_LUT`, a (32768, 3) uint32 table indexed by
the voxel index; :func:`observed_bits` is then one colour conversion and one table gather.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

log = logging.getLogger(__name__)

#: Bins per channel.
BINS = 32
#: Voxels in the quantised colour space.
N_VOXELS = BINS ** 3
#: A mask with every bin set ("this channel carries no information").
ALL_BITS = np.uint32(0xFFFFFFFF)
#: Lightness bin below which hue and saturation are meaningless.
L_DARK = 3
#: Lightness bin from which on hue and saturation are meaningless.
L_BRIGHT = 29
#: Saturation bin below which hue is meaningless.
S_GREY = 3


def significance(l_bin, s_bin, *, l_dark: int = L_DARK, l_bright: int = L_BRIGHT,
                 s_grey: int = S_GREY) -> tuple[np.ndarray, np.ndarray]:
    """Which channels of colours carry information.

    Parameters
    ----------
    l_bin, s_bin : array_like of int, lightness and saturation bins (0..31), same shape
    l_dark, l_bright, s_grey : int, thresholds in bins (see the module docstring)

    Returns
    -------
    hue_ok, sat_ok : bool arrays of the input shape
    """
    l_bin = np.asarray(l_bin)
    s_bin = np.asarray(s_bin)
    sat_ok = (l_bin >= l_dark) & (l_bin < l_bright)
    hue_ok = sat_ok & (s_bin >= s_grey)
    return hue_ok, sat_ok


def make_bits_lut(*, l_dark: int = L_DARK, l_bright: int = L_BRIGHT,
                  s_grey: int = S_GREY) -> np.ndarray:
    """The voxel -> observed-bitmask table.

    Parameters
    ----------
    l_dark, l_bright, s_grey : int, thresholds in bins (see the module docstring)

    Returns
    -------
    (32768, 3) uint32, row ``(h << 10) | (l << 5) | s`` holds the hue, lightness and saturation
    masks of a colour in that voxel.
    """
    for name, v in (("l_dark", l_dark), ("l_bright", l_bright), ("s_grey", s_grey)):
        if not 0 <= v <= BINS:
            raise ValueError(f"{name} must be a bin in 0..{BINS}, got {v}")
    idx = np.arange(N_VOXELS, dtype=np.uint32)
    h, l, s = idx >> 10, (idx >> 5) & 31, idx & 31
    hue_ok, sat_ok = significance(l, s, l_dark=l_dark, l_bright=l_bright, s_grey=s_grey)
    one = np.uint32(1)
    lut = np.empty((N_VOXELS, 3), np.uint32)
    lut[:, 0] = np.where(hue_ok, one << h, ALL_BITS)
    lut[:, 1] = one << l
    lut[:, 2] = np.where(sat_ok, one << s, ALL_BITS)
    lut.flags.writeable = False
    return lut


#: The default table (thresholds of the module docstring).
HLS_BITS_LUT = make_bits_lut()


def _check_bgr(bgr) -> np.ndarray:
    img = np.asarray(bgr)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"expected a BGR image (H, W, 3) uint8, got {img.shape} {img.dtype}")
    return img


def hls_bins(bgr) -> np.ndarray:
    """Per-pixel HLS bins.

    Parameters
    ----------
    bgr : (H, W, 3) uint8, BGR colour image

    Returns
    -------
    (H, W, 3) uint8, hue, lightness, saturation bins in 0..31
    """
    img = _check_bgr(bgr)
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2HLS_FULL) >> 3


def voxel_index(bgr) -> np.ndarray:
    """Per-pixel voxel index ``(h << 10) | (l << 5) | s``.

    Parameters
    ----------
    bgr : (H, W, 3) uint8, BGR colour image

    Returns
    -------
    (H, W) uint16 in 0..32767
    """
    b = hls_bins(bgr).astype(np.uint16)
    return (b[..., 0] << 10) | (b[..., 1] << 5) | b[..., 2]


def observed_bits(bgr, lut: np.ndarray | None = None) -> np.ndarray:
    """Observed HLS bitmasks of every pixel (the engine's ``obs_bits``).

    Parameters
    ----------
    bgr : (H, W, 3) uint8, BGR colour image (undistorted, at the camera's resolution)
    lut : (32768, 3) uint32, optional; :data:`HLS_BITS_LUT` by default

    Returns
    -------
    (H, W, 3) uint32, hue / lightness / saturation masks
    """
    table = HLS_BITS_LUT if lut is None else np.asarray(lut)
    if table.shape != (N_VOXELS, 3) or table.dtype != np.uint32:
        raise ValueError(f"lut must be ({N_VOXELS}, 3) uint32, got {table.shape} {table.dtype}")
    return table[voxel_index(bgr)]


def bins_to_mask(bins) -> np.uint32:
    """A uint32 mask with the given bins (iterable of ints in 0..31) set."""
    m = 0
    for b in bins:
        m |= 1 << int(b)
    return np.uint32(m)
