"""The "naive way" benchmark baseline: one pyrender offscreen render per candidate.

Each candidate is skinned on the CPU in numpy, its vertex positions are uploaded as a fresh
pyrender mesh, one depth image is rendered and read back, and the numpy cost from
:mod:`gltrack.render.reference` is evaluated on it. The GL engine's speed-up is measured against
this.

Process isolation: pyrender drives OpenGL through PyOpenGL on EGL, which must not share a process
with a moderngl context in use (and PyOpenGL fixes its platform at first import). Benchmarks and
tests that also use moderngl therefore call :func:`run_baseline_in_subprocess`, which runs the
work in a ``multiprocessing`` *spawn* child; every public function here takes only picklable
arguments for that reason.

Camera conventions: gltrack cameras are OpenCV (x right, y down, z forward; pixel centres at
integer coordinates). pyrender is OpenGL (looks down -Z, y up; pixel centres at +0.5). The camera
pose given to pyrender is ``inv([R|t]) @ diag(1, -1, -1, 1)`` and the principal point is shifted
by +0.5 pixel; ``tests/test_reference.py`` checks the result against the reference rasteriser.
pyrender clips at ``znear`` per pixel rather than dropping whole triangles as the reference does,
so keep the body in front of ``near`` when comparing the two.
"""
from __future__ import annotations

import logging
import statistics
import time

import numpy as np

from gltrack.render import reference

log = logging.getLogger(__name__)

#: Far plane handed to pyrender, metres; small enough to keep 24-bit depth precise to ~1e-5 m.
DEFAULT_ZFAR = 20.0


def _import_pyrender():
    from gltrack.render.pyrender_egl import import_pyrender

    return import_pyrender("run_baseline_in_subprocess()")


def _as_cameras(K, R, t):
    """Normalise one camera or a stack of C cameras to (C, 3, 3), (C, 3, 3), (C, 3)."""
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if K.ndim == 2:
        K, R, t = K[None], R[None], t.reshape(1, 3)
    if K.shape[1:] != (3, 3) or R.shape != K.shape or t.shape != (len(K), 3):
        raise ValueError(f"cameras must be K (C,3,3), R (C,3,3), t (C,3); got {K.shape}, "
                         f"{R.shape}, {t.shape}")
    return K, R, t


def gl_camera_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) pyrender camera-to-world pose for OpenCV world->camera extrinsics ``R``, ``t``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return np.linalg.inv(T) @ np.diag([1.0, -1.0, -1.0, 1.0])


class PyrenderBaseline:
    """Score candidates by rendering each one separately with pyrender.

    Parameters
    ----------
    mesh : gltrack.body.mesh.BodyMesh
    K : (3, 3) or (C, 3, 3) float, intrinsics, pixels (OpenCV, no skew)
    R : (3, 3) or (C, 3, 3) float, world->camera rotations
    t : (3,) or (C, 3) float, world->camera translations, metres
    width, height : int, pixels (shared by all cameras)
    znear, zfar : float, metres, pyrender clip planes
    """

    def __init__(self, mesh, K, R, t, width: int, height: int, *, znear: float = 0.05,
                 zfar: float = DEFAULT_ZFAR):
        pr = _import_pyrender()
        self._pr = pr
        self.mesh = mesh
        self.K, self.R, self.t = _as_cameras(K, R, t)
        for k in self.K:
            reference._check_K(k)
        self.width, self.height = int(width), int(height)
        self.scene = pr.Scene(bg_color=np.zeros(4))
        self._cams = []
        for K_c, R_c, t_c in zip(self.K, self.R, self.t):
            # pyrender's pixel centres sit at +0.5, ours at integers
            cam = pr.IntrinsicsCamera(K_c[0, 0], K_c[1, 1], K_c[0, 2] + 0.5, K_c[1, 2] + 0.5,
                                      znear=znear, zfar=zfar)
            self._cams.append(self.scene.add(cam, pose=gl_camera_pose(R_c, t_c)))
        self._material = pr.MetallicRoughnessMaterial(doubleSided=True)
        self._node = None
        self.renderer = pr.OffscreenRenderer(self.width, self.height)
        # SEG disables MSAA inside pyrender, so depth is sampled at pixel centres like ours
        self._flags = (pr.RenderFlags.DEPTH_ONLY | pr.RenderFlags.SKIP_CULL_FACES
                       | pr.RenderFlags.SEG)
        self._faces = np.asarray(mesh.faces, dtype=np.uint32)

    @property
    def n_cameras(self) -> int:
        return len(self.K)

    def _set_vertices(self, posed: np.ndarray):
        pr = self._pr
        if self._node is not None:
            self.scene.remove_node(self._node)
        prim = pr.Primitive(positions=posed.astype(np.float32), indices=self._faces,
                            material=self._material, mode=pr.constants.GLTF.TRIANGLES)
        self._node = self.scene.add(pr.Mesh([prim]))

    def _render(self, camera: int) -> np.ndarray:
        self.scene.main_camera_node = self._cams[camera]
        d = self.renderer.render(self.scene, flags=self._flags, seg_node_map={self._node: 255})
        return np.asarray(d, dtype=np.float64)

    def _candidates(self, skinning, per_image):
        """Skin each candidate, render every camera, reduce each image with ``per_image(c, d)``."""
        S = np.asarray(skinning, dtype=np.float64)
        if S.ndim != 4 or S.shape[2:] != (3, 4):
            raise ValueError(f"skinning must have shape (N, B, 3, 4), got {S.shape}")
        out = np.zeros(len(S))
        for n in range(len(S)):
            self._set_vertices(self.mesh.skin(S[n:n + 1])[0])
            out[n] = sum(per_image(c, self._render(c)) for c in range(self.n_cameras))
        return out

    def render_depth(self, skinning) -> np.ndarray:
        """(N, C, H, W) float64 depth, metres (0 = empty), for N candidates in every camera."""
        S = np.asarray(skinning, dtype=np.float64)
        out = np.zeros((len(S), self.n_cameras, self.height, self.width))
        for n in range(len(S)):
            self._set_vertices(self.mesh.skin(S[n:n + 1])[0])
            for c in range(self.n_cameras):
                out[n, c] = self._render(c)
        return out

    def _per_camera(self, img, name):
        a = np.asarray(img)
        if a.ndim == 2:
            a = np.broadcast_to(a, (self.n_cameras,) + a.shape)
        if a.shape != (self.n_cameras, self.height, self.width):
            raise ValueError(f"{name} must be (H, W) or (C, H, W) = "
                             f"({self.n_cameras}, {self.height}, {self.width}), got {a.shape}")
        return a

    def score_depth(self, skinning, obs_z, **cost_kw) -> np.ndarray:
        """Depth cost summed over cameras.

        Parameters
        ----------
        skinning : (N, B, 3, 4) float
        obs_z : (H, W) or (C, H, W) float, observed depth, metres (0 = none)
        **cost_kw : keyword arguments of :func:`gltrack.render.reference.depth_cost`

        Returns
        -------
        (N,) float64
        """
        obs = self._per_camera(obs_z, "obs_z")
        return self._candidates(skinning, lambda c, d: reference.depth_cost(d, obs[c], **cost_kw))

    def score_silhouette(self, skinning, fg, block=None) -> np.ndarray:
        """Silhouette cost summed over cameras; ``fg``/``block`` (H, W) or (C, H, W) bool; (N,)."""
        f = self._per_camera(fg, "fg")
        b = None if block is None else self._per_camera(block, "block")
        return self._candidates(skinning, lambda c, d: reference.silhouette_cost(
            d > 0, f[c], None if b is None else b[c]))

    def close(self):
        """Release the GL context."""
        if self.renderer is not None:
            self.renderer.delete()
            self.renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def baseline_candidates_per_s(mesh, K, R, t, width, height, obs, skinning, mode: str = "depth",
                              n_cameras: int = 1, repeats: int = 3) -> float:
    """Baseline throughput: candidates scored per second (median over ``repeats`` timed runs).

    Parameters
    ----------
    mesh : BodyMesh
    K, R, t : one camera ((3,3), (3,3), (3,)) or C cameras ((C,3,3), (C,3,3), (C,3))
    width, height : int, pixels
    obs : (H, W) or (C, H, W); depth in metres for ``mode="depth"``, foreground bool for
        ``mode="silhouette"``
    skinning : (N, B, 3, 4) float, the candidates scored in each timed run
    mode : "depth" or "silhouette"
    n_cameras : int; with a single camera given, it is rendered this many times per candidate
        (cost equals that of as many distinct cameras)
    repeats : int, timed runs after one untimed warm-up candidate

    Returns
    -------
    float, candidates per second (each candidate seen by every camera)

    Notes
    -----
    Safe to call in a spawn child: ``run_baseline_in_subprocess("candidates_per_s", ...)``.
    """
    if mode not in ("depth", "silhouette"):
        raise ValueError(f"mode must be 'depth' or 'silhouette', got {mode!r}")
    K, R, t = _as_cameras(K, R, t)
    if len(K) == 1 and n_cameras > 1:
        K, R, t = (np.repeat(a, n_cameras, axis=0) for a in (K, R, t))
    S = np.asarray(skinning, dtype=np.float64)
    with PyrenderBaseline(mesh, K, R, t, width, height) as base:
        run = (lambda s: base.score_depth(s, obs)) if mode == "depth" else \
            (lambda s: base.score_silhouette(s, np.asarray(obs) > 0))
        run(S[:1])  # warm-up: shader compilation, first upload
        times = []
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            run(S)
            times.append(time.perf_counter() - t0)
    rate = len(S) / statistics.median(times)
    log.info("pyrender baseline %s, %d camera(s), %dx%d: %.1f candidates/s",
             mode, len(K), width, height, rate)
    return rate


def _render_depth(mesh, K, R, t, width, height, skinning):
    with PyrenderBaseline(mesh, K, R, t, width, height) as base:
        return base.render_depth(skinning)


def _score(mode, mesh, K, R, t, width, height, skinning, *args, **kw):
    with PyrenderBaseline(mesh, K, R, t, width, height) as base:
        fn = base.score_depth if mode == "depth" else base.score_silhouette
        return fn(skinning, *args, **kw)


_KINDS = {
    "candidates_per_s": baseline_candidates_per_s,
    "render_depth": _render_depth,
    "score_depth": lambda *a, **kw: _score("depth", *a, **kw),
    "score_silhouette": lambda *a, **kw: _score("silhouette", *a, **kw),
}


def _child(kind, args, kwargs):
    return _KINDS[kind](*args, **kwargs)


def run_baseline_in_subprocess(kind: str, *args, timeout: float | None = 600, **kwargs):
    """Run one baseline job in a fresh spawn child, isolated from this process's GL state.

    Parameters
    ----------
    kind : str
        ``"candidates_per_s"`` (:func:`baseline_candidates_per_s` arguments),
        ``"render_depth"`` (mesh, K, R, t, width, height, skinning) -> (N, C, H, W),
        ``"score_depth"`` (mesh, K, R, t, width, height, skinning, obs_z, **cost_kw) -> (N,),
        ``"score_silhouette"`` (mesh, K, R, t, width, height, skinning, fg, block=None) -> (N,).
    timeout : float or None, seconds

    Returns
    -------
    whatever the job returns
    """
    if kind not in _KINDS:
        raise ValueError(f"unknown baseline job {kind!r}; choose one of {', '.join(_KINDS)}")
    from gltrack.spawn import run_in_child

    return run_in_child(_child, (kind, args, kwargs), timeout=timeout)
