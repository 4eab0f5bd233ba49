"""Pinhole cameras with OpenCV distortion, the OpenCV -> OpenGL conversion, calibration files.

Conventions
-----------
World: metres, right-handed, +Y up. Cameras follow OpenCV: camera x right, y down, z forward;
``x_img ~ K [R | t] X_world`` with ``R, t`` mapping world to camera coordinates, so the camera
centre is ``-R.T @ t``. Integer pixel coordinates are pixel *centres*: the image spans
``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` and row 0 is the top of the image. Distortion is OpenCV's
five-term model ``[k1, k2, p1, p2, k3]``; skew is not supported (``K[0, 1]`` must be 0).

gltrack renders undistorted pinhole images; observations are undistorted once per frame
(:meth:`Camera.undistort_image`), so the GPU never evaluates lens distortion.

OpenCV -> OpenGL (the one place this happens)
---------------------------------------------
The renderer uses exactly these two matrices (:meth:`Camera.gl_view`,
:meth:`Camera.gl_projection`)::

    view = [[R, t],
            [0, 0, 0, 1]]            # world -> OpenCV camera coordinates, no axis flip

    P    = [[2fx/W, 0,     2(cx+0.5)/W - 1,  0           ],
            [0,     2fy/H, 2(cy+0.5)/H - 1,  0           ],
            [0,     0,     (f+n)/(f-n),      -2fn/(f-n)  ],
            [0,     0,     1,                0           ]]

``clip = P @ view @ [X, 1]`` gives ``w_clip = z_cam`` (> 0 in front of the camera), and with
``glViewport(0, 0, W, H)`` the GL *window* coordinates of a point are ``(u + 0.5, v + 0.5)``
where ``(u, v)`` is its undistorted OpenCV pixel position. Consequences the renderer relies on:

* framebuffer row ``r`` (GL counts rows from the start of memory, i.e. what ``glReadPixels``
  returns first) holds image row ``r``: image top = texture row 0, rows are read back top-first
  and need **no flip**; observation images uploaded as textures with row 0 first line up with
  the framebuffer pixel for pixel;
* NDC z runs from -1 at ``z_cam = near`` to +1 at ``z_cam = far``, increasing with depth, so the
  default ``GL_LESS`` depth test keeps the nearest surface; :func:`linearize_gl_depth` inverts it;
* relative to GL's usual y-up window, the y axis is mirrored, which **flips triangle winding**:
  counter-clockwise-in-world front faces appear clockwise. The renderer must not cull back faces
  (disable culling, or cull ``GL_FRONT`` to remove back faces).

Calibration files
-----------------
* ``calibration.json`` (gltrack dataset schema): :func:`load_calibration`, :func:`save_calibration`.
* OpenCV ``cv2.FileStorage`` YAML / JSON / XML: :func:`load_opencv_yaml`, :func:`save_opencv_yaml`.
* caliscope ``camera_array.toml`` / ``config.toml``: :func:`load_caliscope_toml`.
* :func:`load_cameras` picks the reader from the suffix (and, for ``.json``, the content).
* Pose2Sim / anipose TOML and Qualisys ``.qca.txt`` are read by :mod:`gltrack.data.calibration`,
  whose ``load_any_calibration`` detects every format above from the content and rejects
  translations in millimetres.
"""
from __future__ import annotations

import json
import logging
import math
import operator
import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

KINDS = ("depth", "colour")
#: Tolerance on ``R.T @ R = I`` and ``det R = 1``.
ROTATION_TOL = 1e-6
_KEY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# --------------------------------------------------------------------------------------------
# validation shared by the constructor and every reader
# --------------------------------------------------------------------------------------------
def _array(value, shape, where, fld, shape_text):
    if value is None:
        raise ValueError(f"{where}.{fld} is missing")
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}.{fld} must contain only numbers ({shape_text})") from None
    if arr.shape != shape:
        raise ValueError(f"{where}.{fld} must be {shape_text}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}.{fld} must be finite")
    return arr


def _size(value, where, fld):
    if value is None:
        raise ValueError(f"{where}.{fld} is missing")
    if isinstance(value, bool):
        raise ValueError(f"{where}.{fld} must be a positive integer, got {value!r}")
    try:
        n = operator.index(value)
    except TypeError:
        if isinstance(value, float) and value.is_integer():
            n = int(value)  # OpenCV FileStorage and some JSON writers store sizes as reals
        else:
            raise ValueError(f"{where}.{fld} must be a positive integer, got {value!r}") from None
    if n <= 0:
        raise ValueError(f"{where}.{fld} must be a positive integer, got {n}")
    return int(n)


def _validated(raw: dict, where: str) -> dict:
    """Check and normalise the fields of a camera; errors read ``"{where}.{field} ..."``."""
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where}.name must be a non-empty string, got {name!r}")
    kind = raw.get("kind")
    if kind not in KINDS:
        raise ValueError(f"{where}.kind must be one of {KINDS}, got {kind!r}")
    width = _size(raw.get("width"), where, "width")
    height = _size(raw.get("height"), where, "height")
    K = _array(raw.get("K"), (3, 3), where, "K", "3x3")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{where}.K must have positive focal lengths, "
                         f"got fx={K[0, 0]}, fy={K[1, 1]}")
    if K[0, 1] != 0:
        raise ValueError(f"{where}.K must have zero skew K[0,1] (the GL projection ignores it), "
                         f"got {K[0, 1]}")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(f"{where}.K must have last row [0, 0, 1] and K[1,0] = 0, got {K.tolist()}")
    dist = _array(raw.get("dist"), (5,), where, "dist", "a list of 5 numbers [k1, k2, p1, p2, k3]")
    R = _array(raw.get("R"), (3, 3), where, "R", "3x3")
    orth = np.abs(R.T @ R - np.eye(3)).max()
    det = np.linalg.det(R)
    if orth > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise ValueError(f"{where}.R must be a rotation (orthonormal, det +1 within "
                         f"{ROTATION_TOL}); max |R^T R - I| = {orth:.3g}, det = {det:.9f}")
    t = _array(raw.get("t"), (3,), where, "t", "a list of 3 numbers")
    return {"name": name, "kind": kind, "width": width, "height": height,
            "K": K, "dist": dist, "R": R, "t": t}


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


# --------------------------------------------------------------------------------------------
# the camera
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, repr=False)
class Camera:
    """A calibrated pinhole camera with OpenCV five-term distortion (see module docstring).

    Attributes
    ----------
    name : str
        Identifier, e.g. ``"cam0"``; also the dataset's image folder name.
    kind : {"depth", "colour"}
    width, height : int
        Image size in pixels.
    K : (3, 3) float64
        Intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels; zero skew.
    dist : (5,) float64
        ``[k1, k2, p1, p2, k3]``.
    R : (3, 3) float64
        World -> camera rotation (orthonormal, det +1).
    t : (3,) float64, metres
        World -> camera translation: ``X_cam = R @ X_world + t``.

    Arrays are stored as read-only copies; use :func:`dataclasses.replace` to derive a camera.

    Raises
    ------
    ValueError
        Naming the field that is malformed.
    """

    name: str
    kind: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    _maps: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        fields = _validated({"name": self.name, "kind": self.kind, "width": self.width,
                             "height": self.height, "K": self.K, "dist": self.dist, "R": self.R,
                             "t": self.t}, f"Camera({self.name!r})")
        for key, value in fields.items():
            if isinstance(value, np.ndarray):
                value = _readonly(value)
            object.__setattr__(self, key, value)

    def __repr__(self) -> str:
        c = self.center
        return (f"Camera({self.name!r}, {self.kind}, {self.width}x{self.height}, "
                f"fx={self.fx:.2f}, fy={self.fy:.2f}, cx={self.cx:.2f}, cy={self.cy:.2f}, "
                f"distorted={bool(np.any(self.dist))}, "
                f"centre=({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}))")

    # ---- geometry ---------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """(3,) float64, metres: the camera centre in world coordinates, ``-R.T @ t``."""
        return -self.R.T @ self.t

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def to_camera(self, X) -> np.ndarray:
        """World points to camera coordinates.

        Parameters
        ----------
        X : (N, 3) array_like, metres (any leading shape ``(..., 3)`` works)

        Returns
        -------
        (N, 3) float64, metres, OpenCV camera frame.
        """
        X = np.asarray(X, dtype=np.float64)
        return X @ self.R.T + self.t

    def to_world(self, Xc) -> np.ndarray:
        """Camera coordinates to world points, the inverse of :meth:`to_camera`.

        Parameters
        ----------
        Xc : (N, 3) array_like, metres, OpenCV camera frame (any leading shape ``(..., 3)``)

        Returns
        -------
        (N, 3) float64, metres, world: ``R^T (Xc - t)``.
        """
        Xc = np.asarray(Xc, dtype=np.float64)
        return (Xc - self.t) @ self.R

    def depth_of(self, X) -> np.ndarray:
        """(N,) float64, metres: ``z`` of the world points ``X (N, 3)`` in the camera frame."""
        X = np.asarray(X, dtype=np.float64)
        return X @ self.R[2] + self.t[2]

    def project(self, X, distort: bool = True) -> np.ndarray:
        """Project world points to pixel coordinates, as ``cv2.projectPoints`` does.

        Parameters
        ----------
        X : (N, 3) array_like, metres (any leading shape ``(..., 3)`` works)
        distort : bool
            Apply the lens distortion (the real image); ``False`` gives the undistorted pinhole
            image that gltrack renders.

        Returns
        -------
        (N, 2) float64, pixels ``(u, v)``; integer values are pixel centres. Points behind the
        camera (``depth_of(X) <= 0``) get meaningless (possibly non-finite) coordinates: callers
        that may see them must mask on depth.
        """
        Xc = self.to_camera(X)
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Xc[..., :2] / Xc[..., 2:3]
        if distort and np.any(self.dist):
            xy = _distort_normalised(xy, self.dist)
        return xy * self.K[[0, 1], [0, 1]] + self.K[:2, 2]

    def backproject(self, uv, depth, *, distort: bool = True, frame: str = "world") -> np.ndarray:
        """Pixels with known depth back to 3-D points, the inverse of :meth:`project`.

        The pixel's ray through the pinhole, ``((u - cx) / fx, (v - cy) / fy, 1)`` in the OpenCV
        camera frame (x right, y down, z forward; integer ``(u, v)`` are pixel centres), is
        scaled to the given depth.

        Parameters
        ----------
        uv : (N, 2) array_like, pixels ``(u, v)`` (any leading shape ``(..., 2)``)
        depth : (N,) array_like, metres along the optical axis (the camera-frame ``z``, as a
            depth image stores it; not the distance along the ray)
        distort : bool
            ``uv`` are pixels of the real (distorted) image, whose lens distortion is undone
            first (as :meth:`project` with ``distort=True`` made them); ``False``: pixels of the
            undistorted pinhole image that gltrack renders. No effect for a camera without
            distortion.
        frame : {"world", "camera"}
            Return world points, or points in the OpenCV camera frame.

        Returns
        -------
        (N, 3) float64, metres.
        """
        if frame not in ("world", "camera"):
            raise ValueError(f"frame must be 'world' or 'camera', got {frame!r}")
        uv = np.asarray(uv, dtype=np.float64)
        if distort and np.any(self.dist):
            uv = self.undistort_points(uv)
        z = np.asarray(depth, dtype=np.float64)
        x = (uv[..., 0] - self.cx) / self.fx * z
        y = (uv[..., 1] - self.cy) / self.fy * z
        Xc = np.stack([x, y, z], axis=-1)
        return self.to_world(Xc) if frame == "world" else Xc

    def undistort_points(self, uv) -> np.ndarray:
        """Distorted pixel coordinates to undistorted ones (same ``K``), inverse of the lens model.

        Parameters
        ----------
        uv : (N, 2) array_like, pixels in the real (distorted) image

        Returns
        -------
        (N, 2) float64, pixels in the image of :meth:`undistorted`.
        """
        uv = np.asarray(uv, dtype=np.float64)
        if not np.any(self.dist):
            return uv.copy()
        shape = uv.shape
        # The default 5 iterations of cv2.undistortPoints leave pixel-sized errors with strong
        # barrel distortion (real webcams); iterate to convergence instead.
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        src = uv.reshape(-1, 1, 2)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
            out = cv2.undistortPointsIter(src, self.K, self.dist, None, self.K, crit)
        else:  # OpenCV 5 folded the criteria into undistortPoints
            out = cv2.undistortPoints(src, self.K, self.dist, None, None, self.K, crit)
        return out.reshape(shape)

    # ---- derived cameras --------------------------------------------------------------------
    def scaled(self, width: int, height: int) -> "Camera":
        """The same camera for an image resized to ``width x height`` pixels.

        Pixel-centre geometry is preserved: ``fx' = fx * W'/W`` and ``cx' = (cx + 0.5) W'/W - 0.5``
        (same for y), so the image edges ``-0.5`` and ``W - 0.5`` map onto each other. Distortion
        acts on normalised coordinates and is unchanged.
        """
        where = f"Camera({self.name!r}).scaled"
        width = _size(width, where, "width")
        height = _size(height, where, "height")
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return Camera(self.name, self.kind, width, height, K, self.dist, self.R, self.t)

    def undistorted(self) -> "Camera":
        """The pinhole camera of :meth:`undistort_image`'s output: same ``K``, zero distortion."""
        return Camera(self.name, self.kind, self.width, self.height, self.K, np.zeros(5),
                      self.R, self.t)

    def undistort_image(self, img: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Remove lens distortion from an image taken by this camera.

        gltrack renders undistorted pinhole images; observations are undistorted once per frame
        with this method, and then compared with renders of :meth:`undistorted`.

        Parameters
        ----------
        img : (H, W) or (H, W, C) array, any dtype cv2.remap accepts
            Must have this camera's size.
        interpolation : int
            ``cv2.INTER_LINEAR`` for colour; use ``cv2.INTER_NEAREST`` for masks, labels and
            depth (interpolating depth across silhouette edges invents surfaces).

        Returns
        -------
        Same shape and dtype as ``img``; pixels that map outside the source are 0.

        Notes
        -----
        The remap tables are computed on first use and cached on this camera object.
        """
        img = np.asarray(img)
        if img.shape[:2] != (self.height, self.width):
            raise ValueError(f"Camera({self.name!r}).undistort_image: image is "
                             f"{img.shape[1]}x{img.shape[0]}, camera is {self.width}x{self.height}")
        if not np.any(self.dist):
            return img.copy()
        if "remap" not in self._maps:
            self._maps["remap"] = cv2.initUndistortRectifyMap(
                self.K, self.dist, None, self.K, (self.width, self.height), cv2.CV_32FC1)
        map1, map2 = self._maps["remap"]
        return cv2.remap(img, map1, map2, interpolation, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)

    # ---- OpenGL -----------------------------------------------------------------------------
    def gl_view(self) -> np.ndarray:
        """(4, 4) float64: ``[[R, t], [0, 0, 0, 1]]``, world -> OpenCV camera (no axis flip).

        Row-major; upload transposed (or with ``transpose=True``) for GLSL's column-major mat4.
        """
        V = np.eye(4)
        V[:3, :3] = self.R
        V[:3, 3] = self.t
        return V

    def gl_projection(self, near: float, far: float) -> np.ndarray:
        """(4, 4) float64 projection from OpenCV camera coordinates to GL clip space.

        See the module docstring for the exact matrix and the window-coordinate, row-order,
        depth and winding conventions it implies. Distortion is ignored (renders are pinhole).

        Parameters
        ----------
        near, far : float, metres, ``0 < near < far``
        """
        near, far = float(near), float(far)
        if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far):
            raise ValueError(f"gl_projection needs 0 < near < far, got near={near}, far={far}")
        W, H = self.width, self.height
        P = np.zeros((4, 4))
        P[0, 0] = 2 * self.fx / W
        P[0, 2] = 2 * (self.cx + 0.5) / W - 1
        P[1, 1] = 2 * self.fy / H
        P[1, 2] = 2 * (self.cy + 0.5) / H - 1
        P[2, 2] = (far + near) / (far - near)
        P[2, 3] = -2 * far * near / (far - near)
        P[3, 2] = 1
        return P

    # ---- serialisation ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The camera as one entry of ``calibration.json``'s ``"cameras"`` list (plain lists)."""
        return {"name": self.name, "kind": self.kind, "width": self.width, "height": self.height,
                "K": self.K.tolist(), "dist": self.dist.tolist(), "R": self.R.tolist(),
                "t": self.t.tolist()}

    @classmethod
    def from_dict(cls, d, source: str = "camera") -> "Camera":
        """Build a camera from a ``calibration.json`` entry.

        Parameters
        ----------
        d : dict
            Keys ``name, kind, width, height, K, dist, R, t`` (see :meth:`to_dict`).
        source : str
            Prefix of error messages, e.g. ``"calibration.json: cameras[1]"`` gives
            ``"calibration.json: cameras[1].K must be 3x3, ..."``.
        """
        if not isinstance(d, dict):
            raise ValueError(f"{source} must be an object, got {type(d).__name__}")
        unknown = set(d) - {"name", "kind", "width", "height", "K", "dist", "R", "t"}
        if unknown:
            log.debug("%s: ignoring unknown fields %s", source, sorted(unknown))
        return cls(**_validated(d, source))


def _distort_normalised(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's five-term model on normalised image coordinates ``(..., 2)``."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def triangulate(cameras, uv, *, distort: bool = True):
    """3-D points seen in several calibrated views: linear (DLT) triangulation.

    Each camera's pixels are undistorted first (:meth:`Camera.undistort_points`), so the rays
    are exact for the lens model. The linear solution minimises an algebraic error: exact for
    noise-free observations, close to (not the same as) the reprojection optimum with noise,
    which is why the residuals are returned.

    Parameters
    ----------
    cameras : sequence (C) of Camera
    uv : (C, N, 2) array_like, pixels of each point in each camera's image; NaN where a camera
        does not see the point
    distort : bool, ``uv`` are pixels of the real (distorted) images (as :meth:`Camera.project`
        with ``distort=True`` gives them); False: of the undistorted pinhole images

    Returns
    -------
    points : (N, 3) float64, metres, the cameras' world frame; NaN for a point seen by fewer
        than two cameras
    residual : (C, N) float64, pixels, each observation's distance to the reprojected point
        (NaN where there is none)
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[0] != len(cameras) or uv.shape[2] != 2:
        raise ValueError(f"uv must be ({len(cameras)}, N, 2), got {uv.shape}")
    C, N = uv.shape[:2]
    seen = np.isfinite(uv).all(axis=2)
    und = np.full_like(uv, np.nan)
    for c, cam in enumerate(cameras):
        if seen[c].any():
            und[c, seen[c]] = cam.undistort_points(uv[c, seen[c]]) if distort else uv[c, seen[c]]
    points = np.full((N, 3), np.nan)
    # every point's DLT system at once: two rows per camera, (N, 2C, 4); an unseen view's
    # rows are zero, which leaves the system's null space (the point) as without them
    P = np.stack([np.hstack([cam.R, cam.t[:, None]]) for cam in cameras])  # (C, 3, 4)
    f = np.array([[cam.fx, cam.fy] for cam in cameras])[:, None, :]
    ctr = np.array([[cam.cx, cam.cy] for cam in cameras])[:, None, :]
    xy = (und - ctr) / f  # normalised image coordinates of the rays, (C, N, 2)
    rows = xy[..., None] * P[:, None, None, 2] - P[:, None, :2]  # (C, N, 2, 4)
    rows = np.where(seen[:, :, None, None], rows, 0.0)
    A = rows.transpose(1, 0, 2, 3).reshape(N, 2 * C, 4)
    enough = seen.sum(axis=0) >= 2
    if enough.any():
        X = np.linalg.svd(A[enough])[2][:, -1]
        points[enough] = X[:, :3] / X[:, 3:]
    residual = np.full((C, N), np.nan)
    ok = np.isfinite(points).all(axis=1)
    for c, cam in enumerate(cameras):
        m = seen[c] & ok
        if m.any():
            residual[c, m] = np.linalg.norm(cam.project(points[m], distort=distort) - uv[c, m],
                                            axis=1)
    return points, residual


def linearize_gl_depth(depth, near: float, far: float) -> np.ndarray:
    """Window depth from a :meth:`Camera.gl_projection` render to camera ``z`` in metres.

    Parameters
    ----------
    depth : array_like, window depth in ``[0, 1]`` (``glDepthRange(0, 1)``)
    near, far : float, metres, the values given to ``gl_projection``

    Returns
    -------
    float64 array of the same shape: ``z_cam``; ``depth == 1`` (cleared) gives ``far``.
    """
    ndc = 2.0 * np.asarray(depth, dtype=np.float64) - 1.0
    return 2.0 * far * near / ((far + near) - ndc * (far - near))


# --------------------------------------------------------------------------------------------
# synthetic rigs
# --------------------------------------------------------------------------------------------
def _look_at_rotation(eye, target, up, where) -> tuple[np.ndarray, np.ndarray]:
    eye = _array(eye, (3,), where, "eye", "3 numbers")
    target = _array(target, (3,), where, "target", "3 numbers")
    up = _array(up, (3,), where, "up", "3 numbers")
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError(f"{where}: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9 * max(np.linalg.norm(up), 1e-300):
        raise ValueError(f"{where}: viewing direction is parallel to up={up.tolist()}")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down is the world's -up, as seen by a level camera
    R = np.stack([x, y, z])
    return R, -R @ eye


def look_at_camera(name: str, eye, target, width: int, height: int, fov_y_deg: float,
                   kind: str = "colour", up=(0.0, 1.0, 0.0)) -> Camera:
    """A distortion-free camera at ``eye`` looking at ``target``, for synthetic rigs.

    Parameters
    ----------
    name : str
    eye, target : (3,) array_like, metres, world
    width, height : int, pixels
    fov_y_deg : float, degrees
        Vertical field of view between the top and bottom image *edges*; square pixels, principal
        point at the image centre ``((W-1)/2, (H-1)/2)``.
    kind : {"colour", "depth"}
    up : (3,) array_like
        World direction that appears as image "up" (towards row 0); must not be parallel to the
        viewing direction.

    Returns
    -------
    Camera
    """
    where = f"look_at_camera({name!r})"
    if not (0 < fov_y_deg < 180):
        raise ValueError(f"{where}.fov_y_deg must be in (0, 180), got {fov_y_deg}")
    R, t = _look_at_rotation(eye, target, up, where)
    height_px = _size(height, where, "height")
    f = 0.5 * height_px / math.tan(math.radians(fov_y_deg) / 2)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height_px - 1) / 2], [0, 0, 1]])
    return Camera(name, kind, width, height_px, K, np.zeros(5), R, t)


#: SwissRanger SR4000: 176 x 144 pixels, 43.6 x 34.6 degrees field of view.
SR4000_SIZE = (176, 144)
SR4000_FOV_DEG = (43.6, 34.6)


def depth_camera_sr4000(eye, target, name: str = "cam0", up=(0.0, 1.0, 0.0)) -> Camera:
    """A SwissRanger SR4000-like depth camera (176x144, 43.6 x 34.6 deg FOV, no distortion).

    Parameters
    ----------
    eye, target : (3,) array_like, metres, world
    name : str
    up : (3,) array_like, see :func:`look_at_camera`

    Returns
    -------
    Camera
        ``kind="depth"``; ``fx = 88 / tan(21.8 deg) ~ 220``, ``fy = 72 / tan(17.3 deg) ~ 231`` px.
    """
    (W, H), (hfov, vfov) = SR4000_SIZE, SR4000_FOV_DEG
    R, t = _look_at_rotation(eye, target, up, f"depth_camera_sr4000({name!r})")
    fx = 0.5 * W / math.tan(math.radians(hfov) / 2)
    fy = 0.5 * H / math.tan(math.radians(vfov) / 2)
    K = np.array([[fx, 0, (W - 1) / 2], [0, fy, (H - 1) / 2], [0, 0, 1]])
    return Camera(name, "depth", W, H, K, np.zeros(5), R, t)


# --------------------------------------------------------------------------------------------
# calibration.json (gltrack dataset)
# --------------------------------------------------------------------------------------------
def _check_unique(cameras, source):
    names = [c.name for c in cameras]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{source}: duplicate camera names {dup}")


def _cameras_from_json_obj(obj, source: str) -> list[Camera]:
    if not isinstance(obj, dict):
        raise ValueError(f"{source}: top level must be an object with a 'cameras' list")
    cams = obj.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise ValueError(f"{source}: cameras must be a non-empty list")
    cameras = [Camera.from_dict(c, f"{source}: cameras[{i}]") for i, c in enumerate(cams)]
    _check_unique(cameras, source)
    return cameras


def load_calibration(path) -> list[Camera]:
    """Read a dataset ``calibration.json``.

    Schema: ``{"cameras": [{"name", "kind", "width", "height", "K": 3x3, "dist": [5], "R": 3x3,
    "t": [3]}, ...]}`` (OpenCV, world -> camera, metres).

    Returns
    -------
    list of Camera, in file order.

    Raises
    ------
    ValueError
        Naming the file and field, e.g. ``"calibration.json: cameras[1].K must be 3x3, ..."``.
    """
    path = Path(path)
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    return _cameras_from_json_obj(obj, str(path))


def save_calibration(path, cameras) -> None:
    """Write ``cameras`` (sequence of Camera) as a dataset ``calibration.json``.

    Floats are written with full precision, so :func:`load_calibration` restores them exactly.
    """
    cameras = list(cameras)
    _check_unique(cameras, str(path))
    text = json.dumps({"cameras": [c.to_dict() for c in cameras]}, indent=2)
    Path(path).write_text(text + "\n", encoding="utf-8")


# --------------------------------------------------------------------------------------------
# OpenCV FileStorage (YAML / JSON / XML)
# --------------------------------------------------------------------------------------------
def _fs_matrix(node, where, fld):
    """A FileStorage node as a float64 array: opencv-matrix, a sequence, or ROS-style rows/data."""
    if node.empty() or node.isNone():
        return None
    if node.isMap():
        data = node.getNode("data")
        if not data.empty():  # ROS camera_info YAML: {rows, cols, data: [...]}
            values = [data.at(i).real() for i in range(data.size())]
            rows, cols = int(node.getNode("rows").real()), int(node.getNode("cols").real())
            if rows * cols != len(values):
                raise ValueError(f"{where}.{fld}: rows*cols = {rows * cols} "
                                 f"but {len(values)} values")
            return np.array(values, dtype=np.float64).reshape(rows, cols)
        mat = node.mat()
        if mat is None:
            raise ValueError(f"{where}.{fld} is not a matrix")
        return np.asarray(mat, dtype=np.float64)
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    raise ValueError(f"{where}.{fld} is not a matrix")


def _fs_scalar(node):
    if node.empty() or node.isNone():
        return None
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    return None


def _fs_string(node):
    if node.empty() or not node.isString():
        return None
    return node.string()


def _dist5(d, where, fld="distortion_coefficients"):
    """Accept OpenCV's 4, 5, 8, 12 or 14 coefficients when the model reduces to 5 terms."""
    if d is None:
        return np.zeros(5)
    d = np.asarray(d, dtype=np.float64).ravel()
    if d.size == 4:
        return np.append(d, 0.0)
    if d.size == 5:
        return d
    if d.size in (8, 12, 14) and not np.any(d[5:]):
        return d[:5]
    raise ValueError(f"{where}.{fld} must have 5 coefficients [k1, k2, p1, p2, k3] "
                     f"(4 or 5, or 8/12/14 with zero extra terms), got {d.size}: {d.tolist()}")


def _rotation_from(R, rvec, where, r_field="R", rvec_field="rvec"):
    if R is not None:
        R = np.asarray(R, dtype=np.float64)
        if R.size == 3:  # some writers store the Rodrigues vector in the matrix's place
            rvec, R, rvec_field = R, None, r_field
        elif R.shape != (3, 3):
            raise ValueError(f"{where}.{r_field} must be 3x3 (or a 3-element Rodrigues vector), "
                             f"got shape {R.shape}")
    if R is None and rvec is not None:
        rvec = np.asarray(rvec, dtype=np.float64).ravel()
        if rvec.shape != (3,) or not np.all(np.isfinite(rvec)):
            raise ValueError(f"{where}.{rvec_field} must be 3 finite numbers, got {rvec.tolist()}")
        R = cv2.Rodrigues(rvec)[0]
    return R


def _camera_from_fs(node, name, where) -> Camera:
    K = _fs_matrix(node.getNode("camera_matrix"), where, "camera_matrix")
    if K is None:
        raise ValueError(f"{where}.camera_matrix is missing")
    width = _fs_scalar(node.getNode("image_width"))
    height = _fs_scalar(node.getNode("image_height"))
    dist = _dist5(_fs_matrix(node.getNode("distortion_coefficients"), where,
                             "distortion_coefficients"), where)
    R = _rotation_from(_fs_matrix(node.getNode("R"), where, "R"),
                       _fs_matrix(node.getNode("rvec"), where, "rvec"), where)
    t = _fs_matrix(node.getNode("T"), where, "T")
    if t is None:
        t = _fs_matrix(node.getNode("tvec"), where, "tvec")
    if R is None and t is None:
        log.info("%s: no extrinsics (R/rvec, T/tvec); camera placed at the world origin", where)
    raw = {"name": _fs_string(node.getNode("camera_name")) or name,
           "kind": _fs_string(node.getNode("kind")) or "colour",
           "width": width, "height": height, "K": K, "dist": dist,
           "R": np.eye(3) if R is None else R,
           "t": np.zeros(3) if t is None else np.asarray(t).ravel()}
    fields = {"image_width": "width", "image_height": "height", "camera_matrix": "K",
              "distortion_coefficients": "dist", "R": "R", "T": "t", "kind": "kind",
              "camera_name": "name"}
    try:
        return Camera(**_validated(raw, where))
    except ValueError as exc:
        # Report the file's node names rather than the Camera attribute names.
        msg = str(exc)
        for node_name, attr in fields.items():
            msg = msg.replace(f"{where}.{attr} ", f"{where}.{node_name} ")
        raise ValueError(msg) from None


def load_opencv_yaml(path) -> list[Camera]:
    """Read cameras from an OpenCV ``cv2.FileStorage`` file (YAML, JSON or XML).

    Two layouts are accepted:

    * one camera: top-level nodes ``camera_matrix`` (3x3), ``distortion_coefficients`` (4/5),
      ``image_width``, ``image_height``, and optionally ``R`` (3x3) or ``rvec`` (Rodrigues),
      ``T`` or ``tvec`` (world -> camera, metres), ``camera_name``, ``kind``;
    * several cameras: one top-level map per camera, named by the camera (``cam0``, ``cam1``, ...),
      each holding the nodes above.

    ROS ``camera_info`` style matrices (``{rows, cols, data}``) are read too. Missing extrinsics
    default to ``R = I, t = 0``, missing distortion to zeros, ``kind`` to ``"colour"``, and the
    single-camera name to ``camera_name`` or ``"cam0"``.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        Unparsable file, or a node is missing or malformed (message names file and node).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FileStorage_READ)
    except (cv2.error, SystemError) as exc:  # some cv2 builds wrap the parse error in SystemError
        cause = exc.__cause__ or exc.__context__ or exc
        detail = str(cause).strip().splitlines()[-1] if str(cause).strip() else type(cause).__name__
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file ({detail})") from None
    try:
        if not fs.isOpened():
            raise ValueError(f"{path}: not a readable OpenCV FileStorage file")
        root = fs.root()
        if not root.getNode("camera_matrix").empty():
            cameras = [_camera_from_fs(root, "cam0", f"{path}: root")]
        else:
            cameras = []
            for key in root.keys():
                node = root.getNode(key)
                if node.isMap() and not node.getNode("camera_matrix").empty():
                    cameras.append(_camera_from_fs(node, key, f"{path}: {key}"))
            if not cameras:
                raise ValueError(f"{path}: camera_matrix is missing (neither at the top level nor "
                                 f"in any top-level camera map)")
    finally:
        fs.release()
    _check_unique(cameras, str(path))
    return cameras


def save_opencv_yaml(path, cameras) -> None:
    """Write cameras as an OpenCV FileStorage file; the suffix picks YAML/JSON/XML.

    Always uses the several-cameras layout (one top-level map per camera, keyed by its name, with
    ``image_width, image_height, camera_matrix, distortion_coefficients, R, T, kind``), so names
    must be valid FileStorage keys (letters, digits, underscore, not starting with a digit).
    """
    cameras = list(cameras)
    path = Path(path)
    _check_unique(cameras, str(path))
    for cam in cameras:
        if not _KEY_RE.match(cam.name):
            raise ValueError(f"{path}: camera name {cam.name!r} is not a valid FileStorage key")
    fs = cv2.FileStorage(str(path), cv2.FileStorage_WRITE)
    if not fs.isOpened():
        raise OSError(f"{path}: cannot open for writing")
    try:
        for cam in cameras:
            fs.startWriteStruct(cam.name, cv2.FileNode_MAP)
            fs.write("kind", cam.kind)
            fs.write("image_width", cam.width)
            fs.write("image_height", cam.height)
            fs.write("camera_matrix", np.ascontiguousarray(cam.K))
            fs.write("distortion_coefficients", np.ascontiguousarray(cam.dist.reshape(1, 5)))
            fs.write("R", np.ascontiguousarray(cam.R))
            fs.write("T", np.ascontiguousarray(cam.t.reshape(3, 1)))
            fs.endWriteStruct()
    finally:
        fs.release()


# --------------------------------------------------------------------------------------------
# caliscope camera_array.toml / config.toml
# --------------------------------------------------------------------------------------------
def _load_toml(path: Path) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        try:
            import tomli as tomllib
        except ModuleNotFoundError:
            raise ImportError("reading TOML on Python 3.10 needs the 'tomli' package") from None
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None


def load_caliscope_toml(path) -> list[Camera]:
    """Read the cameras of a caliscope ``camera_array.toml`` (or project ``config.toml``).

    Layout: tables ``[cameras.<id>]`` (camera_array.toml) or ``[cam_<id>]`` (config.toml) with
    ``size = [W, H]``, ``matrix`` (3x3), ``distortions`` (5), ``rotation``, ``translation``.

    What the real file (caliscope 4-camera sample) shows, and this reader assumes:

    * ``rotation`` is a 3x3 matrix (older caliscope/pyxy3d versions wrote a 3-element Rodrigues
      vector; both are accepted) and ``rotation``/``translation`` are OpenCV **world -> camera**
      extrinsics in metres, used as given (``R = rotation``, ``t = translation``). Check on the
      sample: read this way, the four optical axes converge on one point about 1 m in front of
      every camera; read as camera -> world, that point lies about 0.5-0.7 m *behind* them all.
    * The world frame is caliscope's (origin and axes from its bundle adjustment), *not* gltrack's
      +Y-up frame: a caller that needs gravity must align the rig itself.
    * Cameras are named ``cam<id>``; ``ignore = true`` cameras are skipped; ``kind`` is
      ``"colour"``. ``rotation_count`` (90-degree frame rotations caliscope applies before
      calibrating) must be 0: other values would need the video frames rotated first.

    Raises
    ------
    ValueError
        Malformed TOML, no camera tables, or a malformed field (named with file and table).
    """
    path = Path(path)
    data = _load_toml(path)
    tables = []
    if isinstance(data.get("cameras"), dict):
        tables = [(str(k), v, f"cameras.{k}") for k, v in data["cameras"].items()]
    else:
        tables = [(k[4:], v, k) for k, v in data.items() if re.fullmatch(r"cam_\d+", k)]
    tables = [(k, v, w) for k, v, w in tables if isinstance(v, dict)]
    if not tables:
        raise ValueError(f"{path}: no camera tables ([cameras.N] or [cam_N])")
    cameras = []
    for key, tab, table_name in tables:
        where = f"{path}: {table_name}"
        if tab.get("ignore", False):
            log.info("%s: ignore = true, skipped", where)
            continue
        if tab.get("rotation_count", 0) not in (0, None):
            raise ValueError(f"{where}.rotation_count = {tab['rotation_count']} is not supported "
                             "(frames would need rotating before use)")
        cam_id = tab.get("cam_id", tab.get("port", key))
        size = tab.get("size")
        if not (isinstance(size, list) and len(size) == 2):
            raise ValueError(f"{where}.size must be [width, height], got {size!r}")
        if tab.get("rotation") is None:
            raise ValueError(f"{where}.rotation is missing (camera not extrinsically calibrated)")
        if tab.get("translation") is None:
            raise ValueError(f"{where}.translation is missing "
                             "(camera not extrinsically calibrated)")
        try:
            rotation = np.array(tab["rotation"], dtype=np.float64)
            translation = np.array(tab["translation"], dtype=np.float64).ravel()
            dist = np.array(tab.get("distortions", np.zeros(5)), dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ValueError(f"{where}: rotation, translation and distortions "
                             "must be numbers") from None
        R = _rotation_from(rotation, None, where, "rotation")
        raw = {"name": f"cam{cam_id}", "kind": "colour", "width": size[0], "height": size[1],
               "K": tab.get("matrix"), "dist": _dist5(dist, where, "distortions"),
               "R": R, "t": translation}
        try:
            cameras.append(Camera(**_validated(raw, where)))
        except ValueError as exc:
            msg = str(exc)
            for attr, key_name in (("K", "matrix"), ("R", "rotation"), ("t", "translation"),
                                   ("width", "size[0]"), ("height", "size[1]")):
                msg = msg.replace(f"{where}.{attr} ", f"{where}.{key_name} ")
            raise ValueError(msg) from None
    if not cameras:
        raise ValueError(f"{path}: every camera has ignore = true")
    _check_unique(cameras, str(path))
    return cameras


# --------------------------------------------------------------------------------------------
# dispatch
# --------------------------------------------------------------------------------------------
def load_cameras(path) -> list[Camera]:
    """Read cameras from any supported calibration file.

    ``.json``: the dataset schema when the top level has a ``"cameras"`` list, else OpenCV
    FileStorage JSON; ``.yml``/``.yaml``/``.xml``: OpenCV FileStorage; ``.toml``: caliscope.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        try:
            obj = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        if isinstance(obj, dict) and "cameras" in obj:
            return _cameras_from_json_obj(obj, str(path))
        return load_opencv_yaml(path)
    if suffix in (".yml", ".yaml", ".xml"):
        return load_opencv_yaml(path)
    if suffix == ".toml":
        return load_caliscope_toml(path)
    raise ValueError(f"{path}: unknown calibration format {suffix!r} "
                     "(expected .json, .yml, .yaml, .xml or .toml)")
