"""``gltrack eval --reference``: a tracked take against an independent 3-D reconstruction."""
import json

import numpy as np
import pytest

from gltrack.cli import main
from gltrack.eval.reference import (COMPARED, compare_reference, joint_key, load_reference,
                                    reference_table)
from gltrack.export import trc_frame
from gltrack.export.trc import format_trc

from test_eval import make_dataset_and_result

#: Pose2Sim's (HALPE/COCO/BODY_25) spelling of the compared joints, and two it also writes
P2S = {"l_hip": "LHip", "r_hip": "RHip", "l_knee": "LKnee", "r_knee": "RKnee",
       "l_ankle": "LAnkle", "r_ankle": "RAnkle", "l_shoulder": "LShoulder",
       "r_shoulder": "RShoulder", "l_elbow": "LElbow", "r_elbow": "RElbow", "l_wrist": "LWrist",
       "r_wrist": "RWrist"}
NAMES = ["pelvis", "head"] + list(COMPARED)


def z_up_result(rng, T=8):
    """A result in a Z-up user frame (as ``gltrack ingest`` of a Pose2Sim calibration gives)."""
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # internal +Y up -> user +Z up
    joints = rng.normal(scale=0.5, size=(T, len(NAMES), 3)) + [0.0, 0.0, 1.0]
    return {"joints": joints, "joint_names": NAMES, "frame": np.arange(T) + 3,
            "world": {"up": "z", "R_user_from_internal": R}}


def write_reference(path, result, joints, fps, frames, axes="opensim", units="mm",
                    names=None, extra=True):
    """Joints (T, 12, 3) in the result's frame -> a TRC as Pose2Sim writes it."""
    names = names or [P2S[j] for j in COMPARED]
    pts = joints @ trc_frame(result, axes).T
    if extra:  # a marker that is not compared
        names = names + ["Nose"]
        pts = np.concatenate([pts, pts[:, :1] + 0.1], axis=1)
    path.write_text(format_trc(names, pts, fps, frames, units=units))
    return path


def truth_of(result):
    cols = [NAMES.index(j) for j in COMPARED]
    return result["joints"][:, cols].copy()


def test_joint_names_match_whatever_their_spelling():
    for spelling in ("LHip", "L_Hip", "left_hip", "LeftHip", "l_hip", "l-hip", "Left Hip"):
        assert joint_key(spelling) == "lhip", spelling
    assert joint_key("RWrist") == joint_key("r_wrist") != joint_key("l_wrist")
    assert joint_key("LHip") != joint_key("LKnee")


@pytest.mark.parametrize("axes,units", [("opensim", "mm"), ("calibration", "m")])
def test_reference_in_either_axes_lands_on_the_result(tmp_path, axes, units):
    """A reconstruction holding the result's own joints is 0 mm away; moved by 3 cm it is 30 mm
    away, whatever the file's axes and units, and its rows land on the right frames."""
    rng = np.random.default_rng(0)
    res = z_up_result(rng)
    fps = 60.0
    ref_joints = truth_of(res)[2:6]                      # result rows 2..5 = frames 5..8
    p = write_reference(tmp_path / "r.trc", res, ref_joints, fps, res["frame"][2:6], axes,
                        units)
    ref = load_reference(p, res, fps, axes=axes)
    assert ref["names"] == list(COMPARED) and ref["missing"] == []
    assert ref["frame"].tolist() == [5, 6, 7, 8]
    np.testing.assert_allclose(ref["joints"], ref_joints, atol=1e-5)
    assert compare_reference(res, ref)["median_mm"] == pytest.approx(0.0, abs=0.01)
    moved = ref_joints + np.array([0.0, 0.03, 0.0])
    p = write_reference(tmp_path / "m.trc", res, moved, fps, res["frame"][2:6], axes, units)
    cmp = compare_reference(res, load_reference(p, res, fps, axes=axes))
    assert cmp["frames"] == 4 and cmp["median_mm"] == pytest.approx(30.0, abs=0.01)
    assert all(v["n"] == 4 and v["mean_mm"] == pytest.approx(30.0, abs=0.01)
               for v in cmp["joints"].values())
    assert cmp["per_frame"]["frame"] == [5, 6, 7, 8]
    # the wrong axes put it somewhere else: the axes matter
    wrong = "calibration" if axes == "opensim" else "opensim"
    assert compare_reference(res, load_reference(p, res, fps, axes=wrong))["median_mm"] > 100


def test_exchanged_limbs_and_missing_joints_are_reported(tmp_path):
    rng = np.random.default_rng(1)
    res = z_up_result(rng)
    truth = truth_of(res)
    mirror = [COMPARED.index(("r_" if j.startswith("l_") else "l_") + j[2:]) for j in COMPARED]
    ex = truth[:, mirror]          # the result has left and right the wrong way round
    ex[:4] = truth[:4]             # ... from frame 4 on
    p = write_reference(tmp_path / "x.trc", res, ex, 30.0, res["frame"])
    cmp = compare_reference(res, load_reference(p, res, 30.0))
    assert cmp["exchanged_frames"] == pytest.approx(0.5)
    # a file without the wrists and with gaps (empty fields) compares what it has
    keep = [j for j in COMPARED if "wrist" not in j]
    sub = truth[:, [COMPARED.index(j) for j in keep]]
    sub[0, 0] = np.nan
    p = write_reference(tmp_path / "s.trc", res, sub, 30.0, res["frame"],
                        names=[P2S[j] for j in keep], extra=False)
    ref = load_reference(p, res, 30.0)
    assert ref["missing"] == ["l_wrist", "r_wrist"]
    cmp = compare_reference(res, ref)
    assert cmp["joints"]["l_hip"]["n"] == 7 and cmp["joints"]["r_hip"]["n"] == 8
    assert "l_wrist" not in cmp["joints"] and cmp["median_mm"] == pytest.approx(0, abs=0.01)
    text = reference_table(cmp)
    assert "l_hip" in text and "not in the file: l_wrist, r_wrist" in text


def test_bad_references_name_the_file_and_the_field(tmp_path):
    rng = np.random.default_rng(2)
    res = z_up_result(rng)
    truth = truth_of(res)
    p = write_reference(tmp_path / "n.trc", res, truth, 30.0, res["frame"],
                        names=[f"m{i}" for i in range(12)], extra=False)
    with pytest.raises(ValueError, match="n.trc: no marker named like a hip"):
        load_reference(p, res, 30.0)
    p = write_reference(tmp_path / "u.trc", res, truth, 30.0, res["frame"])
    p.write_text(p.read_text().replace("\tmm\t", "\tinches\t", 1))
    with pytest.raises(ValueError, match="u.trc: field 'Units'"):
        load_reference(p, res, 30.0)
    p = write_reference(tmp_path / "t.trc", res, truth, 30.0, res["frame"])
    with pytest.raises(ValueError, match="t.trc: column 'Time' does not fall"):
        load_reference(p, res, 45.0)   # 1/30 s at 45 frames/s is 1.5 frames
    p = write_reference(tmp_path / "f.trc", res, truth, 30.0, res["frame"] + 100)
    with pytest.raises(ValueError, match="f.trc: none of its frames"):
        compare_reference(res, load_reference(p, res, 30.0))
    (tmp_path / "c.csv").write_text("x\n")
    with pytest.raises(ValueError, match="must be a .trc file"):
        load_reference(tmp_path / "c.csv", res, 30.0)


@pytest.mark.parametrize("with_gt", [False, True])
def test_cli_eval_reference(tmp_path, capsys, with_gt):
    """The CLI prints the table and writes it to the JSON, with or without ground truth; a
    dataset given as a file, or a bad reference, is a one-line usage error."""
    res, ds = make_dataset_and_result(tmp_path, 0.0, with_gt=with_gt)
    from gltrack.data.results import load_results

    result = load_results(res)
    cols = [list(result["joint_names"]).index(j) for j in COMPARED]
    ref = np.asarray(result["joints"])[:, cols] + np.array([0.02, 0.0, 0.0])
    trc = write_reference(tmp_path / "ref.trc", result, ref, 30.0, result["frame"])
    j = tmp_path / "m.json"
    assert main(["eval", str(res), str(ds), "--reference", str(trc), "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "against the reconstruction" in out and "l_wrist" in out
    data = json.loads(j.read_text())["reference"]
    assert data["median_mm"] == pytest.approx(20.0, abs=0.01)
    assert data["frames"] == len(result["frame"])
    assert main(["eval", str(res), str(ds), "--reference", str(tmp_path / "no.trc")]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.trc"
    bad.write_text("not a trc\n")
    assert main(["eval", str(res), str(ds), "--reference", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.trc" in err and len(err.strip().splitlines()) == 1
