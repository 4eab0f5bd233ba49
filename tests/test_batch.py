"""``gltrack batch`` (issue 17): many datasets, local spawn workers or Ray, bit-identical to
``gltrack track`` on each dataset alone; bad datasets reported, killed workers retried,
``--resume`` skipping and resuming.

The datasets are tiny depth takes (tests/trackdata.py) tracked with the cheap ``hc`` method from
the recorded body and the true first pose (``--body dataset --init groundtruth``: oracles, here
only to keep the runs short; the comparison is batch against single run with the same inputs).
"""
import contextlib
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from gltrack.cli import main
from gltrack.data.results import load_results

sys.path.insert(0, str(Path(__file__).parent))
from trackdata import make_depth_dataset  # noqa: E402

FAST = ["--body", "dataset", "--init", "groundtruth", "--seed", "4"]
N = 6


@contextlib.contextmanager
def _killer(out, pids):
    """SIGKILL the processes ``pids()`` as soon as the run in ``out`` has written two frames;
    yields the list of the pids killed (filled in by a thread while the body runs)."""
    killed = []

    def kill():
        deadline = time.time() + 240
        while time.time() < deadline:
            frames = out / "frames.jsonl"
            if frames.is_file() and frames.read_text().count("\n") >= 2:
                for pid in pids():
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                return
            time.sleep(0.01)

    t = threading.Thread(target=kill)
    t.start()
    try:
        yield killed
    finally:
        t.join()


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """Three datasets, their single runs (``gltrack track``), and a config of cheap options."""
    root = tmp_path_factory.mktemp("study")
    cfg = root / "cheap.toml"
    cfg.write_text("heading_hypotheses = 1\nlevels = 2\n")
    names = ["s0", "s1", "s2"]
    for i, name in enumerate(names):
        make_depth_dataset(root / "data" / name, n=N, seed=i)
        assert main(["-q", "track", str(root / "data" / name), "--method", "hc", "--out",
                     str(root / "single" / name), "--config", str(cfg), *FAST]) == 0
    return root, names, cfg


def _same(a, b):
    pa, pb = load_results(a)["params"], load_results(b)["params"]
    assert pa.shape == pb.shape
    assert np.array_equal(pa, pb), f"{b}: params differ by up to {np.abs(pa - pb).max():.3g}"


def test_local_workers_match_single_runs_and_a_bad_dataset_does_not_stop_the_others(
        study, tmp_path, capsys):
    root, names, cfg = study
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "meta.json").write_text("{ not json")
    out = tmp_path / "out"
    args = [str(root / "data" / names[0]), str(bad), *(str(root / "data" / n) for n in names[1:])]
    rc = main(["-q", "batch", *args, "--method", "hc", "--out", str(out), "--workers", "2",
               "--config", str(cfg), *FAST])
    assert rc == 1  # one dataset failed
    captured = capsys.readouterr()
    assert "broken" in captured.err and "failed" in captured.out
    for name in names:
        _same(root / "single" / name, out / name)
    summary = json.loads((out / "summary.json").read_text())
    by = {d["name"]: d for d in summary["datasets"]}
    assert [d["name"] for d in summary["datasets"]] == [names[0], "broken", *names[1:]]
    assert by["broken"]["status"] == "failed" and "meta.json" in by["broken"]["error"]
    assert not (out / "broken").exists()  # no debris that blocks a rerun
    for name in names:
        assert by[name]["status"] == "ok" and by[name]["frames"] == N
        assert by[name]["errors"]["mpjpe_mm"] > 0  # scored against the ground truth
    assert summary["frames"] == N * len(names)
    # the folder holds results now: without --resume a second batch is refused
    assert main(["-q", "batch", str(root / "data" / names[0]), "--method", "hc", "--out",
                 str(out), "--config", str(cfg), *FAST]) == 2


def _spawned_children():
    """PIDs of this process's multiprocessing ``spawn`` workers."""
    me, found = os.getpid(), []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == me and b"spawn_main" in cmd:
            found.append(int(d.name))
    return found


def test_a_worker_killed_mid_dataset_is_retried_and_the_result_is_identical(study, tmp_path):
    from gltrack.track.batch import Job, run_local

    root, names, cfg = study
    out = tmp_path / "out" / names[1]
    job = Job(names[1], str(root / "data" / names[1]), str(out), "hc",
              {"heading_hypotheses": 1, "levels": 2}, seed=4, init="groundtruth", body="dataset")
    with _killer(out, _spawned_children) as killed:
        [rec] = run_local([job], workers=1, retries=2)
    assert killed, "the worker was not killed"
    assert rec["status"] == "ok" and rec["attempts"] == 2, rec
    assert 2 <= rec["resumed"] < N, rec  # the second attempt went on from the first's frames
    _same(root / "single" / names[1], out)


def test_resume_skips_finished_and_resumes_partial_datasets(study, tmp_path):
    from gltrack.track.runner import track

    root, names, cfg = study
    out = tmp_path / "out"
    kw = dict(options={"heading_hypotheses": 1, "levels": 2}, body="dataset",
              init="groundtruth", seed=4, progress=False)
    track(root / "data" / names[0], "hc", out / names[0], **kw)  # finished
    before = (out / names[0] / "frames.jsonl").read_bytes()

    class Crash(Exception):
        pass

    def crash(tracker, f):
        if f == 3:
            raise Crash()

    with pytest.raises(Crash):  # frames 0-2 and their checkpoint
        track(root / "data" / names[1], "hc", out / names[1], hooks=[crash], **kw)
    args = ["-q", "batch", *(str(root / "data" / n) for n in names[:2]), "--method", "hc",
            "--out", str(out), "--config", str(cfg), "--workers", "1", *FAST]
    assert main(args) == 2  # not without --resume
    assert main([*args, "--resume"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    by = {d["name"]: d for d in summary["datasets"]}
    assert by[names[0]]["status"] == "skipped"
    assert (out / names[0] / "frames.jsonl").read_bytes() == before
    assert by[names[1]]["status"] == "ok" and by[names[1]]["resumed"] == 3
    for name in names[:2]:
        _same(root / "single" / name, out / name)


def test_manifest_overrides_and_errors_naming_file_and_field(study, tmp_path):
    from gltrack.track.batch_manifest import load_manifest
    from gltrack.track.registry import METHODS

    root, names, cfg = study
    m = tmp_path / "study.toml"
    m.write_text(f'[defaults]\nmethod = "hc"\noptions = {{ levels = 2 }}\n'
                 f'[[dataset]]\npath = "{root / "data" / names[0]}"\nname = "first"\n'
                 f'frames = "1:4"\noptions = {{ heading_hypotheses = 1 }}\n'
                 f'[[dataset]]\npath = "rel/take"\nframes = [0, 2]\nmethod = "hc+ep"\n')
    entries, defaults = load_manifest(m, METHODS)
    assert defaults["method"] == "hc" and defaults["options"] == {"levels": 2}
    assert entries[0]["frames"] == (1, 4) and entries[0]["name"] == "first"
    assert entries[1]["path"] == str(tmp_path / "rel" / "take")  # relative to the manifest
    assert entries[1]["method"] == "hc+ep" and entries[1]["frames"] == (0, 2)
    for text, field in [('[[dataset]]\npath = "a"\nfrmes = "1:2"\n', "dataset[0]: unknown key"),
                        ('[[dataset]]\npath = "a"\nframes = "4:2"\n', "dataset[0].frames"),
                        ('[[dataset]]\npath = "a"\nmethod = "nope"\n', "dataset[0].method"),
                        ('[[dataset]]\nname = "a"\n', "dataset[0].path"),
                        ('[defaults]\noptions = 3\n[[dataset]]\npath = "a"\n',
                         "defaults.options"),
                        ('dataset = 1\n', "dataset"),
                        ('[[dataset]\n', "not valid TOML")]:
        m.write_text(text)
        with pytest.raises(ValueError, match=str(m).replace(".", r"\.")) as err:
            load_manifest(m, METHODS)
        assert field in str(err.value), (text, str(err.value))
    # an unknown tracker option of one dataset: refused before anything runs (usage, exit 2)
    m.write_text(f'[[dataset]]\npath = "{root / "data" / names[0]}"\n'
                 f'options = {{ levles = 2 }}\n')
    assert main(["-q", "batch", "--manifest", str(m), "--method", "hc", "--out",
                 str(tmp_path / "o")]) == 1
    assert not (tmp_path / "o").exists()
    # the override of frames and options reaches the run: as `gltrack track --frames 1:4`
    # and a dataset that fails inside its worker (frames beyond its end) is reported
    m.write_text(f'[defaults]\noptions = {{ levels = 2 }}\n[[dataset]]\n'
                 f'path = "{root / "data" / names[0]}"\nname = "first"\nframes = "1:4"\n'
                 f'options = {{ heading_hypotheses = 1 }}\n'
                 f'[[dataset]]\npath = "{root / "data" / names[1]}"\nname = "beyond"\n'
                 f'frames = "50:60"\n')
    assert main(["-q", "batch", "--manifest", str(m), "--method", "hc", "--out",
                 str(tmp_path / "o"), "--workers", "1", *FAST]) == 1
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert [d["status"] for d in summary["datasets"]] == ["ok", "failed"]
    assert "50:60" in summary["datasets"][1]["error"]
    assert not (tmp_path / "o" / "beyond").exists()
    assert main(["-q", "track", str(root / "data" / names[0]), "--method", "hc", "--frames",
                 "1:4", "--out", str(tmp_path / "single"), "--config", str(cfg), *FAST]) == 0
    _same(tmp_path / "single", tmp_path / "o" / "first")
    assert len(load_results(tmp_path / "o" / "first")["params"]) == 3


def test_ray_without_ray_says_how_to_install_it(study, tmp_path, monkeypatch, capsys):
    root, names, cfg = study
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    assert main(["batch", str(root / "data" / names[0]), "--method", "hc", "--out",
                 str(tmp_path / "o"), "--ray", "local"]) == 2
    assert "pip install 'gltrack[ray]'" in capsys.readouterr().err


def test_local_ray_with_two_workers_matches_single_runs(study, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'gltrack[test]')")
    root, names, cfg = study
    out = tmp_path / "out"
    assert main(["-q", "batch", *(str(root / "data" / n) for n in names[:2]), "--method", "hc",
                 "--out", str(out), "--workers", "2", "--ray", "local", "--config", str(cfg),
                 *FAST]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["backend"] == "ray"
    assert [d["status"] for d in summary["datasets"]] == ["ok", "ok"]
    for name in names[:2]:
        _same(root / "single" / name, out / name)


def test_a_ray_actor_killed_mid_dataset_is_restarted_and_the_result_is_identical(study, tmp_path):
    """Ray restarts the actor and retries its task (``max_restarts``/``max_task_retries``);
    the retried job resumes from the killed attempt's checkpoint."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'gltrack[test]')")
    import subprocess

    from gltrack.track.batch import Job, run_ray

    root, names, cfg = study
    out = tmp_path / "out" / names[2]
    job = Job(names[2], str(root / "data" / names[2]), str(out), "hc",
              {"heading_hypotheses": 1, "levels": 2}, seed=4, init="groundtruth", body="dataset")
    def actors():  # the actor's process (Ray names it after the class and method)
        return [int(p) for p in subprocess.run(["pgrep", "-f", "ray::TrackActor"],
                                               capture_output=True, text=True).stdout.split()]

    with _killer(out, actors) as killed:
        [rec] = run_ray([job], "local", workers=1)
    assert killed, "the actor was not killed"
    assert rec["status"] == "ok" and 2 <= rec["resumed"] < N, rec
    _same(root / "single" / names[2], out)


def test_a_folder_of_datasets_stands_for_the_datasets_in_it(tmp_path):
    from gltrack.cli.batch import expand_folders

    study = tmp_path / "study"
    for name in ("b_take", "a_take"):
        (study / name).mkdir(parents=True)
        (study / name / "meta.json").write_text("{}")
    (study / "notes").mkdir()  # not a dataset: left out
    single = study / "a_take"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert expand_folders([str(study)]) == [str(study / "a_take"), str(study / "b_take")]
    # a dataset stays itself; a folder without datasets is kept (and fails as a dataset)
    assert expand_folders([str(single), str(empty)]) == [str(single), str(empty)]
