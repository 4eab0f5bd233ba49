"""03 - Synthesise a short 4-camera sequence and track it with hierarchical partitioned sampling.

Bandouch & Beetz's tracker: silhouettes from background subtraction, HLS colour bitmasks, the
hierarchical parallel-partition particle filter (``hps``).

Run: python examples/03_track_multiview.py [OUT_DIR]
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
    out = Path(out or tempfile.mkdtemp(prefix="gltrack-ex03-"))
    body = BodyModel.build()
    params = performance(body, fps=15.0, seconds=0.6)
    ds = synthesize_in_subprocess(params, body.skeleton, body.dofs, 15.0, "multiview", str(out / "data"),
                                  seed=2, size=(240, 180), progress=False, overwrite=True)
    timing = track(ds, "hps", out / "result", options={"particles": 100}, overwrite=True, progress=False)
    m = evaluate(load_results(out / "result"), Dataset.open(ds).groundtruth())
    print(f"tracked {timing['frames']} frames ({timing['evaluations'] // timing['frames']} evaluations each): "
          f"mean joint error {m['mean_joint_error_mm']:.0f} mm, MPJPE {m['mpjpe_mm']:.0f} mm")
    return m


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
