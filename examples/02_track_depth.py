"""02 - Synthesise a short depth sequence and track it with hill climbing (Ganapathi et al.).

Run: python examples/02_track_depth.py [OUT_DIR]
"""
import sys
import tempfile
from pathlib import Path

from gltrack.body.model import BodyModel
from gltrack.data.dataset import Dataset
from gltrack.data.procedural import performance
from gltrack.data.results import load_results
from gltrack.data.simulate import synthesize_in_subprocess
from gltrack.eval.metrics import evaluate
from gltrack.track.runner import track


def main(out=None):
    out = Path(out or tempfile.mkdtemp(prefix="gltrack-ex02-"))
    body = BodyModel.build()
    params = performance(body, fps=15.0, seconds=1.0)  # the walking part of the demo performance
    # The simulator renders with pyrender (an independent renderer) in a child process, so its
    # GL context never meets gltrack's.
    ds = synthesize_in_subprocess(params, body.skeleton, body.dofs, 15.0, "depth", str(out / "data"),
                                  seed=1, progress=False, overwrite=True)
    timing = track(ds, "hc", out / "result", overwrite=True, progress=False)
    m = evaluate(load_results(out / "result"), Dataset.open(ds).groundtruth())
    print(f"tracked {timing['frames']} frames at {timing['fps']:.1f} frames/s: mean joint error "
          f"{m['mean_joint_error_mm']:.0f} mm, markers within 10 cm {100 * m['frac_markers_tracked']:.0f} %")
    print(f"results in {out / 'result'} (poses.npz, poses.bvh, frames.jsonl)")
    return m


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
