"""Hierarchical shape-from-silhouette voxel reconstruction (Caillette et al. 2008, sec. 6.1).

The tracking volume is cut into a coarse grid of cubic voxels. Each voxel is projected into every
camera and classified per camera from the foreground mask inside the pixel bounding box of its
eight projected corners (a summed-area table makes that one look-up per voxel and camera):

* ``background`` - no foreground pixel in the box;
* ``foreground`` - every pixel of the box (all of it inside the image) is foreground;
* ``edge``       - anything else, or a corner behind the camera.

A voxel is discarded when more than ``tolerance`` cameras say background, kept whole when the
others all say foreground, and split into its eight octants otherwise, down to ``max_depth``.
At the finest level an edge camera is resolved by the mask pixel under the voxel centre.
The cameras classify in turn, each only the voxels the ones before it left alive
(:func:`classify_level`), and the corners a level's voxels share are projected once
(:func:`block_boxes`); both leave the result as it would be without them.

The box of an octant lies inside its parent's box (a pinhole projection maps the convex cube onto
the convex hull of its corners), so an octant is never classified "more foreground" than its
parent: the coarse-to-fine result equals classifying every finest voxel directly
(:func:`carve_brute_force`), which the tests check. With lens distortion the containment is only
approximate; masks of undistorted images (``distort=False``) keep it exact.

The paper classifies robustly from pixel samples against a colour background model; here the
foreground masks are given (the dataset's ``camN_mask``), which is the same decision with the
segmentation done beforehand.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

BACKGROUND, EDGE, FOREGROUND = 0, 1, 2
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)


@dataclass
class Voxels:
    """A set of cubic voxels of mixed sizes.

    Attributes
    ----------
    ijk : (M, 3) int64, integer corner of each voxel in units of its own size
    level : (M,) int64, subdivision depth (0 = coarse grid)
    origin : (3,) float64, metres, world corner of the coarse grid
    size0 : float, metres, edge of a coarse voxel
    colour : (M, 3) float32 or None, mean BGR colour (0..255) over the cameras
    """

    ijk: np.ndarray
    level: np.ndarray
    origin: np.ndarray
    size0: float
    colour: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.level)

    @property
    def size(self) -> np.ndarray:
        """(M,) float64, metres, edge length of each voxel."""
        return self.size0 / (2.0 ** self.level)

    @property
    def centers(self) -> np.ndarray:
        """(M, 3) float64, metres, world centre of each voxel."""
        return self.origin + (self.ijk + 0.5) * self.size[:, None]

    @property
    def volumes(self) -> np.ndarray:
        """(M,) float64, cubic metres."""
        return self.size ** 3

    @property
    def volume(self) -> float:
        """Total reconstructed volume, cubic metres."""
        return float(self.volumes.sum())

    def at_level(self, level: int) -> np.ndarray:
        """(M', 3) int64 indices of every voxel of ``level`` covered (coarser ones expanded)."""
        out = []
        for lv in np.unique(self.level):
            if lv > level:
                raise ValueError(f"voxels of level {lv} are finer than {level}")
            f = 1 << int(level - lv)
            base = self.ijk[self.level == lv] * f
            off = np.stack(np.meshgrid(*[np.arange(f)] * 3, indexing="ij"), -1).reshape(-1, 3)
            out.append((base[:, None, :] + off[None]).reshape(-1, 3))
        return np.concatenate(out) if out else np.zeros((0, 3), np.int64)

    def points(self, max_size: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Voxel centres and volumes, big voxels split to at most ``max_size`` metres.

        Returns
        -------
        centres : (P, 3) float64, metres
        volumes : (P,) float64, cubic metres (summing to :attr:`volume`)
        """
        if max_size is None or len(self) == 0:
            return self.centers, self.volumes
        target = int(np.ceil(np.log2(max(self.size0 / max_size, 1.0)) - 1e-9))
        target = max(target, int(self.level.max()))
        keep = self.level >= target
        fine = Voxels(self.ijk[~keep], self.level[~keep], self.origin, self.size0)
        s = self.size0 / 2.0 ** target
        ijk = fine.at_level(target) if len(fine) else np.zeros((0, 3), np.int64)
        c = np.concatenate([self.centers[keep], self.origin + (ijk + 0.5) * s])
        v = np.concatenate([self.volumes[keep], np.full(len(ijk), s ** 3)])
        return c, v


class _MaskTable:
    """Summed-area table of one camera's foreground mask."""

    def __init__(self, camera, mask, distort):
        m = np.asarray(mask)
        if m.shape != (camera.height, camera.width):
            raise ValueError(f"mask for camera {camera.name} must be ({camera.height}, "
                             f"{camera.width}), got {m.shape}")
        self.cam, self.mask, self.distort = camera, m.astype(bool), distort
        self.sat = np.zeros((m.shape[0] + 1, m.shape[1] + 1), np.int64)
        self.sat[1:, 1:] = np.cumsum(np.cumsum(self.mask, axis=0), axis=1)

    def classify(self, lo, size):
        """(M,) states of voxels with world corner ``lo`` (M, 3) and edge ``size`` (M,)."""
        return self.classify_boxes(*pixel_boxes(self.cam, lo, size, self.distort))

    def classify_boxes(self, front, lo_px, hi_px):
        """(M,) states of voxels from their pixel boxes (:func:`pixel_boxes`)."""
        area = (hi_px[:, 0] - lo_px[:, 0]) * (hi_px[:, 1] - lo_px[:, 1])
        W, H = self.cam.width, self.cam.height
        c0 = np.clip(lo_px[:, 0], 0, W)
        c1 = np.clip(hi_px[:, 0], 0, W)
        r0 = np.clip(lo_px[:, 1], 0, H)
        r1 = np.clip(hi_px[:, 1], 0, H)
        c1, r1 = np.maximum(c1, c0), np.maximum(r1, r0)
        s = self.sat
        count = s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]
        state = np.full(len(front), EDGE, np.int8)
        state[front & (count == 0)] = BACKGROUND
        state[front & (count == area)] = FOREGROUND
        return state

    def centre_state(self, centres):
        """(M,) FOREGROUND/BACKGROUND of the mask pixel under each centre (M, 3)."""
        ok, px = centre_pixels(self.cam, centres, self.distort)
        fg = np.zeros(len(centres), bool)
        fg[ok] = self.mask[px[ok, 1], px[ok, 0]]
        return np.where(fg, FOREGROUND, BACKGROUND).astype(np.int8)


def pixel_boxes(camera, lo, size, distort: bool):
    """Pixel bounding boxes of voxels projected into ``camera``.

    Parameters
    ----------
    camera : gltrack.camera.Camera
    lo : (M, 3) float, world corner of each voxel, metres
    size : (M,) float, edge of each voxel, metres
    distort : bool, project with the lens distortion

    Returns
    -------
    front : (M,) bool, every corner in front of the camera with a finite projection
    lo_px, hi_px : (M, 2) int64, first and one-past-last pixel column / row of the box (zeros
        where not ``front``); pixel i spans [i - 0.5, i + 0.5), so the box holds every pixel
        the projected corners' hull touches. Not clipped to the image.
    """
    M = len(lo)
    corners = lo[:, None, :] + size[:, None, None] * _CORNERS[None]
    z = camera.depth_of(corners)
    uv = camera.project(corners.reshape(-1, 3), distort=distort).reshape(M, 8, 2)
    # numpy reduces a length-8 middle axis slowly; pairwise minimum/maximum is ~5x faster and
    # propagates NaN, so the finiteness test below covers every corner
    uv_lo, uv_hi, z_lo = uv[:, 0].copy(), uv[:, 0].copy(), z[:, 0].copy()
    for i in range(1, 8):
        np.minimum(uv_lo, uv[:, i], out=uv_lo)
        np.maximum(uv_hi, uv[:, i], out=uv_hi)
        np.minimum(z_lo, z[:, i], out=z_lo)
    return _boxes(uv_lo, uv_hi, z_lo)


def block_boxes(camera, origin, size: float, blocks, extent, distort: bool):
    """:func:`pixel_boxes` of the voxels of whole blocks, each corner projected once.

    A block is ``extent`` voxels of edge ``size`` along each axis from the lattice point
    ``blocks[b]`` (the coarse grid is one block, the octants of each split voxel one block of
    2 x 2 x 2); its voxels share the corners of a lattice of ``extent + 1`` points per axis, so
    27 points are projected for 8 octants instead of 64, and each voxel's box is the minimum
    and maximum over its 2 x 2 x 2 lattice neighbourhood, taken one axis at a time.

    Parameters
    ----------
    camera : gltrack.camera.Camera
    origin : (3,) float, world position of lattice point 0, metres
    size : float, voxel edge, metres
    blocks : (B, 3) int, lattice coordinates of each block's first corner
    extent : (3,) int, voxels per block along each axis
    distort : bool, project with the lens distortion

    Returns
    -------
    front, lo_px, hi_px : as :func:`pixel_boxes`, for the B * prod(extent) voxels in the
        order block by block, each block's voxels in C order (the last axis fastest), i.e.
        voxel ``blocks[b] + (i, j, k)``.
    """
    e = np.asarray(extent, dtype=np.int64)
    B = len(blocks)
    q = np.stack(np.meshgrid(*[np.arange(n + 1) for n in e], indexing="ij"), -1).reshape(-1, 3)
    pts = np.asarray(origin, np.float64) + (np.asarray(blocks)[:, None, :] + q[None]) * size
    shape = (B, *(e + 1))
    z = camera.depth_of(pts).reshape(shape)
    uv = camera.project(pts.reshape(-1, 3), distort=distort).reshape(*shape, 2)
    lo, hi = uv, uv
    for axis in (1, 2, 3):  # minimum / maximum over neighbouring lattice points, per axis
        a, b = (slice(None),) * axis + (slice(None, -1),), (slice(None),) * axis + (slice(1, None),)
        lo, hi = np.minimum(lo[a], lo[b]), np.maximum(hi[a], hi[b])
        z = np.minimum(z[a], z[b])
    return _boxes(lo.reshape(-1, 2), hi.reshape(-1, 2), z.reshape(-1))


def _boxes(uv_lo, uv_hi, z_lo):
    """front, lo_px, hi_px of :func:`pixel_boxes` from each voxel's projected corners' extremes
    (M, 2) and nearest depth (M,) (NaN, from a corner with no projection, makes it not front)."""
    front = (z_lo > 1e-6) & np.isfinite(uv_lo).all(axis=1) & np.isfinite(uv_hi).all(axis=1)
    lo_px = np.floor(np.where(front[:, None], uv_lo, 0.0) + 0.5).astype(np.int64)
    hi_px = np.floor(np.where(front[:, None], uv_hi, 0.0) + 0.5).astype(np.int64) + 1
    return front, lo_px, hi_px


def centre_pixels(camera, centres, distort: bool):
    """The pixel under each point (M, 3): ``ok`` (M,) bool (in front and inside the image) and
    ``px`` (M, 2) int64 column, row (meaningless where not ``ok``)."""
    z = camera.depth_of(centres)
    uv = camera.project(centres, distort=distort)
    ok = (z > 1e-6) & np.all(np.isfinite(uv), axis=1)
    px = np.floor(np.where(ok[:, None], uv, -1.0) + 0.5).astype(np.int64)
    ok &= (px[:, 0] >= 0) & (px[:, 0] < camera.width)
    ok &= (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    return ok, px


def _grid(bounds, base):
    b = np.asarray(bounds, dtype=np.float64).reshape(-1)
    if b.shape != (6,) or not np.all(np.isfinite(b)) or np.any(b[3:] <= b[:3]):
        raise ValueError(f"bounds must be (xmin, ymin, zmin, xmax, ymax, zmax) with max > min, "
                         f"got {bounds}")
    if int(base) < 1:
        raise ValueError(f"base must be >= 1, got {base}")
    ext = b[3:] - b[:3]
    size0 = float(ext.max() / int(base))
    n = np.maximum(np.ceil(ext / size0 - 1e-9).astype(np.int64), 1)
    ijk = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3)
    return b[:3].copy(), size0, ijk


#: Share of a level's voxels still alive above which a camera projects the whole lattice of
#: blocks (:func:`block_boxes`, 27 points for 8 octants) rather than the eight corners of each
#: live voxel (:func:`pixel_boxes`): 27 / 64.
LATTICE_SHARE = 27 / 64


def classify_level(views, origin, size: float, ijk, blocks, extent, tolerance: int,
                   distort: bool, classify):
    """Classify one level's voxels camera by camera, each camera only the voxels the cameras
    before it left alive.

    A voxel that more than ``tolerance`` cameras call background is dropped whatever the
    others say, so a camera need not look at it: on the coarse grid, where nine voxels in ten
    are empty space, the first camera alone drops most of them. The result is the same as
    classifying every voxel in every camera; a camera that did not look at a voxel records
    it as background.

    Parameters
    ----------
    views : sequence of C objects with a ``cam`` (gltrack.camera.Camera)
    origin, size, blocks, extent : the level's lattice, as :func:`block_boxes`
    ijk : (M, 3) int, the level's voxels in the order of :func:`block_boxes`
    tolerance : int, background cameras a voxel survives
    distort : bool, project with the lens distortion
    classify : callable ``(view, front, lo_px, hi_px) -> tuple``, the first element the
        (m,) int8 states of the m voxels given (:data:`BACKGROUND`, :data:`EDGE`,
        :data:`FOREGROUND`), the others per-voxel arrays (m, ...) or None

    Returns
    -------
    states : (C, M) int8
    looked : list of C (m_c,) int64, the voxels each camera classified
    outputs : list of C tuples, ``classify``'s outputs for those voxels
    """
    M = len(ijk)
    states = np.full((len(views), M), BACKGROUND, np.int8)
    n_bg = np.zeros(M, np.int64)
    looked, outputs = [], []
    for c, view in enumerate(views):
        idx = np.nonzero(n_bg <= tolerance)[0]
        if len(idx) > LATTICE_SHARE * M:
            boxes = block_boxes(view.cam, origin, size, blocks, extent, distort)
            boxes = boxes if len(idx) == M else tuple(b[idx] for b in boxes)
        else:
            boxes = pixel_boxes(view.cam, origin + ijk[idx] * size, np.full(len(idx), size),
                                distort)
        out = classify(view, *boxes)
        states[c, idx] = out[0]
        n_bg[idx] += out[0] == BACKGROUND
        looked.append(idx)
        outputs.append(out)
    return states, looked, outputs


def _first_block(ijk):
    """The coarse grid ``ijk`` of :func:`_grid` as one block of :func:`block_boxes`."""
    return np.zeros((1, 3), np.int64), ijk.max(axis=0) + 1


def _octants(ijk):
    """The octants of voxels ``ijk`` (M, 3), one level finer: (8M, 3) in the order of
    :func:`block_boxes`, and their blocks (M, 3) and extent (3,)."""
    return ((2 * ijk[:, None, :] + _CORNERS.astype(np.int64)[None]).reshape(-1, 3), 2 * ijk,
            np.full(3, 2, np.int64))


def _decide(states, tolerance, final, tables, centres):
    """Keep / split / drop per voxel from its (C, M) per-camera states."""
    if final:
        for c, t in enumerate(tables):
            edge = states[c] == EDGE
            if np.any(edge):
                states[c, edge] = t.centre_state(centres[edge])
    n_bg = np.sum(states == BACKGROUND, axis=0)
    n_edge = np.sum(states == EDGE, axis=0)
    alive = n_bg <= tolerance
    return alive & (n_edge == 0), alive & (n_edge > 0)


def _check_inputs(cameras, masks, tolerance, max_depth):
    if len(cameras) != len(masks) or not cameras:
        raise ValueError(f"need one mask per camera, got {len(masks)} masks for "
                         f"{len(cameras)} cameras")
    if not 0 <= int(tolerance) < len(cameras):
        raise ValueError(f"tolerance must be in [0, {len(cameras) - 1}], got {tolerance}")
    if not 0 <= int(max_depth) <= 8:
        raise ValueError(f"max_depth must be in 0..8, got {max_depth}")


def carve(cameras, masks, bounds, *, base: int = 16, max_depth: int = 3, tolerance: int = 0,
          distort: bool = True, images=None) -> Voxels:
    """Coarse-to-fine visual hull of the foreground masks.

    Parameters
    ----------
    cameras : list of gltrack.camera.Camera, C of them
    masks : list of (H, W) bool, foreground of each camera (its own resolution)
    bounds : (6,) float, metres, tracking volume ``(xmin, ymin, zmin, xmax, ymax, zmax)``
    base : int, coarse voxels along the longest side of ``bounds`` (the paper's 16)
    max_depth : int, subdivision levels below the coarse grid; the finest voxel edge is
        ``longest side / (base * 2**max_depth)``
    tolerance : int, a voxel survives up to this many "background" cameras (occlusion by
        scenery, a bad mask)
    distort : bool, project with the lens distortion (masks of the raw images); False for
        masks of undistorted images
    images : list of (H, W, 3) uint8 or None, colour images for per-voxel colours

    Returns
    -------
    Voxels (with ``colour`` when ``images`` is given). ``carve.last_stats`` holds the number of
    voxel-camera classifications made, for comparison with :func:`carve_brute_force`.
    """
    _check_inputs(cameras, masks, tolerance, max_depth)
    tables = [_MaskTable(c, m, distort) for c, m in zip(cameras, masks)]
    origin, size0, ijk = _grid(bounds, base)
    blocks, extent = _first_block(ijk)
    kept_ijk, kept_lv = [], []
    tests = 0
    for level in range(int(max_depth) + 1):
        if len(ijk) == 0:
            break
        size = size0 / 2.0 ** level
        states, looked, _ = classify_level(
            tables, origin, size, ijk, blocks, extent, tolerance, distort,
            lambda t, *boxes: (t.classify_boxes(*boxes),))
        tests += sum(len(i) for i in looked)
        keep, split = _decide(states, tolerance, level == max_depth, tables,
                              origin + ijk * size + 0.5 * size)
        kept_ijk.append(ijk[keep])
        kept_lv.append(np.full(int(keep.sum()), level, np.int64))
        ijk, blocks, extent = _octants(ijk[split])
    carve.last_stats = {"classifications": int(tests)}
    vox = Voxels(np.concatenate(kept_ijk) if kept_ijk else np.zeros((0, 3), np.int64),
                 np.concatenate(kept_lv) if kept_lv else np.zeros(0, np.int64), origin, size0)
    if images is not None:
        vox.colour = voxel_colours(vox, cameras, images, distort=distort)
    log.debug("carved %d voxels, %.4f m^3, %d classifications", len(vox), vox.volume, tests)
    return vox


carve.last_stats = {}


def carve_brute_force(cameras, masks, bounds, *, base: int = 16, max_depth: int = 3,
                      tolerance: int = 0, distort: bool = True) -> Voxels:
    """Classify every finest-level voxel directly (the oracle of :func:`carve`; slow)."""
    _check_inputs(cameras, masks, tolerance, max_depth)
    tables = [_MaskTable(c, m, distort) for c, m in zip(cameras, masks)]
    origin, size0, ijk = _grid(bounds, base)
    f = 1 << int(max_depth)
    off = np.stack(np.meshgrid(*[np.arange(f)] * 3, indexing="ij"), -1).reshape(-1, 3)
    ijk = (ijk[:, None, :] * f + off[None]).reshape(-1, 3)
    size = size0 / f
    lo = origin + ijk * size
    states = np.stack([t.classify(lo, np.full(len(ijk), size)) for t in tables])
    keep, _ = _decide(states, tolerance, True, tables, lo + 0.5 * size)
    return Voxels(ijk[keep], np.full(int(keep.sum()), int(max_depth), np.int64), origin, size0)


def voxel_colours(voxels: Voxels, cameras, images, *, distort: bool = True) -> np.ndarray:
    """(M, 3) float32 mean BGR colour of the pixels under each voxel centre over the cameras
    that see the centre inside their image (occlusion is not modelled)."""
    return point_colours(voxels.centers, cameras, images, distort=distort)


def point_colours(points, cameras, images, *, distort: bool = True) -> np.ndarray:
    """(M, 3) float32 mean BGR colour (0..255) of the pixels under points (M, 3), metres, over
    the cameras that see each point inside their image (occlusion is not modelled)."""
    if len(images) != len(cameras):
        raise ValueError(f"need one image per camera, got {len(images)} for {len(cameras)}")
    c = np.asarray(points, dtype=np.float64)
    acc = np.zeros((len(c), 3))
    n = np.zeros(len(c))
    for cam, img in zip(cameras, images):
        img = np.asarray(img)
        if img.shape != (cam.height, cam.width, 3):
            raise ValueError(f"image for camera {cam.name} must be ({cam.height}, {cam.width}, 3),"
                             f" got {img.shape}")
        ok, px = centre_pixels(cam, c, distort)
        acc[ok] += img[px[ok, 1], px[ok, 0]]
        n[ok] += 1
    return (acc / np.maximum(n, 1)[:, None]).astype(np.float32)
