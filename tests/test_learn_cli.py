"""``gltrack learn``: BVH clips in, behaviour model out, report printed."""
import copy

import numpy as np
import pytest

from gltrack.bench.vlmm import periodic_motion
from gltrack.body.model import BodyModel
from gltrack.cli import main
from gltrack.motion.behaviour import BehaviourModel
from gltrack.motion.bvh import write_bvh
from gltrack.export.bvh import params_to_bvh
from gltrack.motion.retarget import load_motion


def _mb_bvh(body, P):
    """BVH of params ``P`` on ``body`` with MotionBuilder joint names."""
    bvh = params_to_bvh(body, P, 30.0)
    side = {"clavicle": "Shoulder", "shoulder": "Arm", "elbow": "ForeArm", "wrist": "Hand",
            "hip": "UpLeg", "knee": "Leg", "ankle": "Foot"}
    rename = {"pelvis": "Hips", "spine_lower": "LowerBack", "spine_upper": "Spine",
              "neck": "Neck", "head": "Head"}
    for j, s in side.items():
        rename[f"l_{j}"], rename[f"r_{j}"] = f"Left{s}", f"Right{s}"
    bvh.names = [rename[n] for n in bvh.names]
    bvh.end_sites = {rename[k]: v for k, v in bvh.end_sites.items()}
    return bvh


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A synthetic walk-like BVH: 4 s at 30 frames/s written from the gltrack body with
    MotionBuilder joint names (the convention CMU conversions use)."""
    body = BodyModel.build(preset="full", lod=0)
    P = periodic_motion(body, 120, period=1.0)
    path = tmp_path_factory.mktemp("learn") / "walk.bvh"
    write_bvh(path, _mb_bvh(body, P))
    return path


def test_learn_end_to_end(clip, tmp_path, capsys):
    out = tmp_path / "model.npz"
    rc = main(["learn", "--motion", str(clip), "--out", str(out), "--max-memory", "6",
               "--heldout", "0.25"])
    text = capsys.readouterr().out
    assert rc == 0, text
    m = BehaviourModel.load(out)
    assert m.n_angles == 19 and m.fps == 30.0  # preset 25: 25 - 6 angles
    assert m.dof_names[0].startswith("spine_lower")
    rep = m.report()
    assert rep["max_memory_used"] <= 6 and rep["n_clusters"] >= 2
    assert rep["heldout_entropy"] is not None and rep["heldout_frames"] == 30
    assert f"{rep['train_entropy']:.3f}" in text and f"{rep['heldout_entropy']:.3f}" in text
    assert "clusters:" in text and str(out) in text
    assert f"heading rate sd {rep['heading_rate_sd']:.2f} rad/s" in text
    assert rep["local_covariances"] and "local dynamics:   each cluster's full covariance" in text
    # augmentation multiplies the training frames (3 speeds x 3 smoothings)
    rc = main(["learn", "--motion", str(clip), "--out", str(tmp_path / "b.npz"), "--no-augment",
               "--heldout", "0.25"])
    assert rc == 0
    n_plain = BehaviourModel.load(tmp_path / "b.npz").report()["train_frames"]
    assert n_plain == 90 and rep["train_frames"] > 7 * n_plain


def test_learnt_model_predicts_the_clip(clip, tmp_path):
    out = tmp_path / "m.npz"
    assert main(["-q", "learn", "--motion", str(clip), str(clip), "--out", str(out),
                 "--heldout", "0", "--preset", "full", "--fps", "30"]) == 0
    m = BehaviourModel.load(out)
    _, dofs, P, _ = load_motion(clip, "full", fps=30)
    assert m.n_angles == dofs.size - 6 and m.report()["heldout_entropy"] is None
    X = m.features(P)
    labels = m.label(X)
    # the learnt VLMM predicts the clip's own cluster sequence with low entropy
    assert m.vlmm.entropy([labels]) < 1.0
    assert len(np.unique(labels)) >= 2


def test_usage_errors(clip, tmp_path, capsys):
    assert main(["learn", "--motion", str(tmp_path / "nope.bvh"), "--out",
                 str(tmp_path / "m.npz")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["learn", "--motion", str(clip), "--out", str(tmp_path / "m.npz"),
                 "--heldout", "1.5"]) == 2
    assert main(["learn", "--motion", str(clip), "--out", str(tmp_path / "x" / "m.npz")]) == 2
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    assert main(["learn", "--motion", str(bad), "--out", str(tmp_path / "m.npz")]) == 1
    assert "bad.bvh" in capsys.readouterr().err
    assert not (tmp_path / "m.npz").exists()


def test_learn_on_cmu_walk(shared, tmp_path, capsys):
    clip = shared / "mocap" / "cmu_02_01_walk.bvh"
    if not clip.is_file():
        pytest.skip(f"{clip} absent")
    assert main(["learn", "--motion", str(clip), "--out", str(tmp_path / "w.npz")]) == 0
    rep = BehaviourModel.load(tmp_path / "w.npz").report()
    assert rep["n_clusters"] >= 2 and rep["train_entropy"] < rep["heldout_entropy"] + 1.0


def test_memory_sweep(clip, tmp_path, capsys):
    """The sweep's row at the model's own memory reproduces the model's entropies; longer
    memories never fit the training labels worse and never have fewer states."""
    out = tmp_path / "m.npz"
    rc = main(["learn", "--motion", str(clip), "--out", str(out), "--max-memory", "4",
               "--heldout", "0.25", "--sweep-memory", "0:6"])
    text = capsys.readouterr().out
    assert rc == 0 and "entropy against maximal memory" in text
    m = BehaviourModel.load(out)
    _, dofs, params, _ = load_motion(clip, "25", fps=30.0)
    cut = int(round(len(params) * 0.75))
    rows = m.memory_sweep(params[:cut], [params[cut:]], range(0, 7))
    own = rows[4]
    rep = m.report()
    assert own["n_states"] == rep["n_states"]
    assert own["train_entropy"] == pytest.approx(rep["train_entropy"], rel=1e-9)
    assert own["heldout_entropy"] == pytest.approx(rep["heldout_entropy"], rel=1e-9)
    tr = [r["train_entropy"] for r in rows]
    st = [r["n_states"] for r in rows]
    assert all(b <= a + 1e-9 for a, b in zip(tr, tr[1:])), tr
    assert st == sorted(st) and st[0] == 1 and st[-1] > 1
    assert f"{rows[6]['n_states']:7d}" in text
    assert main(["learn", "--motion", str(clip), "--out", str(out), "--sweep-memory", "3"]) == 2


def _clips(folder, n, frames=90):
    """``n`` synthetic walk-like BVH files of different periods and phases (one dancer's
    takes), written from the gltrack body with its own joint names."""
    body = BodyModel.build(preset="full", lod=0)
    paths = []
    for i in range(n):
        P = periodic_motion(body, frames, phase=0.7 * i, period=0.9 + 0.15 * i)
        paths.append(folder / f"take{i}.bvh")
        write_bvh(paths[-1], _mb_bvh(body, P))
    return paths


def test_learn_from_several_files(tmp_path, capsys):
    """Several takes are learnt together (each its own sequence), a separate take gives the
    held-out entropy, the report lists every take and the learning time."""
    *train, held = _clips(tmp_path, 4)
    out = tmp_path / "m.npz"
    rc = main(["learn", "--motion", *map(str, train), "--heldout-motion", str(held),
               "--out", str(out), "--max-memory", "4", "--sweep-memory", "1:4"])
    text = capsys.readouterr().out
    assert rc == 0, text
    m = BehaviourModel.load(out)
    rep = m.report()
    assert all(f"{p} (90 frames)" in text for p in train) and "learnt in:" in text
    # every training take learnt whole (9 augmented copies each); the held-out take is not
    assert rep["heldout_frames"] == 90
    _, _, one, _ = load_motion(train[0], "25", fps=30)
    from gltrack.motion.features import augment
    assert rep["train_frames"] == 3 * sum(len(a) for a in augment(one, (0.9, 1.0, 1.1),
                                                                   (0.0, 1.0, 2.0)))
    assert m.info["learn_seconds"] > 0 and len(m.info["clips"]) == 3
    assert rep["heldout_entropy"] is not None and f"{rep['heldout_entropy']:.3f}" in text
    # fewer takes: fewer training frames, the same held-out take
    assert main(["-q", "learn", "--motion", str(train[0]), "--heldout-motion", str(held),
                 "--out", str(tmp_path / "one.npz")]) == 0
    assert BehaviourModel.load(tmp_path / "one.npz").report()["train_frames"] * 3 == \
        rep["train_frames"]
    # a held-out take that is also trained on is refused
    assert main(["learn", "--motion", *map(str, train), "--heldout-motion", str(train[1]),
                 "--out", str(tmp_path / "x.npz")]) == 2
    assert "also a training clip" in capsys.readouterr().err
    assert main(["learn", "--motion", str(train[0]), "--heldout-motion",
                 str(tmp_path / "nope.bvh"), "--out", str(tmp_path / "x.npz")]) == 2
    assert "--heldout-motion: no such file" in capsys.readouterr().err


def test_learn_from_several_shared_files(shared, tmp_path, capsys):
    """Small files cut from the shared salsa take (CMU 60, Daz names, metres) are learnt
    together; the T-pose frame opening the first file is skipped."""
    from gltrack.motion.bvh import read_bvh

    src = shared / "mocap" / "cmu_60_10_salsa_daz_metres.bvh"
    if not src.is_file():
        pytest.skip(f"{src} absent")
    bvh = read_bvh(src)
    paths = []
    for i, (a, b) in enumerate(((0, 240), (240, 480), (480, 720), (720, 1080))):
        part = copy.copy(bvh)
        part.motion = bvh.motion[a:b].copy()
        paths.append(tmp_path / f"part{i}.bvh")
        write_bvh(paths[-1], part)
    out = tmp_path / "salsa.npz"
    rc = main(["learn", "--motion", *map(str, paths[:3]), "--heldout-motion", str(paths[3]),
               "--fps", "30", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rep = BehaviourModel.load(out).report()
    assert rep["n_clusters"] >= 2 and rep["n_states"] > rep["n_clusters"]
    assert rep["heldout_frames"] == 90  # 360 source frames at 120 fps -> 90 at 30 fps
    assert rep["heldout_entropy"] < 3.0 * rep["train_entropy"] + 1.0
