"""body.json: the body a run used, recorded in the results folder and read by export/render/eval;
``gltrack track --body dataset|FILE.json``; resume refuses another body."""
import json

import numpy as np
import pytest

from gltrack.body.model import (BodyModel, body_from_meta, body_from_record, body_record,
                                body_to_meta)
from gltrack.body.skeleton import default_skeleton
from gltrack.cli import main
from gltrack.data.dataset import Dataset
from gltrack.data.results import (ResultsWriter, load_body_record, load_results,
                                  save_body_record)
from trackdata import make_depth_dataset

N = 4


def _random_poses(body, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = np.clip(body.dofs.lower, -np.pi, np.pi), np.clip(body.dofs.upper, -np.pi, np.pi)
    lo[:3], hi[:3] = -1.0, 1.0  # root translation, metres
    return body.dofs.validate(rng.uniform(lo, hi, size=(n, body.dofs.size)))


def _assert_same_body(a, b, seed=0):
    assert a.skeleton.names == b.skeleton.names and a.dofs.names == b.dofs.names
    P = _random_poses(a, 5, seed)
    np.testing.assert_array_equal(a.joints(P), b.joints(P))
    np.testing.assert_array_equal(a.marker_positions(P), b.marker_positions(P))
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


# --------------------------------------------------------------------------------------------
# the record <-> BodyModel conversion (no GL)

def test_record_rebuilds_the_identical_body_shape_parameters_included(tmp_path):
    body = BodyModel.build(default_skeleton(1.62, shoulder_width=0.36), "38", lod=0,
                           girth_scale=1.15, girths={"thigh": 0.58})
    save_body_record(tmp_path, body, "file")
    again, rec = load_body_record(tmp_path)  # a results folder
    assert rec["source"] == "file" and rec["preset"] == "38" and rec["girths"] == {"thigh": 0.58}
    _assert_same_body(body, again)
    assert (again.dofs.preset, again.lod, again.girth_scale) == ("38", 0, 1.15)
    # the girths matter: without them the mesh (and so the markers) differ
    plain = BodyModel.build(body.skeleton, "38", lod=0)
    assert not np.allclose(plain.mesh.vertices, body.mesh.vertices)
    # a hand-written file: only the skeleton, everything else defaulted
    hand = tmp_path / "hand.json"
    sk = rec["skeleton"]
    hand.write_text(json.dumps({"skeleton": {k: sk[k] for k in ("names", "parents", "offsets", "ends")}}))
    b2, _ = load_body_record(hand)
    _assert_same_body(BodyModel.build(body.skeleton), b2)
    # meta.json records (datasets) still read as before
    _assert_same_body(body_from_meta(body_to_meta(body.skeleton, "38", 0)),
                      BodyModel.build(body.skeleton, "38", 0))
    _assert_same_body(body_from_meta({"height": 1.6}), BodyModel.build(default_skeleton(1.6)))


def _corrupt(rec, field, value):
    rec = json.loads(json.dumps(rec))
    *path, last = field.split(".")
    d = rec
    for k in path:
        d = d[k]
    if value is KeyError:
        del d[last]
    else:
        d[last] = value
    return rec


@pytest.mark.parametrize("field, value", [
    ("skeleton", KeyError), ("skeleton", [1, 2]), ("skeleton.names", "pelvis"),
    ("skeleton.parents", [0]), ("skeleton.offsets", "zero"), ("skeleton.ends", [[0, 0]] * 19),
    ("skeleton.orders", ["XYZ"] * 18 + ["XXY"]), ("preset", "42"), ("lod", 7), ("lod", 1.5),
    ("girth_scale", "thin"), ("girth_scale", 9.0), ("girths", {"thigh": -1.0}),
    ("girths", {"tail": 0.3}), ("format", "gltrack-dataset"), ("version", 2), ("source", "guess"),
])
def test_invalid_record_names_the_file_and_the_field(tmp_path, field, value):
    rec = body_record(BodyModel.build(lod=0), "dataset")
    path = tmp_path / "body.json"
    path.write_text(json.dumps(_corrupt(rec, field, value)))
    with pytest.raises(ValueError) as exc:
        load_body_record(path)
    msg = str(exc.value)
    assert str(path) in msg and field.split(".")[-1] in msg and "\n" not in msg


def test_unreadable_or_missing_body_file(tmp_path):
    path = tmp_path / "body.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match="body.json: unreadable JSON"):
        load_body_record(path)
    with pytest.raises(ValueError, match="no such body file"):
        load_body_record(tmp_path / "none.json")
    with pytest.raises(ValueError, match="JSON object"):
        body_from_record([1, 2], "x.json")


def test_writer_records_the_body_and_resume_compares_it(tmp_path):
    a = BodyModel.build(lod=0)
    b = BodyModel.build(default_skeleton(1.6), lod=0)
    rec_a = body_record(a, "dataset")
    with ResultsWriter(tmp_path, "t", a.skeleton.names, body=rec_a):
        pass
    assert json.loads((tmp_path / "body.json").read_text()) == rec_a
    with pytest.raises(ValueError, match=r"skeleton\.(ends|offsets).*cannot resume"):
        ResultsWriter(tmp_path, "t", a.skeleton.names, resume=True, body=body_record(b, "file"))
    with pytest.raises(ValueError, match="'preset'"):
        ResultsWriter(tmp_path, "t", a.skeleton.names, resume=True,
                      body=body_record(a.with_preset("38"), "dataset"))
    # the same body from another source resumes; the stored record is kept
    ResultsWriter(tmp_path, "t", a.skeleton.names, resume=True, body=body_record(a, "file")).close()
    assert json.loads((tmp_path / "body.json").read_text())["source"] == "dataset"
    # overwrite replaces it
    ResultsWriter(tmp_path, "t", b.skeleton.names, overwrite=True, body=body_record(b, "file")).close()
    _assert_same_body(load_body_record(tmp_path)[0], b)


# --------------------------------------------------------------------------------------------
# end to end: track, export, render, eval (real GL)

@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("bodyrec")
    make_depth_dataset(root / "ds", n=N)
    short = root / "short"
    short.mkdir()
    save_body_record(short, BodyModel.build(default_skeleton(1.6)), "file")
    ds, res = str(root / "ds"), root / "res"
    assert main(["-q", "track", "--body", "dataset", ds, "--method", "hc", "--out", str(res)]) == 0
    assert main(["-q", "track", ds, "--method", "hc", "--out", str(root / "res16"),
                 "--body", str(short / "body.json")]) == 0
    return {"root": root, "ds": root / "ds", "res": res, "res16": root / "res16",
            "short": short / "body.json"}


def test_a_run_records_the_dataset_body(runs, gl_ctx):
    body, rec = load_body_record(runs["res"])
    assert rec["source"] == "dataset" and rec["preset"] == "full"
    with Dataset.open(runs["ds"]) as ds:
        truth = body_from_meta(ds.body)
    _assert_same_body(truth, body, seed=1)
    res = load_results(runs["res"])
    np.testing.assert_allclose(body.joints(res["params"]), res["joints"], atol=1e-9)


def test_body_file_is_used_and_recorded(runs, gl_ctx):
    short, _ = load_body_record(runs["short"])
    used, rec = load_body_record(runs["res16"])
    assert rec["source"] == "file"
    _assert_same_body(short, used, seed=2)
    r16, r = load_results(runs["res16"]), load_results(runs["res"])
    # the joints are the 1.6 m body's, not the dataset body's
    np.testing.assert_allclose(short.joints(r16["params"]), r16["joints"], atol=1e-9)
    with Dataset.open(runs["ds"]) as ds:
        tall = body_from_meta(ds.body)
    assert np.abs(tall.joints(r16["params"]) - r16["joints"]).max() > 0.03
    assert np.abs(r16["joints"] - r["joints"]).max() > 0.03
    # eval reports the recorded body
    js = runs["root"] / "m16.json"
    assert main(["eval", str(runs["res16"]), str(runs["ds"]), "--json", str(js)]) == 0
    body = json.loads(js.read_text())["body"]
    assert body["source"] == "file" and body["height_m"] == pytest.approx(1.6, abs=1e-6)


def test_export_and_render_of_a_dof38_result_need_no_dof(runs, gl_ctx, capsys):
    res = runs["root"] / "res38"
    assert main(["-q", "track", "--body", "dataset", str(runs["ds"]), "--method", "hc", "--out", str(res), "--dof", "38",
                 "--init", "auto", "--frames", "0:2"]) == 0
    assert main(["export", str(res), "--format", "json"]) == 0
    doc = json.loads((res / "poses.json").read_text())
    assert doc["dof_preset"] == "38" and len(doc["frames"]) == 2
    assert main(["export", str(res), "--format", "bvh", "--dof", "38", "--overwrite"]) == 0  # agrees
    capsys.readouterr()
    assert main(["export", str(res), "--format", "bvh", "--dof", "full", "--overwrite"]) == 1
    err = capsys.readouterr().err
    assert "body.json" in err and "'38'" in err and len(err.strip().splitlines()) == 1
    assert main(["-q", "render", str(res), str(runs["ds"]), "--out",
                 str(runs["root"] / "o38.mp4")]) == 0
    # without body.json (results of older versions) the preset must be given again
    (res / "body.json").unlink()
    assert main(["export", str(res), "--format", "bvh", "--dataset", str(runs["ds"]), "--overwrite"]) == 1
    assert "'38'" in capsys.readouterr().err
    assert main(["export", str(res), "--format", "bvh", "--dof", "38", "--overwrite"]) == 0


def test_corrupt_or_foreign_body_json_is_refused(runs, tmp_path, capsys):
    import shutil

    res = tmp_path / "res"
    shutil.copytree(runs["res"], res)
    rec = json.loads((res / "body.json").read_text())
    rec["skeleton"]["offsets"] = "broken"
    (res / "body.json").write_text(json.dumps(rec))
    for argv in (["export", str(res), "--format", "bvh", "--overwrite"], ["eval", str(res), str(runs["ds"])],
                 ["render", str(res), str(runs["ds"]), "--out", str(tmp_path / "o.mp4")]):
        capsys.readouterr()
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip()
        assert str(res / "body.json") in err and "skeleton.offsets" in err, err
        assert len(err.splitlines()) == 1
    # a valid body.json of another body: the joints are not the result's
    shutil.copy(runs["short"], res / "body.json")
    for argv in (["export", str(res), "--format", "bvh", "--overwrite"], ["eval", str(res), str(runs["ds"])]):
        capsys.readouterr()
        assert main(argv) == 1, argv
        assert "does not belong to this result" in capsys.readouterr().err


def test_resume_with_another_body_is_refused(runs, tmp_path, capsys):
    out = tmp_path / "r"
    ds = str(runs["ds"])
    assert main(["-q", "track", ds, "--method", "hc", "--out", str(out), "--frames", "0:2"]) == 0
    log = (out / "frames.jsonl").read_text()
    capsys.readouterr()
    rc = main(["-q", "track", ds, "--method", "hc", "--out", str(out), "--frames", "0:3",
               "--resume", "--body", str(runs["short"])])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "body.json" in err and "cannot resume" in err and len(err.splitlines()) == 1
    assert (out / "frames.jsonl").read_text() == log
    # the same body given as a file (the run's own body.json) resumes
    assert main(["-q", "track", ds, "--method", "hc", "--out", str(out), "--frames", "0:3",
                 "--resume", "--body", str(out / "body.json")]) == 0
    assert load_results(out)["params"].shape[0] == 3
    # the default (--body estimate) resumes with the body estimated when the run began
    estimated = (out / "body.json").read_bytes()
    assert json.loads(estimated)["source"] == "estimate"
    assert main(["-q", "track", ds, "--method", "hc", "--out", str(out), "--frames", "0:4",
                 "--resume"]) == 0
    assert (out / "body.json").read_bytes() == estimated
    assert load_results(out)["params"].shape[0] == 4


def test_body_json_is_written_before_the_first_frame(runs, tmp_path, gl_ctx):
    from gltrack.track.runner import track

    def crash(tracker, frame):
        raise KeyboardInterrupt  # the run dies before its first frame is tracked

    with pytest.raises(KeyboardInterrupt):
        track(runs["ds"], "hc", tmp_path / "r", body=str(runs["short"]), progress=False,
              hooks=[crash])
    assert (tmp_path / "r" / "frames.jsonl").read_text() == ""
    body, rec = load_body_record(tmp_path / "r")
    assert rec["source"] == "file"
    _assert_same_body(body, load_body_record(runs["short"])[0], seed=3)


def test_bad_body_argument(runs, tmp_path, capsys):
    assert main(["track", str(runs["ds"]), "--method", "hc", "--out", str(tmp_path / "x"),
                 "--body", str(tmp_path / "missing.json")]) == 1
    assert "--body" in capsys.readouterr().err
    bad = tmp_path / "b.json"
    bad.write_text(json.dumps({"skeleton": {"names": ["pelvis"], "parents": [-1],
                                            "offsets": [[0, 0]], "ends": [[0, 0, 0]]}}))
    assert main(["track", str(runs["ds"]), "--method", "hc", "--out", str(tmp_path / "y"),
                 "--body", str(bad)]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "skeleton.offsets" in err
    assert not (tmp_path / "y").exists()


def test_with_lod_rebuilds_only_the_surface():
    body = BodyModel.build(default_skeleton(1.62, shoulder_width=0.36), "38", lod=1,
                           girth_scale=1.15)
    assert body.with_lod(1) is body
    coarse = body.with_lod(0)
    assert coarse.lod == 0 and coarse.mesh.n_faces < body.mesh.n_faces
    assert coarse.skeleton is body.skeleton and coarse.dofs.preset == "38"
    assert coarse.girth_scale == 1.15 and coarse.girths == body.girths
    want = BodyModel.build(body.skeleton, "38", lod=0, girth_scale=1.15)
    np.testing.assert_array_equal(coarse.mesh.vertices, want.mesh.vertices)
