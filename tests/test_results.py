"""Results folder: append/finish round trip, resume after torn writes and after a real SIGKILL."""
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gltrack.data.results import ResultsWriter, load_results

JOINTS = ["pelvis", "neck", "head"]
MARKERS = ["m0", "m1"]


def frame_data(f):
    """Deterministic per-frame values, so a reader can check every stored number."""
    params = np.array([f, 0.1 * f, -f, 1.0 / (f + 3)])
    joints = np.arange(9, dtype=float).reshape(3, 3) + f + 1.0 / 3.0
    markers = -np.arange(6, dtype=float).reshape(2, 3) - f
    return params, joints, markers


def write_frames(w, frames):
    for f in frames:
        p, j, m = frame_data(f)
        w.append(f, p, j, m, score=-0.5 * f, evaluations=100 + f, seconds=0.25)


def check_arrays(r, frames):
    assert r["frame"].tolist() == list(frames)
    for i, f in enumerate(frames):
        p, j, m = frame_data(f)
        np.testing.assert_array_equal(r["params"][i], p)  # JSON floats round-trip exactly
        np.testing.assert_array_equal(r["joints"][i], j)
        np.testing.assert_array_equal(r["markers"][i], m)
        assert r["score"][i] == -0.5 * f


def test_append_finish_round_trip(tmp_path):
    out = tmp_path / "res"
    w = ResultsWriter(out, "sir", JOINTS, MARKERS)
    write_frames(w, range(5))
    timing = w.finish()
    assert timing == {"frames": 5, "seconds": 1.25, "fps": 4.0, "evaluations": 510}
    assert json.loads((out / "timing.json").read_text()) == timing
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert len(lines) == 5 and json.loads(lines[2])["frame"] == 2
    r = load_results(out)
    assert r["method"] == "sir" and r["joint_names"] == JOINTS and r["marker_names"] == MARKERS
    assert r["params"].shape == (5, 4) and r["joints"].shape == (5, 3, 3)
    assert r["markers"].shape == (5, 2, 3) and r["score"].shape == (5,)
    check_arrays(r, range(5))
    with np.load(out / "poses.npz", allow_pickle=False) as z:
        assert str(z["method"]) == "sir"
        assert set(z.files) >= {"params", "joints", "joint_names", "markers", "score", "method"}
    # Without poses.npz the arrays are rebuilt from frames.jsonl, identically.
    (out / "poses.npz").unlink()
    r2 = load_results(out)
    for key in ("params", "joints", "markers", "score", "frame"):
        np.testing.assert_array_equal(r2[key], r[key])
    assert r2["method"] == "sir"


def test_no_markers_and_bad_shapes(tmp_path):
    w = ResultsWriter(tmp_path / "r", "hc", JOINTS)
    p, j, _ = frame_data(0)
    w.append(0, p, j, None, score=1.0, evaluations=1, seconds=0.1)
    with pytest.raises(ValueError, match=r"joints must be \(3, 3\)"):
        w.append(1, p, j[:2])
    with pytest.raises(ValueError, match="params has 3 values"):
        w.append(1, p[:3], j)
    with pytest.raises(ValueError, match="already recorded"):
        w.append(0, p, j)
    w.finish()
    r = load_results(tmp_path / "r")
    assert r["markers"].shape == (1, 0, 3) and r["marker_names"] == []


def test_existing_run_needs_resume_or_overwrite(tmp_path):
    out = tmp_path / "r"
    w = ResultsWriter(out, "sir", JOINTS, MARKERS)
    write_frames(w, range(3))
    w.close()
    with pytest.raises(FileExistsError):
        ResultsWriter(out, "sir", JOINTS, MARKERS)
    with pytest.raises(ValueError, match="'method' is 'sir'"):
        ResultsWriter(out, "apf", JOINTS, MARKERS, resume=True)
    w = ResultsWriter(out, "sir", JOINTS, MARKERS, overwrite=True)
    assert w.done_frames == [] and w.last() is None
    write_frames(w, [7])
    w.finish()
    assert load_results(out)["frame"].tolist() == [7]


@pytest.mark.parametrize("garbage", [b'{"frame": 3, "params": [1.0, 2', b"\x00\xff garbage\n"])
def test_resume_drops_torn_last_line(tmp_path, caplog, garbage):
    out = tmp_path / "r"
    w = ResultsWriter(out, "sir", JOINTS, MARKERS)
    write_frames(w, range(3))
    w.close()
    with open(out / "frames.jsonl", "ab") as f:
        f.write(garbage)
    with caplog.at_level(logging.WARNING, logger="gltrack.data.results"):
        w = ResultsWriter(out, "sir", JOINTS, MARKERS, resume=True)
    assert "line 4" in caplog.text
    assert w.done_frames == [0, 1, 2]
    last = w.last()
    assert last["frame"] == 2
    np.testing.assert_array_equal(last["params"], frame_data(2)[0])
    write_frames(w, range(3, 5))
    w.finish()
    lines = (out / "frames.jsonl").read_bytes().split(b"\n")
    assert lines[-1] == b"" and len(lines) == 6  # torn tail cut away, 5 clean lines
    assert [json.loads(x)["frame"] for x in lines[:-1]] == list(range(5))
    check_arrays(load_results(out), range(5))
    (out / "poses.npz").unlink()
    check_arrays(load_results(out), range(5))


def test_corrupt_line_in_the_middle_is_an_error(tmp_path):
    out = tmp_path / "r"
    w = ResultsWriter(out, "sir", JOINTS, MARKERS)
    write_frames(w, range(3))
    w.close()
    lines = (out / "frames.jsonl").read_text().splitlines()
    lines[1] = "not json"
    (out / "frames.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="frames.jsonl, line 2: corrupt record"):
        ResultsWriter(out, "sir", JOINTS, MARKERS, resume=True)
    with pytest.raises(ValueError, match="line 2"):
        load_results(out)


def test_load_results_validation(tmp_path):
    with pytest.raises(ValueError, match="no such results folder"):
        load_results(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="neither poses.npz nor frames.jsonl"):
        load_results(tmp_path / "empty")
    good = dict(params=np.zeros((2, 4)), joints=np.zeros((2, 3, 3)),
                joint_names=np.array(JOINTS), markers=np.zeros((2, 0, 3)), score=np.zeros(2),
                method=np.array("x"))
    for key, bad, pattern in [
        ("joints", np.zeros((2, 3)), "field 'joints'"),
        ("joint_names", np.array(JOINTS[:2]), "field 'joint_names'"),
        ("score", np.zeros(3), "field 'score'"),
        ("params", np.zeros((3, 4)), "field 'params'"),
        ("method", np.array([{"a": 1}], dtype=object), "unreadable"),
        ("markers", np.zeros((2, 2)), "field 'markers'"),
    ]:
        arrays = dict(good, **{key: bad})
        np.savez(tmp_path / "poses.npz", **arrays)
        with pytest.raises(ValueError, match=pattern):
            load_results(tmp_path / "poses.npz")
    np.savez(tmp_path / "poses.npz", **good)
    assert load_results(tmp_path / "poses.npz")["method"] == "x"


CHILD = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from test_results import JOINTS, MARKERS, frame_data
    from gltrack.data.results import ResultsWriter
    w = ResultsWriter({out!r}, "sir", JOINTS, MARKERS, resume=True)
    start = w.done_frames[-1] + 1 if w.done_frames else 0
    for f in range(start, 10000):
        p, j, m = frame_data(f)
        w.append(f, p, j, m, score=-0.5 * f, evaluations=100 + f, seconds=0.25)
        print(f, flush=True)   # acknowledged: append() has returned
        time.sleep(0.01)
""")


def test_sigkill_mid_run_loses_no_finished_frame(tmp_path):
    out = tmp_path / "r"
    script = CHILD.format(tests=os.path.dirname(__file__), out=str(out))
    acked = []
    for _ in range(2):  # kill, then resume in a second child and kill again
        child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        try:
            first = None
            for line in child.stdout:
                f = int(line)
                first = f if first is None else first
                acked.append(f)
                if f - first >= 15:
                    break
            os.kill(child.pid, signal.SIGKILL)
        finally:
            child.wait(timeout=30)
            child.stdout.close()
            child.stderr.close()
        assert child.returncode == -signal.SIGKILL
    w = ResultsWriter(out, "sir", JOINTS, MARKERS, resume=True)
    done = w.done_frames
    assert set(acked) <= set(done), "a frame whose append() returned was lost"
    assert done == list(range(len(done)))  # the resumed child continued exactly after the last
    w.finish()
    check_arrays(load_results(out), done)


def test_world_frame_rotates_points_records_it_and_guards_resume(tmp_path):
    from gltrack.data.results import internal_points, result_frame
    from gltrack.data.world import world_meta

    world = world_meta("z")
    recorded = {k: world[k] for k in ("up", "R_user_from_internal")}  # not the dataset's floor
    R = np.array(world["R_user_from_internal"])
    out = tmp_path / "res"
    w = ResultsWriter(out, "sir", JOINTS, MARKERS, world=world)
    write_frames(w, [0, 1])
    w.close()
    assert json.loads((out / "run.json").read_text())["world"] == recorded
    # a crashed run (frames.jsonl only) and a finished one read back alike
    for finish in (False, True):
        if finish:
            with pytest.raises(ValueError, match="world"):
                ResultsWriter(out, "sir", JOINTS, MARKERS, resume=True)  # another frame
            w = ResultsWriter(out, "sir", JOINTS, MARKERS, resume=True, world=world)
            write_frames(w, [2])
            w.finish()
        r = load_results(out)
        assert r["world"] == recorded
        np.testing.assert_array_equal(result_frame(r), R)
        for i, f in enumerate(r["frame"]):
            p, j, m = frame_data(f)
            np.testing.assert_allclose(r["joints"][i], j @ R.T, atol=1e-12)
            np.testing.assert_allclose(r["markers"][i], m @ R.T, atol=1e-12)
            np.testing.assert_allclose(internal_points(r)[i], j, atol=1e-12)
            np.testing.assert_array_equal(r["params"][i], p)  # params stay internal
    npz = np.load(out / "poses.npz")
    assert str(npz["world_up"]) == "z"
    np.testing.assert_array_equal(npz["R_user_from_internal"], R)
    assert load_results(out / "poses.npz")["world"] == recorded


def test_identity_frame_records_nothing(tmp_path):
    w = ResultsWriter(tmp_path / "res", "sir", JOINTS, MARKERS)
    write_frames(w, [0])
    w.finish()
    assert "world" not in json.loads((tmp_path / "res" / "run.json").read_text())
    assert "R_user_from_internal" not in np.load(tmp_path / "res" / "poses.npz").files
    assert load_results(tmp_path / "res")["world"] is None


def test_engine_calls_recorded_and_old_logs_still_resume(tmp_path):
    """Per-frame engine calls go into frames.jsonl and their total into timing.json; a log
    written before engine accounting (records without the key) still resumes, and the total
    then says how many frames were counted."""
    out = tmp_path / "res"
    w = ResultsWriter(out, "hc", JOINTS, MARKERS)
    write_frames(w, range(3))  # the old writer: no counts
    w.close()
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert all("engine_calls" not in json.loads(line) for line in lines)
    w = ResultsWriter(out, "hc", JOINTS, MARKERS, resume=True)
    assert w.done_frames == [0, 1, 2]
    for f in (3, 4):
        p, j, m = frame_data(f)
        w.append(f, p, j, m, score=0.0, evaluations=50, seconds=0.5, engine_calls=10 + f,
                 engine_seconds=0.25)
    timing = w.finish()
    assert timing["engine_calls"] == 13 + 14 and timing["engine_calls_frames"] == 2
    assert timing["engine_seconds"] == pytest.approx(0.5)
    last = json.loads((out / "frames.jsonl").read_text().splitlines()[-1])
    assert last["engine_calls"] == 14 and last["engine_seconds"] == 0.25
    assert load_results(out)["frame"].tolist() == [0, 1, 2, 3, 4]
    # a fully counted run has no partial-count note
    out2 = tmp_path / "res2"
    w = ResultsWriter(out2, "hc", JOINTS, MARKERS)
    p, j, m = frame_data(0)
    w.append(0, p, j, m, evaluations=5, seconds=0.1, engine_calls=7)
    timing = w.finish()
    assert timing["engine_calls"] == 7 and "engine_calls_frames" not in timing
