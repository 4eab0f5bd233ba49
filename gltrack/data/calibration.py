"""Calibration files of other tools, and one entry point that recognises them by their content.

Formats (every reader returns :class:`gltrack.camera.Camera` objects: OpenCV ``K``, five-term
distortion, world -> camera ``R, t`` in metres, in the file's own world frame):

==================  =======================================  =====================================
format name          file                                     reader
==================  =======================================  =====================================
``gltrack``          dataset ``calibration.json``             :func:`gltrack.camera.load_calibration`
``opencv``           ``cv2.FileStorage`` YAML / JSON / XML    :func:`gltrack.camera.load_opencv_yaml`
``caliscope``        ``camera_array.toml`` / ``config.toml``  :func:`gltrack.camera.load_caliscope_toml`
``pose2sim``         Pose2Sim / anipose ``Calib*.toml``       :func:`load_pose2sim_toml`
``qualisys``         Qualisys ``*.qca.txt`` (XML)             :func:`load_qualisys_qca`
==================  =======================================  =====================================

:func:`load_any_calibration` detects the format from the content (:func:`detect_format`), not
from the file name, reads it and checks the units (:func:`check_metres`).

Units
-----
Every format but Qualisys (millimetres by definition, converted by its reader) stores
translations in metres. A calibration written in millimetres where metres are expected is
detected from the spread of the camera centres: a rig whose centres lie more than
:data:`MAX_RIG_SPAN_M` (50) apart is taken to be in millimetres, and reading it is an **error**,
not a silent conversion. Why an error: the file's unit is the user's unit, and results are
written back in the user's frame; converting would make them come back in metres against a
calibration in millimetres, and a file that is wrong for gltrack is probably wrong for the tool
that wrote it too. Real motion-capture rigs span 2-20 m (50 m would be a stadium); in
millimetres the same rigs span 2000-20000 "units", so the threshold separates them by orders of
magnitude on both sides.
"""
from __future__ import annotations

import json
import logging
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from gltrack.camera import (Camera, _check_unique, _dist5, _load_toml, _rotation_from, _validated,
                            load_caliscope_toml, load_calibration, load_opencv_yaml)

log = logging.getLogger(__name__)

FORMATS = ("gltrack", "opencv", "caliscope", "pose2sim", "qualisys")
#: Camera centres further apart than this (in the file's units) mean millimetres, not metres.
MAX_RIG_SPAN_M = 50.0
#: Calibration files are small; anything larger is not one (and is not read into memory).
MAX_FILE_BYTES = 16 * 1024 * 1024
#: Qualisys camera models whose calibration describes a video image (as Pose2Sim selects them).
QCA_VIDEO_MODELS = ("Miqus Video", "Miqus Video UnderWater", "none")
#: Qualisys stores focal length, principal point (and, as Pose2Sim reads them, distortion) in
#: units of 1/64 pixel.
QCA_SUBPIXELS = 64.0
_ROTATION_FIELDS = ("r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33")


def _natural_key(name):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _renamed(exc, where, names):
    """Re-raise a Camera validation error with the file's field names instead of ours."""
    msg = str(exc)
    for attr, key in names:
        msg = msg.replace(f"{where}.{attr} ", f"{where}.{key} ")
    return ValueError(msg)


# --------------------------------------------------------------------------------------------
# Pose2Sim / anipose TOML
# --------------------------------------------------------------------------------------------
def load_pose2sim_toml(path) -> list[Camera]:
    """Read a Pose2Sim / anipose calibration TOML.

    Layout: one table per camera (any table name, e.g. ``[cam_01]``; ``[metadata]`` is skipped)
    with ``name`` (str, optional: the table name), ``size = [width, height]`` (pixels, may be
    reals), ``matrix`` (3x3 K), ``distortions`` (``[k1, k2, p1, p2]`` or with ``k3``),
    ``rotation`` (Rodrigues vector, radians; a 3x3 matrix is accepted too) and ``translation``
    (metres), OpenCV world -> camera, and ``fisheye`` (must be false: the fisheye lens model is
    not supported).

    Returns
    -------
    list of Camera, in file order, ``kind="colour"``.

    Raises
    ------
    ValueError
        Bad TOML, no camera table, or a missing/malformed field, named as ``FILE: [table].field``.
    """
    path = Path(path)
    data = _load_toml(path)
    tables = [(k, v) for k, v in data.items() if isinstance(v, dict) and k != "metadata"]
    if not tables:
        raise ValueError(f"{path}: no camera tables (e.g. [cam_01] with matrix, distortions, "
                         "rotation, translation, size)")
    cameras = []
    for key, tab in tables:
        where = f"{path}: [{key}]"
        name = tab.get("name", key)
        if not isinstance(name, str) or not name:
            raise ValueError(f"{where}.name must be a non-empty string, got {name!r}")
        if tab.get("fisheye", False):
            raise ValueError(f"{where}.fisheye = true: the fisheye lens model is not supported "
                             "(calibrate with the pinhole model)")
        for fld in ("size", "matrix", "rotation", "translation"):
            if tab.get(fld) is None:
                raise ValueError(f"{where}.{fld} is missing")
        size = tab["size"]
        if not (isinstance(size, list) and len(size) == 2):
            raise ValueError(f"{where}.size must be [width, height], got {size!r}")
        try:
            rotation = np.array(tab["rotation"], dtype=np.float64)
            dist = np.array(tab.get("distortions", np.zeros(5)), dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ValueError(f"{where}: rotation and distortions must be numbers") from None
        if rotation.shape not in ((3,), (3, 3)):
            raise ValueError(f"{where}.rotation must be a Rodrigues vector of 3 numbers, got "
                             f"shape {rotation.shape}")
        raw = {"name": name, "kind": "colour", "width": size[0], "height": size[1],
               "K": tab["matrix"], "dist": _dist5(dist, where, "distortions"),
               "R": _rotation_from(None if rotation.shape == (3,) else rotation,
                                   rotation if rotation.shape == (3,) else None, where,
                                   "rotation", "rotation"),
               "t": tab["translation"]}
        try:
            cameras.append(Camera(**_validated(raw, where)))
        except ValueError as exc:
            raise _renamed(exc, where, (("K", "matrix"), ("R", "rotation"), ("t", "translation"),
                                        ("width", "size[0]"), ("height", "size[1]"))) from None
    _check_unique(cameras, str(path))
    return cameras


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v))


def save_pose2sim_toml(path, cameras) -> None:
    """Write cameras as a Pose2Sim / anipose calibration TOML (see :func:`load_pose2sim_toml`).

    Tables are ``[cam_01]``, ``[cam_02]``, ... in order, each with the camera's ``name``;
    distortion is written with five terms, the rotation as a Rodrigues vector; a
    ``[metadata]`` table closes the file as Pose2Sim writes it. Floats keep full precision.
    """
    import cv2

    cameras = list(cameras)
    _check_unique(cameras, str(path))
    lines = []
    for i, cam in enumerate(cameras, 1):
        rvec = cv2.Rodrigues(cam.R)[0].ravel()
        lines += [f"[cam_{i:02d}]", f"name = {_toml_value(cam.name)}",
                  f"size = {_toml_value([cam.width, cam.height])}",
                  f"matrix = {_toml_value(cam.K.tolist())}",
                  f"distortions = {_toml_value(cam.dist.tolist())}",
                  f"rotation = {_toml_value(rvec.tolist())}",
                  f"translation = {_toml_value(cam.t.tolist())}", "fisheye = false", ""]
    lines += ["[metadata]", "adjusted = false", "error = 0.0", ""]
    Path(path).write_text("\n".join(lines), encoding="utf-8")


# --------------------------------------------------------------------------------------------
# Qualisys .qca.txt
# --------------------------------------------------------------------------------------------
def _attr_float(el, name, where):
    value = el.get(name)
    if value is None:
        raise ValueError(f"{where}.{name} is missing")
    try:
        x = float(value)
    except ValueError:
        raise ValueError(f"{where}.{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{where}.{name} must be finite, got {value!r}")
    return x


def _child(el, tag, where):
    child = el.find(tag)
    if child is None:
        raise ValueError(f"{where}: element <{tag}> is missing")
    return child


def load_qualisys_qca(path, binning: int = 1) -> list[Camera]:
    """Read a Qualisys ``.qca.txt`` calibration (XML), converting it as Pose2Sim does.

    Conventions (those of Pose2Sim's ``calib_qca_to_toml``, so that a Pose2Sim user's TOML and
    the ``.qca.txt`` it came from give the same cameras):

    * ``<transform>``: ``r11 .. r33`` read row by row are the world -> camera rotation of a
      camera that looks down its -z axis with y up; OpenCV's is ``R = diag(1, -1, -1) @ R_qca``.
      ``x y z`` is the camera centre in **millimetres**: ``t = -R @ (x, y, z) / 1000``.
    * ``<intrinsic>``: ``focalLengthU/V`` and ``centerPointU/V`` are in 1/64 pixel of the full
      sensor; the principal point is measured from the corner of the sensor, so the
      ``<fov_video>`` window's ``left``/``top`` are subtracted (``cx = U/64/binning - left``);
      Pose2Sim takes the result directly as OpenCV's ``cx`` (pixel centres at integers).
      ``radialDistortion1/2`` and ``tangentalDistortion1/2`` are divided by 64 (and by the
      binning) as Pose2Sim does; ``radialDistortion3`` is dropped as Pose2Sim drops it (with a
      warning when it is not 0).
    * Image size: ``<fov_video>`` ``right - left + 1`` by ``bottom - top + 1``, divided by the
      binning.
    * A camera attribute ``video_resolution="540p"`` (etc.) scales the image and ``K`` by
      ``res / 1080`` (Miqus video cameras calibrate at 1080p); without it 1080p is assumed.
    * Only video cameras (``model`` one of :data:`QCA_VIDEO_MODELS`) are kept: marker-only
      Qualisys cameras have no images to track. Cameras are named by ``serial`` and sorted in
      natural order of it.

    Parameters
    ----------
    path : path
    binning : int
        Sensor binning factor of the recording (Pose2Sim's ``binning_factor``), usually 1.

    Raises
    ------
    ValueError
        Not XML, no ``<calibration><cameras><camera>``, or a missing/malformed element or
        attribute, named as ``FILE: camera[i] (serial S).<element>.attribute``.
    """
    path = Path(path)
    if binning not in (1, 2, 4):
        raise ValueError(f"binning must be 1, 2 or 4, got {binning!r}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not valid XML ({exc})") from None
    if root.tag != "calibration":
        raise ValueError(f"{path}: root element must be <calibration>, got <{root.tag}>")
    elements = root.findall("cameras/camera")
    if not elements:
        raise ValueError(f"{path}: no <cameras><camera> elements")
    cameras = []
    for i, el in enumerate(elements):
        serial = el.get("serial") or f"cam{i}"
        where = f"{path}: camera[{i}] (serial {serial})"
        model = el.get("model")
        if model not in QCA_VIDEO_MODELS:
            log.info("%s: model %r is not a video camera; skipped", where, model)
            continue
        res_text = el.get("video_resolution")
        res = 1080
        if res_text not in (None, "", "N/A"):
            m = re.fullmatch(r"\s*(\d+)\s*p?\s*", res_text)
            if not m or int(m.group(1)) <= 0:
                raise ValueError(f"{where}.video_resolution must look like '1080p', "
                                 f"got {res_text!r}")
            res = int(m.group(1))
        scale = res / 1080.0
        fov = _child(el, "fov_video", where)
        fw = f"{where}.fov_video"
        left, top = _attr_float(fov, "left", fw), _attr_float(fov, "top", fw)
        right, bottom = _attr_float(fov, "right", fw), _attr_float(fov, "bottom", fw)
        width = (right - left + 1) / binning * scale
        height = (bottom - top + 1) / binning * scale
        intr = _child(el, "intrinsic", where)
        iw = f"{where}.intrinsic"
        q = QCA_SUBPIXELS * binning
        fu = _attr_float(intr, "focalLengthU", iw) / q * scale
        fv = _attr_float(intr, "focalLengthV", iw) / q * scale
        cu = (_attr_float(intr, "centerPointU", iw) / q - left) * scale
        cv = (_attr_float(intr, "centerPointV", iw) / q - top) * scale
        dist = [_attr_float(intr, "radialDistortion1", iw) / q,
                _attr_float(intr, "radialDistortion2", iw) / q,
                _attr_float(intr, "tangentalDistortion1", iw) / q,
                _attr_float(intr, "tangentalDistortion2", iw) / q, 0.0]
        k3 = intr.get("radialDistortion3")
        if k3 is not None and float(k3) != 0.0:
            log.warning("%s.radialDistortion3 = %s ignored (as Pose2Sim ignores it)", iw, k3)
        tr = _child(el, "transform", where)
        tw = f"{where}.transform"
        R_qca = np.array([_attr_float(tr, k, tw) for k in _ROTATION_FIELDS]).reshape(3, 3)
        centre_mm = np.array([_attr_float(tr, k, tw) for k in ("x", "y", "z")])
        R = np.diag([1.0, -1.0, -1.0]) @ R_qca
        t = -R @ (centre_mm / 1000.0)
        if abs(round(width) - width) > 1e-6 or abs(round(height) - height) > 1e-6:
            raise ValueError(f"{fw}: image size {width}x{height} (after binning {binning} and "
                             f"video_resolution {res}p) is not whole pixels")
        raw = {"name": serial, "kind": "colour", "width": int(round(width)),
               "height": int(round(height)),
               "K": [[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]], "dist": dist, "R": R, "t": t}
        try:
            cameras.append(Camera(**_validated(raw, where)))
        except ValueError as exc:
            raise _renamed(exc, where, (("K", "intrinsic"), ("R", "transform.r11..r33"),
                                        ("t", "transform.x/y/z"))) from None
    if not cameras:
        raise ValueError(f"{path}: no video camera (model one of {QCA_VIDEO_MODELS})")
    cameras.sort(key=lambda c: _natural_key(c.name))
    _check_unique(cameras, str(path))
    return cameras


# --------------------------------------------------------------------------------------------
# detection and the one entry point
# --------------------------------------------------------------------------------------------
def _read_text(path: Path) -> str:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{path}: {size} bytes is too large for a calibration file")
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (a calibration is TOML, XML, YAML or "
                         "JSON)") from None


def detect_format(path) -> str:
    """Name the calibration format of ``path`` from its content (see :data:`FORMATS`).

    XML with a ``<calibration>`` root is Qualisys, with ``<opencv_storage>`` OpenCV; ``%YAML``
    is OpenCV; JSON with a ``"cameras"`` list is gltrack's ``calibration.json``, other JSON
    OpenCV FileStorage; TOML with a ``[cameras.N]`` table or tables holding ``cam_id``/``port``
    is caliscope, TOML tables holding ``matrix`` are Pose2Sim / anipose.

    Raises
    ------
    FileNotFoundError, ValueError
        The file is none of these (the message names the file and what was expected).
    """
    path = Path(path)
    text = _read_text(path)
    head = text.lstrip()
    if head.startswith("<"):
        if re.search(r"<\s*opencv_storage\b", head):
            return "opencv"
        if re.search(r"<\s*calibration\b", head):
            return "qualisys"
        raise ValueError(f"{path}: XML but neither a Qualisys .qca.txt (<calibration>) nor an "
                         "OpenCV FileStorage file (<opencv_storage>)")
    if head.startswith("%YAML"):
        return "opencv"
    if head.startswith("{"):
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        return "gltrack" if isinstance(obj, dict) and "cameras" in obj else "opencv"
    try:
        data = _load_toml(path)
    except ValueError:
        raise ValueError(f"{path}: not a calibration file this gltrack reads (Pose2Sim/anipose "
                         "or caliscope TOML, Qualisys .qca.txt, OpenCV YAML/JSON/XML, gltrack "
                         "calibration.json)") from None
    if isinstance(data.get("cameras"), dict):
        return "caliscope"
    tables = [v for k, v in data.items() if isinstance(v, dict) and k != "metadata"]
    if any("cam_id" in v or "port" in v for v in tables):
        return "caliscope"
    if any("matrix" in v for v in tables):
        return "pose2sim"
    raise ValueError(f"{path}: TOML without camera tables (expected [cam_01] tables with "
                     "matrix, distortions, rotation, translation, size; or caliscope's "
                     "[cameras.N])")


_READERS = {"gltrack": load_calibration, "opencv": load_opencv_yaml,
            "caliscope": load_caliscope_toml, "pose2sim": load_pose2sim_toml,
            "qualisys": load_qualisys_qca}
#: the name of the translation field in each format, for messages
_TRANSLATION_FIELD = {"gltrack": "t", "opencv": "T (or tvec)", "caliscope": "translation",
                      "pose2sim": "translation", "qualisys": "transform.x/y/z"}


def check_metres(cameras, path, fmt="gltrack") -> float:
    """Raise ValueError when the cameras' translations look like millimetres; return the span.

    The span is the largest distance between two camera centres, in the file's units; more than
    :data:`MAX_RIG_SPAN_M` is an error (see the module docstring for why it is not converted).
    A single camera cannot be checked this way; its distance from the world origin is used.
    """
    centres = np.array([c.center for c in cameras])
    if len(centres) > 1:
        span = float(np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)))
        what = "camera centres lie up to"
    else:
        span = float(np.linalg.norm(centres[0]))
        what = "the camera lies"
    if span > MAX_RIG_SPAN_M:
        fld = _TRANSLATION_FIELD.get(fmt, "translation")
        raise ValueError(f"{path}: {fld}: {what} {span:.0f} units apart; gltrack expects metres "
                         f"and no rig spans more than {MAX_RIG_SPAN_M:g} m: this calibration "
                         "looks like millimetres (divide the translations by 1000)")
    return span


def load_any_calibration(path, fmt: str | None = None) -> list[Camera]:
    """Read the cameras of any supported calibration file, detecting its format from the content.

    Parameters
    ----------
    path : path
    fmt : str, optional
        One of :data:`FORMATS` to skip detection.

    Returns
    -------
    list of Camera
        In the file's world frame, metres; names as the file gives them.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Unknown format, a missing or malformed field (message names the file and the field), or
        translations in millimetres (:func:`check_metres`).
    """
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
    elif fmt not in _READERS:
        raise ValueError(f"unknown calibration format {fmt!r} (one of {FORMATS})")
    cameras = _READERS[fmt](path)
    check_metres(cameras, path, fmt)
    log.info("%s: %d cameras (%s format)", path, len(cameras), fmt)
    return cameras
