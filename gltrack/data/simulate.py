"""The sensor simulator: synthetic depth or multi-view datasets from a motion (``gltrack synth``).

A skinned body (:func:`gltrack.body.mesh.make_body_mesh` of the motion's skeleton) performs the
motion in a room (:mod:`gltrack.data.scene`) and is rendered with **pyrender** through PyOpenGL
on EGL: a renderer independent of gltrack's moderngl scoring engine, so tracking synthetic data
tests the engine against something it did not draw itself. Sensor effects are added in numpy
(:mod:`gltrack.data.sim_depth`, :mod:`gltrack.data.sim_multiview`) and the frames are written with
:class:`gltrack.data.dataset.DatasetWriter` (atomically).

Rigs
----
``depth``
    One SR4000-like ToF camera (176x144 by default) 2-4 m in front of the subject's mean position
    (the smallest distance in 0.1 m steps that keeps the subject in view, at most 4 m), 1 m above
    the floor, looking at the mean pelvis position. Writes ``cam0/`` (uint16 mm with the ToF
    noise model), ``cam0_gtmask/`` (visible body pixels), ``cam0_background.png`` (the empty scene
    as the per-pixel median of 9 noisy empty frames, invalid samples ignored).
``multiview``
    ``n_cameras`` colour cameras (320x240 by default) evenly spaced on a circle of at least
    3.5 m radius around the subject (cam0 in front), 1.5-2 m high, each zoomed so the whole
    motion stays in view. Clothing colours per body part, a cluttered textured room, per-frame
    lighting (gain/offset) jitter and pixel noise. Writes ``camN/`` (BGR), 12 empty-scene frames
    per camera in ``camN_background/``, ``camN_mask/`` from MOG2 background subtraction trained on
    those frames, and ``camN_gtmask/`` (visible body pixels, diagnosis only).

Subject: by default the body is drawn with the tracker's own procedural mesh. ``subject=FILE``
(``--mesh``) draws a rigged glTF body fitted to the motion's skeleton instead, and
``girth_scale`` (``--girth-scale``) makes the subject thinner or stouter
(:mod:`gltrack.data.subject`). Both change the subject's surface only: cameras, room, props,
noise and the ground truth (joints, and markers of the tracker's body) stay those of the default
run with the same seed. ``meta.json`` then carries a ``"subject"`` record
(``{"mesh": ..., "girth_scale": ...}``); without it the subject was the default one.

Keypoints: ``keypoints=MODEL`` (``--keypoints auto`` or a model file) runs the landmark network
that ``gltrack ingest`` runs on a user's videos on the multiview frames, triangulates them with
the dataset's cameras and writes ``keypoints.npz`` (:func:`gltrack.data.ingest.write_keypoints`),
as a user's dataset would have them; ``meta.json`` records them under ``"keypoints"``. The
network sees only the rendered images, so its errors are its own (on the MakeHuman subject its
hips lie about 55 mm below and 25 mm inside the CMU skeleton's hip joints, its shoulders 60 mm
inside: different definitions of a joint, not noise). Off by default, so the datasets of earlier
figures are reproduced.

Options: ``occluder="table"`` puts a table between cam0 and the subject (legs hidden in that
view); its convex image outline per camera goes to ``environment.json``. ``distractor="box"``
adds a box sliding beside the subject: in the images and the background-subtraction masks, not
in the ground-truth masks. ``groundtruth.npz`` holds joints, markers, params (clamped to the
joint limits, as the body was posed), the preset, and for diagnosis ``distractor_centre``
(N, 3) and ``table_corners`` (8, 3) when present. ``synth.json`` records the settings.

Reproducibility: every random choice (placement jitter, room, clothes, noise) comes from
generators seeded with ``[seed, stream]``, one stream per purpose, so the same seed gives
byte-identical images and switching an option (noise level, distractor) leaves the rest of the
scene unchanged.

GL isolation: PyOpenGL fixes its platform at import and its context must not fight a moderngl
context in the same process. :func:`synthesize` refuses to run where PyOpenGL was already
imported for another platform; processes that hold a moderngl context use
:func:`synthesize_in_subprocess` (a ``multiprocessing`` spawn child).
"""
from __future__ import annotations

import json
import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from gltrack.body.kinematics import Kinematics
from gltrack.body.mesh import PARTS
from gltrack.camera import Camera, depth_camera_sr4000, look_at_camera
from gltrack.data import scene as scn
from gltrack.data.dataset import RIGS, DatasetWriter
from gltrack.data.sim_depth import NOISE_LEVELS, TofNoise, apply_tof_noise
from gltrack.data.sim_multiview import ColourNoise, mask_model, sensor_image
from gltrack.data.subject import subject_mesh, subject_record, top_of_head

log = logging.getLogger(__name__)

OCCLUDERS = ("none", "table")
DISTRACTORS = ("none", "box")
DEFAULT_SIZE = {"depth": (176, 144), "multiview": (320, 240)}
#: Empty-scene frames per camera: written for background models and used to train MOG2.
N_BACKGROUND = {"depth": 9, "multiview": 12}
ZNEAR, ZFAR = 0.05, 30.0
_STREAMS = {"layout": 1, "room": 2, "clothes": 3, "sensor": 4, "background": 5}
_UP = np.array([0.0, 1.0, 0.0])

#: peak memory of :func:`synthesize`: BASE + pixels per image x (SHARED + PER_CAMERA x cameras)
#: bytes, measured as the peak RSS of ``gltrack synth`` (2 frames; the peak does not grow with
#: the frame count: frames are written as they are made) at 64x64 .. 2048x2048 (depth: 236,
#: 338, 646, 1817 MB at 64, 512, 1024, 2048 px square, i.e. 380..400 bytes per pixel) and
#: multiview 256..1536 px square with 2 and 4 cameras (444 bytes per pixel with 2 cameras,
#: 114 more per pixel for each further camera), rounded up
SYNTH_MEMORY = {"base": 300e6,
                "depth": {"shared": 410.0, "per_camera": 0.0},
                "multiview": {"shared": 230.0, "per_camera": 120.0}}


def synth_memory_estimate(rig: str, size, n_cameras: int = 4) -> float:
    """Bytes of memory :func:`synthesize` needs at its peak (see :data:`SYNTH_MEMORY`).

    Parameters
    ----------
    rig : {"depth", "multiview"}
    size : (W, H) pixels of each image
    n_cameras : int, cameras of the multiview rig (the depth rig has one)

    Returns
    -------
    float, bytes
    """
    c = SYNTH_MEMORY[rig]
    cams = 1 if rig == "depth" else int(n_cameras)
    return SYNTH_MEMORY["base"] + int(size[0]) * int(size[1]) * (c["shared"]
                                                                  + c["per_camera"] * cams)


def available_memory():
    """Bytes of memory this process can still use, or None when unknown.

    ``MemAvailable`` of ``/proc/meminfo`` (else free physical pages from ``os.sysconf``),
    lowered to what a cgroup (v2 ``memory.max`` or v1 ``memory.limit_in_bytes``) leaves, its
    inactive page cache counted as free.
    """
    avail = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            avail = None
    for folder, limit, usage, cache in (
            ("/sys/fs/cgroup", "memory.max", "memory.current", "inactive_file"),
            ("/sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.usage_in_bytes",
             "total_inactive_file")):
        try:
            with open(f"{folder}/{limit}") as f:
                text = f.read().strip()
            if text == "max" or int(text) >= 1 << 60:
                continue
            with open(f"{folder}/{usage}") as f:
                used = int(f.read().strip())
        except (OSError, ValueError):
            continue
        try:  # page cache the kernel drops under pressure counts as free (as `docker stats`)
            with open(f"{folder}/memory.stat") as f:
                used -= next(int(line.split()[1]) for line in f
                             if line.split()[0] == cache)
        except (OSError, ValueError, IndexError, StopIteration):
            pass
        left = int(text) - max(used, 0)
        avail = left if avail is None else min(avail, left)
    return None if avail is None else max(int(avail), 0)


def check_synth_memory(rig: str, size, n_cameras: int = 4):
    """Refuse a synthesis that would not fit in the memory left (before anything is written).

    Raises
    ------
    MemoryError
        One line naming the size, the estimate and the memory available.
    """
    need = synth_memory_estimate(rig, size, n_cameras)
    have = available_memory()
    if have is None:
        log.debug("available memory unknown; synthesis needs about %.1f GB", need / 1e9)
        return
    if need > have:
        cams = "" if rig == "depth" else f" with {n_cameras} cameras"
        raise MemoryError(f"a {rig} dataset of {size[0]}x{size[1]} images{cams} needs about "
                          f"{need / 1e9:.1f} GB of memory, {have / 1e9:.1f} GB is available; "
                          "use a smaller size (or fewer cameras)")


def _rng(seed: int, stream: str, *more: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), _STREAMS[stream], *[int(m) for m in more]])


# ---------------------------------------------------------------------------------------------
# clothing
# ---------------------------------------------------------------------------------------------
SKIN = ((0.87, 0.69, 0.56), (0.76, 0.57, 0.45), (0.55, 0.38, 0.26), (0.36, 0.24, 0.16))
HAIR = ((0.10, 0.07, 0.05), (0.30, 0.20, 0.10), (0.60, 0.45, 0.25), (0.04, 0.04, 0.04))
SHIRT = ((0.70, 0.10, 0.10), (0.10, 0.30, 0.70), (0.15, 0.55, 0.20), (0.85, 0.75, 0.20),
         (0.90, 0.90, 0.90), (0.50, 0.20, 0.60))
# Saturated or very dark trousers: grey-brown ones look like shadows on the parquet to MOG2.
TROUSERS = ((0.15, 0.25, 0.55), (0.10, 0.12, 0.35), (0.45, 0.08, 0.08), (0.06, 0.06, 0.06),
            (0.20, 0.20, 0.22))
SHOES = ((0.05, 0.05, 0.05), (0.40, 0.25, 0.10), (0.85, 0.85, 0.85))
#: Garment of each body part (:data:`gltrack.body.mesh.PARTS`); hair is cut from the head.
GARMENT = {"head": "skin", "torso": "shirt", "l_upper_arm": "shirt", "r_upper_arm": "shirt",
           "pelvis": "trousers", "l_thigh": "trousers", "r_thigh": "trousers",
           "l_shin": "trousers", "r_shin": "trousers", "l_forearm": "skin", "r_forearm": "skin",
           "l_hand": "skin", "r_hand": "skin", "l_foot": "shoes", "r_foot": "shoes"}


def clothing_colours(mesh, skeleton, rng: np.random.Generator, head_end=None):
    """Per-vertex colours of a dressed body.

    Parameters
    ----------
    mesh : BodyMesh (rest pose of ``skeleton``)
    skeleton : Skeleton
    rng : numpy.random.Generator, picks the garment colours and a faint fabric texture
    head_end : (3,) float, optional, head joint -> top of the head (metres) for the hair line;
        default the skeleton's head end site (or 0.12 stature up), which the procedural head
        is built from

    Returns
    -------
    colours : (V, 3) float32, linear RGB in [0, 1]
    garments : dict of garment name to its (3,) base colour (list of float)
    """
    palette = {"skin": SKIN, "hair": HAIR, "shirt": SHIRT, "trousers": TROUSERS, "shoes": SHOES}
    base = {k: np.array(v[int(rng.integers(len(v)))]) for k, v in palette.items()}
    names = np.array([GARMENT[p] for p in PARTS])[mesh.part]
    head = skeleton.index("head")
    p_head = skeleton.rest_positions()[head]
    if head_end is not None:
        top = np.asarray(head_end, dtype=np.float64)
    elif np.linalg.norm(skeleton.ends[head]) > 1e-6:
        top = skeleton.ends[head]
    else:
        top = _UP * 0.12 * skeleton.height()
    rel = mesh.vertices.astype(np.float64) - p_head
    along = rel @ top / (top @ top)
    back = rel[:, 2] < -0.01
    is_head = mesh.part == PARTS.index("head")
    names[is_head & ((along > 0.55) | (back & (along > 0.2)))] = "hair"
    cols = np.stack([base[n] for n in names])
    cols *= 1.0 + 0.04 * rng.standard_normal((len(cols), 1))  # fabric / skin variation
    return (np.clip(cols, 0, 1).astype(np.float32),
            {k: [round(float(c), 3) for c in v] for k, v in base.items()})


def vertex_normals(vertices, faces) -> np.ndarray:
    """(V, 3) float32 unit area-weighted vertex normals of a triangle mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return n.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# layout: where the cameras, walls, table and distractor go
# ---------------------------------------------------------------------------------------------
def _sample_points(mesh, kin, params, max_frames: int = 120, every: int = 6) -> np.ndarray:
    """(n, V', 3) posed vertices (every ``every``-th) of up to ``max_frames`` spread frames."""
    idx = np.unique(np.linspace(0, len(params) - 1, min(len(params), max_frames)).round()
                    .astype(int))
    S = kin.skinning_matrices(params[idx])
    sub = np.arange(0, mesh.n_vertices, every)
    verts = mesh.vertices[sub].astype(np.float64)
    w, j = mesh.weights[sub].astype(np.float64), mesh.joints[sub]
    vh = np.concatenate([verts, np.ones((len(sub), 1))], 1)
    out = np.zeros((len(idx), len(sub), 3))
    for k in range(4):
        out += w[None, :, k, None] * np.einsum("nvij,vj->nvi", S[:, j[:, k]], vh)
    return out


def _fits(cam: Camera, pts: np.ndarray, margin: float) -> bool:
    z = cam.depth_of(pts)
    if np.any(z < 0.3):
        return False
    uv = cam.project(pts, distort=False)
    return bool(np.all((uv[:, 0] >= margin - 0.5) & (uv[:, 0] <= cam.width - 0.5 - margin)
                       & (uv[:, 1] >= margin - 0.5) & (uv[:, 1] <= cam.height - 0.5 - margin)))


def _facing(pose) -> np.ndarray:
    """Mean horizontal facing direction (+Z of the pelvis frame)."""
    f = pose.rotations[:, 0, :, 2].mean(0)
    f[1] = 0.0
    n = np.linalg.norm(f)
    return f / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def _depth_layout(pts, centre, forward, floor_y, size, rng):
    W, H = size
    target = centre.copy()
    cam = None
    for D in np.arange(2.0, 4.0001, 0.1):
        eye = centre + D * forward
        eye[1] = floor_y + 1.0 + float(rng.uniform(-0.05, 0.05))
        c = depth_camera_sr4000(eye, target)
        c = c if (W, H) == (c.width, c.height) else c.scaled(W, H)
        if _fits(c, pts, margin=2.0):
            cam = c
            break
    if cam is None:
        log.info("the subject leaves the depth camera's view in some frames (camera at 4 m)")
        cam = c
    return [cam]


def _multiview_layout(pts, centre, forward, floor_y, n, size, rng):
    W, H = size
    radial = np.linalg.norm((pts - centre)[..., [0, 2]], axis=-1).max()
    radius = max(3.5, float(radial) + 1.5)
    heading = math.atan2(forward[0], forward[2])
    cams = []
    for c in range(n):
        ang = heading + 2 * math.pi * c / n + float(rng.uniform(-0.15, 0.15))
        eye = centre + radius * np.array([math.sin(ang), 0.0, math.cos(ang)])
        eye[1] = floor_y + float(rng.uniform(1.5, 2.0))
        probe = look_at_camera(f"cam{c}", eye, centre, W, H, 60.0)
        Xc = probe.to_camera(pts)
        z = np.maximum(Xc[:, 2], 0.3)
        # the focal length that keeps every body point 8 % inside the image edges
        f = min(0.42 * W / np.max(np.abs(Xc[:, 0]) / z), 0.42 * H / np.max(np.abs(Xc[:, 1]) / z))
        fov = math.degrees(2 * math.atan(0.5 * H / f))
        cams.append(look_at_camera(f"cam{c}", eye, centre, W, H, float(np.clip(fov, 25, 100))))
    return cams, radius


class Layout:
    """Cameras, room and props for one motion (see :func:`make_layout`).

    Attributes
    ----------
    cameras : list of Camera
    room : scene.Room
    floor_y : float, metres
    centre : (3,) float, metres, mean pelvis position
    forward : (3,) float, unit mean facing direction
    table_centre : (3,) float or None
    distractor_centres : (T, 3) float or None
    """

    def __init__(self, cameras, room, floor_y, centre, forward, table_centre, distractor_centres):
        self.cameras = cameras
        self.room = room
        self.floor_y = floor_y
        self.centre = centre
        self.forward = forward
        self.table_centre = table_centre
        self.distractor_centres = distractor_centres


def make_layout(mesh, kin, params, fps, rig, size, n_cameras, occluder, distractor,
                seed) -> Layout:
    """Place cameras, room, table and distractor around the motion (see module docstring)."""
    rng = _rng(seed, "layout")
    pose = kin.forward(params)
    pelvis = pose.positions[:, 0]
    centre = pelvis.mean(0)
    forward = _facing(pose)
    lateral = np.cross(_UP, forward)
    pts = _sample_points(mesh, kin, params)
    floor_y = float(pts[..., 1].min())
    flat = pts.reshape(-1, 3)
    rel = flat - centre
    if rig == "depth":
        cameras = _depth_layout(flat, centre, forward, floor_y, size, rng)
        D = float((cameras[0].center - centre) @ forward)
        lat_ext = float(np.abs(rel @ lateral).max())
        room = scn.Room(centre, forward, (-(lat_ext + 2.5), lat_ext + 2.5),
                        (-(float(-(rel @ forward).min()) + 1.5), D + 1.0), floor_y)
        towards = forward
    else:
        cameras, radius = _multiview_layout(flat, centre, forward, floor_y, n_cameras, size, rng)
        half = radius + 1.5
        room = scn.Room(centre, forward, (-half, half), (-half, half), floor_y)
        towards = cameras[0].center - centre
        towards[1] = 0.0
        towards /= np.linalg.norm(towards)
    table_centre = None
    if occluder == "table":
        reach = float((rel @ towards).max())
        table_centre = centre + (reach + 0.1 + 0.5 * scn.TABLE_SIZE[2]) * towards
        table_centre[1] = floor_y
        gap = float((cameras[0].center - table_centre) @ towards)
        if gap < 0.6:
            log.warning("the table stands only %.2f m from cam0", gap)
    dist = None
    if distractor == "box":
        dist = scn.distractor_path(pelvis, lateral, fps, floor_y)
    return Layout(cameras, room, floor_y, centre, forward, table_centre, dist)


def table_polygons(corners, cameras) -> dict:
    """Image outline of a box in every camera that sees it.

    Parameters
    ----------
    corners : (8, 3) float, metres
    cameras : sequence of Camera

    Returns
    -------
    dict of camera name to a list with one (K, 2) float64 polygon: the convex hull of the
    projected corners clipped to the image; cameras with a corner behind them or no overlap are
    left out.
    """
    out = {}
    for cam in cameras:
        if np.any(cam.depth_of(corners) <= ZNEAR):
            continue
        uv = cam.project(corners, distort=False).astype(np.float32)
        hull = cv2.convexHull(uv).reshape(-1, 2)
        w, h = cam.width - 0.5, cam.height - 0.5
        rect = np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]], np.float32)
        area, inter = cv2.intersectConvexConvex(hull, rect)
        if area > 0 and inter is not None and len(inter) >= 3:
            out[cam.name] = [inter.reshape(-1, 2).astype(np.float64)]
    return out


# ---------------------------------------------------------------------------------------------
# rendering with pyrender
# ---------------------------------------------------------------------------------------------
def _import_pyrender():
    from gltrack.render.pyrender_egl import import_pyrender

    return import_pyrender("synthesize_in_subprocess()")


def _gl_pose(cam: Camera) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cam.R, cam.t
    return np.linalg.inv(T) @ np.diag([1.0, -1.0, -1.0, 1.0])


class _Renderer:
    """One pyrender scene with the room, the body and the props; segmentation and colour passes.

    Segmentation ids: 1 body, 2 distractor, then one id per static piece (``self.pieces``).
    """

    def __init__(self, cameras, pieces, body_faces, body_colours, distractor, key_light):
        pr = _import_pyrender()
        self.pr = pr
        self.cameras = cameras
        W, H = cameras[0].width, cameras[0].height
        self.scene = pr.Scene(bg_color=np.zeros(4), ambient_light=np.full(3, 0.5))
        self._mat = pr.MetallicRoughnessMaterial(metallicFactor=0.0, roughnessFactor=0.9,
                                                 baseColorFactor=np.ones(4))
        self.pieces = list(pieces)
        self.seg_map = {}
        for k, p in enumerate(self.pieces):
            node = self.scene.add(self._mesh(p.vertices, p.faces, p.colours, p.normals))
            self.seg_map[node] = np.full(3, 3 + k)
        self.refl_lut = np.zeros(256)
        self.label_lut = np.zeros(256, np.uint8)
        self.refl_lut[1], self.label_lut[1] = scn.REFLECTIVITY["body"], scn.LABELS["body"]
        self.refl_lut[2], self.label_lut[2] = scn.REFLECTIVITY["distractor"], \
            scn.LABELS["distractor"]
        for k, p in enumerate(self.pieces):
            self.refl_lut[3 + k], self.label_lut[3 + k] = p.reflectivity, p.label
        self._dist_mesh = None if distractor is None else self._mesh(
            distractor.vertices, distractor.faces, distractor.colours, distractor.normals)
        self._dist_node = None
        self._body_node = None
        self._body_faces = np.asarray(body_faces, np.uint32)
        self._body_colours = np.asarray(body_colours, np.float32)
        self._cam_nodes = []
        for cam in cameras:
            pc = pr.IntrinsicsCamera(cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5,
                                     znear=ZNEAR, zfar=ZFAR)
            self._cam_nodes.append(self.scene.add(pc, pose=_gl_pose(cam)))
        # a key light and a weaker fill light from the opposite side, both from above
        key = _unit(key_light)
        for direction, intensity in ((key, 2.0), (key * [-1, 1, -1], 1.0)):
            self.scene.add(pr.DirectionalLight(color=np.ones(3), intensity=intensity),
                           pose=_light_pose(direction))
        self.renderer = pr.OffscreenRenderer(W, H)

    def _mesh(self, vertices, faces, colours, normals):
        pr = self.pr
        prim = pr.Primitive(positions=np.asarray(vertices, np.float32),
                            normals=np.asarray(normals, np.float32),
                            color_0=np.concatenate([colours, np.ones((len(colours), 1))], 1)
                            .astype(np.float32),
                            indices=np.asarray(faces, np.uint32), material=self._mat,
                            mode=pr.constants.GLTF.TRIANGLES)
        return pr.Mesh([prim])

    def set_body(self, vertices):
        """Show the body with these (V, 3) posed vertices, or remove it (None)."""
        if self._body_node is not None:
            self.seg_map.pop(self._body_node, None)
            self.scene.remove_node(self._body_node)
            self._body_node = None
        if vertices is not None:
            mesh = self._mesh(vertices, self._body_faces, self._body_colours,
                              vertex_normals(vertices, self._body_faces))
            self._body_node = self.scene.add(mesh)
            self.seg_map[self._body_node] = np.full(3, 1)

    def set_distractor(self, centre):
        """Move the distractor to ``centre`` (3,), or remove it (None)."""
        if centre is None or self._dist_mesh is None:
            if self._dist_node is not None:
                self.seg_map.pop(self._dist_node, None)
                self.scene.remove_node(self._dist_node)
                self._dist_node = None
            return
        pose = np.eye(4)
        pose[:3, 3] = centre
        if self._dist_node is None:
            self._dist_node = self.scene.add(self._dist_mesh, pose=pose)
            self.seg_map[self._dist_node] = np.full(3, 2)
        else:
            self.scene.set_pose(self._dist_node, pose)

    def segment(self, c):
        """Segmentation ids (H, W) uint8 and clean depth (H, W) float64 (metres, 0 = none)."""
        pr = self.pr
        self.scene.main_camera_node = self._cam_nodes[c]
        # SEG also switches multisampling off, so depth is sampled at pixel centres
        ids, depth = self.renderer.render(self.scene, flags=pr.RenderFlags.SEG
                                          | pr.RenderFlags.SKIP_CULL_FACES,
                                          seg_node_map=self.seg_map)
        return np.ascontiguousarray(ids[..., 0]), np.asarray(depth, np.float64)

    def colour(self, c):
        """Clean colour image (H, W, 3) uint8 RGB of camera ``c``."""
        self.scene.main_camera_node = self._cam_nodes[c]
        rgb, _ = self.renderer.render(self.scene, flags=self.pr.RenderFlags.SHADOWS_DIRECTIONAL)
        return rgb

    def close(self):
        if self.renderer is not None:
            self.renderer.delete()
            self.renderer = None


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _light_pose(towards_light) -> np.ndarray:
    """Pose of a pyrender directional light shining *from* ``towards_light`` (its -Z axis)."""
    z = _unit(towards_light)
    x = np.cross(_UP, z)
    x = _unit(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    return T


# ---------------------------------------------------------------------------------------------
# the simulator
# ---------------------------------------------------------------------------------------------
def _check_args(params, dofs, fps, rig, seed, size, n_cameras, occluder, distractor, noise):
    if rig not in RIGS:
        raise ValueError(f"rig must be one of {RIGS}, got {rig!r}")
    P = np.asarray(params)
    if P.ndim != 2 or P.shape[1] != dofs.size or len(P) == 0:
        raise ValueError(f"params must have shape (T >= 1, {dofs.size}) for preset "
                         f"{dofs.preset!r}, got {P.shape}")
    if not (isinstance(fps, (int, float)) and fps > 0 and math.isfinite(fps)):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    W, H = size
    if not (isinstance(W, (int, np.integer)) and isinstance(H, (int, np.integer))
            and 16 <= W <= 8192 and 16 <= H <= 8192):
        raise ValueError(f"size must be two integers within 16..8192, got {size!r}")
    if rig == "multiview" and not (isinstance(n_cameras, (int, np.integer)) and
                                   1 <= n_cameras <= 64):
        raise ValueError(f"n_cameras must be an integer within 1..64, got {n_cameras!r}")
    if occluder not in OCCLUDERS:
        raise ValueError(f"occluder must be one of {OCCLUDERS}, got {occluder!r}")
    if distractor not in DISTRACTORS:
        raise ValueError(f"distractor must be one of {DISTRACTORS}, got {distractor!r}")
    if noise not in NOISE_LEVELS:
        raise ValueError(f"noise must be one of {tuple(NOISE_LEVELS)}, got {noise!r}")


def synthesize(params, skeleton, dofs, fps, rig, out, *, seed: int = 0, size=None,
               n_cameras: int = 4, occluder: str | None = None, distractor: str | None = None,
               noise: str = "default", mesh=None, progress: bool = True,
               overwrite: bool = False, lod: int = 1, subject=None,
               girth_scale: float = 1.0, keypoints=None) -> Path:
    """Render a motion into a dataset folder (see the module docstring for what is written).

    Parameters
    ----------
    params : (T, D) float, poses of ``dofs`` (clamped to the joint limits)
    skeleton : Skeleton
    dofs : DofSet
    fps : float, frames per second of ``params``
    rig : {"depth", "multiview"}
    out : path, dataset folder to create
    seed : int >= 0
    size : (W, H) int pixels, optional; default 176x144 (depth) or 320x240 (multiview)
    n_cameras : int, multiview cameras
    occluder : None, "none" or "table"
    distractor : None, "none" or "box"
    noise : {"none", "default", "heavy"}
    mesh : BodyMesh, optional; default ``make_body_mesh(skeleton, lod=lod)``
    progress : bool, tqdm bar (only shown on a terminal)
    overwrite : bool, replace a non-empty ``out``
    lod : int, level of detail of the default mesh
    subject : path, optional, a rigged glTF body drawn instead of the body's mesh
        (:func:`gltrack.data.subject.fit_gltf_subject`); ground truth is unchanged
    girth_scale : float, within :data:`gltrack.data.subject.GIRTH_SCALE_RANGE`; the drawn
        subject's girths relative to the default body (1 = unchanged)
    keypoints : path, optional, the pose landmark model
        (:func:`gltrack.observe.keypoints.find_model`); the multiview frames' keypoints are
        found with it and written (see the module docstring). None: no keypoints

    Returns
    -------
    Path of the dataset folder.

    Raises
    ------
    ValueError
        Bad arguments, or a glTF ``subject`` that cannot be read or mapped (naming the file).
    FileNotFoundError
        ``subject`` or ``keypoints`` does not exist.
    FileExistsError
        ``out`` exists, is not empty and ``overwrite`` is False.
    MemoryError
        The images are too large for the memory available (:func:`check_synth_memory`).
    """
    from tqdm import tqdm

    from gltrack.body.model import BodyModel, body_to_meta

    occluder = occluder or "none"
    distractor = distractor or "none"
    size = tuple(size) if size is not None else DEFAULT_SIZE.get(rig, (0, 0))
    _check_args(params, dofs, fps, rig, seed, size, n_cameras, occluder, distractor, noise)
    if keypoints is not None:
        if rig != "multiview":
            raise ValueError("keypoints are found in colour frames: the multiview rig only")
        if not Path(keypoints).is_file():
            raise FileNotFoundError(f"{keypoints}: no such pose landmark model file")
    check_synth_memory(rig, size, n_cameras)
    t0 = time.perf_counter()
    custom_mesh = mesh is not None
    body = BodyModel.build(skeleton, dofs.preset, lod, mesh=mesh)
    mesh = body.mesh
    # what the cameras see; the layout and the ground truth stay the body's
    drawn = subject_mesh(skeleton, mesh, gltf=subject, girth_scale=girth_scale, lod=lod,
                         custom=custom_mesh)
    subject_rec = subject_record(subject, girth_scale, drawn)
    kin = Kinematics(skeleton, dofs)
    P = dofs.validate(params)
    T = len(P)
    layout = make_layout(mesh, kin, P, fps, rig, size, n_cameras, occluder, distractor, seed)
    cameras = layout.cameras

    pieces = scn.make_room(layout.room, _rng(seed, "room"))
    corners = None
    if layout.table_centre is not None:
        table, corners = scn.make_table(layout.table_centre, _unit(
            cameras[0].center * [1, 0, 1] - layout.table_centre * [1, 0, 1]), layout.floor_y)
        pieces.append(table)
    dist_piece = scn.make_distractor() if layout.distractor_centres is not None else None
    colours, garments = clothing_colours(
        drawn, skeleton, _rng(seed, "clothes"),
        head_end=None if subject is None else top_of_head(drawn, skeleton))

    meta_body = body_to_meta(skeleton, dofs.preset, lod)
    # a tracker rebuilding the body from meta.json gets the procedural mesh only
    meta_body["mesh"] = "custom" if custom_mesh else "procedural"
    pose = kin.forward(P)
    joints = pose.positions
    markers = kin.transform_points(pose, body.markers.bone, body.markers.local)

    out = Path(out)
    writer = DatasetWriter(out, rig, fps, cameras, body=meta_body, overwrite=overwrite,
                           meta=None if subject_rec is None else {"subject": subject_rec})
    renderer = None
    try:
        # key light high above and beside cam0, so shadows fall visibly onto the floor
        to_cam0 = _unit((cameras[0].center - layout.centre) * [1, 0, 1])
        key_light = to_cam0 + 0.7 * np.cross(_UP, to_cam0) + 1.5 * _UP
        renderer = _Renderer(cameras, pieces, drawn.faces, colours, dist_piece, key_light)
        if rig == "depth":
            _depth_frames(writer, renderer, cameras[0], drawn, kin, P, layout, noise, seed,
                          tqdm, progress)
        else:
            _multiview_frames(writer, renderer, cameras, drawn, kin, P, layout, noise, seed,
                              tqdm, progress)
            if keypoints is not None:
                from gltrack.data.ingest import write_keypoints

                writer.extra_meta["keypoints"], _ = write_keypoints(writer, T, keypoints)
        if corners is not None:
            polys = table_polygons(corners, cameras)
            if polys:
                writer.write_environment(polys)
        extra = {"preset": np.array(dofs.preset), "fps": np.array(float(fps)),
                 "marker_names": np.array(body.markers.names)}
        if layout.distractor_centres is not None:
            extra["distractor_centre"] = layout.distractor_centres
        if corners is not None:
            extra["table_corners"] = corners
        writer.write_groundtruth(joints, skeleton.names, markers=markers, params=P, **extra)
        settings = {"generator": "gltrack.data.simulate", "rig": rig, "seed": int(seed),
                    "noise": noise, "occluder": occluder, "distractor": distractor,
                    "size": list(size), "cameras": len(cameras), "frames": T, "fps": fps,
                    "floor_y": layout.floor_y, "garments": garments}
        if subject_rec is not None:
            settings["subject"] = subject_rec
        if "keypoints" in writer.extra_meta:
            settings["keypoints"] = writer.extra_meta["keypoints"]["model"]
        (writer.tmp / "synth.json").write_text(json.dumps(settings, indent=1) + "\n")
    except BaseException:
        writer.abort()
        raise
    finally:
        if renderer is not None:
            renderer.close()
    writer.close()
    dt = time.perf_counter() - t0
    log.info("synthesised %d %s frames in %.1f s (%.1f frames/s) -> %s", T, rig, dt, T / dt, out)
    return out


def _bar(tqdm, total, progress, desc):
    return tqdm(total=total, desc=desc, unit="frame",
                disable=not (progress and sys.stderr.isatty()))


def _depth_frames(writer, renderer, cam, mesh, kin, P, layout, noise, seed, tqdm, progress):
    model = TofNoise.preset(noise)
    # the empty scene, as a user would capture it: median of several noisy frames
    renderer.set_body(None)
    renderer.set_distractor(None)
    ids, z = renderer.segment(0)
    brng = _rng(seed, "background")
    frames = [apply_tof_noise(z, renderer.refl_lut[ids], cam.K, brng, model)[0]
              for _ in range(N_BACKGROUND["depth"])]
    stack = np.where(np.stack(frames) > 0, np.stack(frames), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pixels never valid stay 0
        bg = np.nan_to_num(np.nanmedian(stack, axis=0), nan=0.0)
    writer.write_background(0, bg)
    rng = _rng(seed, "sensor", 0)
    with _bar(tqdm, len(P), progress, "synth depth") as bar:
        for f in range(len(P)):
            renderer.set_body(mesh.skin(kin.skinning_matrices(P[f:f + 1]))[0])
            if layout.distractor_centres is not None:
                renderer.set_distractor(layout.distractor_centres[f])
            ids, z = renderer.segment(0)
            zn, _ = apply_tof_noise(z, renderer.refl_lut[ids], cam.K, rng, model)
            writer.write_depth(f, 0, zn)
            writer.write_gtmask(f, 0, ids == 1)
            bar.update(1)


def _multiview_frames(writer, renderer, cameras, mesh, kin, P, layout, noise, seed, tqdm,
                      progress):
    model = ColourNoise.preset(noise)
    renderer.set_body(None)
    renderer.set_distractor(None)
    subtractors, rngs = [], []
    for c in range(len(cameras)):
        clean = renderer.colour(c)
        brng = _rng(seed, "background", c)
        bgs = [sensor_image(clean, brng, model) for _ in range(N_BACKGROUND["multiview"])]
        for k, b in enumerate(bgs):
            writer.write_background(c, b, index=k)
        subtractors.append(mask_model(bgs))
        rngs.append(_rng(seed, "sensor", c))
    with _bar(tqdm, len(P), progress, "synth multiview") as bar:
        for f in range(len(P)):
            renderer.set_body(mesh.skin(kin.skinning_matrices(P[f:f + 1]))[0])
            if layout.distractor_centres is not None:
                renderer.set_distractor(layout.distractor_centres[f])
            for c in range(len(cameras)):
                ids, _ = renderer.segment(c)
                bgr = sensor_image(renderer.colour(c), rngs[c], model)
                writer.write_colour(f, c, bgr)
                writer.write_mask(f, c, subtractors[c].foreground(bgr))
                writer.write_gtmask(f, c, ids == 1)
            bar.update(1)


def _child(args, kwargs):
    logging.basicConfig(level=logging.WARNING)
    return str(synthesize(*args, **kwargs))


def synthesize_in_subprocess(*args, timeout: float | None = None, **kwargs) -> Path:
    """:func:`synthesize` in a fresh ``multiprocessing`` spawn child.

    For processes that hold a moderngl context or imported PyOpenGL for another platform (the
    demo, tests). Arguments as for :func:`synthesize` (all picklable); ``timeout`` in seconds.
    """
    from gltrack.spawn import run_in_child

    return Path(run_in_child(_child, (args, kwargs), timeout=timeout))
