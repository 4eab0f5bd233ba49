"""The tiled candidate-scoring engine (Ganapathi et al. 2010, sec. "GPU-accelerated implementation").

Per frame the observations are uploaded once (:meth:`ScoringEngine.set_depth`, ``set_masks``,
``set_appearance``). Per batch only the candidates' skinning matrices go up and only
``N x C x K`` floats come back:

1. the skinning matrices of all candidates go into one RGBA32F texture (3 texels per bone);
2. one instanced draw per camera renders candidate ``i`` into tile ``i`` of a power-of-two grid,
   writing metric depth and triangle id (``shaders/model.frag``). The vertices are skinned in
   the draw's vertex shader (``shaders/skin.vert``) or, once for all cameras, by a compute pass
   (``shaders/skin.comp``, read by ``shaders/skinned.vert``); a candidate is kept inside its tile
   by ``gl_ClipDistance`` or by a fragment test. The triangle id comes from ``gl_PrimitiveID``
   or from each triangle's provoking vertex (:mod:`gltrack.render.provoking`). Which is faster
   depends on the device (:func:`choose_skinning`, :func:`choose_tile_clip`,
   :func:`choose_triangle_ids`; ``gltrack info`` shows the choice); the images are the same;
3. the per-pixel costs of ``shaders/costs.glsl`` are reduced to one sum per tile and channel,
   either by a full-screen cost pass plus the mipmap chain (the paper's method,
   ``shaders/cost.frag``) or by one compute work group per tile (``shaders/reduce.comp``, GL 4.3+).
   The compute reduction writes every camera's sums to a slice of one buffer that is read back
   once per batch, so the device is not made to wait between the cameras; the mipmap one reads
   each camera's top level as soon as it is built.
   Each reduction sums in a fixed order, so a score is bit for bit the same on every call on a
   given machine; the two orders differ in the last bits of float32 (about 1e-7 relative), so
   ``reduction="auto"`` picks by capability (compute where there is GL 4.3), never by timing: a
   timed choice flips between runs and the searches follow those last bits apart
   (``"fastest"`` times them, for benchmarks).

Channels (K = 4, always in this order): ``depth`` (sum of Ganapathi's smoothstep cost),
``silhouette`` (Bandouch's XOR pixel count outside the blocking mask), ``appearance`` (count of
colour-consistent pixels) and ``custom`` (a user-supplied GLSL cost, see :class:`CustomCost`).
One more channel, ``model`` (the count of pixels the model covers outside the blocking mask,
|M \\ B|), shares the first slot with ``depth`` and cannot be asked for with it: with the
silhouette XOR count X and the unblocked foreground area F of a camera it gives the silhouette
IoU ``(M + F - X) / (M + F + X)`` in the same call (:func:`silhouette_iou`).

Tiles are square with a power-of-two side; observations are resampled to the tile (nearest
neighbour, so depths are never blended across silhouettes) and each camera's intrinsics are scaled
to match (:meth:`gltrack.camera.Camera.scaled`). Cameras are rendered undistorted: observations must
be undistorted before they are handed over.
"""
from __future__ import annotations

import itertools
import logging
import os
import time
from dataclasses import dataclass

import cv2
import moderngl
import numpy as np

from gltrack.body.mesh import BodyMesh
from gltrack.gl.context import park_framebuffer
from gltrack.gl.programs import ProgramCache
from gltrack.render.provoking import provoking_layout
from gltrack.render import workers as worker_pool
from gltrack.render.workers import WorkerError, choose_workers, core_budget

log = logging.getLogger(__name__)

CHANNELS = ("depth", "silhouette", "appearance", "custom", "model")
#: Slot of each channel in the last axis of :meth:`ScoringEngine.score`'s result.
SLOTS = {"depth": 0, "silhouette": 1, "appearance": 2, "custom": 3, "model": 0}
_GL_CLIP_DISTANCE0 = 0x3000
_TRI_BITS_WIDTH = 1024
#: A view's observation textures: attribute of ``_View`` -> (components, dtype).
_TEXTURES = {"obs_z": (1, "f4"), "obs_mask": (2, "f4"), "obs_bits": (3, "u4"), "tri_bits": (3, "u4")}
#: Least work, in candidates x cameras, each worker process gets in one call
#: (``ScoringEngine(workers=...)``, :func:`use_workers`): a smaller call stays in this process.
#: A call renders, reduces and reads back once per camera, and the workers overlap those steps.
#: Measured on llvmpipe (2 cores, 2 workers; 2026-11-29, Intel Xeon VM, medians): four cameras
#: at 64 px, 4 candidates 10.8 ms against 11.7 in this process, 8 18.5 against 25.9, 16 29.7
#: against 44.8, 91 158 against 208; the Pose2Sim take's body estimate (about 6000 calls, most
#: of 4-17 candidates) 75.6 s against 95-101 s with the former 64, the same body (1.8081 m).
#: One camera (the depth climb, ~55 candidates a call): hc+ep 1.32-1.44x the frames/s with
#: this threshold against 64 (medians over 3 noise seeds of the bench's walk, hop and salsa),
#: and the tracks' errors within the seeds' spread (4 seeds, hc+ep mean marker error 0.044 /
#: 0.085 / 0.054 m against 0.043 / 0.102 / 0.053); on an AMD EPYC VM the climb ran as fast
#: with workers as without (docs/measurements.md, "Engine workers for small calls").
WORKER_MIN_WORK = 8
_ENGINE_IDS = itertools.count()
#: Bytes of render target per grid pixel: depth (4) + depth and triangle id (8) + depth buffer
#: (4) + RGBA32F cost with its mipmaps (16 * 4/3), rounded up.
TARGET_BYTES_PER_PIXEL = 40
#: Render-target memory one grid may take (bytes) when ``GLTRACK_GPU_MEMORY_MB`` is unset: a
#: software renderer draws into system memory shared with everything else (256 MiB keeps the
#: 2048-pixel grid it always had); a GPU has gigabytes of its own.
SOFTWARE_TARGET_BYTES = 256 << 20
GPU_TARGET_BYTES = 2 << 30
#: Most grid sizes whose render targets are kept alive at once (least recently used go first).
MAX_TARGETS = 6
_SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "swiftshader", "lavapipe")


def batch_side(max_texture_size: int, tile: int, memory_bytes: int,
               bytes_per_pixel: int = TARGET_BYTES_PER_PIXEL, max_texture: int | None = None) -> int:
    """Tiles along a side of the largest batch grid the device allows (a power of two).

    Parameters
    ----------
    max_texture_size : int, the context's ``GL_MAX_TEXTURE_SIZE`` (pixels)
    tile : int, tile side (pixels)
    memory_bytes : int, render-target memory one grid may take
    bytes_per_pixel : int, render-target bytes per grid pixel
    max_texture : int, optional, a further cap on the grid side (pixels)

    Returns
    -------
    int >= 1; a batch holds at most its square (:func:`grid_for` chunks larger ones)
    """
    side = int(max_texture_size)
    if max_texture is not None:
        side = min(side, int(max_texture))
    side = min(side, int(np.sqrt(max(int(memory_bytes), 0) / float(bytes_per_pixel))))
    return max(1, 1 << int(np.log2(max(side // int(tile), 1))))


def target_memory(renderer: str, env: str | None = None) -> int:
    """Render-target bytes one grid may take on ``renderer`` (``GL_RENDERER``).

    Parameters
    ----------
    renderer : str
    env : str, optional, ``GLTRACK_GPU_MEMORY_MB`` (megabytes) when set; wins

    Raises
    ------
    ValueError
        ``env`` is not a positive number.
    """
    if env not in (None, ""):
        try:
            mb = float(env)
        except ValueError:
            mb = -1.0
        if not mb > 0:
            raise ValueError(f"GLTRACK_GPU_MEMORY_MB must be a positive number of megabytes, "
                             f"got {env!r}")
        return int(mb * (1 << 20))
    return SOFTWARE_TARGET_BYTES if is_software_renderer(renderer) else GPU_TARGET_BYTES


@dataclass
class EngineStats:
    """Process-wide count of scoring-engine calls (:meth:`ScoringEngine.score`).

    Why process-wide: the trackers reach the engine through likelihood objects of their own, and
    the runner and the benches account calls per frame without knowing them; read the counters
    before and after the work to account (:meth:`snapshot`).

    Attributes
    ----------
    calls : int, ``score`` calls
    candidates : int, candidate poses scored
    seconds : float, wall time inside ``score`` (upload, render, reduce, read back)
    """

    calls: int = 0
    candidates: int = 0
    seconds: float = 0.0

    def snapshot(self) -> tuple[int, int, float]:
        """(calls, candidates, seconds) so far."""
        return self.calls, self.candidates, self.seconds

    def since(self, snap) -> dict:
        """Counts since ``snap`` (:meth:`snapshot`): ``calls``, ``candidates``, ``seconds``."""
        return {"calls": self.calls - snap[0], "candidates": self.candidates - snap[1],
                "seconds": self.seconds - snap[2]}


#: The counters of every engine in this process.
ENGINE_STATS = EngineStats()


@dataclass(frozen=True)
class DepthCostParams:
    """Parameters of the per-pixel depth cost (all documented in ``shaders/costs.glsl``).

    scale : float, metres
        Depth difference at which the smoothstep saturates (cost 1). 0.15 m: the ToF noise plus the
        model's shape error (about 2-5 cm each) sit well inside the quadratic part.
    c_model_only : float
        Cost of a pixel where the model is and nothing was observed (equals saturation: the model
        claims surface where the sensor saw none).
    c_obs_only : float
        Cost of an observed foreground pixel the model does not explain.
    penalty : float
        Smoothed likelihood's cost of matching a neighbouring pixel: ~3 (d/scale)^2 for the
        ~1.3 cm a pixel spans at 2 m for a 128-px SR4000 crop.
    smooth : bool
        Use Ganapathi's smoothed likelihood (best of the 3x3 neighbourhood plus penalty).
    """

    scale: float = 0.15
    c_model_only: float = 1.0
    c_obs_only: float = 1.0
    penalty: float = 0.02
    smooth: bool = False

    def as_vec4(self):
        return (float(self.scale), float(self.c_model_only), float(self.c_obs_only), float(self.penalty))


@dataclass(frozen=True)
class CustomCost:
    """A user's per-pixel cost in GLSL, summed into channel ``custom``.

    The file must define ``float custom_cost(ivec2 pixel, ivec2 local)`` where ``pixel`` is the
    texel in the grid textures (``model_z``: ``.r`` = camera depth of the model, 0 = none;
    ``model_tri``: ``.g`` = 1 + triangle id as a float, 0 = none) and ``local`` the texel in the
    tile-sized observation textures (``obs_z``, ``obs_mask``, ``obs_bits``); it may call
    ``depth_pixel(zo, zm)`` and read ``depth_params``, ``tile`` (see ``shaders/costs.glsl``).
    Test it against a CPU twin the same way the stock costs are tested (examples/05).
    """

    path: str


def grid_for(n: int, max_tiles_side: int) -> tuple[int, int]:
    """The tile grid of a batch: the smallest power-of-two (cols, rows) grid, with cols in
    {rows, 2 rows}, holding ``n`` tiles.

    Parameters
    ----------
    n : int, number of candidates (tiles) in the batch
    max_tiles_side : int, largest number of tiles along a grid side
        (:attr:`ScoringEngine.max_tiles_side`)

    Returns
    -------
    (cols, rows) : tuple of int

    Raises
    ------
    ValueError
        The grid would need more than ``max_tiles_side`` tiles on a side.
    """
    cols = rows = 1
    while cols * rows < n:
        if cols == rows:
            cols *= 2
        else:
            rows *= 2
    if cols > max_tiles_side or rows > max_tiles_side:
        raise ValueError(f"{n} candidates do not fit one {max_tiles_side}x{max_tiles_side}-tile batch")
    return cols, rows


class _View:
    """One camera at tile resolution and its uploaded observations."""

    def __init__(self, camera, tile):
        self.camera = camera
        self.cam_tile = camera.scaled(tile, tile)
        self.view = np.asarray(self.cam_tile.gl_view(), dtype=np.float32)
        self.obs_z = None
        self.obs_mask = None
        self.obs_bits = None
        self.tri_bits = None


class ScoringEngine:
    """Score N candidate poses of a skinned mesh against C camera observations on the GPU.

    Parameters
    ----------
    ctx : moderngl.Context
        From :func:`gltrack.gl.context.create_context`.
    mesh : BodyMesh
    n_bones : int
        Number of bones B of the skinning matrices passed to :meth:`score`.
    cameras : list of gltrack.camera.Camera
    tile : int
        Tile side in pixels, a power of two (16..512). Observations are resampled to it.
    max_texture : int, optional
        Largest grid texture side; batches are chunked so the grid fits. None (default): sized
        to the device (:func:`batch_side`): ``GL_MAX_TEXTURE_SIZE`` and a render-target memory
        budget (:func:`target_memory`; ``GLTRACK_GPU_MEMORY_MB`` sets it). Always clamped to
        ``GL_MAX_TEXTURE_SIZE``.
    reduction : {"auto", "mipmap", "compute", "fastest"}
        "auto": "compute" where the context has GL 4.3, else "mipmap" (the same on every run);
        "fastest" times both on the first batch and keeps the faster (the choice may differ
        between runs, and with it the last bits of the scores: for benchmarks only).
    depth_params : DepthCostParams
    custom : CustomCost, optional
    near, far : float, metres
        Clip planes.
    cull_back_faces : bool
        Skip triangles facing away from the camera. Exact for closed meshes whose faces wind
        counter-clockwise seen from outside (the default body); turn it off for open meshes.
    skinning : {"auto", "vertex", "compute"}
        Where the vertices are skinned: "vertex" in the vertex shader of every camera's draw
        (``shaders/skin.vert``), "compute" once per batch for all cameras in a compute pass
        (``shaders/skin.comp`` then ``shaders/skinned.vert``; GL 4.3). Both give the same
        images. "auto": ``GLTRACK_SKINNING`` when it is set, else :func:`choose_skinning`.
    tile_clip : {"auto", "distance", "fragment"}
        How a candidate is kept inside its tile: "distance" clips its triangles at the tile's
        frustum (``gl_ClipDistance``), "fragment" drops the fragments that fall outside the tile
        (``shaders/model.frag``). The same pixels are covered either way. "auto":
        ``GLTRACK_TILE_CLIP`` when it is set, else :func:`choose_tile_clip`.
    triangle_ids : {"auto", "primitive", "provoking"}
        How the draws for the appearance and custom costs get each pixel's triangle id:
        "primitive" reads ``gl_PrimitiveID`` in the fragment shader, "provoking" draws a vertex
        layout in which every triangle has a provoking vertex of its own that carries its id
        (:mod:`gltrack.render.provoking`; up to twice the vertices). The ids are the same
        but for a few pixels where two triangles meet (see that module).
        "auto": ``GLTRACK_TRIANGLE_IDS`` when it is set, else :func:`choose_triangle_ids`.
    fk : {"auto", "cpu", "gpu"}
        Where :meth:`score_poses` computes the skinning matrices from pose parameters: "cpu"
        with :class:`gltrack.body.kinematics.Kinematics` (float64), "gpu" in a compute pass
        (``shaders/fk.comp``, float32; GL 4.3). "auto": ``GLTRACK_FK`` when it is set, else
        "cpu" (the GPU pass is not yet measured on a GPU).
    reduce_group : {"auto", "wide", "narrow"}
        The work group of the compute reduction (``shaders/reduce.comp``): "wide", 16x16
        invocations per tile summed as a tree; "narrow", 8x8 whose partial sums one invocation
        adds up. Counts (silhouette, appearance) come out the same; float costs (depth) differ in
        their last bits, the order of the sum. "auto": ``GLTRACK_REDUCE_GROUP`` when it is set,
        else :func:`choose_reduce_group`.
    workers : int or "auto"
        Helper processes (:mod:`gltrack.render.workers`) that score equal shares of every call
        that is large enough (:func:`use_workers`), each with a context of its own;
        0 scores everything here. The scores are this process's up to an edge pixel here and
        there (a candidate's pixels depend on its tile's place in the grid, and a share has a
        smaller grid). They start on the first such call; if one cannot start or dies, the
        engine logs a warning and scores here from then on.
        "auto": ``GLTRACK_ENGINE_WORKERS`` when it is set, else :func:`choose_workers` (one per
        core on a software renderer, none on a GPU); none with ``reduction="fastest"``, which
        times its choice in this process (give a count to have both).
    """

    def __init__(self, ctx: moderngl.Context, mesh: BodyMesh, n_bones: int, cameras, *, tile: int = 64,
                 max_texture: int | None = None, reduction: str = "auto",
                 depth_params: DepthCostParams = DepthCostParams(), custom: CustomCost | None = None,
                 near: float = 0.05, far: float = 50.0, cull_back_faces: bool = True,
                 programs: ProgramCache | None = None, skinning: str = "auto",
                 tile_clip: str = "auto", fk: str = "auto", triangle_ids: str = "auto",
                 reduce_group: str = "auto", workers: int | str = "auto"):
        if tile < 16 or tile > 512 or tile & (tile - 1):
            raise ValueError(f"tile must be a power of two in 16..512, got {tile}")
        if reduction not in ("auto", "mipmap", "compute", "fastest"):
            raise ValueError("reduction must be auto, mipmap, compute or fastest, got "
                             f"{reduction!r}")
        if reduction == "compute" and ctx.version_code < 430:
            raise ValueError("compute reduction needs OpenGL 4.3; this context is "
                             f"{ctx.version_code}")
        renderer = ctx.info.get("GL_RENDERER", "")
        skinning = _engine_option(ctx, "skinning", skinning, "GLTRACK_SKINNING",
                                  choose_skinning(renderer, ctx.version_code, len(cameras or ())),
                                  ("vertex", "compute"),
                                  needs_430="compute")
        tile_clip = _engine_option(ctx, "tile_clip", tile_clip, "GLTRACK_TILE_CLIP",
                                   choose_tile_clip(renderer), ("distance", "fragment"))
        fk = _engine_option(ctx, "fk", fk, "GLTRACK_FK", "cpu", ("cpu", "gpu"), needs_430="gpu")
        triangle_ids = _engine_option(ctx, "triangle_ids", triangle_ids, "GLTRACK_TRIANGLE_IDS",
                                      choose_triangle_ids(renderer), ("primitive", "provoking"))
        reduce_group = _engine_option(ctx, "reduce_group", reduce_group, "GLTRACK_REDUCE_GROUP",
                                      choose_reduce_group(renderer), ("wide", "narrow"))
        if not cameras:
            raise ValueError("at least one camera is needed")
        if mesh.joints.max() >= n_bones:
            raise ValueError(f"mesh references bone {mesh.joints.max()} but n_bones={n_bones}")
        self.ctx = ctx
        self.mesh = mesh
        self.n_bones = int(n_bones)
        self.tile = int(tile)
        self.depth_params = depth_params
        self.custom = custom
        self.near, self.far = float(near), float(far)
        self.cull_back_faces = bool(cull_back_faces)
        self.skinning = skinning
        self.tile_clip = tile_clip
        self.fk = fk
        self.triangle_ids = triangle_ids
        self.reduce_group = reduce_group
        self.workers = resolve_workers(workers, renderer, reduction)
        self._engine_id = next(_ENGINE_IDS)
        self._on_workers = 0  # generation of the worker pool that holds this engine's copy
        # what the workers must mirror: key -> value, and the keys not yet sent (in order)
        self._mirror: dict = {}
        self._unsent: list = []
        self.kin = None  # set_kinematics
        self._joints_buf = None
        self._layout = (provoking_layout(mesh.faces, mesh.n_vertices) if triangle_ids == "provoking"
                        else None)
        limit = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096))
        memory = target_memory(ctx.info.get("GL_RENDERER", ""), os.environ.get("GLTRACK_GPU_MEMORY_MB"))
        self._memory = memory
        self.max_tiles_side = batch_side(limit, self.tile, memory, max_texture=max_texture)
        if skinning == "compute":
            # the skinned vertices of a batch are one shader storage block
            block = int(ctx.info.get("GL_MAX_SHADER_STORAGE_BLOCK_SIZE", 1 << 27))
            while self.max_tiles_side > 1 and \
                    self.max_tiles_side ** 2 * self._skinned_bytes_per_candidate() > block:
                self.max_tiles_side //= 2
        self.max_batch = self.max_tiles_side * self.max_tiles_side
        if reduction in ("auto", "fastest"):
            self.reduction = choose_reduction(ctx)
        else:
            self.reduction = reduction
        self._auto_pending = reduction == "fastest" and ctx.version_code >= 430
        self.programs = programs or ProgramCache(ctx)
        self._owns_programs = programs is None
        self.views = [_View(c, self.tile) for c in cameras]
        self.evaluations = 0
        #: reads of scores from the device (one per call and batch with the compute reduction,
        #: one per camera with the mipmap one); a worker's reads are its own
        self.readbacks = 0
        self._released = False
        self._targets: dict = {}
        self._build_geometry()
        self._worker_options = dict(
            max_texture=max_texture, reduction=self.reduction, depth_params=depth_params,
            custom=custom, near=near, far=far, cull_back_faces=cull_back_faces,
            skinning=skinning, tile_clip=tile_clip, fk=fk, triangle_ids=triangle_ids,
            reduce_group=reduce_group, tile=self.tile)

    # ----------------------------------------------------------------------------------- setup
    def _build_geometry(self):
        ctx, m = self.ctx, self.mesh
        self._vbo_pos = ctx.buffer(m.vertices.astype("f4").tobytes())
        self._vbo_j = ctx.buffer(m.joints.astype("i4").tobytes())
        self._vbo_w = ctx.buffer(m.weights.astype("f4").tobytes())
        self._ibo = ctx.buffer(m.faces.astype("i4").tobytes())
        # With triangle_ids="provoking" the draws with triangle ids use a layout in which every
        # triangle has a provoking vertex of its own (gltrack.render.provoking); its first V
        # vertices are the mesh's, so the depth-only draw indexes the same skinned buffer.
        lay = self._layout
        src = np.arange(m.n_vertices) if lay is None else lay.source
        self._vbo_layout = []
        if lay is not None:
            self._ibo_tri = ctx.buffer(lay.faces.astype("i4").tobytes())
            self._vbo_tri = ctx.buffer(lay.triangle.astype("i4").tobytes())
            self._vbo_layout += [self._ibo_tri, self._vbo_tri]
        # Two model programs: depth only, and depth + triangle id (for the appearance cost).
        self._prog_model, self._vao = {}, {}
        self._skin_in = []
        if self.skinning == "compute":
            # std430 arrays of vec4 / ivec4: the rest positions padded to four floats
            rest = np.zeros((len(src), 4), np.float32)
            rest[:, :3] = m.vertices[src]
            self._skin_in = [ctx.buffer(rest.tobytes()), ctx.buffer(m.joints[src].astype("i4").tobytes()),
                             ctx.buffer(m.weights[src].astype("f4").tobytes())]
            self._prog_skin = self.programs.get(compute="skin.comp")
        for with_tri in (False, True):
            layout = with_tri and lay is not None
            defines = {"WITH_TRI": 1} if with_tri else {}
            if layout:
                defines["TRI_FROM_VERTEX"] = 1
            if self.tile_clip == "fragment":
                defines["TILE_CLIP_FRAGMENT"] = 1
            if self.skinning == "compute":
                prog = self.programs.get(vertex="skinned.vert", fragment="model.frag", defines=defines)
                # the vertex shader reads skin.comp's buffer by gl_VertexID
                content = [(self._vbo_tri, "i", "in_tri")] if layout else []
            elif layout:
                prog = self.programs.get(vertex="skin.vert", fragment="model.frag", defines=defines)
                bufs = [ctx.buffer(a[src].astype(f"{k}4").tobytes())
                        for a, k in ((m.vertices, "f"), (m.joints, "i"), (m.weights, "f"))]
                self._vbo_layout += bufs
                content = [(bufs[0], "3f", "in_pos"), (bufs[1], "4i", "in_joints"),
                           (bufs[2], "4f", "in_weights"), (self._vbo_tri, "i", "in_tri")]
            else:
                prog = self.programs.get(vertex="skin.vert", fragment="model.frag", defines=defines)
                content = [(self._vbo_pos, "3f", "in_pos"), (self._vbo_j, "4i", "in_joints"),
                           (self._vbo_w, "4f", "in_weights")]
            self._prog_model[with_tri] = prog
            self._vao[with_tri] = ctx.vertex_array(prog, content,
                                                   index_buffer=self._ibo_tri if layout else self._ibo,
                                                   index_element_size=4)
        self._prog_fs = None
        self._vao_fs = None

    @property
    def _n_skinned(self) -> int:
        """Vertices a candidate has in the skinned buffer of compute skinning."""
        return self.mesh.n_vertices if self._layout is None else len(self._layout.source)

    def _run_fk(self, t, P, n):
        data = P.tobytes()
        if t.get("params") is None or t["params"].size < len(data):
            if t.get("params") is not None:
                t["params"].release()
            t["params"] = self.ctx.buffer(reserve=t["bones"].height * P.shape[1] * 4)
        t["params"].write(data)
        prog = self._prog_fk
        prog["n_params"].value = int(P.shape[1])
        prog["n_candidates"].value = int(n)
        self._joints_buf.bind_to_storage_buffer(5)
        t["params"].bind_to_storage_buffer(6)
        t["bones"].bind_to_image(0, read=False, write=True)
        prog.run(-(-n // 64), 1, 1)
        self.ctx.memory_barrier()

    def _skinned_bytes_per_candidate(self) -> int:
        return self._n_skinned * 16

    def _upload_batch(self, t, X, n, poses=False):
        """The batch's skinning matrices into the bones texture (uploaded, or with ``poses``
        computed from the parameters ``X`` by ``shaders/fk.comp``), and with compute skinning
        the skinned vertices of every candidate into ``t["skinned"]`` (once for all cameras)."""
        if poses:
            self._run_fk(t, X, n)
        else:
            t["bones"].write(X.reshape(n, -1).tobytes(), viewport=(0, 0, 3 * self.n_bones, n))
        if self.skinning != "compute":
            return
        prog, nv = self._prog_skin, self._n_skinned
        t["bones"].use(location=0)
        prog["bones"].value = 0
        prog["n_vertices"].value = nv
        for binding, buf in enumerate(self._skin_in, start=1):
            buf.bind_to_storage_buffer(binding)
        t["skinned"].bind_to_storage_buffer(4)
        prog.run(-(-nv // 64), n, 1)
        self.ctx.memory_barrier()

    def _defines(self, channels):
        d = {}
        if "depth" in channels:
            d["CH_DEPTH_SMOOTH" if self.depth_params.smooth else "CH_DEPTH"] = 1
        if "silhouette" in channels:
            d["CH_SILHOUETTE"] = 1
        if "appearance" in channels:
            d["CH_APPEARANCE"] = 1
        if "custom" in channels:
            d["CH_CUSTOM"] = 1
        if "model" in channels:
            d["CH_MODEL"] = 1
        return d

    def _aliases(self):
        return {"custom_cost.glsl": self.custom.path} if self.custom else None

    def _target(self, cols, rows):
        """Render targets for a grid, cached by grid size."""
        key = (cols, rows)
        if key in self._targets:
            self._targets[key] = self._targets.pop(key)  # most recently used last
            return self._targets[key]
        ctx, W, H = self.ctx, cols * self.tile, rows * self.tile
        park_framebuffer(ctx)  # whatever is bound may be released by other code later
        z = ctx.texture((W, H), 1, dtype="f4")
        # Depth and triangle id in one RG32F attachment (id + 1 as a float, exact below 2^24):
        # one colour write per fragment instead of two, which software GL notices.
        zt = ctx.texture((W, H), 2, dtype="f4")
        for tex in (z, zt):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        depth = ctx.depth_renderbuffer((W, H))
        fbo = ctx.framebuffer(color_attachments=[zt], depth_attachment=depth)
        fbo_z = ctx.framebuffer(color_attachments=[z], depth_attachment=depth)
        levels = int(np.log2(self.tile))
        cost = ctx.texture((W, H), 4, dtype="f4")
        cost.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.NEAREST)
        cost_fbo = ctx.framebuffer(color_attachments=[cost])
        bones = ctx.texture((3 * self.n_bones, cols * rows), 4, dtype="f4")
        bones.filter = (moderngl.NEAREST, moderngl.NEAREST)
        # one slice of cols * rows vec4 sums per camera: a call reads them back once
        sums = (ctx.buffer(reserve=len(self.views) * cols * rows * 16)
                if ctx.version_code >= 430 else None)
        skinned = (ctx.buffer(reserve=cols * rows * self._skinned_bytes_per_candidate())
                   if self.skinning == "compute" else None)
        t = dict(z=z, zt=zt, depth=depth, fbo=fbo, fbo_z=fbo_z, cost=cost, cost_fbo=cost_fbo, bones=bones,
                 sums=sums, skinned=skinned, levels=levels, W=W, H=H)
        # Keep the most recently used grid sizes within the render-target budget (and at most
        # MAX_TARGETS): memory stays bounded whatever batch sizes come, and a tracker that
        # alternates between a few batch sizes (the stages of a climb, its lanes) does not
        # re-allocate its targets on every call.
        def size(k):
            per_tile = self.tile * self.tile * TARGET_BYTES_PER_PIXEL
            if self.skinning == "compute":
                per_tile += self._skinned_bytes_per_candidate()
            return k[0] * k[1] * per_tile

        while self._targets and (len(self._targets) >= MAX_TARGETS or
                                 size(key) + sum(size(k) for k in self._targets) > self._memory):
            old_key = next(iter(self._targets))
            self._release_target(self._targets.pop(old_key))
        self._targets[key] = t
        return t

    @staticmethod
    def _release_target(t):
        for k in ("fbo", "fbo_z", "cost_fbo", "z", "zt", "depth", "cost", "bones", "sums", "skinned",
                  "params"):
            if t.get(k) is not None:
                t[k].release()

    # ----------------------------------------------------------------------------- observations
    def _check_view(self, cam):
        if not 0 <= cam < len(self.views):
            raise ValueError(f"camera index {cam} out of range (engine has {len(self.views)} cameras)")
        return self.views[cam]

    def _check_size(self, v, arr, what):
        h, w = v.camera.height, v.camera.width
        if arr.shape[:2] != (h, w):
            raise ValueError(f"{what} for camera {v.camera.name!r} has size {arr.shape[1]}x{arr.shape[0]},"
                             f" the camera is {w}x{h}")

    def to_tile(self, img) -> np.ndarray:
        """An observation image resampled to the tile, as the engine uploads it.

        Nearest-neighbour sampling (``cv2.INTER_NEAREST_EXACT``: the source pixel whose centre is
        nearest to each tile pixel's centre; plain ``INTER_NEAREST`` is off by up to most of a
        pixel when shrinking), so values (depths, mask and bit-mask words) are never mixed.

        Parameters
        ----------
        img : (H, W) or (H, W, C) array at a camera's resolution, any dtype cv2.resize takes

        Returns
        -------
        (tile, tile) or (tile, tile, C) array of the same dtype
        """
        return cv2.resize(img, (self.tile, self.tile), interpolation=cv2.INTER_NEAREST_EXACT)

    def set_camera(self, cam: int, camera):
        """Replace camera ``cam`` (e.g. a crop window that follows the subject).

        The camera's observations are dropped with it: upload new ones before scoring.
        """
        v = self._check_view(cam)
        for tex in (v.obs_z, v.obs_mask, v.obs_bits, v.tri_bits):
            if tex is not None:
                tex.release()
        self.views[cam] = _View(camera, self.tile)
        for kind in _TEXTURES:
            self._mirror.pop((kind, cam), None)
        self._remember(("camera", cam), camera)

    def _set_texture(self, cam: int, kind: str, data: np.ndarray) -> None:
        """Upload one observation texture of view ``cam`` (``kind`` in :data:`_TEXTURES`),
        already at its final size, and remember it for the workers."""
        v = self.views[cam]
        old = getattr(v, kind)
        if old is not None:
            old.release()
        components, dtype = _TEXTURES[kind]
        tex = self.ctx.texture((data.shape[1], data.shape[0]), components, data.tobytes(), dtype=dtype)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        setattr(v, kind, tex)
        self._remember((kind, cam), data)

    def _remember(self, key, value) -> None:
        """Keep an observation (or camera, or kinematics) for workers started later, and mark
        it to be sent to running ones with their next request."""
        if self.workers:
            self._mirror[key] = value
            if key in self._unsent:
                self._unsent.remove(key)
            self._unsent.append(key)

    def _apply_mirrored(self, key, value) -> None:
        """In a worker: apply what the owning engine's :meth:`_remember` recorded."""
        if key[0] == "camera":
            self.set_camera(key[1], value)
        elif key[0] == "kinematics":
            self.set_kinematics(value)
        else:
            self._check_view(key[1])
            self._set_texture(key[1], key[0], value)

    def set_depth(self, cam: int, depth):
        """Upload an observed depth image.

        Parameters
        ----------
        cam : int, camera index
        depth : (H, W) float, metres at the camera's resolution; 0 (or non-finite) = no observation
        """
        v = self._check_view(cam)
        z = np.asarray(depth, dtype=np.float32)
        if z.ndim != 2:
            raise ValueError(f"depth must be a 2-D image, got shape {z.shape}")
        self._check_size(v, z, "depth")
        z = np.where(np.isfinite(z) & (z > 0), z, 0).astype(np.float32)
        self._set_texture(cam, "obs_z", np.ascontiguousarray(self.to_tile(z)))

    def set_masks(self, cam: int, foreground, blocking=None):
        """Upload a foreground mask and an optional blocking mask (True = ignore the pixel).

        Parameters
        ----------
        foreground, blocking : (H, W) bool (or uint8, non-zero = True) at the camera's resolution
        """
        v = self._check_view(cam)
        fg = np.asarray(foreground)
        self._check_size(v, fg, "foreground mask")
        bl = np.zeros_like(fg, dtype=bool) if blocking is None else np.asarray(blocking)
        self._check_size(v, bl, "blocking mask")
        rg = np.stack([fg != 0, bl != 0], axis=-1).astype(np.float32)
        self._set_texture(cam, "obs_mask", np.ascontiguousarray(self.to_tile(rg)))

    def set_appearance(self, cam: int, obs_bits, tri_bits):
        """Upload observed HLS bitmasks and the triangles' colour-cluster bitmasks.

        Parameters
        ----------
        obs_bits : (H, W, 3) uint32, the hue/lightness/saturation bitmasks of each observed pixel
        tri_bits : (F, 3) uint32, the bitmasks of the colour cluster of each mesh triangle
        """
        v = self._check_view(cam)
        ob = np.asarray(obs_bits)
        if ob.ndim != 3 or ob.shape[2] != 3 or ob.dtype != np.uint32:
            raise ValueError(f"obs_bits must be (H, W, 3) uint32, got {ob.shape} {ob.dtype}")
        self._check_size(v, ob, "obs_bits")
        tb = np.asarray(tri_bits)
        if tb.shape != (self.mesh.n_faces, 3) or tb.dtype != np.uint32:
            raise ValueError(f"tri_bits must be ({self.mesh.n_faces}, 3) uint32, got {tb.shape} {tb.dtype}")
        tiled = np.ascontiguousarray(self.to_tile(ob.view(np.float32)).view(np.uint32))
        self._set_texture(cam, "obs_bits", tiled)
        rows = -(-len(tb) // _TRI_BITS_WIDTH)
        padded = np.zeros((rows * _TRI_BITS_WIDTH, 3), np.uint32)
        padded[: len(tb)] = tb
        self._set_texture(cam, "tri_bits", padded.reshape(rows, _TRI_BITS_WIDTH, 3))

    # --------------------------------------------------------------------------------- scoring
    def score(self, skinning, channels=("depth",)) -> np.ndarray:
        """Score candidates.

        Parameters
        ----------
        skinning : (N, B, 3, 4) float, skinning matrices (``Kinematics.skinning_matrices``)
        channels : sequence of str, subset of ``CHANNELS``

        Returns
        -------
        (N, C, 4) float64 per-candidate, per-camera sums of the four slots (channels not
        requested are 0): depth cost (or, with ``"model"``, the model's unblocked pixel
        count), silhouette XOR count, appearance count, custom cost (see :data:`SLOTS`).
        """
        channels = self._check_channels(channels)
        S = np.asarray(skinning)
        if S.ndim != 4 or S.shape[1:] != (self.n_bones, 3, 4):
            raise ValueError(f"skinning must have shape (N, {self.n_bones}, 3, 4), got {S.shape}")
        if not np.all(np.isfinite(S)):
            raise ValueError("skinning matrices contain NaN or inf")
        return self._score_all(np.ascontiguousarray(S, dtype=np.float32), channels, poses=False)

    def set_kinematics(self, kin) -> None:
        """The body's kinematics, for :meth:`score_poses`.

        Parameters
        ----------
        kin : gltrack.body.kinematics.Kinematics, with ``n_bones`` joints
        """
        if kin.skeleton.n_joints != self.n_bones:
            raise ValueError(f"kinematics has {kin.skeleton.n_joints} joints, the engine {self.n_bones} bones")
        self.kin = kin
        if self.fk != "gpu":
            return
        self._remember(("kinematics",), kin)  # the workers run fk.comp too
        tab = kin.joint_table()
        rec = np.zeros(self.n_bones, dtype=[("parent_cols", "i4", 4), ("axes", "i4", 4),
                                            ("offset", "f4", 4), ("rest", "f4", 4)])
        rec["parent_cols"][:, 0] = tab["parents"]
        rec["parent_cols"][:, 1:] = tab["cols"]
        rec["axes"][:, :3] = tab["axes"]
        rec["offset"][:, :3] = tab["offsets"]
        rec["rest"][:, :3] = tab["rest"]
        if self._joints_buf is not None:
            self._joints_buf.release()
        self._joints_buf = self.ctx.buffer(rec.tobytes())
        self._prog_fk = self.programs.get(compute="fk.comp", defines={"N_JOINTS": self.n_bones})

    def score_poses(self, params, channels=("depth",)) -> np.ndarray:
        """Score candidate poses (clamped to the joint limits) as :meth:`score` does.

        Parameters
        ----------
        params : (N, D) or (D,) float, pose parameters of the kinematics given to
            :meth:`set_kinematics`
        channels : sequence of str, as :meth:`score`

        Returns
        -------
        (N, C, 4) float64, as :meth:`score`
        """
        if self.kin is None:
            raise RuntimeError("score_poses needs set_kinematics first")
        if self.fk == "cpu":
            return self.score(self.kin.skinning_matrices(params), channels)
        channels = self._check_channels(channels)
        P = self.kin.dofs.validate(params)  # clamped, float64, finite
        return self._score_all(np.ascontiguousarray(P, dtype=np.float32), channels, poses=True)

    def _check_channels(self, channels) -> tuple:
        if self._released:
            raise RuntimeError("ScoringEngine has been released")
        channels = tuple(channels)
        bad = [c for c in channels if c not in CHANNELS]
        if bad or not channels:
            raise ValueError(f"unknown or empty channels {bad or channels}; choose from {CHANNELS}")
        if "depth" in channels and "model" in channels:
            raise ValueError("channels 'depth' and 'model' share a slot; ask for one of them")
        if "custom" in channels and self.custom is None:
            raise ValueError("channel 'custom' needs a CustomCost shader")
        for v in self.views:
            need = {"depth": v.obs_z, "silhouette": v.obs_mask, "appearance": v.obs_bits,
                    "model": v.obs_mask}
            missing = [c for c in channels if c in need and need[c] is None]
            if "appearance" in channels and v.obs_mask is None:
                missing.append("appearance (needs set_masks for the blocking mask)")
            if missing:
                raise ValueError(f"camera {v.camera.name!r}: no observation uploaded for {missing}")
        return channels

    def _score_all(self, X, channels, poses):
        """Score skinning matrices (N, B, 3, 4) or, with ``poses``, pose parameters (N, D), both
        float32 and checked, in batches of at most :attr:`max_batch`."""
        t0 = time.perf_counter()
        N = X.shape[0]
        out = self._score_on_workers(X, channels, poses)
        if out is None:
            out = np.zeros((N, len(self.views), 4))
            for start in range(0, N, self.max_batch):
                out[start:start + self.max_batch] = self._score_batch(
                    X[start:start + self.max_batch], channels, poses)
        self.evaluations += N
        ENGINE_STATS.calls += 1
        ENGINE_STATS.candidates += N
        ENGINE_STATS.seconds += time.perf_counter() - t0
        return out

    def _score_on_workers(self, X, channels, poses):
        """Equal shares of ``X`` scored by the worker processes, or None: too few candidates,
        no workers, or they failed (logged; the engine then scores everything itself)."""
        if not use_workers(len(X), len(self.views), self.workers):
            return None
        try:
            pool = worker_pool.shared_pool(self.workers)
            spec = None
            if self._on_workers != pool.generation:
                spec = {"mesh": self.mesh, "n_bones": self.n_bones,
                        "cameras": [v.camera for v in self.views], "options": self._worker_options}
                # a copy starts with the cameras of the spec; it needs every observation
                self._unsent = [key for key in self._mirror if key[0] != "camera"]
            state = [(key, self._mirror[key]) for key in self._unsent if key in self._mirror]
            parts = pool.score(self._engine_id, spec, np.array_split(X, len(pool)), state,
                               channels, poses)
            self._on_workers = pool.generation
            self._unsent = []
            return np.concatenate(parts)
        except WorkerError as e:
            log.warning("engine workers failed, scoring in this process from now on: %s", e)
            worker_pool.close_shared_pool()  # every engine's copies went with it
            self._on_workers = 0
            self.workers = 0
            return None

    def _drop_from_workers(self) -> None:
        """Release this engine's copies in the workers (the pool itself lives on)."""
        pool = worker_pool.current_pool()
        if pool is not None and self._on_workers == pool.generation:
            try:
                pool.drop(self._engine_id)
            except WorkerError as e:
                log.warning("engine workers failed: %s", e)
                worker_pool.close_shared_pool()
        self._on_workers = 0

    def _score_batch(self, X, channels, poses=False):
        n = X.shape[0]
        cols, rows = grid_for(n, self.max_tiles_side)
        t = self._target(cols, rows)
        self._upload_batch(t, X, n, poses)
        if self._auto_pending:
            self._auto_pending = False
            self.reduction = self._time_reductions(t, n, cols, rows, channels)
        res = np.empty((n, len(self.views), 4))
        with_tri = self._needs_tri(channels)
        # The compute reduction writes each camera's sums to a slice of its own, read back once
        # after the last camera: a read waits for the GPU to finish everything queued, so one
        # read per camera would stall the pipeline between the cameras (render, reduce, wait,
        # render...). The mipmap reduction reuses one cost texture and reads every camera.
        deferred = self.reduction == "compute"
        for c, v in enumerate(self.views):
            self._render(t, v, n, cols, rows, with_tri)
            sums = self._reduce(t, v, n, cols, rows, channels, self.reduction, slot=c,
                                read=not deferred)
            if not deferred:
                res[:, c] = sums
        if deferred:
            res[:] = self._read_sums(t, n, cols * rows, len(self.views))
        return res

    def _read_sums(self, t, n, stride, slots):
        """(n, slots, 4) float64: the first ``n`` sums of each of the compute reduction's first
        ``slots`` slices (``stride`` tiles apart) in ``t["sums"]``, in one read."""
        # glGetBufferSubData after shader storage writes needs the barrier (GL 4.3, 7.13)
        self.ctx.memory_barrier()
        raw = np.frombuffer(t["sums"].read(size=slots * stride * 16), dtype=np.float32)
        self.readbacks += 1
        return raw.reshape(slots, stride, 4)[:, :n].transpose(1, 0, 2).astype(np.float64)

    def _used_height(self, n, cols):
        """Pixel rows of a target that a batch of ``n`` tiles in ``cols`` columns uses: the grid
        is a power of two, so up to half its tiles can be empty (17 candidates take an 8x4
        grid), and clearing, scoring and reducing them cost llvmpipe about half a candidate
        each."""
        return -(-n // cols) * self.tile

    def _render(self, t, v, n, cols, rows, with_tri=True):
        ctx = self.ctx
        proj = np.asarray(v.cam_tile.gl_projection(self.near, self.far), dtype=np.float32)
        prog = self._prog_model[with_tri]
        fbo = t["fbo"] if with_tri else t["fbo_z"]
        self._clear_targets(t, with_tri, self._used_height(n, cols))
        fbo.use()
        fbo.viewport = (0, 0, t["W"], t["H"])
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.BLEND)
        if self.cull_back_faces:
            # Our projection mirrors y (see gltrack.camera), so outward CCW faces appear clockwise:
            # the back faces are GL's "front" ones. Culling halves llvmpipe's triangle setup work.
            ctx.enable(moderngl.CULL_FACE)
            ctx.cull_face = "front"
        else:
            ctx.disable(moderngl.CULL_FACE)
        if with_tri and self._layout is not None:
            # the triangle id is the last corner's (gltrack.render.provoking); GL's default, set
            # here because other code on the context may change it
            ctx.provoking_vertex = moderngl.LAST_VERTEX_CONVENTION
        clip_planes = range(4 if self.tile_clip == "distance" else 0)
        for i in clip_planes:
            ctx.enable_direct(_GL_CLIP_DISTANCE0 + i)
        if self.tile_clip == "fragment":
            prog["tile"].value = self.tile
        if self.skinning == "compute":
            t["skinned"].bind_to_storage_buffer(4)
            prog["n_vertices"].value = self._n_skinned
        else:
            t["bones"].use(location=0)
            prog["bones"].value = 0
        prog["view"].write(v.view.T.copy().tobytes())
        prog["proj"].write(proj.T.copy().tobytes())
        prog["grid"].value = (cols, rows)
        self._vao[with_tri].render(moderngl.TRIANGLES, instances=n)
        for i in clip_planes:
            ctx.disable_direct(_GL_CLIP_DISTANCE0 + i)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)

    @staticmethod
    def _clear_targets(t, with_tri=True, height=None):
        # Zero means "no model" in both attachments: the triangle texture stores id + 1 (moderngl
        # clears integer attachments with the bit pattern of a float, so only 0 is portable).
        # Only the rows of tiles in use (``height`` pixels) are cleared; the others are never read.
        (t["fbo"] if with_tri else t["fbo_z"]).clear(
            0.0, 0.0, 0.0, 0.0, depth=1.0,
            viewport=(0, 0, t["W"], t["H"] if height is None else height))

    @staticmethod
    def _needs_tri(channels):
        return "appearance" in channels or "custom" in channels

    def _bind_cost_inputs(self, prog, t, v, channels):
        model = t["zt"] if self._needs_tri(channels) else t["z"]
        units = {"model_z": model, "model_tri": model, "obs_z": v.obs_z, "obs_mask": v.obs_mask,
                 "obs_bits": v.obs_bits, "tri_bits": v.tri_bits}
        for unit, (name, tex) in enumerate(units.items()):
            if name in prog and tex is not None:
                tex.use(location=unit)
                prog[name].value = unit
        if "tile" in prog:
            prog["tile"].value = self.tile
        if "depth_params" in prog:
            prog["depth_params"].value = self.depth_params.as_vec4()

    def _reduce(self, t, v, n, cols, rows, channels, method, slot=0, read=True):
        """Sum the per-pixel costs of each of the ``n`` tiles of camera ``v`` just rendered:
        (n, 4) float64, or None for the compute reduction with ``read`` False, which leaves
        them in slice ``slot`` of ``t["sums"]`` (:meth:`_read_sums`)."""
        defines = self._defines(channels)
        if method == "compute":
            if self.reduce_group == "narrow":
                defines = {**defines, "NARROW_GROUP": 1}
            prog = self.programs.get(compute="reduce.comp", defines=defines, aliases=self._aliases())
            self._bind_cost_inputs(prog, t, v, channels)
            prog["grid"].value = (cols, rows)
            prog["base"].value = slot * cols * rows
            t["sums"].bind_to_storage_buffer(0)
            prog.run(cols, self._used_height(n, cols) // self.tile, 1)  # the tiles in use
            return self._read_sums(t, n, cols * rows, slot + 1)[:, slot] if read else None
        prog = self.programs.get(vertex="fullscreen.vert", fragment="cost.frag", defines=defines,
                                 aliases=self._aliases())
        self._bind_cost_inputs(prog, t, v, channels)
        vao = self._fullscreen_vao(prog)
        t["cost_fbo"].use()
        # the rows of tiles in use; the mipmaps average each tile on its own, so the stale
        # values of the others never reach them
        t["cost_fbo"].viewport = (0, 0, t["W"], self._used_height(n, cols))
        vao.render(moderngl.TRIANGLES, vertices=3)
        t["cost"].build_mipmaps(0, t["levels"])
        raw = np.frombuffer(t["cost"].read(level=t["levels"]), dtype=np.float32).reshape(rows, cols, 4)
        self.readbacks += 1
        means = raw.reshape(rows * cols, 4)[:n].astype(np.float64)
        return means * float(self.tile * self.tile)

    # ------------------------------------------------------------------- for benchmarks
    def mesh_vertex_array(self, program) -> moderngl.VertexArray:
        """The mesh's rest-pose vertex positions and triangles bound to another program.

        The program reads ``in_pos`` (vec3, metres) and is drawn instanced like the engine's
        own (e.g. a trivial shader that measures the draw-rate bound, ``gltrack bench engine``).

        Parameters
        ----------
        program : moderngl.Program with a ``vec3 in_pos`` attribute

        Returns
        -------
        moderngl.VertexArray, indexed; the caller releases it
        """
        return self.ctx.vertex_array(program, [(self._vbo_pos, "3f", "in_pos")],
                                     index_buffer=self._ibo, index_element_size=4)

    def depth_framebuffer(self, cols: int, rows: int) -> moderngl.Framebuffer:
        """The depth-only framebuffer of the engine's render target for a tile grid.

        Parameters
        ----------
        cols, rows : int, the grid (:func:`grid_for`)

        Returns
        -------
        moderngl.Framebuffer, ``cols * tile`` x ``rows * tile`` pixels, one float colour
        attachment and a depth buffer; owned and cached by the engine (do not release it)
        """
        return self._target(cols, rows)["fbo_z"]

    def _fullscreen_vao(self, prog):
        if not hasattr(self, "_fs_vaos"):
            self._fs_vaos = {}
        key = id(prog)
        if key not in self._fs_vaos:
            self._fs_vaos[key] = self.ctx.vertex_array(prog, [])
        return self._fs_vaos[key]

    def _time_reductions(self, t, n, cols, rows, channels):
        """Time both reductions on a real batch and return the faster one's name."""
        v = self.views[0]
        if any(x is None for x in (v.obs_z if "depth" in channels else 0,
                                     v.obs_mask if "silhouette" in channels else 0,
                                     v.obs_mask if "model" in channels else 0,
                                     v.obs_bits if "appearance" in channels else 0)):
            return "compute"
        self._render(t, v, n, cols, rows, self._needs_tri(channels))
        times = {}
        for method in ("mipmap", "compute"):
            self._reduce(t, v, n, cols, rows, channels, method)  # compile and warm up
            t0 = time.perf_counter()
            for _ in range(3):
                self._reduce(t, v, n, cols, rows, channels, method)
            times[method] = time.perf_counter() - t0
        best = min(times, key=times.get)
        log.info("reduction timing %s -> using %s", {k: round(s * 1e3, 2) for k, s in times.items()}, best)
        return best

    # ------------------------------------------------------------------------------ utilities
    def _single_batch_target(self, n: int, caller: str):
        """The render targets of one batch of ``n`` candidates, and its grid (cols, rows)."""
        if n > self.max_batch:
            raise ValueError(f"{caller} takes at most {self.max_batch} candidates")
        cols, rows = grid_for(n, self.max_tiles_side)
        return self._target(cols, rows), cols, rows

    def gpu_skinning(self, params) -> np.ndarray:
        """Test helper: the skinning matrices ``shaders/fk.comp`` computes for ``params``.

        Parameters
        ----------
        params : (N, D) float, at most :attr:`max_batch` poses (clamped as :meth:`score_poses`)

        Returns
        -------
        (N, B, 3, 4) float32, as ``Kinematics.skinning_matrices`` (its CPU twin)
        """
        if self.fk != "gpu" or self.kin is None:
            raise RuntimeError("gpu_skinning needs fk='gpu' and set_kinematics")
        P = np.ascontiguousarray(self.kin.dofs.validate(params), dtype=np.float32)
        n = P.shape[0]
        t, cols, rows = self._single_batch_target(n, "gpu_skinning")
        self._run_fk(t, P, n)
        raw = np.frombuffer(t["bones"].read(), np.float32).reshape(cols * rows, self.n_bones, 3, 4)
        return raw[:n].copy()

    def render_tiles(self, skinning, cam: int = 0):
        """Debug/test helper: the rendered model depth and triangle-id tiles of a batch.

        Returns
        -------
        depth : (N, tile, tile) float32, metres (0 = empty); tri : (N, tile, tile) int32 (-1 = empty)
        """
        S = np.ascontiguousarray(skinning, dtype=np.float32)
        n = S.shape[0]
        t, cols, rows = self._single_batch_target(n, "render_tiles")
        self._upload_batch(t, S, n)
        self._render(t, self._check_view(cam), n, cols, rows)
        T = self.tile
        zt = np.frombuffer(t["zt"].read(), np.float32).reshape(rows, T, cols, T, 2).transpose(0, 2, 1, 3, 4)
        z = zt[..., 0]
        tri = zt[..., 1].astype(np.int32) - 1
        return z.reshape(-1, T, T)[:n].copy(), tri.reshape(-1, T, T)[:n].copy()

    def release(self):
        """Free every GL object the engine made (idempotent)."""
        if self._released:
            return
        self._drop_from_workers()
        # moderngl re-binds "the previous framebuffer" when it creates the next one; if that is
        # one of ours after release, the next engine gets GL_INVALID_OPERATION. Park the binding
        # on a tiny framebuffer that lives as long as the context.
        park_framebuffer(self.ctx)
        for t in self._targets.values():
            self._release_target(t)
        self._targets.clear()
        for vao in getattr(self, "_fs_vaos", {}).values():
            vao.release()
        for v in self.views:
            for tex in (v.obs_z, v.obs_mask, v.obs_bits, v.tri_bits):
                if tex is not None:
                    tex.release()
        for obj in (*self._vao.values(), *self._skin_in, self._vbo_pos, self._vbo_j, self._vbo_w,
                    self._ibo, *self._vbo_layout, *([self._joints_buf] if self._joints_buf is not None else [])):
            obj.release()
        if self._owns_programs:
            self.programs.release()
        self._released = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


def silhouette_iou(model_px, foreground_px, xor_px):
    """Silhouette IoU from the engine's counts: ``|M & F| / |M | F|`` with
    ``|M | F| = (M + F + X) / 2`` and ``|M & F| = (M + F - X) / 2``.

    Parameters
    ----------
    model_px : array, the model's unblocked pixel count M (channel ``model``)
    foreground_px : array, the unblocked foreground pixel count F (same shape, broadcastable)
    xor_px : array, the silhouette XOR count X (channel ``silhouette``)

    Returns
    -------
    array of float64 in 0..1, the shape of the broadcast inputs; NaN where both model and
    foreground are empty: there is nothing to compare, and a camera that sees neither the
    person nor the model is no evidence of a good fit
    """
    return silhouette_overlap(model_px, foreground_px, xor_px)[0]


def silhouette_overlap(model_px, foreground_px, xor_px):
    """IoU and its two one-sided shares from the engine's counts: ``|M & F| = (M + F - X) / 2``
    and ``|M | F| = (M + F + X) / 2`` (see :func:`silhouette_iou`).

    Parameters
    ----------
    model_px, foreground_px, xor_px : arrays, as for :func:`silhouette_iou`

    Returns
    -------
    iou : ``|M & F| / |M | F|``
    model_on_fg : ``|M & F| / |M|``, the share of the model's silhouette on the foreground
        (low: the model sticks out of the mask, e.g. too large or a limb off the person)
    fg_covered : ``|M & F| / |F|``, the share of the foreground the model covers (low: the
        mask holds what the model does not explain, e.g. background taken for the person, or
        a limb the model missed)
    each an array of float64 in 0..1 of the broadcast shape, NaN where its denominator is 0
    """
    m, f, x = (np.asarray(a, dtype=np.float64) for a in (model_px, foreground_px, xor_px))
    inter = np.clip(0.5 * (m + f - x), 0.0, None)

    def share(den):
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(den > 0, np.clip(inter / np.where(den > 0, den, 1.0), 0.0, 1.0),
                            np.nan)
    return share(0.5 * (m + f + x)), share(m), share(f)


def _engine_option(ctx, name: str, value: str, env: str, auto: str, allowed: tuple,
                   needs_430: str | None = None) -> str:
    """One of the engine's path options: ``value``, or for "auto" the environment variable
    ``env`` when it is set, else ``auto``; checked against ``allowed``; the choice
    ``needs_430`` needs a GL 4.3 context (compute shaders)."""
    if value == "auto":
        value = os.environ.get(env) or auto
    if value not in allowed:
        raise ValueError(f"{name} must be auto, {' or '.join(allowed)} (also {env}), got {value!r}")
    if value == needs_430 and ctx.version_code < 430:
        raise ValueError(f"{name}={value!r} needs OpenGL 4.3; this context is {ctx.version_code}")
    return value


def is_software_renderer(renderer: str) -> bool:
    """Whether ``GL_RENDERER`` names a software rasteriser (llvmpipe and the like)."""
    return any(k in str(renderer).lower() for k in _SOFTWARE_RENDERERS)


def choose_skinning(renderer: str, version_code: int, n_cameras: int = 1) -> str:
    """Where ``skinning="auto"`` skins the vertices (unless ``GLTRACK_SKINNING`` says).

    Without GL 4.3 there is only "vertex". "compute" on a hardware GPU: one pass for all cameras,
    on every multiprocessor (measured on an NVIDIA H100, where by NVIDIA's description two of
    66 processor clusters can run vertex shaders: 4 cameras x 64 px 2.5x faster, one camera the
    same). On a software renderer the compute pass costs about one camera's vertex skinning
    (llvmpipe, 800 candidates at 64 px, draws with triangle ids, which have twice the vertices
    of the depth-only draw: one camera 0.15 s a batch with "vertex" against 0.16-0.17, two
    cameras 0.24-0.27 against 0.21-0.25, four 0.47-0.54 against 0.40-0.52), so there it is
    "compute" from three cameras on and "vertex" below.
    """
    if int(version_code) < 430:
        return "vertex"
    if is_software_renderer(renderer) and int(n_cameras) < 3:
        return "vertex"
    return "compute"


def choose_triangle_ids(renderer: str) -> str:
    """How ``triangle_ids="auto"`` gets triangle ids (unless ``GLTRACK_TRIANGLE_IDS`` says).

    "provoking" on a software renderer: llvmpipe assembles primitives on a slow path when the
    fragment shader reads ``gl_PrimitiveID`` (800 candidates at 64 px, four cameras: the draw
    with ids took 0.67-0.84 s against 0.41-0.56 s without them; the provoking layout, with
    twice the vertices, 0.59-0.73 s with vertex skinning and 0.42-0.50 s with compute skinning).
    "primitive" on a hardware GPU: the layout doubles the work of the vertex stage, the scarce
    one there (see :func:`choose_skinning`), and it has not been timed on a GPU.
    """
    return "provoking" if is_software_renderer(renderer) else "primitive"


def use_workers(candidates: int, cameras: int, workers: int) -> bool:
    """Whether the engine's worker processes score a call (in equal shares) or this process does.

    Parameters
    ----------
    candidates : int, candidates in the call
    cameras : int, the engine's cameras
    workers : int, the engine's worker processes (0: none)

    Returns
    -------
    bool, True when there are workers, each gets at least one candidate, and each share holds
    at least :data:`WORKER_MIN_WORK` candidates x cameras.
    """
    if workers < 1 or candidates < workers:
        return False
    return candidates * cameras >= workers * WORKER_MIN_WORK


def resolve_workers(workers, renderer: str, reduction: str = "auto") -> int:
    """The engine's number of worker processes (its ``workers`` argument resolved).

    Parameters
    ----------
    workers : int >= 0 or "auto" (``GLTRACK_ENGINE_WORKERS``, else
        :func:`gltrack.render.workers.choose_workers`)
    renderer : str, ``GL_RENDERER``
    reduction : str, the engine's ``reduction`` argument ("fastest": none on "auto", whatever
        ``GLTRACK_ENGINE_WORKERS`` says)

    Raises
    ------
    ValueError
        Not a count or "auto" (naming ``GLTRACK_ENGINE_WORKERS`` when it came from there).
    """
    source = "workers"
    if workers == "auto":
        if reduction == "fastest":  # it times the reductions in this process
            return 0
        env = os.environ.get("GLTRACK_ENGINE_WORKERS")
        if not env:
            return choose_workers(is_software_renderer(renderer), core_budget())
        workers, source = env, "GLTRACK_ENGINE_WORKERS"
    try:
        n = int(str(workers).strip())
    except ValueError:
        n = -1
    if n < 0:
        raise ValueError(f"{source} must be auto or a count >= 0, got {workers!r}")
    return n


def choose_reduce_group(renderer: str) -> str:
    """The compute reduction's work group for ``reduce_group="auto"`` (unless
    ``GLTRACK_REDUCE_GROUP`` says).

    "narrow" on a software renderer: llvmpipe runs a work group's invocations as coroutines in
    SIMD batches, and each barrier switches all of them, so the wide group's tree of nine
    barriers costs more than the 64 additions one invocation does after a single barrier (800
    candidates at 64 px, silhouette and appearance: 28-31 ms a camera against 38-51 ms; with the
    tile mask of ``costs.glsl`` 22 against 38-47). "wide" on a hardware GPU, where a narrow group
    would leave a quarter of the threads to hide texture latency, and which has not timed it.
    """
    return "narrow" if is_software_renderer(renderer) else "wide"


def choose_tile_clip(renderer: str) -> str:
    """How ``tile_clip="auto"`` keeps candidates in their tiles (unless ``GLTRACK_TILE_CLIP``).

    "fragment" on a hardware GPU: four clip distances per vertex cost an NVIDIA H100 3.2x its
    draw rate (depth, 64 px: 94k against 304k candidates/s), the fragment test almost nothing.
    "distance" on a software renderer, where the fragment test costs 17 % on four cameras and
    the clip distances 5 %.
    """
    return "distance" if is_software_renderer(renderer) else "fragment"


def choose_reduction(ctx: moderngl.Context) -> str:
    """The reduction ``reduction="auto"`` picks here: "compute" with GL 4.3, else "mipmap".

    Used by ``gltrack info``.
    """
    return "compute" if ctx.version_code >= 430 else "mipmap"


def fastest_reduction(ctx: moderngl.Context, n: int = 256, tile: int = 64) -> str:
    """The reduction ``reduction="fastest"`` picks here (timed: it may differ between calls).

    Times both reductions on ``n`` candidates of the default body (depth cost, one camera at
    ``tile``); "mipmap" without GL 4.3.
    """
    if ctx.version_code < 430:
        return "mipmap"
    from gltrack.body.model import BodyModel
    from gltrack.camera import look_at_camera

    body = BodyModel.build()
    cam = look_at_camera("probe", (0.0, 1.0, 2.6), (0.0, 0.9, 0.0), tile, tile, 50.0, kind="depth")
    with ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, [cam], tile=tile,
                       reduction="fastest") as eng:
        eng.set_depth(0, np.zeros((tile, tile)))
        eng.score(body.skinning(np.repeat(body.dofs.zero(body.skeleton)[None], n, axis=0)))
        return eng.reduction
