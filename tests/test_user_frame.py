"""Results and exports in the user's frame (a dataset whose meta.json has a "world" record).

The dataset with a user frame is a small synthetic depth dataset plus the record ``gltrack
ingest`` writes for a Z-up calibration: its cameras and ground truth are internal (+Y up), as
ingest leaves them, and only ``meta.json`` says that the user's frame is Z-up. The same
dataset without the record is the reference: tracking sees identical data, so every
user-frame output must be the reference's rotated by ``R_user_from_internal``, and everything
that is Y-up by convention (params, BVH, GLB, overlay) must be byte-identical.
"""
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from gltrack.cli import main
from gltrack.data.results import load_results
from gltrack.data.world import world_meta
from gltrack.export import opensim_axes, read_trc

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset  # noqa: E402

N = 4
WORLD = world_meta("z")
#: run.json records the rotation (the floor's height is the dataset's business)
RUN_WORLD = {k: WORLD[k] for k in ("up", "R_user_from_internal")}
R = np.array(WORLD["R_user_from_internal"])  # X_user = R @ X_internal


def _track(ds, out, *extra):
    args = ["-q", "track", str(ds), "--method", "hc", "--out", str(out), "--init", "groundtruth",
            "--body", "dataset", *extra]
    assert main(args) == 0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("userframe")
    body, P = make_depth_dataset(root / "ds", n=N)
    shutil.copytree(root / "ds", root / "ds_z")
    meta = json.loads((root / "ds_z" / "meta.json").read_text())
    meta["world"] = WORLD
    (root / "ds_z" / "meta.json").write_text(json.dumps(meta))
    # both runs are interrupted after 2 frames and resumed: --resume keeps working (a resumed
    # run restarts the tracker's state, so the reference is resumed the same way); without
    # --frames a resume tracks the range run.json records, so the longer range is given
    for ds, res in (("ds", "res"), ("ds_z", "res_z")):
        _track(root / ds, root / res, "--frames", "0:2")
        _track(root / ds, root / res, "--resume", "--frames", f"0:{N}")
    return {"root": root, "body": body, "P": P, "res": root / "res", "res_z": root / "res_z",
            "ds": root / "ds", "ds_z": root / "ds_z"}


def test_results_are_the_reference_rotated_into_the_user_frame(runs):
    ref, res = load_results(runs["res"]), load_results(runs["res_z"])
    assert ref["world"] is None
    assert res["world"] == RUN_WORLD
    assert res["frame"].tolist() == list(range(N))
    np.testing.assert_array_equal(res["params"], ref["params"])  # params stay internal
    body = runs["body"]
    for key, fk in (("joints", body.joints), ("markers", body.marker_positions)):
        np.testing.assert_allclose(res[key], ref[key] @ R.T, atol=1e-12)
        # the user-frame truth of the tracked pose
        np.testing.assert_allclose(res[key], fk(res["params"]) @ R.T, atol=1e-6)
    # Z-up: the user's z is the height above the floor (the internal y)
    pelvis = list(res["joint_names"]).index("pelvis")
    np.testing.assert_allclose(res["joints"][:, pelvis, 2], ref["joints"][:, pelvis, 1])
    # frames.jsonl holds user-frame joints too
    rec = json.loads((runs["res_z"] / "frames.jsonl").read_text().splitlines()[0])
    np.testing.assert_allclose(rec["joints"], res["joints"][0], atol=1e-12)
    assert json.loads((runs["res_z"] / "run.json").read_text())["world"] == RUN_WORLD
    # the runner's BVH is Y-up (internal): the same file as the reference's
    assert (runs["res_z"] / "poses.bvh").read_bytes() == (runs["res"] / "poses.bvh").read_bytes()


def test_trc_is_pose2sim_convention_and_calibration_axes_on_request(runs, tmp_path):
    res = load_results(runs["res_z"])
    trc = tmp_path / "m.trc"
    assert main(["-q", "export", str(runs["res_z"]), "--out", str(trc),
                 "--dataset", str(runs["ds_z"])]) == 0
    t = read_trc(trc)
    assert t["units"] == "m"
    # Pose2Sim's zup2yup: X, Y, Z = the calibration's y, z, x
    expect = res["markers"][..., [1, 2, 0]]
    np.testing.assert_allclose(t["points"], expect, atol=1e-6)
    np.testing.assert_allclose(t["points"], res["markers"] @ opensim_axes("z").T, atol=1e-6)
    cal = tmp_path / "cal.trc"
    assert main(["-q", "export", str(runs["res_z"]), "--out", str(cal), "--trc-axes",
                 "calibration", "--units", "mm", "--points", "joints"]) == 0
    t = read_trc(cal)
    assert t["units"] == "mm" and t["names"] == list(res["joint_names"])
    np.testing.assert_allclose(t["points"], 1000 * res["joints"], atol=1e-3)


def test_json_bvh_glb_exports(runs, tmp_path):
    out = {}
    for run in ("res", "res_z"):
        for fmt in ("json", "bvh", "glb"):
            (tmp_path / run).mkdir(exist_ok=True)
            path = tmp_path / run / f"motion.{fmt}"  # the same name: GLB records it
            assert main(["-q", "export", str(runs[run]), "--out", str(path)]) == 0
            out[run, fmt] = path.read_bytes()
    doc, ref = json.loads(out["res_z", "json"]), json.loads(out["res", "json"])
    assert "world" not in ref and doc["world"] == RUN_WORLD and "user" in doc["axes"]
    res = load_results(runs["res_z"])
    np.testing.assert_allclose([f["joints"] for f in doc["frames"]], res["joints"], atol=1e-12)
    np.testing.assert_allclose([f["markers"] for f in doc["frames"]], res["markers"], atol=1e-12)
    assert [f["params"] for f in doc["frames"]] == [f["params"] for f in ref["frames"]]
    # Y-up by convention: written in the internal frame, identical to the reference
    assert out["res_z", "bvh"] == out["res", "bvh"]
    assert out["res_z", "glb"] == out["res", "glb"]


def test_eval_compares_like_with_like(runs, tmp_path, capsys):
    m = {}
    for run, ds in (("res", "ds"), ("res_z", "ds_z")):
        path = tmp_path / f"{run}.json"
        assert main(["-q", "eval", str(runs[run]), str(runs[ds]), "--json", str(path)]) == 0
        m[run] = json.loads(path.read_text())
    for key in ("mean_joint_error_mm", "mpjpe_mm", "pa_mpjpe_mm", "marker_mean_m"):
        assert m["res_z"][key] == pytest.approx(m["res"][key], abs=1e-6), key
    assert m["res"]["mean_joint_error_mm"] < 40  # a tracked result, not noise
    # a result of one frame against the dataset of another is refused, naming the field
    capsys.readouterr()
    assert main(["eval", str(runs["res"]), str(runs["ds_z"])]) != 0
    assert "world" in capsys.readouterr().err


def test_overlay_is_unchanged(runs):
    from gltrack.eval.overlay import OverlayRenderer

    with OverlayRenderer(runs["res"], runs["ds"]) as a, \
            OverlayRenderer(runs["res_z"], runs["ds_z"]) as b:
        assert len(a) == len(b) == N
        for i in (0, N - 1):
            np.testing.assert_array_equal(a.frame(i), b.frame(i))
            assert b.frame_error(i) == pytest.approx(a.frame_error(i), abs=1e-9)
        assert np.isfinite(b.frame_error(0))


def test_opensim_axes_put_up_on_y_and_are_rotations():
    from gltrack.data.world import AXES, axis_vector

    for up in AXES:
        M = opensim_axes(up)
        np.testing.assert_array_equal(M @ axis_vector(up), [0, 1, 0])
        np.testing.assert_allclose(M @ M.T, np.eye(3))
        assert np.linalg.det(M) == pytest.approx(1.0)
    np.testing.assert_array_equal(opensim_axes("y"), np.eye(3))
    np.testing.assert_array_equal(opensim_axes("z") @ [1, 2, 3], [2, 3, 1])  # Pose2Sim zup2yup
    with pytest.raises(ValueError, match="up axis"):
        opensim_axes("w")
