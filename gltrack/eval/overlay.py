"""Overlay videos: the tracked body drawn over the input frames, one tile per camera.

Per frame and camera:

1. the input frame: colour as recorded, depth colour-mapped (:func:`depth_to_bgr`, a fixed
   range per camera so colours mean the same depth all through the video). Distorted cameras
   are undistorted first, because the model is rendered as an ideal pinhole image;
2. the posed body rendered with the CPU reference rasteriser (:mod:`gltrack.render.reference`)
   at the camera's resolution, coloured by body part and shaded by the angle between surface
   normal and viewing ray, alpha-blended over the silhouette only (pixels the body does not
   cover keep the input exactly);
   The silhouette's outline is drawn on top (:data:`OUTLINE_BGR`), so on real footage the
   person's own outline and the model's can be compared at a glance;
3. the skeleton of the tracked joints (yellow) and, when the dataset has ``groundtruth.npz``,
   of the ground-truth joints (green), projected with the camera;
4. frame number, camera name, the frame's mean joint error (with ground truth) and the
   camera's silhouette IoU when ``frames.jsonl`` records it (``info["iou"]`` of the multi-view
   trackers, :mod:`gltrack.eval.quality`; shown in red below 0.6) in the top-left corner.

Tiles are laid out in a near-square grid, ``ceil(sqrt(C))`` columns (2x2 for 3 or 4 cameras,
3x2 for 5 or 6), with cells of the largest camera size; smaller images are scaled to fit,
keeping their aspect. The video in an .mp4 file is H.264 (``avc1``) when this OpenCV build can
encode it (it plays in browsers and every player), else MPEG-4 Part 2 (``mp4v``: VLC, ffmpeg
and most desktop players; the opencv-python wheels carry no H.264 encoder); Motion JPEG in an
.avi when neither is available (logged as a warning).
"""
from __future__ import annotations

import logging
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

TRACKED_BGR = (0, 230, 255)
GROUNDTRUTH_BGR = (60, 220, 60)
OUTLINE_BGR = (255, 60, 255)
ALPHA = 0.6
#: IoU below which the overlay prints a camera's IoU in red (:data:`gltrack.eval.quality.IOU_LOW`).
IOU_LOW = 0.6

#: Per-body-part base colours (BGR), index = gltrack.body.mesh.PARTS.
_PART_BGR = np.array([
    (200, 200, 230), (180, 140, 90), (140, 110, 80),          # head, torso, pelvis
    (60, 60, 220), (40, 110, 240), (40, 170, 250),            # left arm (reds/oranges)
    (220, 80, 60), (240, 140, 40), (250, 200, 60),            # right arm (blues)
    (80, 60, 200), (100, 90, 230), (130, 130, 250),           # left leg
    (200, 90, 80), (230, 130, 100), (250, 170, 130),          # right leg
], dtype=np.float64)


def depth_to_bgr(depth: np.ndarray, near: float, far: float,
                 colormap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Colour-map a depth image.

    Parameters
    ----------
    depth : (H, W) float, metres; ``<= 0`` or non-finite = invalid
    near, far : float, metres; ``near`` maps to the warm end of the map, ``far`` to the cold end
    colormap : int, an OpenCV ``cv2.COLORMAP_*``

    Returns
    -------
    (H, W, 3) uint8 BGR; invalid pixels black.
    """
    z = np.asarray(depth, dtype=np.float64)
    if not far > near:
        raise ValueError(f"far ({far}) must exceed near ({near})")
    valid = np.isfinite(z) & (z > 0)
    v = np.clip((np.where(valid, z, far) - near) / (far - near), 0.0, 1.0)
    img = cv2.applyColorMap(np.round(255.0 * (1.0 - v)).astype(np.uint8), colormap)
    img[~valid] = 0
    return img


def _face_shading(posed_cam: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) in [0, 1]: |cos| between each face normal and the viewing ray to its centroid."""
    tri = posed_cam[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(axis=1)
    denom = np.linalg.norm(n, axis=1) * np.linalg.norm(c, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.einsum("fi,fi->f", n, c)) / denom
    return np.nan_to_num(cos, nan=0.0)


def _select_cameras(dataset, cameras):
    if cameras is None or (isinstance(cameras, str) and cameras == "all"):
        return list(range(len(dataset.cameras)))
    items = cameras if isinstance(cameras, (list, tuple)) else [cameras]
    names = [c.name for c in dataset.cameras]
    out = []
    for c in items:
        if isinstance(c, str) and c.isdigit():
            c = int(c)
        if isinstance(c, (int, np.integer)):
            if not 0 <= c < len(names):
                raise ValueError(f"{dataset.path}: camera {c} out of range 0..{len(names) - 1}")
            out.append(int(c))
        elif c in names:
            out.append(names.index(c))
        else:
            raise ValueError(f"{dataset.path}: no camera {c!r} (have {names})")
    return out


class OverlayRenderer:
    """Composes overlay frames of a result on its dataset (see the module docstring).

    Parameters
    ----------
    result : dict or path
        A results folder (or its loaded dict, :func:`gltrack.data.results.load_results`).
    dataset : gltrack.data.dataset.Dataset or path
    cameras : "all", int, str or sequence of those
        Camera indices or names to show.
    preset : str, optional
        DOF preset of the result (default: the recorded one). The body is the one the results
        folder records in ``body.json``; results without one (older versions, or a result
        passed as a dict) use the dataset's body record.

    Attributes
    ----------
    rows : (N,) int, dataset frame of each result row, in order
    cams : list of int, camera indices shown
    depth_range : dict of camera name -> (near, far) metres used by :func:`depth_to_bgr`
    """

    def __init__(self, result, dataset, cameras="all", preset=None):
        from gltrack.data.dataset import Dataset
        from gltrack.data.results import check_result_world, internal_points, load_results, \
            recorded_body
        from gltrack.export import body_for_result

        recorded = None if isinstance(result, dict) else recorded_body(result)
        self.result = load_results(result) if not isinstance(result, dict) else result
        self._owns_dataset = not isinstance(dataset, Dataset)
        self.dataset = Dataset.open(dataset) if self._owns_dataset else dataset
        ds = self.dataset
        check_result_world(self.result, ds, "the result" if isinstance(result, dict) else result)
        # the joints drawn and scored in the dataset's (internal) frame, that of its cameras
        self._joints = internal_points(self.result)
        if recorded is not None:
            self.body = body_for_result(self.result, None, preset, where=str(recorded[2]),
                                        body=recorded[0])
        else:
            self.body = body_for_result(self.result, ds.body, preset,
                                        where=str(ds.path / "meta.json"))
        order = np.argsort(self.result["frame"], kind="stable")
        self.rows = np.asarray(self.result["frame"], dtype=np.int64)[order]
        self._order = order
        if len(self.rows) and (self.rows.min() < 0 or self.rows.max() >= ds.frames):
            raise ValueError(f"result frames {self.rows.min()}..{self.rows.max()} are outside the "
                             f"dataset's 0..{ds.frames - 1} ({ds.path})")
        self.cams = _select_cameras(ds, cameras)
        sk = self.body.skeleton
        names = list(self.result["joint_names"])
        self._bones = [(names.index(n), names.index(sk.names[p]))
                       for n, p in zip(sk.names, sk.parents)
                       if p >= 0 and n in names and sk.names[p] in names]
        self.gt = ds.groundtruth()
        self._gt_bones, self._err_idx = [], None
        if self.gt is not None:
            from gltrack.eval.metrics import EVAL_JOINTS, common_names

            gnames = list(self.gt["joint_names"])
            self._gt_bones = [(gnames.index(n), gnames.index(sk.names[p]))
                              for n, p in zip(sk.names, sk.parents)
                              if p >= 0 and n in gnames and sk.names[p] in gnames]
            _, ia, ib = common_names(names, gnames, EVAL_JOINTS)
            if len(ia):
                self._err_idx = (ia, ib)
        from gltrack.data.results import frame_infos

        self.infos = {} if isinstance(result, dict) else frame_infos(result)
        # info["iou"] lists follow the dataset's colour cameras in order
        colour = [k for k, cam in enumerate(ds.cameras) if cam.kind == "colour"]
        self._iou_pos = {k: n for n, k in enumerate(colour)}
        self.depth_range = {}
        for c in self.cams:
            cam = ds.cameras[c]
            if cam.kind == "depth":
                self.depth_range[cam.name] = self._depth_range(c)

    def _depth_range(self, c):
        z = self.dataset.depth(int(self.rows[0]) if len(self.rows) else 0, c)
        valid = z[z > 0]
        if valid.size < 10:
            return 0.5, 8.0
        lo, hi = np.percentile(valid, [1, 99])
        return max(float(lo) - 0.2, 0.01), float(hi) + 0.2

    def __len__(self):
        return len(self.rows)

    def close(self):
        """Close the dataset if this renderer opened it."""
        if self._owns_dataset:
            self.dataset.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def frame_error(self, i) -> float:
        """Mean joint error of result row ``i`` against the ground truth, metres (NaN if none)."""
        if self._err_idx is None:
            return float("nan")
        ia, ib = self._err_idx
        pred = self._joints[self._order[i]][ia]
        gt = self.gt["joints"][self.rows[i]][ib]
        d = np.linalg.norm(pred - gt, axis=1)
        d = d[np.isfinite(d)]
        return float(d.mean()) if d.size else float("nan")

    def frame_iou(self, i, c) -> float:
        """Silhouette IoU of result row ``i`` in camera ``c`` from ``frames.jsonl`` (NaN if none)."""
        iou = self.infos.get(int(self.rows[i]), {}).get("iou")
        k = self._iou_pos.get(c)
        if not isinstance(iou, (list, tuple)) or k is None or k >= len(iou) or iou[k] is None:
            return float("nan")
        return float(iou[k])

    def input_image(self, i, c) -> np.ndarray:
        """(H, W, 3) uint8 BGR: the undistorted, colour-mapped input of row ``i``, camera ``c``."""
        cam = self.dataset.cameras[c]
        f = int(self.rows[i])
        if cam.kind == "depth":
            z = cam.undistort_image(self.dataset.depth(f, c), cv2.INTER_NEAREST)
            return depth_to_bgr(z, *self.depth_range[cam.name])
        return cam.undistort_image(self.dataset.colour(f, c))

    def model_layer(self, posed: np.ndarray, c):
        """Render posed world vertices (V, 3) in camera ``c``.

        Returns
        -------
        colour : (H, W, 3) float64 BGR of the shaded body
        mask : (H, W) bool, pixels the body covers
        """
        from gltrack.render import reference as ref

        cam = self.dataset.cameras[c]
        pc = ref.world_to_camera(posed, cam.R, cam.t)
        depth, tri = ref.rasterize(pc, self.body.mesh.faces, cam.K, cam.width, cam.height)
        mask = tri >= 0
        faces = self.body.mesh.faces
        shade = 0.3 + 0.7 * _face_shading(pc, faces)
        base = _PART_BGR[self.body.mesh.part[faces[:, 0]] % len(_PART_BGR)]
        face_bgr = base * shade[:, None]
        colour = np.zeros((cam.height, cam.width, 3))
        colour[mask] = face_bgr[tri[mask]]
        return colour, mask

    def _draw_skeleton(self, img, cam, joints, bones, bgr, thick):
        uv = cam.project(joints, distort=False)
        front = cam.depth_of(joints) > 0.05
        for a, b in bones:
            if front[a] and front[b] and np.all(np.isfinite(uv[[a, b]])):
                pa, pb = np.round(uv[[a, b]]).astype(int)
                cv2.line(img, tuple(int(x) for x in pa), tuple(int(x) for x in pb), bgr, thick,
                         cv2.LINE_AA)
        used = np.unique(np.array(bones, dtype=np.int64).reshape(-1))
        for k in used:
            if front[k] and np.all(np.isfinite(uv[k])):
                cv2.circle(img, tuple(int(x) for x in np.round(uv[k])), thick + 1, bgr, -1,
                           cv2.LINE_AA)

    def camera_frame(self, i, c, posed=None) -> np.ndarray:
        """(H, W, 3) uint8 BGR overlay of result row ``i`` in camera ``c``."""
        cam = self.dataset.cameras[c]
        img = self.input_image(i, c)
        if posed is None:
            posed = self._posed(i)
        colour, mask = self.model_layer(posed, c)
        blended = (1.0 - ALPHA) * img[mask].astype(np.float64) + ALPHA * colour[mask]
        img[mask] = np.clip(np.round(blended), 0, 255).astype(np.uint8)
        thick = max(1, round(min(cam.width, cam.height) / 360))
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, OUTLINE_BGR, thick, cv2.LINE_AA)
        f = int(self.rows[i])
        if self.gt is not None and self._gt_bones:
            self._draw_skeleton(img, cam, self.gt["joints"][f], self._gt_bones, GROUNDTRUTH_BGR,
                                thick)
        joints = self._joints[self._order[i]]
        self._draw_skeleton(img, cam, joints, self._bones, TRACKED_BGR, thick)
        err = self.frame_error(i)
        lines = [f"frame {f}  {cam.name}"]
        colours = [None]
        if np.isfinite(err):
            lines.append(f"err {1000.0 * err:.0f} mm")
            colours.append(None)
        iou = self.frame_iou(i, c)
        if np.isfinite(iou):
            lines.append(f"IoU {iou:.2f}")
            colours.append((80, 80, 255) if iou < IOU_LOW else None)
        _corner_text(img, lines, colours)
        return img

    def _posed(self, i):
        from gltrack.render import reference as ref

        params = np.asarray(self.result["params"])[self._order[i]][None]
        return ref.skin_vertices(self.body.mesh, self.body.skinning(params))[0]

    def frame(self, i) -> np.ndarray:
        """(H, W, 3) uint8 BGR: all chosen cameras of result row ``i``, tiled."""
        posed = self._posed(i)
        return tile([self.camera_frame(i, c, posed) for c in self.cams])


def _corner_text(img, lines, colours=None):
    h = img.shape[0]
    scale = max(0.35, h / 720.0 * 0.6)
    thick = max(1, round(scale * 1.5))
    font = cv2.FONT_HERSHEY_SIMPLEX
    sizes = [cv2.getTextSize(t, font, scale, thick) for t in lines]
    step = max(th + base for (_, th), base in sizes) + 2
    width = max(tw for (tw, _), _ in sizes)
    # An opaque box: outlined glyphs smear at the small sizes of depth-camera images.
    cv2.rectangle(img, (0, 0), (width + 6, step * len(lines) + 3), (0, 0, 0), -1)
    for k, text in enumerate(lines):
        bgr = (colours[k] if colours and k < len(colours) else None) or (255, 255, 255)
        cv2.putText(img, text, (3, step * (k + 1) - 2), font, scale, bgr, thick, cv2.LINE_AA)


def tile(images) -> np.ndarray:
    """Lay images out in a near-square grid.

    Parameters
    ----------
    images : list of (H_k, W_k, 3) uint8

    Returns
    -------
    (rows * Hc, cols * Wc, 3) uint8 with ``cols = ceil(sqrt(n))``, cells of the largest image
    size; an image of another size is scaled to fit its cell (aspect kept, top-left aligned).
    A single image comes back unchanged.
    """
    if len(images) == 1:
        return images[0]
    cols = math.ceil(math.sqrt(len(images)))
    rows = math.ceil(len(images) / cols)
    Hc = max(im.shape[0] for im in images)
    Wc = max(im.shape[1] for im in images)
    out = np.zeros((rows * Hc, cols * Wc, 3), dtype=np.uint8)
    for k, im in enumerate(images):
        if im.shape[:2] != (Hc, Wc):
            s = min(Hc / im.shape[0], Wc / im.shape[1])
            size = (max(1, round(im.shape[1] * s)), max(1, round(im.shape[0] * s)))
            im = cv2.resize(im, size, interpolation=cv2.INTER_AREA)
        r, c = divmod(k, cols)
        out[r * Hc:r * Hc + im.shape[0], c * Wc:c * Wc + im.shape[1]] = im
    return out


@contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (FFmpeg and OpenCV print failed encoder probes there)."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


_H264: bool | None = None


def h264_available() -> bool:
    """Whether this OpenCV can write H.264 (``avc1``) into .mp4 (probed once per process on a
    tiny temporary file; the failed probe's encoder messages are silenced)."""
    global _H264
    if _H264 is None:
        with tempfile.TemporaryDirectory() as d, _quiet_stderr():
            path = os.path.join(d, "probe.mp4")
            w = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"avc1"), 10.0, (64, 64))
            ok = w.isOpened()
            if ok:
                for _ in range(2):
                    w.write(np.zeros((64, 64, 3), np.uint8))
            w.release()
            _H264 = bool(ok and os.path.getsize(path) > 0)
        log.debug("H.264 (avc1) writer %s", "available" if _H264 else "unavailable")
    return _H264


def open_video_writer(out, fps: float, size):
    """Open a cv2.VideoWriter: for .mp4 H.264 (``avc1``) when available (:func:`h264_available`),
    else MPEG-4 Part 2 (``mp4v``), falling back to Motion JPEG in .avi.

    Parameters
    ----------
    out : path, ``.mp4`` or ``.avi``
    fps : float
    size : (width, height) pixels, both even

    Returns
    -------
    writer : cv2.VideoWriter, opened
    path : Path actually written (``.avi`` after a fallback)
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".mp4", ".avi"):
        raise ValueError(f"{out}: video file must end in .mp4 or .avi")
    tries = ([("avc1", out)] if h264_available() else []) + [("mp4v", out)] \
        if suffix == ".mp4" else []
    tries.append(("MJPG", out.with_suffix(".avi")))
    for fourcc, path in tries:
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), float(fps), tuple(size))
        if w.isOpened():
            if path != out:
                log.warning("%s: this OpenCV cannot write mp4v; wrote Motion JPEG to %s instead",
                            out, path)
            elif fourcc == "mp4v":
                log.info("%s: MPEG-4 Part 2 (mp4v; this OpenCV has no H.264 encoder): plays in "
                         "VLC/ffmpeg-based players, not in every browser", out)
            return w, path
        w.release()
    raise OSError(f"{out}: cv2.VideoWriter could open neither mp4v nor MJPG")


def render_overlay(result, dataset, out, cameras="all", max_frames=None, progress=True,
                   fps=None, preset=None, min_height: int | None = None) -> Path:
    """Write an overlay video of a tracking result on its dataset.

    Parameters
    ----------
    result : path or dict
        Results folder, or the dict of :func:`gltrack.data.results.load_results`.
    dataset : path or gltrack.data.dataset.Dataset
    out : path, ``.mp4`` (H.264 or MPEG-4, see :func:`open_video_writer`) or ``.avi`` (Motion JPEG)
    cameras : "all", int, str or sequence of those
    max_frames : int, optional
        Render only the first ``max_frames`` result frames.
    progress : bool, show a tqdm bar
    fps : float, optional, video frame rate (default: the dataset's)
    preset : str, optional, DOF preset of the result (default: the recorded body's, see
        :class:`OverlayRenderer`)
    min_height : int, optional
        Enlarge small frames (e.g. a 176x144 ToF camera) by an integer factor, nearest
        neighbour, until they are at least this tall, so the video is watchable.

    Returns
    -------
    Path
        The file written: ``out``, or ``out`` with ``.avi`` when mp4v was unavailable.
        Frames are padded with black to even width and height (what MPEG-4 encoders need).
    """
    with OverlayRenderer(result, dataset, cameras, preset) as r:
        return _write_video(r, out, max_frames, progress, fps, min_height)


def _write_video(r, out, max_frames, progress, fps, min_height=None):
    from tqdm import tqdm

    n = len(r) if max_frames is None else min(len(r), int(max_frames))
    if n <= 0:
        raise ValueError("nothing to render: the result holds no frames")
    fps = r.dataset.fps if fps is None else float(fps)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    writer = path = None
    try:
        for i in tqdm(range(n), desc="overlay", unit="frame", disable=not progress):
            img = r.frame(i)
            if min_height and img.shape[0] < min_height:
                k = -(-int(min_height) // img.shape[0])
                img = cv2.resize(img, None, fx=k, fy=k, interpolation=cv2.INTER_NEAREST)
            h, w = img.shape[:2]
            if h % 2 or w % 2:
                img = cv2.copyMakeBorder(img, 0, h % 2, 0, w % 2, cv2.BORDER_CONSTANT, value=0)
            if writer is None:
                writer, path = open_video_writer(out, fps, (img.shape[1], img.shape[0]))
            writer.write(img)
    except BaseException:
        if writer is not None:
            writer.release()
            path.unlink(missing_ok=True)  # a truncated video would look like a finished one
        raise
    writer.release()
    log.info("wrote %s (%d frames, %d cameras)", path, n, len(r.cams))
    return path
