"""Overlay videos: the tracked body drawn over the input frames, one tile per camera.

Per frame and camera:

1. the input frame: colour as recorded, depth colour-mapped (:func:`depth_to_bgr`, a fixed
   range per camera so colours mean the same depth all through the video). Distorted cameras
   are undistorted first, because the model is rendered as an ideal pinhole image;
2. the posed body rendered with the CPU reference rasteriser (:mod:`gltrack.render.reference`)
   at the camera's resolution, coloured by body part (:data:`PART_GROUPS`: left limbs warm,
   right limbs cool) and shaded by the angle between surface normal and viewing ray,
   alpha-blended over the silhouette only (pixels the body does not cover keep the input
   exactly); over a depth image the body is nearly opaque (:data:`ALPHA_DEPTH`), or its parts
   would drown in the colour map. Small images are then enlarged by an integer factor (nearest
   neighbour) so that what follows is drawn at the output size;
3. the silhouette's outline (:data:`OUTLINE_BGR`), so on real footage the person's own outline
   and the model's can be compared at a glance; the skeleton of the tracked joints (yellow) and,
   when the dataset has ``groundtruth.npz``, of the ground-truth joints (green), and when it has
   ``keypoints.npz``, thinner and white, of the triangulated keypoints the tracker fits,
   projected with the camera;
4. frame number, camera name, the frame's mean joint error (with ground truth) and the
   camera's silhouette IoU when ``frames.jsonl`` records it (``info["iou"]`` of the multi-view
   trackers, :mod:`gltrack.eval.quality`; shown in red below 0.6) in the top-left corner, in a
   font that scales with the image height.

Tiles are laid out in a near-square grid, ``ceil(sqrt(C))`` columns (2x2 for 3 or 4 cameras,
3x2 for 5 or 6), with cells of the largest camera size; smaller images are scaled to fit,
keeping their aspect. Below the grid a legend strip (:func:`legend_strip`) says what each colour
means (the part colours, outline, tracked and ground-truth skeletons) and, for each depth
camera, shows a colour bar of its depth range in metres.

Video files (:func:`open_video_writer`): an .mp4 is H.264 (yuv420p, ``+faststart``; plays in
browsers and every player) when an ffmpeg with libx264 is at hand (the ``imageio-ffmpeg``
package's, else an ``ffmpeg`` on ``PATH``) or this OpenCV build can encode ``avc1`` (the
opencv-python wheels cannot); otherwise MPEG-4 Part 2 (``mp4v``: VLC, ffmpeg and most desktop
players, not browsers), with a warning that says how to get H.264; Motion JPEG in an .avi
when neither is available (also a warning). The codec chosen is logged and returned
(:class:`OverlayVideo`).
"""
from __future__ import annotations

import logging
import math
import os
import re
import shutil
import subprocess
import tempfile
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

TRACKED_BGR = (0, 230, 255)
GROUNDTRUTH_BGR = (60, 220, 60)
#: the dataset's triangulated body keypoints (``keypoints.npz``), what the tracker fits
KEYPOINT_BGR = (255, 255, 255)
#: the keypoints' "bones": limbs, the shoulder and hip lines and the flanks
KEYPOINT_BONES = (("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("r_shoulder", "r_elbow"),
                  ("r_elbow", "r_wrist"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
                  ("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("l_shoulder", "r_shoulder"),
                  ("l_hip", "r_hip"), ("l_shoulder", "l_hip"), ("r_shoulder", "r_hip"))
OUTLINE_BGR = (255, 60, 255)
#: Opacity of the model over colour images, and over colour-mapped depth images.
ALPHA = 0.6
ALPHA_DEPTH = 0.85
#: IoU below which the overlay prints a camera's IoU in red (:data:`gltrack.eval.quality.IOU_LOW`).
IOU_LOW = 0.6
#: Default least height (pixels) of an overlay video's camera grid, see :func:`render_overlay`.
MIN_HEIGHT = 432
#: Background of the corner text and of the legend strip (BGR).
PANEL_BGR = (24, 24, 24)

#: Per-body-part base colours (BGR), index = gltrack.body.mesh.PARTS: head pale pink, torso
#: khaki, pelvis brown; the subject's left limbs warm (arm red to yellow, leg violet to pink),
#: the right ones cool (arm blue to light blue, leg teal to cyan), lighter towards their ends.
_PART_BGR = np.array([
    (200, 205, 235), (120, 165, 190), (70, 105, 135),         # head, torso, pelvis
    (50, 50, 215), (40, 120, 245), (60, 200, 250),            # left arm: red, orange, yellow
    (215, 90, 40), (245, 150, 70), (250, 210, 150),           # right arm: blue -> light blue
    (150, 40, 150), (190, 90, 210), (215, 160, 240),          # left leg: violet -> pink
    (120, 140, 20), (170, 190, 60), (215, 230, 140),          # right leg: teal -> light cyan
], dtype=np.float64)

#: Colours of the mask view (``masks=True``): where the model and the frame's foreground mask
#: agree, where only the mask is (the masks hold what the model does not explain), where only
#: the model is (the model sticks out of the masks).
MASK_BOTH_BGR = (60, 200, 60)
MASK_ONLY_BGR = (40, 40, 235)
MODEL_ONLY_BGR = (235, 120, 30)

#: The legend's part groups: (label, index into ``_PART_BGR`` of the colour shown). "left" and
#: "right" are the subject's.
PART_GROUPS = (("head", 0), ("torso", 1), ("pelvis", 2), ("left arm", 3), ("right arm", 6),
               ("left leg", 9), ("right leg", 12))


def part_colour(part: int) -> tuple:
    """BGR colour (ints) of body part ``part`` (an index into gltrack.body.mesh.PARTS), unshaded."""
    return tuple(int(v) for v in _PART_BGR[int(part) % len(_PART_BGR)])


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
    masks : bool
        Colour cameras with a foreground mask for the frame show the model against it instead
        of the body parts: :data:`MASK_BOTH_BGR` where both are, :data:`MASK_ONLY_BGR` where
        only the mask is, :data:`MODEL_ONLY_BGR` where only the model is (what the silhouette
        IoU counts, at full resolution).

    Attributes
    ----------
    rows : (N,) int, dataset frame of each result row, in order
    cams : list of int, camera indices shown
    depth_range : dict of camera name -> (near, far) metres used by :func:`depth_to_bgr`
    """

    def __init__(self, result, dataset, cameras="all", preset=None, masks: bool = False):
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
        self.masks = bool(masks)
        sk = self.body.skeleton
        names = list(self.result["joint_names"])
        self._bones = [(names.index(n), names.index(sk.names[p]))
                       for n, p in zip(sk.names, sk.parents)
                       if p >= 0 and n in names and sk.names[p] in names]
        self.gt = ds.groundtruth()
        #: the dataset's keypoints (None without ``keypoints.npz``) and their bones
        self.kp = ds.keypoints()
        self._kp_bones = []
        if self.kp is not None:
            kn = self.kp["names"]
            self._kp_bones = [(kn.index(a), kn.index(b)) for a, b in KEYPOINT_BONES
                              if a in kn and b in kn]
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
        self._legends = {}
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

    def _draw_skeleton(self, img, cam, joints, bones, bgr, thick, scale=1):
        uv = (cam.project(joints, distort=False) + 0.5) * scale - 0.5
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

    def camera_frame(self, i, c, posed=None, scale: int = 1) -> np.ndarray:
        """Overlay of result row ``i`` in camera ``c``.

        Parameters
        ----------
        i : int, result row
        c : int, camera index
        posed : (V, 3) float, optional, the posed world vertices of row ``i`` (computed if None)
        scale : int
            Enlarge the camera image by this factor (nearest neighbour) before the outline,
            skeletons and text are drawn, so that they are sharp at the output size.

        Returns
        -------
        (H * scale, W * scale, 3) uint8 BGR
        """
        cam = self.dataset.cameras[c]
        k = int(scale)
        if k < 1:
            raise ValueError(f"scale must be a positive integer, got {scale}")
        img = self.input_image(i, c)
        if posed is None:
            posed = self._posed(i)
        colour, mask = self.model_layer(posed, c)
        alpha = ALPHA_DEPTH if cam.kind == "depth" else ALPHA
        fg = self.foreground(i, c) if self.masks else None
        painted = mask
        if fg is not None:
            colour = np.zeros_like(colour)
            colour[mask & fg] = MASK_BOTH_BGR
            colour[fg & ~mask] = MASK_ONLY_BGR
            colour[mask & ~fg] = MODEL_ONLY_BGR
            painted = mask | fg
        blended = (1.0 - alpha) * img[painted].astype(np.float64) + alpha * colour[painted]
        img[painted] = np.clip(np.round(blended), 0, 255).astype(np.uint8)
        if k > 1:
            img = cv2.resize(img, None, fx=k, fy=k, interpolation=cv2.INTER_NEAREST)
            mask = cv2.resize(mask.astype(np.uint8), None, fx=k, fy=k,
                              interpolation=cv2.INTER_NEAREST).astype(bool)
        thick = max(1, round(min(img.shape[:2]) / 220))
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, contours, -1, OUTLINE_BGR, thick, cv2.LINE_AA)
        f = int(self.rows[i])
        if self.gt is not None and self._gt_bones:
            self._draw_skeleton(img, cam, self.gt["joints"][f], self._gt_bones, GROUNDTRUTH_BGR,
                                thick, k)
        if self._kp_bones:
            self._draw_skeleton(img, cam, self.kp["points"][f], self._kp_bones, KEYPOINT_BGR,
                                max(1, thick // 2), k)
        joints = self._joints[self._order[i]]
        self._draw_skeleton(img, cam, joints, self._bones, TRACKED_BGR, thick, k)
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

    def foreground(self, i, c):
        """(H, W) bool undistorted foreground mask of result row ``i`` in colour camera ``c``,
        or None (a depth camera, or no mask for that frame)."""
        cam = self.dataset.cameras[c]
        if cam.kind != "colour":
            return None
        m = self.dataset.mask(int(self.rows[i]), c)
        if m is None:
            return None
        return cam.undistort_image(m.astype(np.uint8), cv2.INTER_NEAREST) > 0

    def _posed(self, i):
        from gltrack.render import reference as ref

        params = np.asarray(self.result["params"])[self._order[i]][None]
        return ref.skin_vertices(self.body.mesh, self.body.skinning(params))[0]

    def upscale_for(self, min_height) -> int:
        """The integer factor that makes the camera grid at least ``min_height`` pixels tall
        (1 when ``min_height`` is None or the grid is tall enough)."""
        if not min_height:
            return 1
        n = len(self.cams)
        rows = math.ceil(n / math.ceil(math.sqrt(n)))
        grid = rows * max(self.dataset.cameras[c].height for c in self.cams)
        return max(1, -(-int(min_height) // grid))

    def legend(self, width: int, scale: int = 1) -> np.ndarray:
        """The legend strip (:func:`legend_strip`) for a frame ``width`` pixels wide whose
        cameras are enlarged by ``scale``: text as large as the corner text, a colour bar per
        depth camera shown, the ground truth listed only when the dataset has it."""
        key = (int(width), int(scale))
        if key not in self._legends:
            h = max(self.dataset.cameras[c].height for c in self.cams) * int(scale)
            ranges = [(self.dataset.cameras[c].name, self.depth_range[self.dataset.cameras[c].name])
                      for c in self.cams if self.dataset.cameras[c].kind == "depth"]
            gt = self.gt is not None and bool(self._gt_bones)
            self._legends[key] = legend_strip(width, text_scale(h), groundtruth=gt,
                                              depth_ranges=ranges, masks=self.masks,
                                              keypoints=bool(self._kp_bones))
        return self._legends[key].copy()

    def frame(self, i, scale: int = 1, legend: bool = True) -> np.ndarray:
        """All chosen cameras of result row ``i``, tiled (:func:`tile`), each enlarged by
        ``scale`` (see :meth:`camera_frame`), with the legend strip below when ``legend``.

        Returns
        -------
        (H, W, 3) uint8 BGR
        """
        posed = self._posed(i)
        img = tile([self.camera_frame(i, c, posed, scale) for c in self.cams])
        if legend:
            img = np.vstack([img, self.legend(img.shape[1], scale)])
        return img


def text_scale(height: int) -> float:
    """OpenCV font scale (FONT_HERSHEY_SIMPLEX) of overlay text on an image ``height`` pixels tall:
    letters about 1/36 of the height (9 pixels at least)."""
    return max(0.4, height / 800.0)


def _corner_text(img, lines, colours=None):
    scale = text_scale(img.shape[0])
    thick = max(1, round(scale * 1.5))
    font = cv2.FONT_HERSHEY_SIMPLEX
    sizes = [cv2.getTextSize(t, font, scale, thick) for t in lines]
    step = max(th + base for (_, th), base in sizes) + 2
    width = max(tw for (tw, _), _ in sizes)
    # An opaque box: outlined glyphs smear at the small sizes of depth-camera images.
    cv2.rectangle(img, (0, 0), (width + 6, step * len(lines) + 3), PANEL_BGR, -1)
    for k, text in enumerate(lines):
        bgr = (colours[k] if colours and k < len(colours) else None) or (255, 255, 255)
        cv2.putText(img, text, (3, step * (k + 1) - 2), font, scale, bgr, thick, cv2.LINE_AA)


def _tick_step(span: float, fits: int) -> float:
    """The smallest of 0.1, 0.2, 0.25, 0.5, 1, 2, 5, 10 metres giving at most ``fits`` ticks."""
    for step in (0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0):
        if span / step + 1 <= max(fits, 2):
            return step
    return 10.0


def legend_strip(width: int, scale: float, groundtruth: bool = True,
                 depth_ranges=(), masks: bool = False, keypoints: bool = False) -> np.ndarray:
    """A strip saying what the overlay's colours mean.

    Left to right, wrapping onto more rows as ``width`` needs: a swatch per part group
    (:data:`PART_GROUPS`) of the model's colours, the model's outline, the tracked skeleton and
    (with ``groundtruth``) the ground-truth skeleton, (with ``keypoints``) the keypoints. Then,
    per depth camera, a row with the
    camera's name and a colour bar from near (left) to far (right), each column coloured exactly
    as :func:`depth_to_bgr` colours that depth, with ticks in metres below it.

    Parameters
    ----------
    width : int, pixels
    scale : float, OpenCV font scale (:func:`text_scale`)
    groundtruth : bool, list the ground-truth skeleton
    depth_ranges : sequence of (camera name, (near, far) metres)
    masks : bool, the mask view's colours (model and mask, mask only, model only) instead of
        the parts'
    keypoints : bool, list the dataset's triangulated keypoints

    Returns
    -------
    (H, width, 3) uint8 BGR on :data:`PANEL_BGR`
    """
    font = cv2.FONT_HERSHEY_SIMPLEX
    thick = max(1, round(scale * 1.5))
    (_, th), base = cv2.getTextSize("Ag", font, scale, thick)
    pad = max(3, th // 2)
    row_h = th + base + pad
    sw = th + 2
    items = [(None, None, "silhouettes:" if masks else "model:")]
    if masks:
        items += [("box", MASK_BOTH_BGR, "model and mask"), ("box", MASK_ONLY_BGR, "mask only"),
                  ("box", MODEL_ONLY_BGR, "model only")]
    else:
        items += [("box", part_colour(k), label) for label, k in PART_GROUPS]
    items += [("line", OUTLINE_BGR, "outline"), ("dots", TRACKED_BGR, "tracked")]
    if groundtruth:
        items.append(("dots", GROUNDTRUTH_BGR, "ground truth"))
    if keypoints:
        items.append(("dots", KEYPOINT_BGR, "keypoints"))
    placed, x, row = [], pad, 0
    for kind, bgr, label in items:
        w = (sw + pad if kind else 0) + cv2.getTextSize(label, font, scale, thick)[0][0]
        if x > pad and x + w > width - pad:
            row, x = row + 1, pad
        placed.append((x, row, kind, bgr, label))
        x += w + 2 * pad
    rows = row + 1
    bars = []
    for name, (near, far) in depth_ranges:
        label = f"{name} depth (m)"
        tw = cv2.getTextSize(label, font, scale, thick)[0][0]
        if width - 3 * pad - tw >= width / 3:  # label and bar on one row
            bars.append((rows, label, rows, 2 * pad + tw, near, far))
            rows += 2
        else:
            bars.append((rows, label, rows + 1, pad, near, far))
            rows += 3
    strip = np.empty((rows * row_h + pad, width, 3), np.uint8)
    strip[:] = PANEL_BGR
    white = (255, 255, 255)

    def text(x, r, label):
        cv2.putText(strip, label, (x, r * row_h + pad + th), font, scale, white, thick, cv2.LINE_AA)

    for x, r, kind, bgr, label in placed:
        y0 = r * row_h + pad
        if kind == "box":
            strip[y0:y0 + sw, x:x + sw] = bgr
        elif kind == "line":
            cv2.line(strip, (x, y0 + sw // 2), (x + sw - 1, y0 + sw // 2), bgr, max(2, thick))
        elif kind == "dots":
            cv2.line(strip, (x, y0 + sw - 2), (x + sw - 1, y0 + 1), bgr, max(1, thick))
            for px, py in ((x + 1, y0 + sw - 2), (x + sw - 2, y0 + 1)):
                cv2.circle(strip, (px, py), max(2, thick), bgr, -1, cv2.LINE_AA)
        text(x + (sw + pad if kind else 0), r, label)
    for label_row, label, bar_row, x0, near, far in bars:
        text(pad, label_row, label)
        x1 = width - pad
        n = max(x1 - x0, 2)
        y0 = bar_row * row_h + pad
        z = near + (far - near) * np.arange(n) / (n - 1)
        strip[y0:y0 + sw, x0:x0 + n] = depth_to_bgr(z[None], near, far)[0]
        tick_w = cv2.getTextSize("0.00", font, scale, thick)[0][0] + 2 * pad
        step = _tick_step(far - near, n // tick_w)
        for v in np.arange(math.ceil(near / step - 1e-9) * step, far + 1e-9, step):
            px = x0 + int(round((v - near) / (far - near) * (n - 1)))
            cv2.line(strip, (px, y0 + sw), (px, y0 + sw + pad // 2 + 1), white, 1)
            s = f"{v:.2f}".rstrip("0").rstrip(".") if step < 1 else f"{v:.0f}"
            tw = cv2.getTextSize(s, font, scale, thick)[0][0]
            tx = min(max(px - tw // 2, 0), width - tw)
            cv2.putText(strip, s, (tx, y0 + sw + pad + th), font, scale, white, thick,
                        cv2.LINE_AA)
    return strip


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


_FFMPEG: tuple | None | bool = False  # False: not looked for yet


def ffmpeg_h264():
    """An ffmpeg executable that can encode H.264 (libx264), looked for once per process.

    Candidates: the binary of the ``imageio-ffmpeg`` package when it is installed (a static
    build with libx264; ``IMAGEIO_FFMPEG_EXE`` overrides it), then ``ffmpeg`` on ``PATH``. Each
    is asked for its encoder list; the first that lists libx264 is used.

    Returns
    -------
    (exe, where) : (str, str), ``where`` = ``"imageio-ffmpeg"`` or ``"PATH"``; or None
    """
    global _FFMPEG
    if _FFMPEG is False:
        _FFMPEG = None
        candidates = []
        try:
            import imageio_ffmpeg

            candidates.append((imageio_ffmpeg.get_ffmpeg_exe(), "imageio-ffmpeg"))
        except Exception as e:  # ImportError, or RuntimeError when its binary is missing
            log.debug("no ffmpeg from imageio-ffmpeg: %s", e)
        exe = shutil.which("ffmpeg")
        if exe:
            candidates.append((exe, "PATH"))
        for exe, where in candidates:
            try:
                listing = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True,
                                         text=True, timeout=60).stdout
            except (OSError, subprocess.SubprocessError) as e:
                log.debug("%s (%s) does not run: %s", exe, where, e)
                continue
            if re.search(r"^\s*V\S*\s+libx264\s", listing, re.M):
                _FFMPEG = (exe, where)
                break
            log.debug("%s (%s) has no libx264 encoder", exe, where)
        log.debug("ffmpeg with libx264: %s", _FFMPEG)
    return _FFMPEG


class _FfmpegWriter:
    """``cv2.VideoWriter``'s ``write``/``release`` over an ffmpeg process that encodes the BGR
    frames it is piped as H.264 (libx264, yuv420p, CRF 20) in an .mp4 with ``+faststart`` (the
    index first, so a browser starts playing before the whole file has arrived)."""

    def __init__(self, exe, path, fps, size):
        self.path = Path(path)
        self.size = (int(size[0]), int(size[1]))
        self._err = tempfile.TemporaryFile()
        cmd = [exe, "-hide_banner", "-loglevel", "error", "-y",
               "-f", "rawvideo", "-pix_fmt", "bgr24", "-s", f"{self.size[0]}x{self.size[1]}",
               "-r", f"{float(fps):.6g}", "-i", "pipe:0", "-an",
               "-c:v", "libx264", "-preset", "medium", "-crf", "20", "-pix_fmt", "yuv420p",
               "-movflags", "+faststart", "-f", "mp4", str(self.path)]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                      stderr=self._err)

    def isOpened(self):  # noqa: N802 (cv2.VideoWriter's name)
        return self._proc.poll() is None

    def _failure(self, what):
        self._err.seek(0)
        msg = self._err.read().decode(errors="replace").strip().splitlines()
        return OSError(f"{self.path}: ffmpeg {what}" + (f": {msg[-1]}" if msg else ""))

    def write(self, img):
        """Append one (H, W, 3) uint8 BGR frame of the writer's size."""
        if img.shape != (self.size[1], self.size[0], 3) or img.dtype != np.uint8:
            raise ValueError(f"frame {img.shape} {img.dtype}: the writer takes "
                             f"{self.size[1]}x{self.size[0]}x3 uint8")
        try:
            self._proc.stdin.write(np.ascontiguousarray(img).tobytes())
        except (BrokenPipeError, OSError):
            self._proc.wait()
            raise self._failure(f"stopped (exit {self._proc.returncode})") from None

    def release(self):
        """Finish the file; raises OSError when ffmpeg failed."""
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            with suppress(OSError):
                self._proc.stdin.close()
        rc = self._proc.wait()
        if not self._err.closed:
            err = self._failure(f"failed (exit {rc})") if rc else None
            self._err.close()
            if err is not None:
                raise err


@dataclass(frozen=True)
class OverlayVideo:
    """A video file written by :func:`render_overlay`.

    Attributes
    ----------
    path : Path, the file (``.avi`` after a fallback to Motion JPEG)
    codec : str, ``"h264"``, ``"mpeg4"`` (MPEG-4 Part 2, ``mp4v``) or ``"mjpeg"``
    encoder : str, what encoded it: ``"ffmpeg libx264 (imageio-ffmpeg)"``,
        ``"ffmpeg libx264 (PATH)"``, ``"OpenCV avc1"``, ``"OpenCV mp4v"`` or ``"OpenCV MJPG"``
    frames : int, frames written
    size : (width, height) pixels
    """

    path: Path
    codec: str
    encoder: str
    frames: int = 0
    size: tuple = (0, 0)

    def __fspath__(self):
        return os.fspath(self.path)

    def __str__(self):
        return str(self.path)


def open_video_writer(out, fps: float, size):
    """Open a video writer, the best one available for the file's type.

    For .mp4: H.264 through ffmpeg with libx264 (:func:`ffmpeg_h264`), else H.264 through
    this OpenCV (``avc1``, :func:`h264_available`), else MPEG-4 Part 2 (``mp4v``, with a
    warning: browsers do not play it), else Motion JPEG in .avi. For .avi: Motion JPEG.

    Parameters
    ----------
    out : path, ``.mp4`` or ``.avi``
    fps : float
    size : (width, height) pixels, both even

    Returns
    -------
    writer : opened, with cv2.VideoWriter's ``write(img)`` and ``release()``
    video : OverlayVideo, the file actually written (``.avi`` after a fallback), its codec and
        encoder (``frames`` 0)
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".mp4", ".avi"):
        raise ValueError(f"{out}: video file must end in .mp4 or .avi")
    size = (int(size[0]), int(size[1]))
    if suffix == ".mp4":
        ff = ffmpeg_h264()
        if ff is not None:
            try:
                w = _FfmpegWriter(ff[0], out, fps, size)
            except OSError as e:
                log.warning("%s: ffmpeg (%s) does not start (%s); trying OpenCV's encoders",
                            out, ff[0], e)
            else:
                if w.isOpened():
                    video = OverlayVideo(out, "h264", f"ffmpeg libx264 ({ff[1]})", 0, size)
                    log.info("%s: H.264 (%s)", out, video.encoder)
                    return w, video
                with suppress(OSError):
                    w.release()
                log.warning("%s: ffmpeg (%s) stopped at once; trying OpenCV's encoders", out,
                            ff[0])
    tries = ([("avc1", out, "h264")] if suffix == ".mp4" and h264_available() else []) \
        + ([("mp4v", out, "mpeg4")] if suffix == ".mp4" else []) \
        + [("MJPG", out.with_suffix(".avi"), "mjpeg")]
    for fourcc, path, codec in tries:
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), float(fps), size)
        if w.isOpened():
            video = OverlayVideo(path, codec, f"OpenCV {fourcc}", 0, size)
            if path != out:
                log.warning("%s: this OpenCV cannot write mp4v; wrote Motion JPEG to %s instead",
                            out, path)
            elif fourcc == "mp4v":
                log.warning("%s: no H.264 encoder here, so this is MPEG-4 Part 2 (mp4v), which "
                            "browsers and many players do not play. For H.264: pip install "
                            "imageio-ffmpeg (or put an ffmpeg with libx264 on PATH)", out)
            else:
                log.info("%s: %s (%s)", out, codec, video.encoder)
            return w, video
        w.release()
    raise OSError(f"{out}: cv2.VideoWriter could open neither mp4v nor MJPG")


def render_overlay(result, dataset, out, cameras="all", max_frames=None, progress=True,
                   fps=None, preset=None, min_height: int | None = None,
                   legend: bool = True, masks: bool = False) -> OverlayVideo:
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
        Enlarge small camera images (e.g. a 176x144 ToF camera) by an integer factor, nearest
        neighbour, until the camera grid is at least this tall (default :data:`MIN_HEIGHT`;
        0 = never), so the video is watchable and its text readable.
    legend : bool, add the legend strip below the cameras (:func:`legend_strip`)
    masks : bool, show the model against the frames' foreground masks (see
        :class:`OverlayRenderer`)

    Returns
    -------
    OverlayVideo
        The file written (``out``, or ``out`` with ``.avi`` when mp4v was unavailable), its
        codec, frame count and size. Frames are padded with black to even width and height
        (what the encoders need).
    """
    with OverlayRenderer(result, dataset, cameras, preset, masks=masks) as r:
        return _write_video(r, out, max_frames, progress, fps,
                            MIN_HEIGHT if min_height is None else min_height, legend)


def _write_video(r, out, max_frames, progress, fps, min_height=None, legend=True):
    from tqdm import tqdm

    n = len(r) if max_frames is None else min(len(r), int(max_frames))
    if n <= 0:
        raise ValueError("nothing to render: the result holds no frames")
    fps = r.dataset.fps if fps is None else float(fps)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    scale = r.upscale_for(min_height)
    writer = video = None
    try:
        for i in tqdm(range(n), desc="overlay", unit="frame", disable=not progress):
            img = r.frame(i, scale=scale, legend=legend)
            h, w = img.shape[:2]
            if h % 2 or w % 2:
                img = cv2.copyMakeBorder(img, 0, h % 2, 0, w % 2, cv2.BORDER_CONSTANT, value=0)
            if writer is None:
                writer, video = open_video_writer(out, fps, (img.shape[1], img.shape[0]))
            writer.write(img)
        writer.release()
    except BaseException:
        if writer is not None:
            with suppress(Exception):
                writer.release()
            video.path.unlink(missing_ok=True)  # a truncated video would look like a finished one
        raise
    video = OverlayVideo(video.path, video.codec, video.encoder, n, video.size)
    log.info("wrote %s (%d frames, %d cameras, %dx%d, %s by %s)", video.path, n, len(r.cams),
             *video.size, video.codec, video.encoder)
    return video
