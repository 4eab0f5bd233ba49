"""Time-of-flight depth sensor noise (SwissRanger SR4000-like), applied to clean rendered depth.

The model, applied in this order to a clean depth image ``z`` (metres, 0 = no surface):

1. **Flying pixels.** A ToF pixel whose footprint straddles a depth discontinuity integrates
   light from both surfaces and reports a depth in between. Pixels whose 3x3 neighbourhood spans
   more than ``jump`` metres (:func:`depth_edges`) become, with probability
   ``level * flying_fraction``, ``z_fg + u (z_bg - z_fg)`` with ``u ~ U(0.1, 0.9)`` and
   ``z_fg``/``z_bg`` the nearest/farthest depth of the neighbourhood.
2. **Depth-dependent Gaussian noise**, ``sigma(z) = level * sigma_2m * (z / 2 m)^2``: 1 cm at
   2 m, 4 cm at 4 m for ``level = 1``. The returned optical power falls with ``z^2``, and the
   SR4000's range noise grows accordingly (its data sheet: about 1 cm at 2 m on a white target).
3. **Dropouts** (depth 0). The relative return amplitude is
   ``a = reflectivity * cos(incidence) / (z / 2 m)^2`` (1 for a white target facing the camera at
   2 m). A pixel is lost with probability ``level * (dropout_rate + max(0, 1 - a / min_amplitude))``
   (clipped to 1): a small random rate everywhere, certain loss for dark surfaces, grazing angles
   and far away. The incidence angle comes from the normals of the clean depth map.

Quantisation to 16-bit millimetres happens when the frame is written
(:meth:`gltrack.data.dataset.DatasetWriter.write_depth`). ``level = 0`` returns the clean depth
unchanged. Presets (:data:`NOISE_LEVELS`): ``none`` 0, ``default`` 1, ``heavy`` 2.5.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

log = logging.getLogger(__name__)

#: Multiplier of every noise effect per ``--noise`` name.
NOISE_LEVELS = {"none": 0.0, "default": 1.0, "heavy": 2.5}


class NoisePreset:
    """Mixin for noise-model dataclasses with a ``level`` field scaling every effect."""

    @classmethod
    def preset(cls, name: str):
        """The model for a ``--noise`` name: ``none``, ``default`` or ``heavy``."""
        if name not in NOISE_LEVELS:
            raise ValueError(f"unknown noise level {name!r}; choose one of "
                             f"{', '.join(NOISE_LEVELS)}")
        return replace(cls(), level=NOISE_LEVELS[name])


@dataclass(frozen=True)
class TofNoise(NoisePreset):
    """Parameters of the ToF noise model (see module docstring).

    Attributes
    ----------
    level : float, multiplier of every effect (0 = clean)
    sigma_2m : float, metres, Gaussian range noise at 2 m
    flying_fraction : float, probability that an edge pixel becomes a flying pixel
    jump : float, metres, neighbourhood depth span that counts as a discontinuity
    dropout_rate : float, probability of a random dropout anywhere
    min_amplitude : float, relative amplitude below which pixels start to drop out
    """

    level: float = 1.0
    sigma_2m: float = 0.01
    flying_fraction: float = 0.5
    jump: float = 0.1
    dropout_rate: float = 0.003
    min_amplitude: float = 0.03

    def sigma(self, z) -> np.ndarray:
        """Gaussian range noise standard deviation, metres, at depth ``z`` (metres)."""
        return self.level * self.sigma_2m * (np.asarray(z, dtype=np.float64) / 2.0) ** 2


def _neighbourhood_range(z):
    """3x3 nearest and farthest valid depth around each pixel (0 where none is valid)."""
    valid = z > 0
    near = ndimage.minimum_filter(np.where(valid, z, np.inf), size=3, mode="nearest")
    far = ndimage.maximum_filter(np.where(valid, z, -np.inf), size=3, mode="nearest")
    near[~np.isfinite(near)] = 0.0
    far[~np.isfinite(far)] = 0.0
    return near, far


def depth_edges(z, jump: float = 0.1) -> np.ndarray:
    """Pixels at depth discontinuities.

    Parameters
    ----------
    z : (H, W) float, metres, 0 = invalid (ignored)
    jump : float, metres

    Returns
    -------
    (H, W) bool: valid pixels whose 3x3 neighbourhood of valid depths spans more than ``jump``.
    """
    z = np.asarray(z, dtype=np.float64)
    near, far = _neighbourhood_range(z)
    return (z > 0) & (far - near > jump)


def _tangent(P, axis):
    """(H, W, 3) one-sided difference of points P along ``axis``, whichever side is smoother."""
    fwd = np.diff(P, axis=axis, append=np.take(P, [-1], axis=axis))
    bwd = np.diff(P, axis=axis, prepend=np.take(P, [0], axis=axis))
    # At the image border one side is zero: take the other one there.
    fz, bz = np.abs(fwd[..., 2]), np.abs(bwd[..., 2])
    f_ok = np.linalg.norm(fwd, axis=-1) > 0
    b_ok = np.linalg.norm(bwd, axis=-1) > 0
    use_fwd = f_ok & (~b_ok | (fz <= bz))
    return np.where(use_fwd[..., None], fwd, bwd)


def incidence_cosine(z, K) -> np.ndarray:
    """Cosine between the viewing ray and the surface normal, from a depth map.

    Parameters
    ----------
    z : (H, W) float, metres, 0 = invalid
    K : (3, 3) float, intrinsics, pixels

    Returns
    -------
    (H, W) float64 in [0, 1]; 0 where the depth or a neighbour is invalid.
    """
    z = np.asarray(z, dtype=np.float64)
    H, W = z.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    P = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    # One-sided differences towards the neighbour on the same surface (smaller depth step), so a
    # pixel next to a discontinuity gets its own surface's normal rather than a grazing one.
    du, dv = _tangent(P, axis=1), _tangent(P, axis=0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    ray = P / np.maximum(np.linalg.norm(P, axis=-1, keepdims=True), 1e-12)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.einsum("hwi,hwi->hw", n, ray)) / norm
    near, _ = _neighbourhood_range(z)
    return np.where((z > 0) & (near > 0) & np.isfinite(cos), np.clip(cos, 0.0, 1.0), 0.0)


def apply_tof_noise(z, reflectivity, K, rng: np.random.Generator, model: TofNoise | None = None):
    """Turn a clean depth render into a ToF-like measurement.

    Parameters
    ----------
    z : (H, W) float, metres, clean depth along the optical axis (0 = no surface)
    reflectivity : (H, W) float in [0, 1], relative NIR reflectivity of the surface at each pixel
    K : (3, 3) float, intrinsics, pixels
    rng : numpy.random.Generator
        The same number of values is drawn whatever the level, so one stream gives matching
        frames at every level.
    model : TofNoise, default ``TofNoise()``

    Returns
    -------
    depth : (H, W) float32, metres, 0 = invalid
    effects : dict of (H, W) bool
        ``"flying"`` (pixels mixed across a discontinuity) and ``"dropout"`` (pixels lost).
    """
    model = model or TofNoise()
    z = np.asarray(z, dtype=np.float64)
    refl = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64), z.shape)
    u_fly, u_mix, gauss, u_drop = (rng.random(z.shape), rng.uniform(0.1, 0.9, z.shape),
                                   rng.standard_normal(z.shape), rng.random(z.shape))
    valid = z > 0
    if model.level <= 0:
        none = np.zeros(z.shape, bool)
        return z.astype(np.float32), {"flying": none, "dropout": none.copy()}
    near, far = _neighbourhood_range(z)
    edges = valid & (far - near > model.jump)
    flying = edges & (u_fly < min(1.0, model.level * model.flying_fraction))
    out = np.where(flying, near + u_mix * (far - near), z)
    out = out + model.sigma(out) * gauss
    amp = refl * incidence_cosine(z, K) / np.maximum(z / 2.0, 1e-6) ** 2
    weak = np.clip(1.0 - amp / model.min_amplitude, 0.0, 1.0)
    p_drop = np.clip(model.level * (model.dropout_rate + weak), 0.0, 1.0)
    dropout = valid & (u_drop < p_drop)
    out = np.where(valid & ~dropout & (out > 0), out, 0.0)
    return out.astype(np.float32), {"flying": flying & ~dropout, "dropout": dropout}
