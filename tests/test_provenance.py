"""run.json provenance (issue 14, points 1 and 2): what a run records, and how export, eval and
track --resume use the record: the recorded frame rate, no silent overwrite, and refusals of a
dataset that is not the run's."""
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import gltrack
from gltrack.cli import main
from gltrack.data.provenance import dataset_fingerprint
from gltrack.data.results import load_results

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset  # noqa: E402

TRACK = ["-q", "track", "--method", "hc", "--body", "dataset", "--init", "groundtruth"]


def _set_fps(ds, fps):
    meta = json.loads((ds / "meta.json").read_text())
    meta["fps"] = fps
    (ds / "meta.json").write_text(json.dumps(meta))


@pytest.fixture(scope="module")
def prov(tmp_path_factory):
    """ds: 4 frames at 15 fps, tracked over 0:3 into res; other: the same at another noise seed;
    long: 8 frames at 15 fps."""
    root = tmp_path_factory.mktemp("prov")
    make_depth_dataset(root / "ds", n=4, seed=0)
    make_depth_dataset(root / "other", n=4, seed=1)
    make_depth_dataset(root / "long", n=8, seed=0)
    for name in ("ds", "other", "long"):
        _set_fps(root / name, 15)
    assert main(TRACK + [str(root / "ds"), "--out", str(root / "res"), "--frames", "0:3"]) == 0
    return root


def _old_style(res, to):
    """A copy of ``res`` as an older gltrack wrote it: run.json without provenance."""
    shutil.copytree(res, to)
    run = json.loads((to / "run.json").read_text())
    run = {k: run[k] for k in ("format", "version", "method", "joint_names", "marker_names")}
    (to / "run.json").write_text(json.dumps(run))
    return to


def test_run_json_records_the_dataset_and_settings(prov):
    run = json.loads((prov / "res" / "run.json").read_text())
    ds = run["dataset"]
    assert ds["path"] == str((prov / "ds").resolve())
    assert ds["fingerprint"] == dataset_fingerprint(prov / "ds")["fingerprint"]
    assert ds["fps"] == 15 and ds["frames"] == 4 and ds["rig"] == "depth"
    assert run["frames"] == [0, 3] and run["seed"] == 0 and run["init"] == "groundtruth"
    assert run["method"] == "hc" and run["options"]["grid"] == 5 and "tile" in run["options"]
    assert run["body"] == {"source": "dataset", "preset": "full"}
    assert run["gltrack_version"] == gltrack.__version__
    # the fingerprint sees a changed frame file, calibration or ground truth; not a hidden file
    assert dataset_fingerprint(prov / "other")["fingerprint"] != ds["fingerprint"]
    assert set(dataset_fingerprint(prov / "ds")["parts"]) == {
        "meta.json", "calibration.json", "groundtruth.npz", "cam0"}


def test_export_uses_the_recorded_fps_and_never_overwrites(prov, tmp_path, capsys, caplog):
    from gltrack.export import read_trc

    res = prov / "res"
    bvh = (res / "poses.bvh").read_bytes()
    assert b"Frame Time: 0.066666667" in bvh
    capsys.readouterr()
    assert main(["export", str(res), "--format", "bvh"]) == 2
    err = capsys.readouterr().err.strip()
    assert "poses.bvh exists" in err and "--overwrite" in err and len(err.splitlines()) == 1
    assert (res / "poses.bvh").read_bytes() == bvh
    trc = tmp_path / "m.trc"
    assert main(["export", str(res), "--out", str(trc)]) == 0  # no --dataset: run.json's 15 fps
    assert float(read_trc(trc)["header"]["DataRate"]) == 15.0
    assert main(["export", str(res), "--out", str(trc)]) == 2
    assert main(["export", str(res), "--out", str(trc), "--fps", "60", "--overwrite"]) == 0
    assert float(read_trc(trc)["header"]["DataRate"]) == 60.0
    assert main(["export", str(res), "--format", "bvh", "--overwrite"]) == 0
    assert (res / "poses.bvh").read_bytes() == bvh  # the same file the run wrote, 15 fps
    assert not [p for p in res.iterdir() if p.name.startswith(".")]
    # results of an older gltrack: 30 fps, said in a warning
    old = _old_style(res, tmp_path / "old")
    caplog.clear()
    assert main(["export", str(old), "--out", str(tmp_path / "o.trc")]) == 0
    assert float(read_trc(tmp_path / "o.trc")["header"]["DataRate"]) == 30.0
    assert any("assuming 30 fps" in r.getMessage() for r in caplog.records)


def test_resume_refuses_another_dataset_seed_options_or_start(prov, tmp_path, capsys):
    res = tmp_path / "res"
    shutil.copytree(prov / "res", res)
    log = (res / "frames.jsonl").read_bytes()
    cfg = tmp_path / "c.toml"
    cfg.write_text("grid = 3\n")
    cases = [([str(prov / "other")], "dataset.fingerprint"),
             ([str(prov / "ds"), "--seed", "4"], "'seed'"),
             ([str(prov / "ds"), "--config", str(cfg)], "'options.grid'"),
             ([str(prov / "ds"), "--frames", "1:4"], "'frames'")]
    for extra, field in cases:
        capsys.readouterr()
        assert main(TRACK + ["--out", str(res), "--resume"] + extra) == 1, extra
        err = capsys.readouterr().err.strip()
        assert field in err and "cannot resume" in err and len(err.splitlines()) == 1, err
        assert (res / "frames.jsonl").read_bytes() == log
    # the same data at another path resumes; without --frames the recorded range (0:3) is kept
    moved = tmp_path / "moved"
    shutil.copytree(prov / "ds", moved)
    assert main(TRACK + [str(moved), "--out", str(res), "--resume"]) == 0
    assert (res / "frames.jsonl").read_bytes() == log
    # ... and --frames extends it
    assert main(TRACK + [str(moved), "--out", str(res), "--resume", "--frames", "0:4"]) == 0
    assert list(load_results(res)["frame"]) == [0, 1, 2, 3]
    assert json.loads((res / "run.json").read_text())["frames"] == [0, 4]
    # a shorter --frames does not shrink the recorded range
    assert main(TRACK + [str(moved), "--out", str(res), "--resume", "--frames", "0:2"]) == 0
    assert json.loads((res / "run.json").read_text())["frames"] == [0, 4]
    assert len(load_results(res)["frame"]) == 4


def test_eval_refuses_another_dataset_and_counts_frames(prov, tmp_path, capsys):
    res = prov / "res"
    capsys.readouterr()
    assert main(["eval", str(res), str(prov / "other")]) == 1
    err = capsys.readouterr().err.strip()
    assert "another dataset" in err and "--force" in err and len(err.splitlines()) == 1
    assert main(["eval", str(res), str(prov / "other"), "--force"]) == 0
    assert "scored 3 of 3 frames" in capsys.readouterr().out
    js = tmp_path / "m.json"
    assert main(["eval", str(res), str(prov / "ds"), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "scored 3 of 3 frames (the run's range 0:3 of the dataset's 4)" in out
    cov = json.loads(js.read_text())["coverage"]
    assert cov["scored"] == 3 and cov["expected"] == 3 and cov["range"] == [0, 3]
    # an older result against a longer dataset: refused, not half scored in silence
    old = _old_style(res, tmp_path / "old")
    assert main(["eval", str(old), str(prov / "long")]) == 1
    err = capsys.readouterr().err
    assert "holds 3 frames" in err and "8" in err and "--force" in err
    assert main(["eval", str(old), str(prov / "long"), "--force"]) == 0
    assert "scored 3 of 8 frames" in capsys.readouterr().out
    assert np.isfinite(json.loads(js.read_text())["mean_joint_error_mm"])
