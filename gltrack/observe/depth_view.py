"""The depth camera as the depth trackers see it: frames, crop window and the GPU depth cost.

* :class:`DepthObservation` reads, undistorts and background-subtracts a dataset's depth frames;
* :func:`crop_camera` / :func:`resample_depth` build the square window around the predicted body
  that the engine scores (Ganapathi's 128x128 crop) and resample the observation into it;
* :class:`DepthLikelihood` owns the scoring engine and turns N poses into N depth costs in
  units of a surface area (``area_unit``), so the cost's balance against a motion prior does not
  change with tile size, crop or distance.
"""
from __future__ import annotations

import logging

import numpy as np

from gltrack.camera import Camera
from gltrack.render.engine import DepthCostParams, ScoringEngine

from .depth import depth_tolerance, foreground_points, remove_background

log = logging.getLogger(__name__)


class DepthObservation:
    """Reads, undistorts and background-subtracts the depth frames of a dataset's depth camera.

    Parameters
    ----------
    dataset : gltrack.data.dataset.Dataset with a depth camera
    bg_tolerance : float, metres, background-removal margin when an empty-scene frame exists
    bg_sigmas : float, the margin grows by this many range-noise deviations (0 = fixed margin)
    range_noise_2m : float, metres, the sensor's range-noise deviation at 2 m
    """

    def __init__(self, dataset, *, bg_tolerance: float = 0.08, bg_sigmas: float = 3.0,
                 range_noise_2m: float = 0.01):
        cams = [i for i, c in enumerate(dataset.cameras) if c.kind == "depth"]
        if not cams:
            raise ValueError(f"{dataset.path}: the depth tracker needs a depth camera")
        self.dataset, self.index = dataset, cams[0]
        self.camera = dataset.cameras[self.index]
        self.pinhole = self.camera.undistorted()
        self.distorted = bool(np.any(self.camera.dist != 0))
        bg = dataset.background(self.index)
        self.background = self._undistort(bg) if bg is not None else None
        self.tolerance = bg_tolerance
        if self.background is not None and bg_sigmas > 0:
            self.tolerance = depth_tolerance(self.background, bg_tolerance, bg_sigmas,
                                             range_noise_2m)
        if self.background is None:
            log.warning("%s: no empty-scene depth frame; only far pixels are removed", dataset.path)

    def _undistort(self, z):
        import cv2

        return self.camera.undistort_image(z, cv2.INTER_NEAREST) if self.distorted else z

    def __call__(self, frame: int) -> np.ndarray:
        """(H, W) float32 metres, the undistorted foreground of ``frame`` (0 elsewhere)."""
        z = self._undistort(self.dataset.depth(frame, self.index))
        return remove_background(z, self.background, tolerance=self.tolerance)


def crop_camera(pinhole: Camera, points, tile: int, margin: float) -> tuple[Camera, float]:
    """A square ``tile x tile`` camera looking at ``points`` through ``pinhole``'s sensor.

    Parameters
    ----------
    pinhole : Camera, undistorted sensor camera
    points : (P, 3) float, metres, world points to frame (e.g. the predicted joints)
    tile : int, pixels
    margin : float, metres added on every side at the points' median depth

    Returns
    -------
    camera : Camera, same pose as ``pinhole``, ``tile x tile`` pixels of equal metric size; the
        window is shifted to stay inside the sensor's field of view when it fits
    depth : float, metres, median camera depth of ``points``
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ pinhole.R.T + pinhole.t
    P = P[P[:, 2] > 0.1]
    if len(P) == 0:
        raise ValueError("crop_camera: no point in front of the camera")
    zc = float(np.median(P[:, 2]))
    a, b = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    m = margin / zc
    lo_a, hi_a = (-0.5 - pinhole.cx) / pinhole.fx, (pinhole.width - 0.5 - pinhole.cx) / pinhole.fx
    lo_b, hi_b = (-0.5 - pinhole.cy) / pinhole.fy, (pinhole.height - 0.5 - pinhole.cy) / pinhole.fy
    side = min(max(a.max() - a.min(), b.max() - b.min()) + 2 * m, max(hi_a - lo_a, hi_b - lo_b))

    def place(lo, hi, c):
        # keep the window inside the sensor where possible: model pixels outside it would be
        # charged for surface the sensor cannot see
        start = c - side / 2
        if side <= hi - lo:
            start = min(max(start, lo), hi - side)
        else:
            start = 0.5 * (lo + hi) - side / 2
        return start

    a0 = place(lo_a, hi_a, 0.5 * (a.min() + a.max()))
    b0 = place(lo_b, hi_b, 0.5 * (b.min() + b.max()))
    f = tile / side
    K = np.array([[f, 0, -a0 * f - 0.5], [0, f, -b0 * f - 0.5], [0, 0, 1]])
    return Camera(pinhole.name, pinhole.kind, tile, tile, K, np.zeros(5), pinhole.R, pinhole.t), zc


def resample_depth(z, source: Camera, target: Camera) -> np.ndarray:
    """Nearest-neighbour resampling of a depth image between two cameras with the same pose.

    Pixel centres are mapped exactly (``cv2.resize``'s nearest neighbour is off by up to a
    source pixel when shrinking); target pixels outside the source image are 0 (unobserved).

    Parameters
    ----------
    z : (H, W) float, metres, at ``source``'s resolution
    source, target : Camera, undistorted, same R and t

    Returns
    -------
    (target.height, target.width) float32, metres
    """
    z = np.asarray(z, dtype=np.float32)
    u = np.rint(source.cx + source.fx * (np.arange(target.width) - target.cx) / target.fx).astype(int)
    v = np.rint(source.cy + source.fy * (np.arange(target.height) - target.cy) / target.fy).astype(int)
    ok_u = (u >= 0) & (u < z.shape[1])
    ok_v = (v >= 0) & (v < z.shape[0])
    out = z[np.clip(v, 0, z.shape[0] - 1)[:, None], np.clip(u, 0, z.shape[1] - 1)[None, :]]
    return np.where(ok_v[:, None] & ok_u[None, :], out, 0).astype(np.float32)


class DepthLikelihood:
    """The engine's depth cost of N poses against one depth image, per unit of surface area.

    Parameters
    ----------
    ctx : moderngl.Context
    body : gltrack.body.model.BodyModel
    pinhole : Camera, the undistorted sensor camera
    tile : int, tile side in pixels (the observation is resampled to it)
    params : DepthCostParams, the smoothstep sensor model
    crop : bool, score a square window around the body instead of the whole sensor image
    area_unit : float, m^2; costs are in units of this area at the subject's depth (0 = raw
        tile-pixel sums)
    programs : gltrack.gl.programs.ProgramCache, shared compiled programs

    Attributes
    ----------
    engine : ScoringEngine or None (built on the first :meth:`set_view` when cropping)
    view : Camera, the camera the tile shows
    weight : float, tile-pixel area at the subject's depth over ``area_unit``
    area : float, the observed foreground of the uploaded view in cost units (its pixels times
        ``weight``): a cost over ``area`` is the share of the seen person the pose leaves
        unexplained (plus the model's pixels where nothing was seen)
    """

    def __init__(self, ctx, body, pinhole: Camera, *, tile: int, params: DepthCostParams,
                 crop: bool, area_unit: float, programs):
        self.ctx, self.body, self.pinhole = ctx, body, pinhole
        self.tile, self.params, self.crop, self.area_unit = tile, params, crop, area_unit
        self.programs = programs
        self.engine = None
        self.view = None
        self.weight, self.area = 1.0, 0.0
        if not crop:
            self._make_engine(pinhole)

    def _make_engine(self, camera):
        if self.engine is not None:
            self.engine.release()
        self.engine = ScoringEngine(self.ctx, self.body.mesh, self.body.skeleton.n_joints, [camera],
                                    tile=self.tile, depth_params=self.params,
                                    programs=self.programs)
        self.engine.set_kinematics(self.body.kin)
        self.view = camera

    def set_view(self, z, points, margin: float) -> None:
        """Upload the depth image ``z`` (H, W) metres, framed around ``points`` (P, 3) metres
        (None: the image's own foreground) when cropping; sets the area weight."""
        pin = self.pinhole
        if self.crop:
            if points is None:
                points = foreground_points(z, pin)
                if len(points) == 0:
                    points = pin.center[None] + pin.R[2] * 3.0  # nothing seen: look 3 m ahead
            cam, zc = crop_camera(pin, points, self.tile, margin)
            if self.engine is None:
                self._make_engine(cam)
            else:  # keeps the compiled programs and buffers: only the window moves
                self.engine.set_camera(0, cam)
                self.view = cam
            zt = resample_depth(z, pin, cam)
            self.engine.set_depth(0, zt)
        else:
            zt = z
            self.engine.set_depth(0, z)
            cam = self.engine.views[0].cam_tile
            zc = float(np.median((points @ pin.R.T + pin.t)[:, 2])) if points is not None else 3.0
        a_px = zc * zc / (cam.fx * cam.fy)
        self.weight = a_px / self.area_unit if self.area_unit > 0 else 1.0
        # the seen person's area in cost units: a pixel costs at most 1 (c_obs_only, c_model_only)
        # (the tile's pixels: the full image is scaled to the tile when not cropping)
        tile_px = cam.width * cam.height / float(zt.shape[0] * zt.shape[1])
        self.area = float(np.count_nonzero(zt > 0)) * tile_px * self.weight

    def cost(self, X: np.ndarray) -> np.ndarray:
        """(N,) depth cost of N poses (N, D) against the uploaded view, in ``area_unit``s."""
        return self.engine.score_poses(X, ["depth"])[:, 0, 0] * self.weight

    def release(self) -> None:
        if self.engine is not None:
            self.engine.release()
            self.engine = None
