"""05 - Write your own per-pixel cost in GLSL and check it against a numpy twin.

A custom cost is a GLSL file defining ``float custom_cost(ivec2 pixel, ivec2 local)``; the engine
sums it per candidate into channel 3 ("custom"). ``pixel`` indexes the rendered grid textures
(``model_z``: camera depth of the model, 0 = none; ``model_tri``: ``.g`` = 1 + triangle id) and ``local`` the
tile-sized observation textures (``obs_z``, ``obs_mask``, ``obs_bits``). Here: a truncated absolute
depth difference (an L1 alternative to Ganapathi's smoothstep).

Run: python examples/05_custom_cost_shader.py
"""
import tempfile
from pathlib import Path

import numpy as np

from gltrack.body.model import BodyModel
from gltrack.camera import look_at_camera
from gltrack.gl.context import create_context
from gltrack.render import reference as ref
from gltrack.render.engine import CustomCost, ScoringEngine

GLSL = """
float custom_cost(ivec2 pixel, ivec2 local) {
    float zo = texelFetch(obs_z, local, 0).r;
    float zm = texelFetch(model_z, pixel, 0).r;
    if (zo > 0.0 && zm > 0.0) return min(abs(zo - zm), 0.3);
    return (zo > 0.0 || zm > 0.0) ? 0.3 : 0.0;
}
"""


def cpu_twin(model_z, obs_z):
    both = (model_z > 0) & (obs_z > 0)
    one = (model_z > 0) ^ (obs_z > 0)
    return float(np.where(both, np.minimum(np.abs(obs_z - model_z), 0.3), 0).sum() + 0.3 * one.sum())


def main():
    rng = np.random.default_rng(1)
    body = BodyModel.build()
    cam = look_at_camera("cam0", (0.0, 1.0, 2.6), (0.0, 0.9, 0.0), 64, 64, 50.0, kind="depth")
    P = body.dofs.validate(body.dofs.zero(body.skeleton) + rng.normal(size=(8, body.dofs.size)) * 0.2)
    obs, _ = ref.render_candidates(body.mesh, body.skinning(P[:1]), cam.K, cam.R, cam.t, 64, 64)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "l1_depth.glsl"
        path.write_text(GLSL)
        ctx = create_context()
        with ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, [cam], tile=64,
                           custom=CustomCost(str(path))) as eng:
            eng.set_depth(0, obs[0])
            gpu = eng.score(body.skinning(P), ["custom"])[:, 0, 3]
        ctx.release()
    z, _ = ref.render_candidates(body.mesh, body.skinning(P), cam.K, cam.R, cam.t, 64, 64)
    cpu = np.array([cpu_twin(z[i], obs[0]) for i in range(len(P))])
    print("GPU:", np.round(gpu, 2))
    print("CPU:", np.round(cpu, 2))
    err = np.max(np.abs(gpu - cpu) / np.maximum(cpu, 1.0))
    print(f"max relative difference {err:.4f}")
    return float(err)


if __name__ == "__main__":
    main()
