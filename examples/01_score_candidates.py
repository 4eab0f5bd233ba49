"""01 - Score candidate poses with the GPU engine and check them against the CPU twin.

Run: python examples/01_score_candidates.py
"""
import numpy as np

from gltrack.body.model import BodyModel
from gltrack.camera import depth_camera_sr4000
from gltrack.gl.context import capabilities, create_context
from gltrack.render import reference as ref
from gltrack.render.engine import ScoringEngine


def main():
    rng = np.random.default_rng(0)
    body = BodyModel.build()
    cam = depth_camera_sr4000(eye=(0.3, 1.0, 3.0), target=(0.0, 0.9, 0.0))
    truth = body.dofs.zero(body.skeleton)
    truth[body.dofs.index("l_shoulder_rz")] = -1.0
    obs, _ = ref.render_candidates(body.mesh, body.skinning(truth), cam.K, cam.R, cam.t,
                                   cam.width, cam.height)
    # 64 candidates around the truth; candidate 0 is the truth itself.
    cands = truth + rng.normal(size=(64, body.dofs.size)) * body.dofs.sigma30 * 2
    cands[0] = truth
    ctx = create_context()
    print("GL:", capabilities(ctx).renderer)
    with ScoringEngine(ctx, body.mesh, body.skeleton.n_joints, [cam], tile=64) as eng:
        eng.set_depth(0, obs[0])
        scores = eng.score(body.skinning(cands), ["depth"])[:, 0, 0]
    print(f"best candidate: {int(np.argmin(scores))} (the truth is 0), cost {scores.min():.1f}, "
          f"median {np.median(scores):.1f}")
    # The same cost on the CPU for the first 3 candidates.
    small = cam.scaled(64, 64)
    import cv2

    obs64 = cv2.resize(obs[0].astype(np.float32), (64, 64), interpolation=cv2.INTER_NEAREST)
    z, _ = ref.render_candidates(body.mesh, body.skinning(cands[:3]), small.K, small.R, small.t, 64, 64)
    cpu = [ref.depth_cost(z[i], obs64) for i in range(3)]
    print("GPU:", np.round(scores[:3], 2), " CPU:", np.round(cpu, 2))
    ctx.release()
    return int(np.argmin(scores))


if __name__ == "__main__":
    main()
