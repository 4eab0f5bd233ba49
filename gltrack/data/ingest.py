"""Turn a user's calibrated, synchronised videos into a gltrack dataset (``gltrack ingest``).

What :func:`ingest` does, in order, failing before anything is written on bad input:

1. **Calibration**: any format :func:`gltrack.data.calibration.load_any_calibration` reads
   (detected from the content; translations in millimetres are an error).
2. **Videos to cameras**: by name, comparing names case-insensitively with separators removed
   and leading zeros of numbers ignored (``cam01`` = ``cam_01`` = ``CAM-1`` = ``cam01.mp4``);
   when no video name matches any camera and the counts agree, by order (with a warning).
   Missing, extra or unmatched videos are errors naming the file.
3. **Image sizes** (:func:`fit_camera`): the size of the first decoded frame (after OpenCV's
   orientation handling) is compared with the calibration's. Equal: used as is. A uniform
   scaling (within 1 px): ``K`` is rescaled (:meth:`Camera.scaled`). A difference of fewer than
   :data:`PAD_PX` pixels (and 5 %) per side, at the calibration's size or at a uniform scaling
   of it (encoders pad or crop to multiples of 16: the Pose2Sim take's
   1080-wide videos of a 1088-wide calibration): accepted with a warning; the extra or missing
   columns/rows are taken to be at the right/bottom edge, where encoders put them, so ``K`` is
   kept and only the image size changes (a centred crop of 8 px would shift the image by 4 px,
   0.2 % of its width; the calibration cannot tell). Anything else is an error.
4. **Synchronisation** (:func:`frame_map`): with caliscope's ``timestamps.csv`` (beside the
   calibration, or given), dataset frame ``j`` is the ``j``-th ``sync_index`` that every camera
   has, and each camera's video frame is its ``frame_index`` (relative to its first one when
   the video is a clip cut from a longer recording); otherwise frame ``j`` of every video is
   frame ``j`` of the dataset and frame counts that differ are cut to the shortest (warning).
5. **Frames and rate**: ``frames=(A, B)`` selects synchronised frames ``A .. B-1`` at the source
   rate; ``fps=F`` (at most the source rate) keeps the frames nearest to ``A + k * src/F``.
6. **Scale** (:func:`default_scale`): images and cameras are downsized by one factor for all
   cameras. Default: the longest image side becomes at most :data:`DEFAULT_LONG_SIDE` (640)
   pixels. Why 640: the trackers score every candidate pose by rendering it into every camera
   with software GL on 2 cores, so the cost grows with the pixel count; a person who fills most
   of a 1920-pixel portrait frame is still ~450 pixels tall at 640 (limbs 15-30 px wide), far
   more than a silhouette fit needs (the synthetic datasets use 320x240), while a 1920-pixel
   frame would cost 9x more per evaluation for no gain.
7. **World frame** (:mod:`gltrack.data.world`): ``up="auto"`` takes the world axis nearest the
   cameras' mean image-up direction; the cameras are rotated into gltrack's +Y-up frame and
   ``meta.json`` records ``"world": {"up", "R_user_from_internal"}``.
8. **Frames on disk**: the selected frames are decoded once, resized and written as PNG
   (lossless, so the dataset holds exactly what the decoder gave) into a hidden temporary folder
   beside ``out``, renamed into place only when complete (:class:`DatasetWriter`): failing or
   interrupted runs leave nothing that blocks a rerun. The videos are not copied: at the
   default scale a 360x640 frame is ~0.3 MB of PNG, so the 100-frame 4-camera Pose2Sim take
   is 132 MB (caliscope, 111 frames of 640x360: 120 MB); :data:`DEFAULT_MAX_GB` guards against
   extracting gigabytes by accident.
   ``meta.json``'s ``"source"`` records the calibration, its format, each camera's video, its
   size and the video frame of every dataset frame, the scale and the synchronisation used.
9. **Keypoints** (``keypoints="auto"``, when the landmark model is installed;
   :func:`write_keypoints`): MediaPipe's pose landmarks in every camera, triangulated, written
   as ``keypoints.npz``. They come before the masks because the same network also segments the
   person, and that segmentation is the masks' ``"prior"`` cue; each camera's first crop is
   then the whole image (the person is found in it on both shared takes).
10. **Foreground masks** (``masks="auto"``, the default; :func:`write_masks`): real footage has
   no empty-scene frames, so the multi-view trackers (which read ``camN_mask/`` when every
   camera has it, else subtract ``camN_background.png``) need masks estimated from the sequence
   itself: :func:`gltrack.observe.foreground.estimate_foreground` runs over the written frames
   (at its own working resolution) and the masks are written at the dataset's image size as
   ``camN_mask/%06d.png`` (255 = foreground), inside the same temporary folder, so a failure
   leaves nothing behind. ``meta.json``'s ``"masks"`` records what made them. The estimated
   temporal background is *not* written as ``camN_background.png``: that file means an
   empty-scene frame, and this one holds the subject's "ghost" wherever they stood still (and
   inpainting where nothing was observed); a tracker or ``--foreground background`` that used
   it would subtract the ghost. ``masks="none"`` writes frames only.
"""
from __future__ import annotations

import csv
import logging
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from gltrack.camera import Camera
from gltrack.data.calibration import detect_format, load_any_calibration
from gltrack.data.dataset import DatasetWriter
from gltrack.data.world import (AXES, detect_floor, detect_up, internal_from_user, to_internal,
                                world_meta)

log = logging.getLogger(__name__)

#: Differences in image size below this many pixels per side are encoder padding/cropping ...
PAD_PX = 16
#: ... when they are also below this fraction of the side (8 px of 1088 is 0.7 %).
PAD_FRACTION = 0.05
#: Default: the longest image side after scaling, pixels (see the module docstring).
DEFAULT_LONG_SIDE = 640
#: Refuse to write more PNG than this (estimated from the first frame) unless raised.
DEFAULT_MAX_GB = 2.0
TIMESTAMPS = "timestamps.csv"
#: Values of ``ingest(masks=...)``.
MASKS = ("auto", "none")
_NAME_OK = re.compile(r"^[A-Za-z0-9_.-]+$")


# --------------------------------------------------------------------------------------------
# videos
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VideoInfo:
    """What :func:`probe_video` learns from a video file.

    Attributes
    ----------
    path : Path
    width, height : int, pixels of the decoded frames
    frames : int, frame count reported by the container
    fps : float, frames per second reported by the container (0 when unknown)
    """

    path: Path
    width: int
    height: int
    frames: int
    fps: float


def probe_video(path) -> VideoInfo:
    """Open a video and decode its first frame.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        OpenCV cannot open it, or cannot decode its first frame (message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such video file")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise ValueError(f"{path}: OpenCV cannot open this video")
        ok, img = cap.read()
        if not ok or img is None:
            raise ValueError(f"{path}: cannot decode the first frame (not a video, or a codec "
                             "OpenCV lacks)")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    finally:
        cap.release()
    if n <= 0:
        raise ValueError(f"{path}: the container reports no frame count")
    return VideoInfo(path, int(img.shape[1]), int(img.shape[0]), n, fps if fps > 0 else 0.0)


def _norm(name: str) -> str:
    """Name for matching: lower case, only letters and digits, numbers without leading zeros."""
    s = re.sub(r"[^a-z0-9]", "", name.lower())
    return re.sub(r"\d+", lambda m: str(int(m.group())), s)


def match_videos(cameras, videos, calibration) -> list[Path]:
    """The video of each camera, in camera order (see the module docstring, step 2).

    Parameters
    ----------
    cameras : sequence of Camera
    videos : sequence of path
    calibration : path, for messages

    Returns
    -------
    list of Path, one per camera.

    Raises
    ------
    ValueError
        One line naming the video without a camera, or the camera without a video.
    """
    videos = [Path(v) for v in videos]
    names = [c.name for c in cameras]
    if not videos:
        raise ValueError(f"no videos given for the {len(cameras)} cameras of {calibration}")
    seen = {}
    for v in videos:
        key = v.resolve()
        if key in seen:
            raise ValueError(f"{v}: given twice")
        seen[key] = v
    ckeys = [_norm(n) for n in names]
    vkeys = [_norm(v.stem) for v in videos]
    unique = len(set(ckeys)) == len(ckeys) and len(set(vkeys)) == len(vkeys)
    hits = [k in ckeys for k in vkeys] if unique else [False] * len(videos)
    if not any(hits):
        if len(videos) != len(cameras):
            extra = videos[len(cameras)] if len(videos) > len(cameras) else None
            if extra is not None:
                raise ValueError(f"{extra}: {len(videos)} videos for the {len(cameras)} cameras "
                                 f"of {calibration} ({', '.join(names)}); no video name matches "
                                 "a camera name, so they are matched by order")
            raise ValueError(f"{calibration}: camera {names[len(videos)]} has no video "
                             f"({len(videos)} videos for {len(cameras)} cameras; no video name "
                             "matches a camera name, so they are matched by order)")
        log.warning("no video name matches a camera name of %s: matched by order (%s)",
                    calibration, ", ".join(f"{n} <- {v.name}" for n, v in zip(names, videos)))
        return videos
    for v, hit in zip(videos, hits):
        if not hit:
            raise ValueError(f"{v}: matches no camera of {calibration} ({', '.join(names)})")
    by_key = dict(zip(vkeys, videos))
    for name, key in zip(names, ckeys):
        if key not in by_key:
            raise ValueError(f"{calibration}: camera {name} has no video (got "
                             f"{', '.join(v.name for v in videos)})")
    return [by_key[k] for k in ckeys]


def fit_camera(cam: Camera, width: int, height: int, video, calibration) -> Camera:
    """The camera of a video whose frames are ``width x height`` (module docstring, step 3).

    Raises
    ------
    ValueError
        The size is neither the calibration's (within :data:`PAD_PX` - 1 pixels), nor a uniform
        scaling of it (with or without such padding); the message names the video.
    """
    wc, hc = cam.width, cam.height
    if (width, height) == (wc, hc):
        return cam
    for s in (width / wc, height / hc):
        if max(abs(width - wc * s), abs(height - hc * s)) <= 1.0:
            log.info("%s: %dx%d is camera %s's %dx%d scaled by %.4g; K scaled with it", video,
                     width, height, cam.name, wc, hc, s)
            return cam.scaled(width, height)
    # padding at the calibration's size first (the common case), else at the closer of the
    # two uniform scalings that make one side exact
    fits = [(max(abs(width - round(wc * s)), abs(height - round(hc * s))), s,
             round(wc * s), round(hc * s)) for s in (width / wc, height / hc)]
    _, s, sw, sh = (0, 1.0, wc, hc) if max(abs(width - wc), abs(height - hc)) < PAD_PX \
        else min(fits)
    if (abs(width - sw) < min(PAD_PX, PAD_FRACTION * sw)
            and abs(height - sh) < min(PAD_PX, PAD_FRACTION * sh)):
        base = cam if s == 1.0 else cam.scaled(sw, sh)
        log.warning("%s: %dx%d but camera %s of %s is %dx%d%s: taken as encoder padding at "
                    "the right/bottom edge (K kept, image size set to the video's)", video,
                    width, height, cam.name, Path(calibration).name, wc, hc,
                    "" if s == 1.0 else f" (scaled by {s:.4g}: {sw}x{sh})")
        return Camera(cam.name, cam.kind, width, height, base.K, base.dist, base.R, base.t)
    hint = (" (rotated by 90 degrees: rotate the video back, or calibrate it as filmed)"
            if (width, height) == (hc, wc) else "")
    raise ValueError(f"{video}: frames are {width}x{height} but camera {cam.name} of "
                     f"{calibration} is {wc}x{hc}, neither the same size (within "
                     f"{PAD_PX - 1} px and {PAD_FRACTION:.0%} of a side) nor a scaling of it{hint}")


# --------------------------------------------------------------------------------------------
# synchronisation
# --------------------------------------------------------------------------------------------
def _camera_ids(cameras):
    ids = []
    for c in cameras:
        m = re.search(r"(\d+)$", _norm(c.name))
        ids.append(int(m.group(1)) if m else None)
    return ids


def read_timestamps(path, cameras, counts):
    """Video frame of every camera for each synchronised frame, from caliscope's timestamps.

    The file has one row per recorded frame: ``sync_index`` (frames with the same index were
    taken together), ``cam_id`` (older caliscope: ``port``), ``frame_index`` (the frame in that
    camera's video) and ``frame_time`` (seconds). Cameras are identified by the number that ends
    their name (caliscope's ``cam0`` is ``cam_id`` 0). When a camera's largest ``frame_index``
    is past the end of its video, the video is taken to be a clip that starts at its smallest
    ``frame_index``.

    Parameters
    ----------
    path : path to the CSV
    cameras : sequence of Camera
    counts : sequence of int, frames in each camera's video

    Returns
    -------
    frames : (N, C) int64
        Video frame of camera ``c`` for synchronised frame ``j`` (increasing in ``j``).
    fps : float or None
        From the median interval between synchronised ``frame_time`` values, when present.

    Raises
    ------
    ValueError
        Missing columns, non-numbers, duplicate rows, frames outside a video, a camera the file
        does not know (all naming the file).
    """
    path = Path(path)
    ids = _camera_ids(cameras)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            cols = reader.fieldnames or []
            cam_col = "cam_id" if "cam_id" in cols else "port" if "port" in cols else None
            missing = [c for c in ("sync_index", "frame_index") if c not in cols]
            if cam_col is None or missing:
                raise ValueError(f"{path}: columns {missing + ([] if cam_col else ['cam_id'])} "
                                 f"missing (has {cols})")
            rows = []
            for line, r in enumerate(reader, 2):
                try:
                    rows.append((int(r["sync_index"]), int(r[cam_col]), int(r["frame_index"]),
                                 float(r["frame_time"]) if r.get("frame_time") else np.nan))
                except (TypeError, ValueError):
                    raise ValueError(f"{path}: line {line}: sync_index, {cam_col} and "
                                     "frame_index must be integers") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text CSV file") from None
    if not rows:
        raise ValueError(f"{path}: no rows")
    file_ids = {r[1] for r in rows}
    if any(i is None or i not in file_ids for i in ids):
        raise ValueError(f"{path}: {cam_col} values {sorted(file_ids)} do not cover the cameras "
                         f"{[c.name for c in cameras]} (a camera is matched by the number that "
                         "ends its name)")
    col = {cid: k for k, cid in enumerate(ids)}
    offsets = {}
    for cid, n, cam in zip(ids, counts, cameras):
        fi = [r[2] for r in rows if r[1] == cid]
        if max(fi) >= n:
            offsets[cid] = min(fi)
            log.info("%s: camera %s frame_index %d..%d past its %d-frame video: taken as a clip "
                     "starting at frame_index %d", path, cam.name, min(fi), max(fi), n, min(fi))
            if max(fi) - min(fi) >= n:
                raise ValueError(f"{path}: camera {cam.name} frame_index {min(fi)}..{max(fi)} "
                                 f"spans more frames than its video has ({n})")
        else:
            offsets[cid] = 0
    groups = {}
    for s, cid, fi, t in rows:
        if cid not in col:
            continue
        g = groups.setdefault(s, {})
        if cid in g:
            raise ValueError(f"{path}: sync_index {s} has two rows for {cam_col} {cid}")
        g[cid] = (fi - offsets[cid], t)
    full = [s for s in sorted(groups) if len(groups[s]) == len(ids)]
    if len(full) < len(groups):
        log.warning("%s: %d of %d sync indices miss a camera and are dropped", path,
                    len(groups) - len(full), len(groups))
    if not full:
        raise ValueError(f"{path}: no sync_index has a frame of every camera")
    frames = np.array([[groups[s][cid][0] for cid in ids] for s in full], dtype=np.int64)
    if len(frames) > 1 and np.any(np.diff(frames, axis=0) <= 0):
        raise ValueError(f"{path}: frame_index does not increase with sync_index")
    times = np.array([np.mean([groups[s][cid][1] for cid in ids]) for s in full])
    fps = None
    if len(times) > 1 and np.all(np.isfinite(times)):
        dt = float(np.median(np.diff(times)))
        fps = 1.0 / dt if dt > 0 else None
    return frames, fps


def frame_map(cameras, infos, calibration, timestamps=None):
    """Video frame of each camera for every synchronised frame (module docstring, step 4).

    Parameters
    ----------
    cameras : sequence of Camera
    infos : sequence of VideoInfo, one per camera
    calibration : path; ``timestamps.csv`` beside it is used when ``timestamps`` is None
    timestamps : path, False or None
        A caliscope timestamps file, ``False`` for none, ``None`` to look beside the calibration.

    Returns
    -------
    frames : (N, C) int64
    fps : float or None, the source rate the timestamps give
    sync : str, what synchronised the videos (the timestamps file, or ``"frame order"``)
    """
    if timestamps is None:
        cand = Path(calibration).parent / TIMESTAMPS
        timestamps = cand if cand.is_file() else False
    counts = [i.frames for i in infos]
    if timestamps is not False:
        frames, fps = read_timestamps(timestamps, cameras, counts)
        log.info("synchronised by %s: %d frames", timestamps, len(frames))
        return frames, fps, str(Path(timestamps).resolve())
    n = min(counts)
    if len(set(counts)) > 1:
        log.warning("frame counts differ (%s): cut to the common %d frames, assuming the videos "
                    "start together", ", ".join(f"{i.path.name}: {i.frames}" for i in infos), n)
    return np.repeat(np.arange(n, dtype=np.int64)[:, None], len(cameras), axis=1), None, \
        "frame order"


def select_frames(n, src_fps, frames=None, fps=None):
    """Rows of the synchronised frame list to keep, and the dataset's frame rate.

    Parameters
    ----------
    n : int, synchronised frames available
    src_fps : float, their rate (0 when unknown)
    frames : (A, B), optional, synchronised frames ``A .. B-1``
    fps : float, optional, output rate, ``<= src_fps``

    Returns
    -------
    rows : (M,) int64
    fps : float
    """
    a, b = frames if frames is not None else (0, n)
    if not 0 <= a < b:
        raise ValueError(f"frames A:B needs 0 <= A < B, got {a}:{b}")
    if b > n:
        raise ValueError(f"frames {a}:{b} asks for frame {b - 1}, but the synchronised videos "
                         f"have {n} frames (0..{n - 1})")
    if fps is None:
        if not src_fps > 0:
            raise ValueError("the videos do not say their frame rate: give fps")
        return np.arange(a, b, dtype=np.int64), float(src_fps)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if not src_fps > 0:
        return np.arange(a, b, dtype=np.int64), float(fps)
    if fps > src_fps * 1.001:
        raise ValueError(f"fps {fps:g} is above the videos' {src_fps:g} frames per second "
                         "(frames are never invented)")
    step = src_fps / fps
    rows = np.unique(np.round(a + np.arange(0, (b - a) / step) * step).astype(np.int64))
    return rows[rows < b], float(fps)


def default_scale(cameras, long_side=DEFAULT_LONG_SIDE) -> float:
    """One downscale factor for every camera: the longest side becomes ``<= long_side`` pixels
    (never an upscale)."""
    longest = max(max(c.width, c.height) for c in cameras)
    return min(1.0, long_side / longest)


def _folder_name(name, i, used):
    out = name if _NAME_OK.match(name) and name not in (".", "..") else \
        re.sub(r"[^A-Za-z0-9_.-]", "_", name).strip(".") or f"cam{i}"
    while out in used:
        out += "_"
    used.add(out)
    return out


# --------------------------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------------------------
def ingest(calibration, videos, out, *, frames=None, fps=None, scale=None, up="auto",
           timestamps=None, overwrite=False, progress=True, max_gb=DEFAULT_MAX_GB,
           masks="auto", floor="auto", keypoints="auto", scene_trim=False):
    """Make a multi-view gltrack dataset from calibrated videos (see the module docstring).

    Parameters
    ----------
    calibration : path
        Any format :func:`gltrack.data.calibration.load_any_calibration` reads.
    videos : sequence of path
        One per camera of the calibration.
    out : path
        Dataset folder to create (must not exist or be empty unless ``overwrite``).
    frames : (A, B), optional
        Synchronised source frames ``A .. B-1``; default all.
    fps : float, optional
        Output frame rate (frames are subsampled, never invented); default the source rate.
    scale : float, optional
        Downscale factor in (0, 1] for every camera; default :func:`default_scale`.
    up : {"auto", "x", "y", "z", "-x", "-y", "-z"}
        The calibration world's up axis.
    timestamps : path, False or None
        caliscope ``timestamps.csv``; None looks beside the calibration, False uses none.
    overwrite : bool
        Replace an existing non-empty ``out``.
    progress : bool
        tqdm bar (only on a terminal).
    max_gb : float
        Refuse when the PNG frames would take more than this (estimated from the first frame).
    masks : {"auto", "none"}
        ``"auto"``: estimate foreground masks from the sequence and write them (module
        docstring, step 9); ``"none"``: frames only.
    floor : float, "auto" or None
        Height of the floor along the up axis (the calibration's units and origin); ``"auto"``:
        the origin plane when every camera is above it (:func:`~gltrack.data.world.detect_floor`);
        None: unknown. Recorded in ``meta.json`` (``world.floor``); the masks' support cue
        needs it.
    scene_trim : bool
        Trim the person segmentation's masks where they show the scene seen in the other
        frames (:attr:`gltrack.observe.foreground.ForegroundParams.scene_trim`): for a
        subject that moves; off by default.
    keypoints : {"auto", "none"} or path
        ``"auto"``: find each camera's body landmarks and triangulate them
        (:mod:`gltrack.observe.keypoints`) when the landmark model is installed (logged and
        skipped when it is not), written as ``keypoints.npz``; a path: that model file, an
        error if it is missing; ``"none"``: no keypoints.

    Returns
    -------
    dict
        Summary: ``path``, ``frames``, ``fps``, ``cameras`` (names), ``sizes`` ([w, h] each),
        ``scale``, ``up``, ``up_angle_deg`` (auto only), ``floor`` (or None), ``sync``,
        ``bytes`` written, ``masks`` (``meta.json``'s ``"masks"``, or None), ``keypoints``
        (``meta.json``'s ``"keypoints"``, or None).

    Raises
    ------
    FileNotFoundError, ValueError
        One line naming the file at fault; nothing is left at ``out``.
    """
    if masks not in MASKS:
        raise ValueError(f"masks must be one of {MASKS}, got {masks!r}")
    model = None
    if keypoints != "none":
        from gltrack.observe.keypoints import find_model

        model = find_model(None if keypoints == "auto" else keypoints)
        if model is None:
            log.info("keypoints: no pose landmark model installed (scripts/setup.sh copies it); "
                     "the dataset gets none")
    calibration = Path(calibration)
    out = Path(out)
    fmt = detect_format(calibration)
    cams = load_any_calibration(calibration, fmt)
    paths = match_videos(cams, videos, calibration)
    infos = [probe_video(p) for p in paths]
    fitted = [fit_camera(c, i.width, i.height, i.path, calibration) for c, i in zip(cams, infos)]
    fmap, ts_fps, sync = frame_map(fitted, infos, calibration, timestamps)
    vid_fps = [i.fps for i in infos if i.fps > 0]
    if vid_fps and max(vid_fps) > min(vid_fps) * 1.01:
        log.warning("the videos report different frame rates (%s); using %g",
                    ", ".join(f"{i.path.name}: {i.fps:g}" for i in infos), vid_fps[0])
    src_fps = vid_fps[0] if vid_fps else 0.0
    if ts_fps is not None and not (src_fps and abs(ts_fps / src_fps - 1) < 0.01):
        # the timestamps are what was recorded; the container's rate is often a nominal one
        log.info("frame rate from the timestamps: %.4g (videos say %g)", ts_fps, src_fps)
        src_fps = ts_fps
    rows, out_fps = select_frames(len(fmap), src_fps, frames, fps)
    fmap = fmap[rows]

    if scale is None:
        scale = default_scale(fitted)
    elif not 0 < scale <= 1:
        raise ValueError(f"scale must be in (0, 1], got {scale}")
    sizes = [(max(1, round(c.width * scale)), max(1, round(c.height * scale))) for c in fitted]
    scaled = [c.scaled(w, h) if (w, h) != (c.width, c.height) else c
              for c, (w, h) in zip(fitted, sizes)]
    if up == "auto":
        up, up_angle = detect_up(scaled)
    elif up.lstrip("+") in AXES:
        up, up_angle = up.lstrip("+"), None
    else:
        raise ValueError(f"up must be 'auto' or one of {AXES}, got {up!r}")
    R_user_from_internal = internal_from_user(up).T
    used = set()
    named = [Camera(_folder_name(c.name, i, used), "colour", c.width, c.height, c.K, c.dist, c.R,
                    c.t) for i, c in enumerate(scaled)]
    internal = to_internal(named, R_user_from_internal)
    if isinstance(floor, str):
        if floor != "auto":
            raise ValueError(f"floor must be a number, 'auto' or None, got {floor!r}")
        floor = detect_floor(internal)
    elif floor is not None:
        floor = float(floor)
        if not np.isfinite(floor):
            raise ValueError(f"floor must be finite, got {floor}")

    # estimate the disk use from the first frame of the first camera, before writing anything
    cap = cv2.VideoCapture(str(infos[0].path))
    ok, first = cap.read()
    cap.release()
    if not ok:
        raise ValueError(f"{infos[0].path}: cannot decode the first frame")
    ok, png = cv2.imencode(".png", _resize(first, sizes[0]))
    per_pixel = len(png) / (sizes[0][0] * sizes[0][1])
    estimate = per_pixel * sum(w * h for w, h in sizes) * len(fmap)
    if estimate > max_gb * 1e9:
        raise ValueError(f"{out}: would write about {estimate / 1e9:.1f} GB of PNG frames "
                         f"({len(fmap)} frames x {len(sizes)} cameras); choose fewer frames "
                         f"(frames/fps), a smaller scale, or raise the {max_gb:g} GB limit")
    log.info("writing %d frames x %d cameras (about %.0f MB) to %s", len(fmap), len(sizes),
             estimate / 1e6, out)

    meta = {
        "world": world_meta(up, floor),
        "source": {
            "tool": "gltrack ingest",
            "calibration": str(calibration.resolve()),
            "calibration_format": fmt,
            "sync": sync,
            "fps": src_fps,
            "scale": scale,
            "videos": {c.name: {"path": str(i.path.resolve()), "size": [i.width, i.height],
                                "frames": fmap[:, k].tolist()}
                       for k, (c, i) in enumerate(zip(internal, infos))},
        },
    }
    from tqdm import tqdm

    bar = tqdm(total=len(fmap) * len(internal), desc="ingest", unit="frame",
               disable=not (progress and sys.stderr.isatty()))
    with DatasetWriter(out, "multiview", out_fps, internal, overwrite=overwrite,
                       meta=meta) as writer:
        for k, (cam, info) in enumerate(zip(internal, infos)):
            for j, img in enumerate(_read_frames(info.path, fmap[:, k])):
                writer.write_colour(j, k, _resize(img, sizes[k]))
                bar.update(1)
        bar.close()
        # keypoints first: the landmark model's person segmentation is the masks' "prior"
        # cue (its first crops then start from the whole image, not from a mask's blob)
        kp_meta, prior = None, None
        if model is not None:
            kp_meta, prior = write_keypoints(writer, len(fmap), model, segment=masks == "auto")
            writer.extra_meta["keypoints"] = kp_meta
        mask_meta = None
        if masks == "auto":
            from gltrack.observe.foreground import ForegroundParams

            mask_meta = write_masks(writer, len(fmap), ForegroundParams(scene_trim=scene_trim),
                                    floor=floor, person_prior=prior)
            writer.extra_meta["masks"] = mask_meta
    written = sum(p.stat().st_size for p in out.rglob("*.png"))
    return {"path": out, "frames": len(fmap), "fps": out_fps,
            "cameras": [c.name for c in internal], "sizes": [list(s) for s in sizes],
            "scale": scale, "up": up, "up_angle_deg": up_angle, "floor": floor, "sync": sync,
            "calibration_format": fmt, "bytes": written, "masks": mask_meta,
            "keypoints": kp_meta}


def write_masks(writer, frames, params=None, floor=None, person_prior=None):
    """Estimate the foreground of the frames a :class:`DatasetWriter` holds and write them.

    The colour frames already written (in the writer's temporary folder) are read back one at a
    time and handed to :func:`~gltrack.observe.foreground.estimate_foreground`, which downsizes
    each as it arrives; its masks (working resolution) are resized to each camera's image size
    (bilinear, then thresholded at one half: smoother edges than nearest-neighbour blocks) and
    written with :meth:`DatasetWriter.write_mask`.

    Parameters
    ----------
    writer : DatasetWriter, open, with colour frames ``0 .. frames-1`` for every camera
    frames : int
    params : gltrack.observe.foreground.ForegroundParams, optional
    floor : float, optional
        The floor's height along the writer's cameras' +Y (internal frame); without it the
        ``"support"`` cue is off.
    person_prior : list (C) of (frames, h, w) uint8, optional
        A person segmentation (probability times 255; :func:`write_keypoints`), the
        ``"prior"`` cue; without it that cue is off.

    Returns
    -------
    dict
        What ``meta.json`` records as ``"masks"``: ``method``, ``cues``, ``passes``,
        ``work_size``, ``scene_trim``, ``seconds``, ``foreground_fraction`` (per camera), and
        with a prior ``prior_fraction`` (per camera: the fraction of frames whose mask the
        prior shaped).
    """
    import time

    from gltrack.observe.foreground import (CUES, ForegroundParams, estimate_foreground,
                                            level_floor)

    params = params or ForegroundParams()
    cams = writer.cameras
    cues = [c for c in CUES if (c != "support" or floor is not None)
            and (c != "prior" or person_prior is not None)]

    log.info("foreground: estimating masks of %d frames x %d cameras (work size %d px, %d "
             "passes, cues %s)", frames, len(cams), params.work_size, params.passes,
             ", ".join(cues))
    t0 = time.perf_counter()
    res = estimate_foreground([_read_back(writer, c, frames) for c in cams], cams, params=params, cues=cues,
                              floor=level_floor(floor), person_prior=person_prior)
    for k, cam in enumerate(cams):
        for j in range(frames):
            m = res.masks[k][j]
            if m.shape != (cam.height, cam.width):
                m = cv2.resize(m.astype(np.float32), (cam.width, cam.height),
                               interpolation=cv2.INTER_LINEAR) >= 0.5
            writer.write_mask(j, k, m)
    seconds = time.perf_counter() - t0
    frac = [round(float(f), 4) for f in res.foreground_fraction()]
    log.info("foreground: masks written in %.0f s; foreground fraction per camera %s", seconds,
             ", ".join(f"{c.name} {f:.3f}" for c, f in zip(cams, frac)))
    meta = {"method": "sequence-foreground", "cues": cues, "passes": int(params.passes),
            "work_size": int(params.work_size), "scene_trim": bool(params.scene_trim),
            "seconds": round(seconds, 1),
            "foreground_fraction": frac}
    if "prior" in res.stages:
        shaped = [round(float(np.mean(u.any(axis=(1, 2)))), 3) for u in res.stages["prior"]]
        meta["prior_fraction"] = shaped
        log.info("foreground: the person prior shaped %s of the frames",
                 ", ".join(f"{f:.0%}" for f in shaped))
    return meta


def write_keypoints(writer, frames, model, segment=False):
    """Find the body landmarks of the frames a :class:`DatasetWriter` holds, triangulate them
    and write ``keypoints.npz`` (:func:`gltrack.observe.keypoints.detect_keypoints`).

    Parameters
    ----------
    writer : DatasetWriter, open, with colour frames ``0 .. frames-1`` for every camera
    frames : int
    model : path, the landmark model
    segment : bool, also return the model's person segmentation (at the foreground's working
        size, :class:`gltrack.observe.foreground.ForegroundParams`)

    Returns
    -------
    meta : dict
        What ``meta.json`` records as ``"keypoints"``: ``model`` (file name), ``seconds``,
        ``found`` (per camera: the fraction of frames with a person), ``residual_px``
        (median reprojection residual per camera), ``swapped`` (per camera: frames whose
        left and right were exchanged), ``confirmed`` (per camera: the fraction of frames
        whose landmarks the other views confirm,
        :func:`gltrack.observe.keypoints.confirmed_views`; only those frames' segmentation
        is returned).
    segmentation : list (C) of (frames, h, w) uint8, or None without ``segment``
    """
    import time

    from gltrack.observe.foreground import ForegroundParams
    from gltrack.observe.keypoints import detect_keypoints

    cams = writer.cameras

    t0 = time.perf_counter()
    log.info("keypoints: finding body landmarks in %d frames x %d cameras", frames, len(cams))
    # no masks yet (they come after, with this segmentation as their prior): the first crops
    # are the whole images
    kp = detect_keypoints(cams, [_read_back(writer, c, frames) for c in cams], model=model,
                          segment=ForegroundParams().work_size if segment else None)
    writer.write_keypoints(kp["uv"], kp["visibility"], kp["points"], kp["residual"],
                           kp["names"])
    seconds = time.perf_counter() - t0
    found = (kp["presence"] >= 0.5).mean(axis=0)
    with np.errstate(all="ignore"):
        res = [float(np.nanmedian(kp["residual"][:, c])) if np.isfinite(kp["residual"][:, c]).any()
               else None for c in range(len(cams))]
    meta = {"model": Path(model).name, "seconds": round(seconds, 1),
            "found": [round(float(f), 3) for f in found],
            "residual_px": [None if r is None else round(r, 1) for r in res],
            "swapped": [int(v) for v in kp["swapped"].sum(axis=0)],
            "confirmed": [round(float(f), 3) for f in kp["confirmed"].mean(axis=0)]}
    log.info("keypoints: %s in %.0f s; person found in %s of the frames; median residual %s px",
             meta["model"], seconds, ", ".join(f"{f:.0%}" for f in found),
             ", ".join("-" if r is None else f"{r:.1f}" for r in res))
    return meta, kp.get("segmentation")


def _read_back(writer, cam, frames):
    """Yield camera ``cam``'s colour frames ``0 .. frames-1`` that ``writer`` holds (BGR)."""
    for j in range(frames):
        path = writer.tmp / cam.name / f"{j:06d}.png"
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise OSError(f"{path}: cannot read back the frame just written")
        yield img


def _resize(img, size):
    if (img.shape[1], img.shape[0]) == tuple(size):
        return img
    return cv2.resize(img, tuple(size), interpolation=cv2.INTER_AREA)


def _read_frames(path, wanted):
    """Decode the (increasing) frames ``wanted`` of a video, reading forward once."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open this video")
    try:
        pos = 0
        for f in wanted:
            f = int(f)
            while pos < f:
                if not cap.grab():
                    raise ValueError(f"{path}: ends at frame {pos}, before frame {f}")
                pos += 1
            ok, img = cap.read()
            if not ok or img is None:
                raise ValueError(f"{path}: cannot decode frame {f}")
            pos += 1
            if img.ndim == 2:
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            yield img
    finally:
        cap.release()
