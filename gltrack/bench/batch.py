"""``gltrack bench batch``: study throughput of ``gltrack batch`` with 1 and 2 local workers and
2 Ray workers.

Data: :data:`DATASETS` short depth takes (:data:`FRAMES` frames at 30 frames/s each) synthesised
with ``gltrack synth --rig depth`` from consecutive stretches of one CMU clip in
``$GLTRACK_SHARED/mocap`` (:data:`CLIP`), each with its own sensor-noise seed. Every dataset is
tracked with ``hc`` and its default options, the automatic start (``--init auto``) and one
body: the subject's body estimated once, by a run on the first dataset (the same subject
recorded every take, as in a study; the estimate, about a minute per dataset on llvmpipe, is
not repeated per take). That calibration run is timed and reported apart.

Figures per configuration: wall seconds, datasets per hour, frames per second, the mean
seconds a dataset spends tracking (``timing.json``: its frames only) and the per-dataset
overhead (worker time not spent tracking frames: process start, imports, GL context,
dataset loading, the automatic start, writing results), plus the speed-ups the issue's
targets name: ``speedup_2_local`` (2 local workers over 1, target >= 1.7) and
``ray_vs_local`` (2 Ray workers over 2 local ones, target >= 0.85). Workers set
``LP_NUM_THREADS`` to their share of the cores (:func:`gltrack.track.batch.worker_threads`).
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

from gltrack.data.depth_clips import FPS, SOURCE_FPS, synth_depth

from . import machine_name, shared_dir

log = logging.getLogger(__name__)

#: the clip the datasets are cut from, and the first source frame (120 frames/s)
CLIP = "mocap/cmu_131_03_start_hop_stop_max_metres.bvh"
FIRST = 100
DATASETS = 8
FRAMES = 30
TARGET_SPEEDUP = 1.7
TARGET_RAY = 0.85


def _synth_all(bvh: Path, root: Path, n: int, frames: int) -> list[Path]:
    step = int(round(frames * SOURCE_FPS / FPS))
    return [synth_depth(bvh, root / f"take{k:02d}", FIRST + k * step, frames, seed=k)
            for k in range(n)]


def _measure(run, jobs, label: str) -> dict:
    t0 = time.perf_counter()
    records = run(jobs)
    wall = time.perf_counter() - t0
    bad = [r for r in records if r["status"] != "ok"]
    if bad:
        raise RuntimeError(f"bench batch ({label}): {bad[0]['name']} failed: {bad[0]['error']}")
    frames = sum(r["frames"] for r in records)
    tracking = [r["seconds"] for r in records]
    return {"wall_s": wall, "datasets": len(records), "frames": frames,
            "datasets_per_hour": 3600.0 * len(records) / wall, "frames_per_s": frames / wall,
            "tracking_s_mean": sum(tracking) / len(tracking),
            "worker_processes": len({r.get("pid") for r in records if r.get("pid")}) or None}


def bench_batch(quick: bool = False, seed: int = 0, with_ray: bool = True) -> dict:
    """Run the benchmark; the JSON-serialisable results.

    Parameters
    ----------
    quick : 4 datasets of 10 frames instead of :data:`DATASETS` of :data:`FRAMES`
    seed : tracker seed of every dataset
    with_ray : also time 2 Ray workers (needs Ray; skipped with a note when it is missing)
    """
    from gltrack.track.batch import Job, run_local, run_ray, worker_threads

    shared = shared_dir()
    if shared is None or not (shared / CLIP).is_file():
        raise FileNotFoundError(f"bench batch needs {CLIP} in the shared reference folder "
                                "(GLTRACK_SHARED or ../shared)")
    n, frames = (4, 10) if quick else (DATASETS, FRAMES)
    root = Path(tempfile.mkdtemp(prefix="gltrack-bench-batch-"))
    try:
        t0 = time.perf_counter()
        takes = _synth_all(shared / CLIP, root / "data", n, frames)
        synth_s = time.perf_counter() - t0

        def jobs(out, body):
            return [Job(p.name, str(p), str(root / out / p.name), "hc", {}, seed=seed,
                        init="auto", body=body) for p in takes]

        # the subject's body, estimated once on the first take (timed apart)
        calib = jobs("calibration", "estimate")[:1]
        t0 = time.perf_counter()
        [rec] = run_local(calib, workers=1)
        if rec["status"] != "ok":
            raise RuntimeError(f"bench batch: the calibration run failed: {rec['error']}")
        calibration_s = time.perf_counter() - t0
        body = str(Path(calib[0].out) / "body.json")

        res = {"bench": "batch", "machine": machine_name(), "cores": os.cpu_count(),
               "quick": quick, "method": "hc", "datasets": n, "frames_per_dataset": frames,
               "clip": CLIP, "init": "auto", "body": "estimated once on the first dataset",
               "synth_s": synth_s, "calibration_s": calibration_s,
               "lp_num_threads": {str(w): int(os.environ.get("LP_NUM_THREADS")
                                                  or worker_threads(w)) for w in (1, 2)},
               "runs": {}}
        runs = res["runs"]
        runs["local_1"] = _measure(lambda j: run_local(j, workers=1), jobs("local1", body),
                                   "1 local worker")
        runs["local_2"] = _measure(lambda j: run_local(j, workers=2), jobs("local2", body),
                                   "2 local workers")
        if with_ray:
            try:
                import ray  # noqa: F401
            except ImportError:
                res["ray_note"] = "Ray is not installed (pip install 'gltrack[ray]')"
            else:
                runs["ray_2"] = _measure(lambda j: run_ray(j, "local", workers=2),
                                         jobs("ray2", body), "2 Ray workers")
                runs["ray_2"]["includes_ray_start"] = True
        for r in runs.values():
            w = 1 if r is runs["local_1"] else 2
            # worker time not spent tracking frames, per dataset
            r["overhead_s_per_dataset"] = (r["wall_s"] * w / r["datasets"]
                                           - r["tracking_s_mean"])
        res["speedup_2_local"] = runs["local_1"]["wall_s"] / runs["local_2"]["wall_s"]
        res["target_speedup_2_local"] = TARGET_SPEEDUP
        if "ray_2" in runs:
            res["ray_vs_local"] = runs["local_2"]["wall_s"] / runs["ray_2"]["wall_s"]
            res["target_ray_vs_local"] = TARGET_RAY
        return res
    finally:
        shutil.rmtree(root, ignore_errors=True)


def format_table(res: dict) -> str:
    """The results as text."""
    lines = [f"machine:  {res['machine']}",
             f"study:    {res['datasets']} datasets x {res['frames_per_dataset']} frames, "
             f"method {res['method']}, init {res['init']}, body {res['body']}",
             f"synth {res['synth_s']:.1f} s, body calibration run {res['calibration_s']:.1f} s, "
             f"LP_NUM_THREADS per worker {res['lp_num_threads']}", "",
             f"{'run':10s} {'wall s':>8s} {'datasets/h':>11s} {'frames/s':>9s} "
             f"{'track s/ds':>11s} {'overhead s/ds':>14s}"]
    for name, r in res["runs"].items():
        lines.append(f"{name:10s} {r['wall_s']:8.1f} {r['datasets_per_hour']:11.0f} "
                     f"{r['frames_per_s']:9.2f} {r['tracking_s_mean']:11.1f} "
                     f"{r['overhead_s_per_dataset']:14.1f}")
    lines.append("")
    lines.append(f"2 local / 1 local: {res['speedup_2_local']:.2f}x "
                 f"(target >= {res['target_speedup_2_local']})")
    if "ray_vs_local" in res:
        lines.append(f"2 Ray / 2 local:   {res['ray_vs_local']:.2f} "
                     f"(target >= {res['target_ray_vs_local']}, i.e. within 15 %)")
    elif "ray_note" in res:
        lines.append(res["ray_note"])
    return "\n".join(lines)
