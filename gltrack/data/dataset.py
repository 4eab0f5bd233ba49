"""The gltrack dataset folder (version 1): validated reader, atomic writer, plain image folders.

Layout::

    DATASET/
      meta.json           {"format": "gltrack-dataset", "version": 1, "fps": 30, "frames": N,
                           "rig": "depth" | "multiview", "body": {...optional...},
                           "world": {...optional, see Dataset.user_frame...},
                           "source": {...optional, what gltrack ingest read...}}
      calibration.json    cameras, see :func:`gltrack.camera.load_calibration`
      cam0/000000.png ... depth cameras: uint16 millimetres, 0 = invalid;
                          colour cameras: 8-bit BGR (as cv2.imwrite writes it)
      cam0.mp4            instead of cam0/ for a colour camera (read with cv2.VideoCapture)
      cam0_mask/...       optional foreground masks, uint8, 255 = foreground
      cam0_gtmask/...     optional ground-truth masks (diagnosis only), same format
      cam0_background.png optional empty-scene frame, or several in cam0_background/
      environment.json    optional occluder polygons per camera (see :meth:`Dataset.environment`)
      groundtruth.npz     optional: joints (N,J,3) m, joint_names (J,), markers (N,M,3) m,
                          marker_names (M,), params (N,D), anything else numeric
      keypoints.npz       optional 2-D body landmarks per camera and their triangulation
                          (see :meth:`Dataset.keypoints`; ``gltrack ingest`` writes it)

Image folders are read in natural name order (``2.png`` before ``10.png``), so folders that were not
written by :class:`DatasetWriter` work too; :class:`DatasetWriter` names frames ``000000.png``.

:meth:`Dataset.open` checks the whole structure (every file's presence and count, the first image
of every stream for size and pixel format); each later read checks its own image again, so a bad
file in the middle of a sequence is reported by name when it is reached.
"""
from __future__ import annotations

import json
import logging
import os
import re
import shutil
import tempfile
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor
from glob import escape as glob_escape
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

FORMAT = "gltrack-dataset"
VERSION = 1
RIGS = ("depth", "multiview")
META = "meta.json"
CALIBRATION = "calibration.json"
ENVIRONMENT = "environment.json"
GROUNDTRUTH = "groundtruth.npz"
KEYPOINTS = "keypoints.npz"
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
VIDEO_EXTS = (".mp4", ".avi", ".mkv", ".mov")
#: Largest depth a uint16 millimetre PNG holds, metres.
MAX_DEPTH_M = 65.535


def _natural_key(name):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


#: Images read ahead (:meth:`ImageFolder.prefetch`) per folder; older ones are dropped.
PREFETCH_DEPTH = 2
_readers: ThreadPoolExecutor | None = None
_readers_lock = threading.Lock()


def _reader_pool() -> ThreadPoolExecutor:
    """The threads that read images ahead (OpenCV decodes without holding the GIL, so a read
    overlaps the tracker's numpy work)."""
    global _readers
    with _readers_lock:
        if _readers is None:
            _readers = ThreadPoolExecutor(max_workers=2, thread_name_prefix="gltrack-read")
        return _readers


class ImageFolder:
    """A folder of images as a read-only sequence, in natural name order.

    Parameters
    ----------
    folder : path

    Notes
    -----
    ``folder[i]`` is the image as stored (``cv2.IMREAD_UNCHANGED``): (H, W) or (H, W, C), uint8 or
    uint16, colour channels in BGR order. :meth:`prefetch` starts reading an image in a
    background thread; ``folder[i]`` then takes it from there (or reads it itself).
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise ValueError(f"{self.folder}: not a folder")
        self.files = sorted((p for p in self.folder.iterdir()
                             if p.suffix.lower() in IMAGE_EXTS and not p.name.startswith(".")),
                            key=lambda p: _natural_key(p.name))
        self._ahead = {}

    def prefetch(self, i) -> None:
        """Start reading image ``i`` in the background (ignored out of range or when under
        way); at most :data:`PREFETCH_DEPTH` images are held."""
        if not 0 <= i < len(self.files) or i in self._ahead:
            return
        while len(self._ahead) >= PREFETCH_DEPTH:
            self._ahead.pop(next(iter(self._ahead)))
        self._ahead[i] = _reader_pool().submit(self._read, i)

    def __len__(self):
        return len(self.files)

    def path(self, i):
        return self.files[i]

    def __getitem__(self, i):
        if not 0 <= i < len(self.files):
            raise IndexError(f"{self.folder}: frame {i} out of range 0..{len(self.files) - 1}")
        ahead = self._ahead.pop(i, None)
        return self._read(i) if ahead is None else ahead.result()

    def _read(self, i):
        path = self.files[i]
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{path}: not a readable image")
        return img


def open_images(folder):
    """Open a plain image folder (any names, natural order) as an :class:`ImageFolder`."""
    return ImageFolder(folder)


class VideoFile:
    """A video file as a read-only sequence of (H, W, 3) uint8 BGR frames.

    Keeps one ``cv2.VideoCapture`` open and reads forward from where the last read stopped, so
    sequential access decodes each frame once. Going backwards reopens the file and decodes forward
    again: slower, but exact, where ``CAP_PROP_POS_FRAMES`` seeking lands on keyframes for some
    codecs.
    """

    def __init__(self, path):
        self.path_ = Path(path)
        cap = cv2.VideoCapture(str(self.path_))
        if not cap.isOpened():
            raise ValueError(f"{self.path_}: OpenCV cannot open this video")
        self.n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self._cap, self._next = cap, 0

    def __len__(self):
        return self.n

    def path(self, i):
        return f"{self.path_}[frame {i}]"

    def __getitem__(self, i):
        if not 0 <= i < self.n:
            raise IndexError(f"{self.path_}: frame {i} out of range 0..{self.n - 1}")
        if i < self._next:
            self._cap.release()
            self._cap, self._next = cv2.VideoCapture(str(self.path_)), 0
        while self._next < i:
            if not self._cap.grab():
                raise ValueError(f"{self.path_}: ends at frame {self._next}, before frame {i}")
            self._next += 1
        ok, img = self._cap.read()
        if not ok:
            raise ValueError(f"{self.path_}: cannot decode frame {i}")
        self._next += 1
        return img

    def close(self):
        self._cap.release()


def _read_json(path, what):
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: missing ({what})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None


def _check_meta(meta, path):
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: top level must be an object")
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: field 'format' must be {FORMAT!r}, got {meta.get('format')!r}")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path}: field 'version' {meta.get('version')!r} is unknown "
                         f"(this gltrack reads version {VERSION})")
    if meta.get("rig") not in RIGS:
        raise ValueError(f"{path}: field 'rig' must be one of {RIGS}, got {meta.get('rig')!r}")
    fps = meta.get("fps")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0:
        raise ValueError(f"{path}: field 'fps' must be a positive number, got {fps!r}")
    n = meta.get("frames")
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"{path}: field 'frames' must be a non-negative integer, got {n!r}")
    if not isinstance(meta.get("body", {}), dict):
        raise ValueError(f"{path}: field 'body' must be an object")
    if "world" in meta:
        from gltrack.data.world import check_world

        check_world(meta["world"], path)


def _check_image(img, where, cam, role):
    """Raise ValueError unless ``img`` has the pixel format and size ``role`` needs for ``cam``."""
    if role == "depth":
        if img.dtype != np.uint16 or img.ndim != 2:
            raise ValueError(f"{where}: depth image must be 16-bit single-channel (uint16 mm), "
                             f"got {img.dtype} with shape {img.shape}")
    elif role == "colour":
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"{where}: colour image must be 8-bit 3-channel BGR, got "
                             f"{img.dtype} with shape {img.shape}")
    elif img.dtype != np.uint8 or img.ndim != 2:
        raise ValueError(f"{where}: {role} must be uint8 single-channel, got {img.dtype} "
                         f"with shape {img.shape}")
    if img.shape[:2] != (cam.height, cam.width):
        raise ValueError(f"{where}: image is {img.shape[1]}x{img.shape[0]} but calibration.json "
                         f"gives {cam.name} width x height = {cam.width}x{cam.height}")


def _polygons(obj, where):
    """Validate the polygon list of one camera: [[[x, y], ...], ...] in pixels."""
    if not isinstance(obj, list):
        raise ValueError(f"{where} must be a list of polygons")
    polys = []
    for k, poly in enumerate(obj):
        try:
            a = np.asarray(poly, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{where}[{k}] must be a list of [x, y] pixel points") from None
        if a.ndim != 2 or a.shape[1] != 2 or len(a) < 3 or not np.all(np.isfinite(a)):
            raise ValueError(f"{where}[{k}] must be at least 3 finite [x, y] points, got "
                             f"shape {a.shape}")
        polys.append(a)
    return polys


def check_groundtruth(arrays, where, frames=None):
    """Validate ground-truth arrays; return them as a dict of float64 arrays and name lists.

    Parameters
    ----------
    arrays : mapping of str to array
        ``joints`` (N, J, 3) m and ``joint_names`` (J,) str are required; ``markers`` (N, M, 3) m,
        ``marker_names`` (M,) str and ``params`` (N, D) are optional; other numeric arrays pass
        through unchanged.
    where : str
        File name for messages.
    frames : int, optional
        Required N.

    Returns
    -------
    dict
        Same keys; ``joint_names``/``marker_names`` as lists of str.
    """
    def numeric(key, ndim, last=None):
        a = np.asarray(arrays[key])
        if a.ndim != ndim or not (np.issubdtype(a.dtype, np.floating)
                                  or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"{where}: field {key!r} must be a numeric {ndim}-D array, got "
                             f"{a.dtype} with shape {a.shape}")
        if last is not None and a.shape[-1] != last:
            raise ValueError(f"{where}: field {key!r} must end in {last}, got shape {a.shape}")
        if np.isinf(a).any():
            raise ValueError(f"{where}: field {key!r} has infinite values")
        return a.astype(np.float64)

    def names(key, n):
        a = np.asarray(arrays[key])
        if a.dtype.kind != "U" or a.shape != (n,):
            raise ValueError(f"{where}: field {key!r} must be ({n},) strings, got {a.dtype} "
                             f"with shape {a.shape}")
        return [str(s) for s in a]

    for key in ("joints", "joint_names"):
        if key not in arrays:
            raise ValueError(f"{where}: field {key!r} missing")
    out = {k: v for k, v in arrays.items()}
    out["joints"] = numeric("joints", 3, 3)
    n, j = out["joints"].shape[:2]
    if frames is not None and n != frames:
        raise ValueError(f"{where}: field 'joints' has {n} frames, the dataset {frames}")
    out["joint_names"] = names("joint_names", j)
    if "markers" in arrays:
        out["markers"] = numeric("markers", 3, 3)
        if len(out["markers"]) != n:
            raise ValueError(f"{where}: field 'markers' has {len(out['markers'])} frames, "
                             f"'joints' {n}")
        if "marker_names" in arrays:
            out["marker_names"] = names("marker_names", out["markers"].shape[1])
    elif "marker_names" in arrays:
        raise ValueError(f"{where}: field 'marker_names' given without 'markers'")
    if "params" in arrays:
        out["params"] = numeric("params", 2)
        if len(out["params"]) != n:
            raise ValueError(f"{where}: field 'params' has {len(out['params'])} frames, "
                             f"'joints' {n}")
    for key, value in arrays.items():
        if np.asarray(value).dtype.kind == "O":
            raise ValueError(f"{where}: field {key!r} is an object array (not allowed)")
    return out


def load_groundtruth(path, frames=None):
    """Read and validate a ``groundtruth.npz`` (never unpickling); see :func:`check_groundtruth`."""
    from gltrack.npz import read_npz

    return check_groundtruth(read_npz(path), str(path), frames)


class Dataset:
    """A validated dataset folder with lazy per-frame access. Create with :meth:`open`.

    Attributes
    ----------
    path : Path
    meta : dict
        ``meta.json`` as read.
    frames : int
    fps : float
    rig : {"depth", "multiview"}
    body : dict
        Optional body parameters from ``meta.json`` (empty when absent).
    cameras : list of gltrack.camera.Camera

    Camera arguments (``cam``) are an index into :attr:`cameras` or a camera name.
    """

    def __init__(self, path, meta, cameras):
        self.path = Path(path)
        self.meta = meta
        self.frames = int(meta["frames"])
        self.fps = float(meta["fps"])
        self.rig = meta["rig"]
        self.body = dict(meta.get("body", {}))
        self.cameras = list(cameras)
        self._streams = {}
        self._masks = {}
        self._env = None
        self._gt = None
        self._kp = None

    # ---- opening and validation -------------------------------------------------------------
    @classmethod
    def open(cls, path):
        """Open and validate a dataset folder.

        Raises
        ------
        ValueError
            Naming the file and the field or property at fault: missing ``meta.json`` or
            ``calibration.json``, wrong format or version, unknown rig, frame counts that differ
            from ``meta.json``, images whose size differs from the calibration, wrong pixel formats
            (depth not uint16, colour not 8-bit 3-channel, masks not uint8 single-channel), bad
            ``environment.json`` or ``groundtruth.npz``.
        """
        from gltrack.camera import load_calibration

        path = Path(path)
        if not path.is_dir():
            raise ValueError(f"{path}: not a dataset folder")
        meta = _read_json(path / META, "every dataset needs one")
        _check_meta(meta, path / META)
        if not (path / CALIBRATION).is_file():
            raise ValueError(f"{path / CALIBRATION}: missing (every dataset needs one)")
        cameras = load_calibration(path / CALIBRATION)
        for i, c in enumerate(cameras):
            # Camera names become file names: keep every stream inside the dataset folder.
            if c.name in (".", "..") or any(ch in c.name for ch in "/\\\0"):
                raise ValueError(f"{path / CALIBRATION}: cameras[{i}].name {c.name!r} is not a "
                                 "plain folder name")
        if meta["rig"] == "depth" and not any(c.kind == "depth" for c in cameras):
            raise ValueError(f"{path / CALIBRATION}: rig 'depth' (meta.json) needs a camera of "
                             "kind 'depth'")
        ds = cls(path, meta, cameras)
        for cam in cameras:
            ds._validate_camera(cam)
        env = ds.environment()
        if env is not None:
            for name in env:
                ds.blocking_mask(name)
        ds.groundtruth()
        ds.keypoints()
        return ds

    def _validate_camera(self, cam):
        stream = self._stream(cam)
        where = getattr(stream, "folder", None) or stream.path_
        if len(stream) != self.frames:
            raise ValueError(f"{where}: {len(stream)} frames, but {self.path / META} field "
                             f"'frames' is {self.frames}")
        if self.frames:
            _check_image(stream[0], stream.path(0), cam, cam.kind)
        for role in ("mask", "gtmask"):
            masks = self._mask_stream(cam, role)
            if masks is None:
                continue
            if len(masks) != self.frames:
                raise ValueError(f"{masks.folder}: {len(masks)} masks, but {self.path / META} "
                                 f"field 'frames' is {self.frames}")
            if self.frames:
                _check_image(masks[0], masks.path(0), cam, role)
        self.backgrounds(self.cameras.index(cam))

    def _cam(self, cam):
        if isinstance(cam, str):
            for c in self.cameras:
                if c.name == cam:
                    return c
            raise KeyError(f"{self.path}: no camera named {cam!r} "
                           f"(have {[c.name for c in self.cameras]})")
        return self.cameras[cam]

    def _stream(self, cam):
        if cam.name not in self._streams:
            folder = self.path / cam.name
            videos = [self.path / (cam.name + e) for e in VIDEO_EXTS
                      if (self.path / (cam.name + e)).is_file()]
            if folder.is_dir():
                if videos:
                    log.warning("%s: both %s/ and %s exist; reading the folder", self.path,
                                cam.name, videos[0].name)
                stream = ImageFolder(folder)
            elif videos:
                if cam.kind == "depth":
                    raise ValueError(f"{videos[0]}: depth camera {cam.name} must be a folder of "
                                     "16-bit PNGs (video codecs cannot hold depth)")
                stream = VideoFile(videos[0])
            else:
                raise ValueError(f"{self.path}: no frames for camera {cam.name} (expected "
                                 f"{cam.name}/ or {cam.name}.mp4)")
            self._streams[cam.name] = stream
        return self._streams[cam.name]

    def _mask_stream(self, cam, role):
        key = (cam.name, role)
        if key not in self._masks:
            folder = self.path / f"{cam.name}_{role}"
            self._masks[key] = ImageFolder(folder) if folder.is_dir() else None
        return self._masks[key]

    def _frame(self, frame):
        frame = int(frame)
        if not 0 <= frame < self.frames:
            raise IndexError(f"{self.path}: frame {frame} out of range 0..{self.frames - 1}")
        return frame

    # ---- per-frame access -------------------------------------------------------------------
    def depth(self, frame, cam=0):
        """Depth image of a depth camera.

        Returns
        -------
        (H, W) float32, metres along the optical axis; 0 where invalid.
        """
        c = self._cam(cam)
        if c.kind != "depth":
            raise ValueError(f"{self.path}: camera {c.name} is a {c.kind} camera, not depth")
        stream, frame = self._stream(c), self._frame(frame)
        img = stream[frame]
        _check_image(img, stream.path(frame), c, "depth")
        return img.astype(np.float32) * np.float32(0.001)

    def colour(self, frame, cam=0):
        """Colour image of a colour camera: (H, W, 3) uint8, BGR."""
        c = self._cam(cam)
        if c.kind != "colour":
            raise ValueError(f"{self.path}: camera {c.name} is a {c.kind} camera, not colour")
        stream, frame = self._stream(c), self._frame(frame)
        img = stream[frame]
        _check_image(img, stream.path(frame), c, "colour")
        return img

    def prefetch(self, frame, *, colour: bool = True, masks: bool = False) -> None:
        """Start reading ``frame``'s colour images (and foreground masks) of every camera in
        the background, for a tracker that will ask for them next; a frame out of range,
        video cameras and absent masks are skipped. The reads check the images as usual when
        they are taken."""
        frame = int(frame)
        if not 0 <= frame < self.frames:
            return
        for c in self.cameras:
            streams = []
            if colour and c.kind == "colour":
                streams.append(self._stream(c))
            if masks:
                streams.append(self._mask_stream(c, "mask"))
            for s in streams:
                if isinstance(s, ImageFolder):
                    s.prefetch(frame)

    def _read_mask(self, frame, cam, role):
        c = self._cam(cam)
        masks = self._mask_stream(c, role)
        if masks is None:
            return None
        frame = self._frame(frame)
        img = masks[frame]
        _check_image(img, masks.path(frame), c, role)
        return img > 127

    def mask(self, frame, cam=0):
        """Foreground mask: (H, W) bool, or None when the dataset has none for ``cam``."""
        return self._read_mask(frame, cam, "mask")

    def gtmask(self, frame, cam=0):
        """Ground-truth foreground mask (diagnosis only): (H, W) bool, or None."""
        return self._read_mask(frame, cam, "gtmask")

    def backgrounds(self, cam=0):
        """All empty-scene frames of ``cam``: list of images as :meth:`depth` (float32 metres) or
        :meth:`colour` (uint8 BGR) return them; empty when there are none."""
        c = self._cam(cam)
        single = self.path / f"{c.name}_background.png"
        folder = self.path / f"{c.name}_background"
        paths = ([single] if single.is_file() else []) + \
            (list(ImageFolder(folder).files) if folder.is_dir() else [])
        out = []
        for p in paths:
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise ValueError(f"{p}: not a readable image")
            _check_image(img, p, c, c.kind)
            out.append(img.astype(np.float32) * np.float32(0.001) if c.kind == "depth" else img)
        return out

    def background(self, cam=0):
        """One empty-scene frame of ``cam`` for a background model, or None.

        The per-pixel median of all background frames (a single frame is returned as is); for
        depth, the median ignores invalid (0) samples.
        """
        imgs = self.backgrounds(cam)
        if not imgs:
            return None
        if len(imgs) == 1:
            return imgs[0]
        stack = np.stack(imgs)
        if self._cam(cam).kind == "depth":
            valid = np.where(stack > 0, stack, np.nan)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # pixels never valid stay 0
                med = np.nanmedian(valid, axis=0)
            return np.nan_to_num(med, nan=0.0).astype(np.float32)
        return np.median(stack, axis=0).round().astype(np.uint8)

    # ---- the user's world frame -------------------------------------------------------------
    def user_frame(self):
        """(3, 3) float64 ``R_user_from_internal``: ``X_user = R @ X_internal``.

        Cameras and ground truth of a dataset are in gltrack's internal +Y-up frame (results
        are written in the user's: :mod:`gltrack.data.results`); ``meta.json``'s ``"world"``
        record (written by ``gltrack ingest``, see :mod:`gltrack.data.world`) gives the
        rotation back to the frame of the user's calibration. Identity when the dataset has
        none (it was made in the internal frame).
        """
        world = self.meta.get("world")
        if world is None:
            return np.eye(3)
        from gltrack.data.world import check_world

        return check_world(world, self.path / META)

    def floor_height(self):
        """Height of the floor along internal +Y (metres), or None when unknown.

        ``meta.json``'s ``world.floor`` (``gltrack ingest --floor``; the rotation to the user's
        frame is about the origin, so it is also the floor's coordinate along the user's up
        axis). None for a dataset without that record (every synthetic one).
        """
        f = (self.meta.get("world") or {}).get("floor")
        return None if f is None else float(f)

    def assumed_floor(self):
        """Height of the floor along internal +Y (metres) that the data implies, or None.

        The recorded floor (:meth:`floor_height`); for a dataset without a ``world`` record
        (every synthetic one) 0, where the simulator stands its subjects; None for a recording
        whose floor is unknown (``gltrack ingest`` with no floor found: the calibration's
        origin may be anywhere, e.g. on a desk or at head height).
        """
        f = self.floor_height()
        if f is not None or self.meta.get("world") is not None:
            return f
        return 0.0

    def up_axis(self):
        """The user frame's up axis (``"y"``, ``"z"``, ``"-y"``, ...); ``"y"`` without a record."""
        return (self.meta.get("world") or {}).get("up", "y")

    def to_user_frame(self, points):
        """Points in the internal frame to the user's calibration frame.

        Parameters
        ----------
        points : (..., 3) array_like, metres, internal (+Y up) world coordinates

        Returns
        -------
        (..., 3) float64, metres, in the frame (and origin) of the user's calibration.
        """
        return np.asarray(points, dtype=np.float64) @ self.user_frame().T

    def from_user_frame(self, points):
        """The inverse of :meth:`to_user_frame`: (..., 3) user-frame points to internal ones."""
        return np.asarray(points, dtype=np.float64) @ self.user_frame()

    # ---- environment and ground truth -------------------------------------------------------
    def environment(self):
        """Occluder polygons from ``environment.json``, or None when the file is absent.

        File format: ``{"cameras": {"cam0": [[[x, y], [x, y], [x, y], ...], ...], ...}}``; each
        polygon is at least three points in pixel coordinates of that camera's image.

        Returns
        -------
        dict of str to list of (K, 2) float64 arrays
        """
        if self._env is None:
            path = self.path / ENVIRONMENT
            if not path.is_file():
                return None
            obj = _read_json(path, "environment")
            if not isinstance(obj, dict) or not isinstance(obj.get("cameras"), dict):
                raise ValueError(f"{path}: field 'cameras' must be an object mapping camera "
                                 "names to polygon lists")
            names = [c.name for c in self.cameras]
            env = {}
            for name, polys in obj["cameras"].items():
                if name not in names:
                    raise ValueError(f"{path}: field 'cameras.{name}' names no camera of "
                                     f"{CALIBRATION} ({names})")
                env[name] = _polygons(polys, f"{path}: cameras.{name}")
            self._env = env
        return self._env

    def blocking_mask(self, cam=0):
        """(H, W) bool: True where an occluder of ``environment.json`` covers the image of ``cam``
        (all False without an environment)."""
        c = self._cam(cam)
        mask = np.zeros((c.height, c.width), np.uint8)
        polys = (self.environment() or {}).get(c.name, [])
        if polys:
            cv2.fillPoly(mask, [np.round(p).astype(np.int32) for p in polys], 1)
        return mask.astype(bool)

    def groundtruth(self):
        """Ground truth from ``groundtruth.npz`` (validated, see :func:`check_groundtruth`), or
        None when the dataset has none."""
        if self._gt is None:
            path = self.path / GROUNDTRUTH
            if not path.is_file():
                return None
            self._gt = load_groundtruth(path, self.frames)
        return self._gt

    def keypoints(self):
        """Body landmarks from ``keypoints.npz``, or None when the dataset has none.

        Returns
        -------
        dict
            ``uv`` (N, C, L, 2) float64 image pixels of each camera (NaN: not found),
            ``visibility`` (N, C, L) in [0, 1], ``points`` (N, L, 3) float64 metres in the
            calibration's (internal) frame, triangulated (NaN: too few views),
            ``residual`` (N, C, L) pixels, ``names`` (L,) str landmark names (``""`` for
            landmarks gltrack has no name for). N is the dataset's frames, C its cameras.

        Raises
        ------
        ValueError
            Naming the file and the array whose shape or type is wrong.
        """
        if self._kp is None:
            path = self.path / KEYPOINTS
            if not path.is_file():
                return None
            from gltrack.npz import read_npz

            arrays = read_npz(path)
            n, c = self.frames, len(self.cameras)
            missing = [k for k in ("uv", "visibility", "points", "residual", "names")
                       if k not in arrays]
            if missing:
                raise ValueError(f"{path}: missing {', '.join(missing)}")
            L = len(arrays["names"])
            want = {"uv": (n, c, L, 2), "visibility": (n, c, L), "points": (n, L, 3),
                    "residual": (n, c, L)}
            for key, shape in want.items():
                a = arrays[key]
                if a.shape != shape or a.dtype.kind != "f":
                    raise ValueError(f"{path}: {key} must be float {shape} (frames, cameras, "
                                     f"landmarks), got {a.dtype} {a.shape}")
                arrays[key] = a.astype(np.float64)
            arrays["names"] = [str(v) for v in arrays["names"]]
            self._kp = arrays
        return self._kp

    def close(self):
        for s in self._streams.values():
            if isinstance(s, VideoFile):
                s.close()
        self._streams.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self):
        return (f"Dataset({str(self.path)!r}, rig={self.rig!r}, frames={self.frames}, "
                f"fps={self.fps:g}, cameras={[c.name for c in self.cameras]})")


def current_umask() -> int:
    """The process's file mode creation mask (read without changing it where Linux allows)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere: read it by setting it, and put it back at once
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def _remove_stale_partials(path: Path):
    """Delete the hidden ``.NAME.partial-PID-*`` folders that a writer killed outright (kill
    -9, the kernel's out-of-memory killer) left beside ``path``: those whose process is gone."""
    for d in path.parent.glob(f".{glob_escape(path.name)}.partial-*"):
        pid = d.name[len(f".{path.name}.partial-"):].split("-")[0]
        if d.is_dir() and pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            log.warning("removing %s, the partial dataset of a run that was killed", d)
            shutil.rmtree(d, ignore_errors=True)


class DatasetWriter:
    """Write a dataset folder atomically.

    Everything goes to a hidden sibling ``.NAME.partial-PID-XXXX`` (mode from the umask; one
    left by a process killed outright is removed by the next writer of NAME); :meth:`close`
    (or leaving a ``with`` block normally) checks that every camera has the same frames ``0..N-1``, writes
    ``meta.json`` and ``calibration.json`` and renames the folder into place. An exception inside
    the ``with`` block, or :meth:`abort`, deletes the partial folder, so no folder at ``path``
    ever claims to be complete when it is not.

    Parameters
    ----------
    path : path
        Target dataset folder.
    rig : {"depth", "multiview"}
    fps : float, frames per second
    cameras : sequence of gltrack.camera.Camera
    body : dict, optional
        JSON-serialisable body parameters stored in ``meta.json``.
    overwrite : bool
        Replace an existing non-empty ``path``; otherwise that raises FileExistsError.
    meta : dict, optional
        More JSON-serialisable top-level fields of ``meta.json`` (e.g. the simulator's
        ``"subject"``), written after the standard ones, which they may not replace.
    """

    def __init__(self, path, rig, fps, cameras, body=None, overwrite=False, meta=None):
        self.path = Path(path)
        if rig not in RIGS:
            raise ValueError(f"rig must be one of {RIGS}, got {rig!r}")
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.cameras = list(cameras)
        if not self.cameras:
            raise ValueError("a dataset needs at least one camera")
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate camera names {names}")
        if rig == "depth" and not any(c.kind == "depth" for c in self.cameras):
            raise ValueError("rig 'depth' needs a camera of kind 'depth'")
        self.rig, self.fps, self.body = rig, float(fps), dict(body or {})
        json.dumps(self.body)  # fail now, not at close(), on a body that JSON cannot hold
        self.extra_meta = dict(meta or {})
        clash = sorted(set(self.extra_meta) & {"format", "version", "fps", "frames", "rig",
                                               "body"})
        if clash:
            raise ValueError(f"meta may not replace the standard meta.json fields {clash}")
        json.dumps(self.extra_meta)
        if self.path.exists() and not overwrite and (not self.path.is_dir()
                                                     or any(self.path.iterdir())):
            raise FileExistsError(f"{self.path}: exists and is not empty (use overwrite)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_partials(self.path)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.partial-{os.getpid()}-",
                                         dir=self.path.parent))
        # mkdtemp makes drwx------; the dataset gets the mode any folder of the user gets
        os.chmod(self.tmp, 0o777 & ~current_umask())
        self._written = {}  # (camera name, role) -> set of frames
        self._closed = False

    def _cam(self, cam):
        if isinstance(cam, str):
            for c in self.cameras:
                if c.name == cam:
                    return c
            raise KeyError(f"no camera named {cam!r}")
        return self.cameras[cam]

    def _put(self, frame, cam, role, img):
        if self._closed:
            raise RuntimeError(f"{self.path}: writer is closed")
        frame = int(frame)
        if frame < 0:
            raise ValueError(f"frame must be >= 0, got {frame}")
        folder = self.tmp / (cam.name if role in ("depth", "colour") else f"{cam.name}_{role}")
        folder.mkdir(exist_ok=True)
        path = folder / f"{frame:06d}.png"
        if not cv2.imwrite(str(path), img):
            raise OSError(f"{path}: cv2.imwrite failed")
        self._written.setdefault((cam.name, role), set()).add(frame)

    @staticmethod
    def _depth_mm(z, cam):
        z = np.asarray(z, dtype=np.float64)
        if z.shape != (cam.height, cam.width):
            raise ValueError(f"depth for {cam.name} must be ({cam.height}, {cam.width}), got {z.shape}")
        mm = np.round(np.nan_to_num(z, nan=0.0, posinf=0.0, neginf=0.0) * 1000.0)
        # 0 means invalid; what a uint16 cannot hold is invalid too, never wrapped or clipped.
        mm[(mm < 0) | (mm > 65535)] = 0
        return mm.astype(np.uint16)

    def write_depth(self, frame, cam, z_metres):
        """Write a depth frame: (H, W) float metres; NaN, <= 0 and > 65.535 m are stored as 0."""
        c = self._cam(cam)
        if c.kind != "depth":
            raise ValueError(f"camera {c.name} is a {c.kind} camera, not depth")
        self._put(frame, c, "depth", self._depth_mm(z_metres, c))

    def write_colour(self, frame, cam, bgr):
        """Write a colour frame: (H, W, 3) uint8 BGR."""
        c = self._cam(cam)
        if c.kind != "colour":
            raise ValueError(f"camera {c.name} is a {c.kind} camera, not colour")
        bgr = np.asarray(bgr)
        _check_image(bgr, f"colour frame {frame} of {c.name}", c, "colour")
        self._put(frame, c, "colour", bgr)

    def _mask(self, frame, cam, mask, role):
        c = self._cam(cam)
        mask = np.asarray(mask)
        if mask.shape != (c.height, c.width):
            raise ValueError(f"{role} for {c.name} must be ({c.height}, {c.width}), got {mask.shape}")
        self._put(frame, c, role, np.where(mask.astype(bool), 255, 0).astype(np.uint8))

    def write_mask(self, frame, cam, mask):
        """Write a foreground mask: (H, W) bool (or anything, nonzero = foreground)."""
        self._mask(frame, cam, mask, "mask")

    def write_gtmask(self, frame, cam, mask):
        """Write a ground-truth foreground mask (diagnosis only): (H, W) bool."""
        self._mask(frame, cam, mask, "gtmask")

    def write_background(self, cam, image, index=None):
        """Write an empty-scene frame: float metres for a depth camera, uint8 BGR for colour.

        ``index=None`` writes ``CAM_background.png``; an integer writes
        ``CAM_background/INDEX.png`` (several frames for a background model).
        """
        c = self._cam(cam)
        img = self._depth_mm(image, c) if c.kind == "depth" else np.asarray(image)
        _check_image(img, f"background of {c.name}", c, c.kind)
        if index is None:
            path = self.tmp / f"{c.name}_background.png"
        else:
            (self.tmp / f"{c.name}_background").mkdir(exist_ok=True)
            path = self.tmp / f"{c.name}_background" / f"{int(index):06d}.png"
        if not cv2.imwrite(str(path), img):
            raise OSError(f"{path}: cv2.imwrite failed")

    def write_environment(self, polygons):
        """Write ``environment.json``.

        Parameters
        ----------
        polygons : dict of camera name (or index) to a list of (K, 2) pixel polygons, K >= 3
        """
        cams = {}
        for cam, polys in polygons.items():
            c = self._cam(cam)
            cams[c.name] = [p.tolist() for p in
                            _polygons([np.asarray(p, dtype=np.float64).tolist() for p in polys],
                                      f"polygons of {c.name}")]
        (self.tmp / ENVIRONMENT).write_text(json.dumps({"cameras": cams}, indent=1))

    def write_keypoints(self, uv, visibility, points, residual, names):
        """Write ``keypoints.npz`` (shapes in :meth:`Dataset.keypoints`)."""
        np.savez_compressed(self.tmp / KEYPOINTS, uv=np.asarray(uv, np.float32),
                            visibility=np.asarray(visibility, np.float32),
                            points=np.asarray(points, np.float64),
                            residual=np.asarray(residual, np.float32),
                            names=np.asarray(list(names), dtype=str))

    def write_groundtruth(self, joints, joint_names, markers=None, params=None, **extra):
        """Write ``groundtruth.npz``.

        Parameters
        ----------
        joints : (N, J, 3) float, metres
        joint_names : sequence of str, (J,)
        markers : (N, M, 3) float, metres, optional
        params : (N, D) float, optional
        **extra : numeric arrays stored alongside (e.g. ``marker_names`` (M,) str)
        """
        arrays = {"joints": np.asarray(joints, dtype=np.float64),
                  "joint_names": np.asarray(list(joint_names), dtype=str)}
        if markers is not None:
            arrays["markers"] = np.asarray(markers, dtype=np.float64)
        if params is not None:
            arrays["params"] = np.asarray(params, dtype=np.float64)
        for key, value in extra.items():
            v = np.asarray(value)
            arrays[key] = v.astype(str) if v.dtype.kind in "SU" or key.endswith("_names") else v
        check_groundtruth(arrays, "groundtruth")
        np.savez_compressed(self.tmp / GROUNDTRUTH, **arrays)

    def _frame_count(self):
        sets = {c.name: self._written.get((c.name, c.kind), set()) for c in self.cameras}
        n = max(len(s) for s in sets.values())
        expect = set(range(n))
        for name, s in sets.items():
            if s != expect:
                missing = sorted(expect - s)[:5]
                raise ValueError(f"{self.path}: camera {name} has {len(s)} frames, expected "
                                 f"0..{n - 1} (missing e.g. {missing})")
        for (name, role), s in self._written.items():
            if role in ("mask", "gtmask") and s != expect:
                raise ValueError(f"{self.path}: {name}_{role} has {len(s)} of {n} frames")
        return n

    def close(self):
        """Finish the dataset and move it into place; on failure nothing is left behind."""
        from gltrack.camera import save_calibration

        if self._closed:
            return
        try:
            n = self._frame_count()
            gt = self.tmp / GROUNDTRUTH
            if gt.is_file():
                load_groundtruth(gt, n)
            save_calibration(self.tmp / CALIBRATION, self.cameras)
            fps = int(self.fps) if self.fps.is_integer() else self.fps
            meta = {"format": FORMAT, "version": VERSION, "fps": fps, "frames": n,
                    "rig": self.rig, "body": self.body, **self.extra_meta}
            (self.tmp / META).write_text(json.dumps(meta, indent=1) + "\n")
            self._replace_target()
        except BaseException:
            self.abort()
            raise
        self._closed = True
        log.info("wrote dataset %s (%d frames, %d cameras)", self.path, n, len(self.cameras))

    def _replace_target(self):
        old = None
        if self.path.exists():
            if self.path.is_dir() and not any(self.path.iterdir()):
                self.path.rmdir()
            else:
                # Move the old one aside first, so the target is never a half-deleted folder.
                old = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.old-", dir=self.path.parent))
                os.rename(self.path, old / "data")
        os.rename(self.tmp, self.path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def abort(self):
        """Discard everything written; the target folder is left untouched."""
        self._closed = True
        shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False
