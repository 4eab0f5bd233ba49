"""Every method tracks a dataset that has no body record and no ground truth: the defaults
(--body estimate, --init auto) need neither (issue 12). The runs are short; the accuracy of the
estimate and of the start have tests of their own (test_body_estimate, test_track_*)."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gltrack.bench.multiview import RING, render_dataset
from gltrack.bench.rigs import ring_cameras
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.data.results import load_body_record, load_results

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset, smooth_motion  # noqa: E402

FRAMES = 3


def _strip(path):
    """Remove what a real recording lacks: meta.json's body record and groundtruth.npz."""
    meta = json.loads((path / "meta.json").read_text())
    meta.pop("body", None)
    (path / "meta.json").write_text(json.dumps(meta))
    (path / "groundtruth.npz").unlink()
    return path


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from gltrack.bench.vlmm import periodic_motion
    from gltrack.motion.behaviour import BehaviourModel

    root = tmp_path_factory.mktemp("nothing")
    make_depth_dataset(root / "depth", n=FRAMES)
    body = BodyModel.build()
    P = smooth_motion(body, FRAMES, np.random.default_rng(0))
    cams = ring_cameras((0.0, 0.9, 0.0), **dict(RING, radius=3.0))
    render_dataset(root / "mv", body, P, cams, 30.0, np.random.default_rng(1))
    b25 = BodyModel.build(preset="25", lod=0)
    model = BehaviourModel.fit(periodic_motion(b25, 120), 30.0, np.random.default_rng(0),
                               holdout=0.0, dof_names=b25.dofs.names[6:])
    model.save(root / "model.npz")
    return {"depth": _strip(root / "depth"), "multiview": _strip(root / "mv"),
            "model": root / "model.npz", "truth": body, "P": P}


RUNS = {  # method -> (rig, extra CLI arguments: small budgets, the model a method needs)
    "hc": ("depth", []), "ep": ("depth", []), "hc+ep": ("depth", []),
    "hps": ("multiview", ["--particles", "40"]),
    "sir": ("multiview", ["--particles", "100"]),
    "apf": ("multiview", ["--particles", "30", "--layers", "3"]),
    "ps": ("multiview", ["--particles", "20"]),
    "vlmm": ("multiview", ["--particles", "60", "--dof", "25"]),
    "condensation": ("multiview", ["--particles", "200"]),
    "apf-blobs": ("multiview", ["--particles", "60", "--layers", "2"]),
}
FAST = ("hc", "hps")  # one per rig in the default suite; the others are marked slow


@pytest.mark.parametrize("method", [m if m in FAST else pytest.param(m, marks=pytest.mark.slow)
                                    for m in RUNS])
def test_every_method_starts_from_nothing(data, method, tmp_path):
    rig, extra = RUNS[method]
    if method == "vlmm":
        extra = extra + ["--behaviour", str(data["model"])]
    out = tmp_path / "res"
    assert main(["-q", "track", str(data[rig]), "--method", method, "--out", str(out),
                 *extra]) == 0
    res = load_results(out)
    assert res["params"].shape[0] == FRAMES and np.all(np.isfinite(res["joints"]))
    body, rec = load_body_record(out)
    assert rec["source"] == "estimate" and len(rec["estimate"]["frames"]) >= 1
    # a person-sized body standing where the subject is (the subject: 1.75 m, at the origin)
    assert 1.4 < body.skeleton.height() < 2.1
    truth = data["truth"].joints(data["P"])[:, 0]
    assert np.linalg.norm(res["joints"][:, 0] - truth, axis=1).mean() < 0.3
    # eval without ground truth summarises the fit instead of failing
    if rig == "multiview":
        assert main(["-q", "eval", str(out), str(data[rig])]) == 0
