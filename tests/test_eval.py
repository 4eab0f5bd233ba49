"""Evaluation metrics, reports and ``gltrack eval`` end to end."""
import csv
import json

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from gltrack.body.dofs import make_dofs
from gltrack.body.kinematics import Kinematics
from gltrack.body.skeleton import JOINT_NAMES, default_skeleton
from gltrack.cli import main
from gltrack.eval import metrics as M
from gltrack.eval import report

N = 6


def motion(rng, n=N):
    """Joint trajectories of the real skeleton in random poses, (n, 19, 3) metres."""
    sk = default_skeleton(1.75)
    dofs = make_dofs(sk, "full")
    kin = Kinematics(sk, dofs)
    params = np.tile(dofs.zero(sk), (n, 1))
    params[:, 6:] = rng.normal(scale=0.3, size=(n, dofs.size - 6))
    params[:, :3] += rng.normal(scale=0.5, size=(n, 3))
    return params, kin.forward(params).positions


def gt_dict(rng, n=N):
    params, joints = motion(rng, n)
    markers = joints[:, ::2] + rng.normal(scale=0.05, size=joints[:, ::2].shape)
    return {"joints": joints, "joint_names": list(JOINT_NAMES), "markers": markers,
            "marker_names": [f"m{i}" for i in range(markers.shape[1])], "params": params}


def result_from(gt, joints=None, markers=None):
    j = gt["joints"] if joints is None else joints
    return {"joints": j, "joint_names": gt["joint_names"],
            "markers": gt["markers"] if markers is None else markers,
            "marker_names": gt["marker_names"], "params": gt["params"],
            "frame": np.arange(len(j)), "method": "test"}


def test_groundtruth_against_itself_is_zero():
    gt = gt_dict(np.random.default_rng(0))
    m = M.evaluate(result_from(gt), gt)
    for key in ("mean_joint_error_mm", "mpjpe_mm", "marker_mean_m", "marker_max_m",
                "frac_markers_failed"):
        assert m[key] == 0.0, key
    assert m["pa_mpjpe_mm"] == pytest.approx(0.0, abs=1e-9)
    assert m["frac_markers_tracked"] == 1.0 and m["frames"] == N
    assert set(M.SUMMARY_KEYS) <= set(m)
    assert m["joints"] == list(M.EVAL_JOINTS)  # all 15 present, spine/clavicles left out
    assert m["marker_source"] == "markers"


def test_constant_offset():
    gt = gt_dict(np.random.default_rng(1))
    off = np.array([0.03, 0.0, 0.04])  # |off| = 0.05 m
    m = M.evaluate(result_from(gt, gt["joints"] + off, gt["markers"] + off), gt)
    assert m["mean_joint_error_mm"] == pytest.approx(50.0, abs=1e-9)
    assert m["mpjpe_mm"] == pytest.approx(0.0, abs=1e-9)
    assert m["pa_mpjpe_mm"] == pytest.approx(0.0, abs=1e-6)
    assert m["marker_mean_m"] == pytest.approx(0.05) and m["marker_max_m"] == pytest.approx(0.05)
    assert m["frac_markers_tracked"] == 1.0 and m["frac_markers_failed"] == 0.0
    np.testing.assert_allclose(m["per_frame"]["joint_error_mm"], 50.0)
    # Thresholds: 0.2 m is neither tracked nor failed, 0.35 m is failed.
    m2 = M.evaluate(result_from(gt, markers=gt["markers"] + [0.2, 0, 0]), gt)
    assert (m2["frac_markers_tracked"], m2["frac_markers_failed"]) == (0.0, 0.0)
    m3 = M.evaluate(result_from(gt, markers=gt["markers"] + [0, 0.35, 0]), gt)
    assert (m3["frac_markers_tracked"], m3["frac_markers_failed"]) == (0.0, 1.0)


def test_errors_match_a_loop_implementation():
    rng = np.random.default_rng(2)
    gt = gt_dict(rng)
    pred = gt["joints"] + rng.normal(scale=0.04, size=gt["joints"].shape)
    pm = gt["markers"] + rng.normal(scale=0.15, size=gt["markers"].shape)
    m = M.evaluate(result_from(gt, pred, pm), gt)
    idx = [JOINT_NAMES.index(n) for n in M.EVAL_JOINTS]
    root = JOINT_NAMES.index("pelvis")
    je, mp, mmean, mmax, tracked, failed, count = [], [], [], [], 0, 0, 0
    for f in range(N):
        je.append(np.mean([np.linalg.norm(pred[f, j] - gt["joints"][f, j]) for j in idx]))
        mp.append(np.mean([np.linalg.norm((pred[f, j] - pred[f, root])
                                          - (gt["joints"][f, j] - gt["joints"][f, root]))
                           for j in idx]))
        d = [np.linalg.norm(pm[f, k] - gt["markers"][f, k]) for k in range(pm.shape[1])]
        mmean.append(np.mean(d))
        mmax.append(max(d))
        tracked += sum(x <= 0.1 for x in d)
        failed += sum(x >= 0.3 for x in d)
        count += len(d)
    assert m["mean_joint_error_mm"] == pytest.approx(1000 * np.mean(je))
    assert m["mpjpe_mm"] == pytest.approx(1000 * np.mean(mp))
    assert m["marker_mean_m"] == pytest.approx(np.mean(mmean))
    assert m["marker_max_m"] == pytest.approx(np.mean(mmax))
    assert m["frac_markers_tracked"] == pytest.approx(tracked / count)
    assert m["frac_markers_failed"] == pytest.approx(failed / count)
    assert 0 < tracked < count and 0 < failed < count  # the thresholds were actually exercised
    assert m["mpjpe_mm"] != pytest.approx(m["mean_joint_error_mm"])


def test_pa_mpjpe_invariant_to_similarity_and_matches_optimiser():
    rng = np.random.default_rng(3)
    gt = gt_dict(rng)["joints"]
    pred = gt + rng.normal(scale=0.03, size=gt.shape)
    base = M.pa_mpjpe(pred, gt)
    R = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    moved = 1.7 * pred @ R.T + np.array([2.0, -1.0, 0.5])
    np.testing.assert_allclose(M.pa_mpjpe(moved, gt), base, atol=1e-12)
    assert np.all(M.mean_joint_error(moved, gt) > 10 * base)  # unaligned error does change
    # Independent check on frame 0: minimise the mean error over rotation, scale and translation
    # numerically. Procrustes minimises squared error, so the optimum of the *mean* distance is
    # at most as large, and close to it.
    p, g = moved[0], gt[0]

    def mean_err(x):
        rot = Rotation.from_rotvec(x[:3]).as_matrix()
        return np.linalg.norm(x[3] * p @ rot.T + x[4:] - g, axis=1).mean()

    x0 = np.r_[Rotation.from_matrix(R.T).as_rotvec(), 1 / 1.7, np.zeros(3)]
    x0[4:] = g.mean(0) - x0[3] * (p @ R).mean(0)
    best = minimize(mean_err, x0, method="Nelder-Mead",
                    options={"maxiter": 20000, "xatol": 1e-10, "fatol": 1e-12}).fun
    assert best <= base[0] + 1e-9
    assert base[0] == pytest.approx(best, rel=0.1)


def test_pa_never_mirrors():
    gt = gt_dict(np.random.default_rng(4))["joints"]
    mirrored = gt * np.array([-1.0, 1.0, 1.0])
    assert np.all(M.pa_mpjpe(mirrored, gt) > 1e-3)


def test_nan_groundtruth_is_ignored_and_missing_markers_fall_back():
    rng = np.random.default_rng(5)
    gt = gt_dict(rng)
    pred = gt["joints"].copy()
    pred[:, JOINT_NAMES.index("head")] += 1.0   # only the head is wrong ...
    gt["joints"] = gt["joints"].copy()
    gt["joints"][:, JOINT_NAMES.index("head")] = np.nan  # ... and unobserved
    gt["markers"] = None
    m = M.evaluate(result_from(gt, pred), gt)
    assert m["mean_joint_error_mm"] == 0.0
    assert m["marker_source"] == "joints" and m["marker_mean_m"] == 0.0


def test_joint_subset_and_frame_mapping():
    rng = np.random.default_rng(6)
    gt = gt_dict(rng, n=10)
    pred = gt["joints"][4:7].copy()
    pred[:, JOINT_NAMES.index("spine_upper")] += 5.0  # not an evaluated joint
    res = result_from(gt, pred, gt["markers"][4:7])
    res["frame"] = np.array([4, 5, 6])
    m = M.evaluate(res, gt)
    assert m["frames"] == 3 and m["mean_joint_error_mm"] == 0.0
    res["frame"] = np.array([5, 6, 7])  # shifted by one frame: now it must show an error
    assert M.evaluate(res, gt)["mean_joint_error_mm"] > 1.0
    res["frame"] = np.array([8, 9, 10])
    with pytest.raises(ValueError, match="exceed"):
        M.evaluate(res, gt)


def test_per_joint_errors_say_where_the_error_is():
    rng = np.random.default_rng(9)
    gt = gt_dict(rng)
    pred = gt["joints"].copy()
    w = JOINT_NAMES.index("l_wrist")
    pred[:, w, 0] += np.linspace(0.1, 0.3, N)  # the left wrist 100..300 mm off along x
    pred[2, JOINT_NAMES.index("r_knee")] = np.nan  # one missing observation
    m = M.evaluate(result_from(gt, pred), gt)
    pj = m["per_joint"]
    assert list(pj) == m["joints"]
    assert pj["l_wrist"]["mean_mm"] == pytest.approx(200.0)
    assert pj["l_wrist"]["max_mm"] == pytest.approx(300.0)
    assert all(v["mean_mm"] == 0.0 for k, v in pj.items() if k != "l_wrist")
    # the joints' means over the frames average to the mean joint error when nothing is missing
    pred[2, JOINT_NAMES.index("r_knee")] = gt["joints"][2, JOINT_NAMES.index("r_knee")]
    m = M.evaluate(result_from(gt, pred), gt)
    assert np.mean([v["mean_mm"] for v in m["per_joint"].values()]) == \
        pytest.approx(m["mean_joint_error_mm"])
    table = report.summary_table(m)
    assert "(worst: l_wrist 200)" in table and " r_ankle 0" in table
    assert all(len(line) <= 96 for line in table.splitlines() if line.startswith("  "))
    assert json.loads(json.dumps(report.to_jsonable(m)))["per_joint"]["l_wrist"]["max_mm"] == \
        pytest.approx(300.0)


def test_per_joint_lines_without_a_value():
    lines = report.per_joint_lines({"a": {"mean_mm": float("nan"), "max_mm": float("nan")},
                                    "b": {"mean_mm": 12.4, "max_mm": 20.0}})
    assert lines[0].endswith("(worst: b 12):") and lines[1] == "  a n/a b 12"


def test_reports(tmp_path):
    rng = np.random.default_rng(7)
    gt = gt_dict(rng)
    pred = gt["joints"] + rng.normal(scale=0.02, size=gt["joints"].shape)
    m = M.evaluate(result_from(gt, pred), gt)
    table = report.summary_table(m)
    assert f"{m['mean_joint_error_mm']:.1f}" in table and "PA-MPJPE" in table
    report.write_csv(m, tmp_path / "e.csv")
    rows = list(csv.DictReader(open(tmp_path / "e.csv")))
    assert len(rows) == N and int(rows[2]["frame"]) == 2
    assert float(rows[2]["joint_error_mm"]) == pytest.approx(m["per_frame"]["joint_error_mm"][2],
                                                             rel=1e-5)
    report.plot_errors(m, tmp_path / "e.png", title="t", fps=30)
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _heading_joints(joints):
    idx = [list(JOINT_NAMES).index(j) for j in M.HEADING_JOINTS]
    return joints[:, idx]


@pytest.mark.parametrize("up", ["y", "z"])
def test_heading_error_of_a_body_turned_about_its_trunk(up):
    """Each frame's body turned about its own trunk axis by a known angle: the metric gives
    that angle (the twin 180), whatever the world's up axis and wherever the body stands; the
    same joints give 0, and a move without a turn gives 0 too."""
    rng = np.random.default_rng(3)
    _, joints = motion(rng, 8)
    if up == "z":  # the same bodies in a Z-up world
        joints = joints @ Rotation.from_euler("x", 90, degrees=True).as_matrix().T
    J = list(JOINT_NAMES)
    angles = np.array([0.0, 10.0, 45.0, 89.0, 91.0, 135.0, 179.0, 180.0])
    turned = joints.copy()
    for i, a in enumerate(angles):
        pel, neck = joints[i, J.index("pelvis")], joints[i, J.index("neck")]
        axis = (neck - pel) / np.linalg.norm(neck - pel)
        R = Rotation.from_rotvec(np.radians(a) * axis).as_matrix()
        turned[i] = (joints[i] - pel) @ R.T + pel + rng.normal(scale=0.5, size=3)
    deg = M.heading_errors(_heading_joints(turned), _heading_joints(joints))
    np.testing.assert_allclose(deg, angles, atol=1e-6)
    np.testing.assert_allclose(M.heading_errors(_heading_joints(joints),
                                                _heading_joints(joints)), 0.0, atol=1e-5)
    gt = {"joints": joints, "joint_names": list(JOINT_NAMES)}
    m = M.evaluate({"joints": turned, "joint_names": list(JOINT_NAMES)}, gt)
    assert m["heading_error_deg"] == pytest.approx(angles.mean(), abs=1e-6)
    assert m["frac_turned_round"] == pytest.approx(4 / 8)  # 91, 135, 179 and 180 degrees
    np.testing.assert_allclose(m["per_frame"]["heading_error_deg"], angles, atol=1e-6)


def test_heading_error_needs_its_joints():
    """Without a shoulder the heading is not scored (NaN, n/a in the table), and a missing
    (NaN) joint in one frame leaves that frame out of the share."""
    gt = gt_dict(np.random.default_rng(4))
    keep = [j for j in JOINT_NAMES if j != "l_shoulder"]
    idx = [list(JOINT_NAMES).index(j) for j in keep]
    res = {"joints": gt["joints"][:, idx], "joint_names": keep}
    m = M.evaluate(res, {"joints": gt["joints"][:, idx], "joint_names": keep})
    assert np.isnan(m["heading_error_deg"]) and np.isnan(m["frac_turned_round"])
    assert "n/a" in report.summary_table(m).splitlines()[7]
    j = gt["joints"].copy()
    j[0, list(JOINT_NAMES).index("l_hip")] = np.nan  # a joint of the estimate
    g = gt["joints"].copy()
    g[1, list(JOINT_NAMES).index("neck")] = np.nan  # the truth's trunk axis
    h = M.heading_errors(_heading_joints(j), _heading_joints(g))
    assert np.isnan(h[:2]).all() and np.all(np.isfinite(h[2:]))
    m = M.evaluate({"joints": j, "joint_names": list(JOINT_NAMES)},
                   {"joints": g, "joint_names": list(JOINT_NAMES)})
    assert m["frac_turned_round"] == 0.0 and np.isfinite(m["heading_error_deg"])
    with pytest.raises(ValueError, match="heading_errors needs"):
        M.heading_errors(j[:, :5], gt["joints"][:, :5])


def test_error_plot_shades_turned_round_frames(tmp_path):
    """The error plot draws the turned-round frames as a shaded band (one legend entry)."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    gt = gt_dict(np.random.default_rng(5))
    m = M.evaluate(result_from(gt), gt)
    m["per_frame"]["heading_error_deg"] = np.array([0, 0, 120, 150, 0, 0], float)
    saved = plt.Figure.savefig
    spans = []

    def spy(fig, *a, **k):  # count the shaded spans of the figure it saves
        spans.append(sum(len(ax.patches) for ax in fig.axes))
        labels = [t.get_text() for ax in fig.axes if ax.get_legend()
                  for t in ax.get_legend().get_texts()]
        spans.append(sum("turned round" in t for t in labels))
        return saved(fig, *a, **k)

    plt.Figure.savefig = spy
    try:
        report.plot_errors(m, tmp_path / "e.png")
        m["per_frame"]["heading_error_deg"][:] = 0.0
        report.plot_errors(m, tmp_path / "f.png")
    finally:
        plt.Figure.savefig = saved
    assert spans == [2, 1, 0, 0]


# ---- gltrack eval ------------------------------------------------------------------------------
def make_dataset_and_result(tmp_path, offset, with_gt=True, infos=None):
    from gltrack.camera import Camera
    from gltrack.data.dataset import DatasetWriter
    from gltrack.data.results import ResultsWriter

    rng = np.random.default_rng(8)
    gt = gt_dict(rng)
    c = Camera("cam0", "depth", 8, 6, [[8.0, 0, 3.5], [0, 8.0, 2.5], [0, 0, 1]], np.zeros(5),
               np.eye(3), np.array([0.0, 0.0, 3.0]))
    with DatasetWriter(tmp_path / "ds", "depth", 30, [c]) as w:
        for f in range(N):
            w.write_depth(f, 0, np.full((6, 8), 2.0))
        if with_gt:
            w.write_groundtruth(gt["joints"], gt["joint_names"], gt["markers"], gt["params"],
                                marker_names=gt["marker_names"])
    rw = ResultsWriter(tmp_path / "res", "sir", gt["joint_names"], gt["marker_names"])
    for f in range(N):
        rw.append(f, gt["params"][f], gt["joints"][f] + offset, gt["markers"][f] + offset,
                  score=0.0, evaluations=10, seconds=0.1,
                  info=None if infos is None else infos[f])
    rw.finish()
    return tmp_path / "res", tmp_path / "ds"


def test_cli_eval_end_to_end(tmp_path, capsys):
    res, ds = make_dataset_and_result(tmp_path, np.array([0.0, 0.05, 0.0]))
    j, c, p = tmp_path / "m.json", tmp_path / "m.csv", tmp_path / "m.png"
    rc = main(["eval", str(res), str(ds), "--json", str(j), "--csv", str(c), "--plot", str(p)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "50.0" in out and "MPJPE" in out
    data = json.loads(j.read_text())
    assert set(M.SUMMARY_KEYS) <= set(data)
    assert data["mean_joint_error_mm"] == pytest.approx(50.0)
    assert data["mpjpe_mm"] == pytest.approx(0.0, abs=1e-9)
    assert data["frac_markers_tracked"] == 1.0 and data["frames"] == N
    assert len(data["per_frame"]["joint_error_mm"]) == N
    assert len(c.read_text().splitlines()) == N + 1
    assert p.stat().st_size > 1000
    # Without poses.npz (a crashed run) the same numbers come from frames.jsonl.
    (res / "poses.npz").unlink()
    assert main(["eval", str(res), str(ds), "--json", str(j)]) == 0
    assert json.loads(j.read_text())["mean_joint_error_mm"] == pytest.approx(50.0)


def test_cli_eval_errors(tmp_path, capsys):
    res, ds = make_dataset_and_result(tmp_path, 0.0, with_gt=False)
    assert main(["eval", str(res), str(ds), "--plot", str(tmp_path / "p.png")]) == 2
    assert "no groundtruth.npz" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "missing"), str(ds)]) == 1
    err = capsys.readouterr().err
    assert "error:" in err and len(err.strip().splitlines()) == 1
    assert main(["eval", str(res), str(ds), "--json", str(tmp_path / "a"),
                 "--csv", str(tmp_path / "a")]) == 2
    assert main(["eval", str(res)]) == 2


IOUS = [[0.9, 0.8], [0.85, 0.5], [0.95, 0.7], [0.8, 0.75], [0.9, 0.55], [0.7, 0.8]]


def test_cli_eval_without_groundtruth_reports_quality(tmp_path, capsys):
    infos = [{"iou": v, "quality": 0.2} for v in IOUS]
    for k, d in zip((0, 2, 5), (0.04, 0.05, 0.09)):  # the keypoint cue of three frames
        infos[k]["keypoint_m"] = d
    res, ds = make_dataset_and_result(tmp_path, 0.0, with_gt=False, infos=infos)
    j, c = tmp_path / "q.json", tmp_path / "q.csv"
    assert main(["eval", str(res), str(ds), "--json", str(j), "--csv", str(c)]) == 0
    out = capsys.readouterr().out
    assert "no ground truth" in out and "mean IoU" in out and "jitter" in out
    assert "triangulated keypoints [mm]: median 50, mean 60 (3 frames" in out
    assert "cam1" in out and "2 (1, 4)" in out  # frames below 0.6 listed
    q = json.loads(j.read_text())["quality"]
    assert q["iou_mean"] == pytest.approx(np.mean(IOUS, axis=0).tolist())
    assert q["iou_min"] == pytest.approx([0.7, 0.5])
    assert q["iou_frames_below"] == {"cam0": [], "cam1": [1, 4]} and q["iou_frames"] == N
    assert q["jitter_frames"] == N - 2 and q["jitter_mean_mm"] > 0
    assert q["jitter_p95_mm"] >= q["jitter_mean_mm"]
    assert q["keypoint_frames"] == 3 and q["keypoint_mean_mm"] == pytest.approx(60.0)
    rows = list(csv.DictReader(open(c)))
    assert len(rows) == N and float(rows[1]["iou_cam1"]) == pytest.approx(0.5)
    assert float(rows[2]["keypoint_mm"]) == pytest.approx(50.0) and rows[1]["keypoint_mm"] == ""
    assert rows[0]["jitter_mm"] == "" and float(rows[1]["jitter_mm"]) > 0
    # With ground truth the same figures come on top of the joint errors, keys unchanged.
    res2, ds2 = make_dataset_and_result(tmp_path / "gt", 0.0, infos=infos)
    assert main(["eval", str(res2), str(ds2), "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "MPJPE" in out and "mean IoU" in out
    data = json.loads(j.read_text())
    assert set(M.SUMMARY_KEYS) <= set(data) and "joint_error_mm" in data["per_frame"]
    assert data["quality"]["iou_min"] == pytest.approx([0.7, 0.5])


def test_eval_reports_which_side_of_the_silhouette_loses(tmp_path, capsys):
    """With info["model_on_fg"] / info["fg_covered"] recorded, eval prints and writes their
    per-camera means (frames without them left out); a result without them (older runs) keeps
    the IoU-only table and NaN means."""
    on_fg = [[0.9, 0.95], [0.8, None], [0.85, 0.9], [0.9, 0.9], [0.95, 0.85], [0.9, 0.9]]
    covered = [[0.6, 0.7], [0.7, 0.5], [0.65, 0.6], [0.6, 0.7], [0.7, 0.6], [0.6, 0.5]]
    infos = [{"iou": v, "model_on_fg": a, "fg_covered": b} for v, a, b in
             zip(IOUS, on_fg, covered)]
    infos[2] = {"iou": IOUS[2]}  # a frame without the shares
    res, ds = make_dataset_and_result(tmp_path, 0.0, with_gt=False, infos=infos)
    j = tmp_path / "q.json"
    assert main(["eval", str(res), str(ds), "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "model on fg" in out and "fg covered" in out
    q = json.loads(j.read_text())["quality"]
    keep = [0, 1, 3, 4, 5]
    assert q["model_on_fg_mean"][0] == pytest.approx(np.mean([on_fg[i][0] for i in keep]))
    assert q["model_on_fg_mean"][1] == pytest.approx(np.mean([0.95, 0.9, 0.85, 0.9]))
    assert q["fg_covered_mean"] == pytest.approx(np.mean([covered[i] for i in keep], axis=0))
    per = json.loads(j.read_text())["per_frame"]
    assert per["fg_covered_cam1"][1] == pytest.approx(0.5)
    # an older result: IoU only
    res2, ds2 = make_dataset_and_result(tmp_path / "old", 0.0, with_gt=False,
                                        infos=[{"iou": v} for v in IOUS])
    assert main(["eval", str(res2), str(ds2), "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "mean IoU" in out and "model on fg" not in out
    q = json.loads(j.read_text())["quality"]
    assert q["model_on_fg_mean"] == [None, None] and q["fg_covered_mean"] == [None, None]
    # --iou-now needs a body to pose and a dataset folder
    assert main(["eval", str(res2), str(ds2), "--iou-now"]) == 2
    err = capsys.readouterr().err
    assert "--iou-now" in err and len(err.strip().splitlines()) == 1


def test_joint_jitter_of_known_trajectories():
    from gltrack.eval.quality import joint_jitter, quality_summary

    t = np.arange(10, dtype=float)
    X = np.zeros((10, 2, 3))
    X[:, 0, 0] = 0.01 * t                 # constant velocity: no jitter
    X[:, 1, 1] = 0.002 * t ** 2 / 2       # constant acceleration: 2 mm/frame^2
    f, jit = joint_jitter(X)
    assert f.tolist() == list(range(1, 9))
    np.testing.assert_allclose(jit, 1.0)  # mean of 0 and 2 mm/frame^2
    # a shake of +-1 mm on one joint: |x(t+1) - 2x(t) + x(t-1)| = 4 mm
    Y = X.copy()
    Y[:, 0, 2] += 0.001 * (-1.0) ** t
    np.testing.assert_allclose(joint_jitter(Y)[1], (4.0 + 2.0) / 2)
    # rotation-invariant, and only consecutive frames count
    R = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    np.testing.assert_allclose(joint_jitter(Y @ R.T)[1], joint_jitter(Y)[1])
    frames = np.array([0, 1, 2, 4, 5, 6, 7, 8, 9, 10])
    assert joint_jitter(X, frames)[0].tolist() == [1, 5, 6, 7, 8, 9]
    q = quality_summary({"joints": Y, "joint_names": ["a", "b"], "frame": np.arange(10)}, {})
    assert q["cameras"] == [] and q["jitter_mean_mm"] == pytest.approx(3.0)
    assert q["jitter_p95_mm"] == pytest.approx(3.0)


def test_marker_thresholds_are_inclusive():
    gt = np.zeros((1, 4, 3))
    pred = np.array([[[0.1, 0, 0], [0.3, 0, 0], [0.2, 0, 0], [0.0999, 0, 0]]])
    e = M.marker_errors(pred, gt)
    assert e["frac_tracked"][0] == 0.5 and e["frac_failed"][0] == 0.25
    assert e["mean"][0] == pytest.approx(0.174975) and e["max"][0] == pytest.approx(0.3)
    gt[0, 1] = np.nan  # an invisible marker is not counted at all
    e = M.marker_errors(pred, gt)
    assert e["visible"][0] == 3 and e["frac_failed"][0] == 0.0


def test_bench_rows_carry_the_per_joint_means():
    from gltrack.bench.depth import by_joint

    m = {"per_joint": {"pelvis": {"mean_mm": 12.345, "max_mm": 20.0},
                       "l_wrist": {"mean_mm": float("nan"), "max_mm": float("nan")}}}
    assert by_joint(m) == {"pelvis": 12.3, "l_wrist": None}
    assert json.loads(json.dumps(by_joint(m))) == {"pelvis": 12.3, "l_wrist": None}


def test_quality_says_when_the_iou_is_against_masks_the_track_refined():
    """Frames tracked with ``mask_refine`` record ``masks_refined``: the summary counts them and
    the table says the IoU is not an independent check (not after ``--iou-now``)."""
    from gltrack.eval.quality import quality_summary, quality_table

    res = {"joints": np.zeros((4, 1, 3)), "joint_names": ["a"], "frame": np.arange(4)}
    infos = {f: {"iou": [0.9, 0.8], **({"masks_refined": True} if f >= 1 else {})}
             for f in range(4)}
    q = quality_summary(res, infos, ["cam0", "cam1"])
    assert q["iou_frames_self_refined"] == 3 and q["iou_frames"] == 4
    text = quality_table(q)
    assert "3 of them scored against masks the track refined" in text
    assert "not an independent check" not in quality_table({**q, "iou_source": "recomputed"})
    plain = quality_summary(res, {f: {"iou": [0.9, 0.8]} for f in range(4)}, ["cam0", "cam1"])
    assert plain["iou_frames_self_refined"] == 0
    assert "refined" not in quality_table(plain)


def test_quality_reports_an_uncertain_start_and_the_restarts():
    """The runner's record of the start (first frame's ``info["start"]``) and of re-start
    checks reaches the summary and the table; an uncertain start is flagged, a clear one is
    not, and a result without the records says nothing about them."""
    from gltrack.eval.quality import quality_summary, quality_table

    res = {"joints": np.zeros((6, 1, 3)), "joint_names": ["a"], "frame": np.arange(2, 8)}
    start = {"hypotheses": 2, "frames": 4, "measure": "quality", "means": [0.349, 0.371],
             "kept": 0, "uncertain": True, "turned_deg": [0.0, -171.5]}
    infos = {2: {"start": start},
             5: {"restart": {"frame": 4, "hypotheses": 2, "restarted": True,
                             "decision": {"uncertain": False}}},
             7: {"restart": {"frame": 6, "hypotheses": 2, "restarted": False}}}
    q = quality_summary(res, infos)
    assert q["start"] == start
    assert q["restarts"] == [{"frame": 4, "restarted": True, "uncertain": False},
                             {"frame": 6, "restarted": False, "uncertain": False}]
    text = quality_table(q)
    assert "start: 2 hypotheses tracked 4 frames, mean quality 0.349, 0.371; turned 0, -172 " \
        "deg from the kept one; kept 0" in text
    assert "start UNCERTAIN" in text and "re-start checks: 2, re-started at 4" in text
    assert "(if not: --start-hypothesis 1)" in text
    clear = quality_table(quality_summary(res, {2: {"start": {**start, "uncertain": False}}}))
    assert "start: 2 hypotheses" in clear and "UNCERTAIN" not in clear
    assert "re-start" not in clear
    by_hand = quality_table(quality_summary(res, {2: {"start": {
        "hypotheses": 2, "kept": 1, "chosen": "--start-hypothesis"}}}))
    assert "start: hypothesis 1 of 2, kept by --start-hypothesis" in by_hand
    assert "UNCERTAIN" not in by_hand
    bare = quality_summary(res, {})
    assert bare["start"] is None and bare["restarts"] == []
    assert "start" not in quality_table(bare)


def test_body_height_against_the_subject_surface(tmp_path, capsys):
    """A dataset whose subject records its surface stature (``gltrack synth --mesh``) gets the
    estimate's height compared with that surface too, in the bench figures and in ``gltrack
    eval``; without the record nothing is added."""
    from gltrack.bench.protocols import body_error_of
    from gltrack.body.model import BodyModel, body_to_meta
    from gltrack.camera import Camera
    from gltrack.data.dataset import DatasetWriter
    from gltrack.data.results import ResultsWriter, save_body_record

    gt = gt_dict(np.random.default_rng(9))  # a 1.75 m default skeleton
    c = Camera("cam0", "depth", 8, 6, [[8.0, 0, 3.5], [0, 8.0, 2.5], [0, 0, 1]], np.zeros(5),
               np.eye(3), np.array([0.0, 0.0, 3.0]))
    true, estimate = (BodyModel.build(default_skeleton(h), "full") for h in (1.75, 1.80))
    for name, subject in (("with", {"mesh": "x.glb", "girth_scale": 1.0, "stature_m": 1.86}),
                          ("without", None)):
        ds, res = tmp_path / f"ds_{name}", tmp_path / f"res_{name}"
        with DatasetWriter(ds, "depth", 30, [c], body=body_to_meta(default_skeleton(1.75)),
                           meta=None if subject is None else {"subject": subject}) as w:
            for f in range(N):
                w.write_depth(f, 0, np.full((6, 8), 2.0))
            w.write_groundtruth(true.joints(gt["params"]), gt["joint_names"],
                                true.marker_positions(gt["params"]), gt["params"],
                                marker_names=list(true.markers.names))
        rw = ResultsWriter(res, "hc", gt["joint_names"], list(estimate.markers.names))
        J, K = estimate.joints(gt["params"]), estimate.marker_positions(gt["params"])
        for f in range(N):  # the estimate's own joints: eval checks they fit its body.json
            rw.append(f, gt["params"][f], J[f], K[f], score=0.0, evaluations=1, seconds=0.1)
        rw.finish()
        save_body_record(res, estimate, "estimate")
        e = body_error_of(res, ds)
        assert e["height_mm"] == pytest.approx(50.0, abs=0.5)
        assert main(["eval", str(res), str(ds)]) == 0
        out = capsys.readouterr().out
        if subject is None:
            assert "height_vs_surface_mm" not in e and "surface" not in report.body_error_text(e)
            assert "subject's surface" not in out
        else:
            assert e["height_vs_surface_mm"] == pytest.approx(-60.0, abs=0.5)
            assert "(against the subject's surface -60 mm)" in report.body_error_text(e)
            assert "height +50 mm (against the subject's surface -60 mm)" in out
