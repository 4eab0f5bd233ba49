"""Bandouch's implicit environment model (sec. 3.4, eqs. 3-7) as a GPU mask pass, with a CPU twin.

Inputs per camera image: the foreground mask I_F (background subtraction), the colour image (its
pixels' HLS voxels index the appearance model's human-colour table, giving I_H) and the user's
occluder polygons (``gltrack.data.dataset.Dataset.blocking_mask``: True inside a polygon).

The paper's blocking layer I_B is 1 where pixels are *processed*; polygons unset it. Exactly as
written in the paper::

    I_F'  = AND(I_F, I_H)                     (5)  non-human colours are not foreground ...
    I_B'  = AND(I_B, NOT(DIFF(I_F, I_F')))    (6)  ... and are blocked (they may hide the person)
    I_B'' = OR(I_B', I_F')                    (7)  human-coloured foreground is never blocked,
                                                   not even inside an occluder polygon
    fg'   = AND(I_F', I_B'')                  (3)  the masked foreground (equals I_F')

Eq. 4 (masking the model projection I_P with I_B'') is what the scoring engine does with its
blocking mask, whose convention is inverted (True = ignore): :meth:`EnvironmentLayers.apply`
therefore returns ``block' = NOT(I_B'')``, ready for ``ScoringEngine.set_masks(cam, fg', block')``.
Since the engine counts ``XOR(I_P, I_F) AND NOT block``, eqs. 3 and 4 together give
``COUNT(XOR(AND(I_P, I_B''), AND(I_F', I_B'')))``: the paper's shape error.

Only the colour -> voxel quantisation runs on the CPU (OpenCV's HLS conversion, which a shader
could not reproduce bit for bit); the table look-up and every mask operation run in
``shaders/env_masks.frag``.
"""
from __future__ import annotations

import logging

import moderngl
import numpy as np

from gltrack.gl.context import park_framebuffer
from gltrack.gl.programs import ProgramCache
from gltrack.observe import hls

log = logging.getLogger(__name__)

_LUT_SHAPE = (128, 256)  # rows, columns of the human-colour table texture


def _check_inputs(fg_mask, bgr_image, polygons_mask, lut, shape=None):
    img = np.asarray(bgr_image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"bgr_image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    hw = img.shape[:2]
    if shape is not None and hw != shape:
        raise ValueError(f"bgr_image is {hw[1]}x{hw[0]}, the camera is {shape[1]}x{shape[0]}")
    fg = np.asarray(fg_mask)
    if fg.shape != hw:
        raise ValueError(f"fg_mask must be {hw}, got {fg.shape}")
    poly = np.zeros(hw, bool) if polygons_mask is None else np.asarray(polygons_mask)
    if poly.shape != hw:
        raise ValueError(f"polygons_mask must be {hw}, got {poly.shape}")
    table = np.asarray(lut)
    if table.shape != (hls.N_VOXELS,):
        raise ValueError(f"lut must be ({hls.N_VOXELS},) bool, got {table.shape}")
    return fg != 0, img, poly != 0, table != 0


def environment_masks_cpu(fg_mask, bgr_image, polygons_mask, lut) -> tuple[np.ndarray, np.ndarray]:
    """CPU twin of :meth:`EnvironmentLayers.apply` (eqs. 3-7, see the module docstring).

    Parameters
    ----------
    fg_mask : (H, W) bool, I_F
    bgr_image : (H, W, 3) uint8, the colour image
    polygons_mask : (H, W) bool or None, True inside the user's occluder polygons
    lut : (32768,) bool, the human-colour table (``AppearanceModel.human_lut``)

    Returns
    -------
    fg : (H, W) bool, the masked foreground AND(I_F', I_B'')
    block : (H, W) bool, NOT(I_B''): pixels the scoring engine must ignore
    """
    i_f, img, poly, table = _check_inputs(fg_mask, bgr_image, polygons_mask, lut)
    i_h = table[hls.voxel_index(img)]
    i_b = ~poly
    i_f1 = i_f & i_h                    # (5)
    i_b1 = i_b & ~(i_f & ~i_f1)         # (6)
    i_b2 = i_b1 | i_f1                  # (7)
    return i_f1 & i_b2, ~i_b2           # (3), engine convention


class EnvironmentLayers:
    """The environment mask pass on the GPU, one camera-sized target per camera.

    Parameters
    ----------
    ctx : moderngl.Context
    cameras : list of gltrack.camera.Camera (only their sizes are used)
    programs : gltrack.gl.programs.ProgramCache, optional (shared with an engine)
    """

    def __init__(self, ctx: moderngl.Context, cameras, programs: ProgramCache | None = None):
        if not cameras:
            raise ValueError("at least one camera is needed")
        self.ctx = ctx
        self.cameras = list(cameras)
        self.programs = programs or ProgramCache(ctx)
        self._owns_programs = programs is None
        self._prog = self.programs.get(vertex="fullscreen.vert", fragment="env_masks.frag")
        self._vao = ctx.vertex_array(self._prog, [])
        self._lut_tex = ctx.texture(_LUT_SHAPE[::-1], 1, dtype="u1")
        self._lut_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._lut = None
        self._targets = {}
        self._released = False

    def _target(self, cam):
        if not 0 <= cam < len(self.cameras):
            raise ValueError(f"camera index {cam} out of range ({len(self.cameras)} cameras)")
        if cam not in self._targets:
            c = self.cameras[cam]
            size = (c.width, c.height)
            src = self.ctx.texture(size, 1, dtype="u4")
            dst = self.ctx.texture(size, 1, dtype="u1")
            for t in (src, dst):
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._targets[cam] = (src, dst, self.ctx.framebuffer(color_attachments=[dst]))
        return self._targets[cam]

    def _upload_lut(self, table):
        if self._lut is None or not np.array_equal(self._lut, table):
            self._lut_tex.write(table.astype(np.uint8).reshape(_LUT_SHAPE).tobytes())
            self._lut = table.copy()

    def codes(self, cam: int, fg_mask, bgr_image, polygons_mask, lut) -> np.ndarray:
        """Run the pass; (H, W) uint8 with bit 0 = fg', bit 1 = block', bit 2 = I_H."""
        if self._released:
            raise RuntimeError("EnvironmentLayers has been released")
        src, dst, fbo = self._target(cam)
        c = self.cameras[cam]
        i_f, img, poly, table = _check_inputs(fg_mask, bgr_image, polygons_mask, lut,
                                              (c.height, c.width))
        packed = (hls.voxel_index(img).astype(np.uint32) | (i_f.astype(np.uint32) << 15)
                  | (poly.astype(np.uint32) << 16))
        src.write(np.ascontiguousarray(packed).tobytes())
        self._upload_lut(table)
        src.use(location=0)
        self._lut_tex.use(location=1)
        self._prog["obs_packed"].value = 0
        self._prog["human_lut"].value = 1
        fbo.use()
        fbo.viewport = (0, 0, c.width, c.height)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE | moderngl.BLEND)
        self._vao.render(moderngl.TRIANGLES, vertices=3)
        return np.frombuffer(dst.read(), np.uint8).reshape(c.height, c.width).copy()

    def apply(self, cam: int, fg_mask, bgr_image, polygons_mask, lut) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. 3-7 on the GPU for one camera image.

        Parameters
        ----------
        cam : int, camera index
        fg_mask : (H, W) bool, I_F at the camera's resolution
        bgr_image : (H, W, 3) uint8
        polygons_mask : (H, W) bool or None, True inside occluder polygons
        lut : (32768,) bool, the human-colour table (re-uploaded only when it changes)

        Returns
        -------
        fg : (H, W) bool, the masked foreground
        block : (H, W) bool, True = the engine ignores the pixel (``ScoringEngine.set_masks``)
        """
        code = self.codes(cam, fg_mask, bgr_image, polygons_mask, lut)
        return (code & 1) != 0, (code & 2) != 0

    def release(self):
        """Free the GL objects (idempotent)."""
        if self._released:
            return
        # As in ScoringEngine.release: moderngl re-binds the previous framebuffer when it makes
        # the next one, so never leave one of ours bound once it is gone.
        park_framebuffer(self.ctx)
        for src, dst, fbo in self._targets.values():
            fbo.release()
            src.release()
            dst.release()
        self._targets.clear()
        self._vao.release()
        self._lut_tex.release()
        if self._owns_programs:
            self.programs.release()
        self._released = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
