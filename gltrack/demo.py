"""The embedded end-to-end demo: synthesise, track, evaluate, visualise.

Needs no downloads and no reference data: the motion is :func:`gltrack.data.procedural.performance`
(walk, turn, arm raise, squat) on the default body. Steps:

1. synthesise a depth dataset (one ToF-like camera, default noise) and a 4-camera colour dataset
   (cluttered background, background-subtracted masks) with the pyrender sensor simulator;
2. track the depth data with Ganapathi's hill climbing (plus evidence propagation when available)
   and the multi-view data with Bandouch's hierarchical partitioned sampler;
3. evaluate both against the ground truth, plot the errors over time, render overlay videos;
4. return a summary (and ``summary.json``) with errors, speed and file locations.
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: Demo settings: small enough to finish in about three minutes on a 2-core machine with
#: software GL, large enough to show every phase of the performance.
FPS = 15.0
SECONDS = 4.0
MULTIVIEW_OPTIONS = {"particles": 100}


def run_demo(out="gltrack-demo", *, seed: int = 0, progress: bool = True, overwrite: bool = True,
             seconds: float = SECONDS, fps: float = FPS, rigs=("depth", "multiview")) -> dict:
    """Run the demo into ``out``; returns the summary dict (also written to ``summary.json``)."""
    from gltrack.body.model import BodyModel
    from gltrack.data.dataset import Dataset
    from gltrack.data.procedural import performance
    from gltrack.data.results import load_results
    from gltrack.data.simulate import synthesize_in_subprocess
    from gltrack.eval.metrics import evaluate
    from gltrack.eval.overlay import render_overlay
    from gltrack.eval.report import plot_comparison, write_json
    from gltrack.track.runner import track

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    body = BodyModel.build()
    params = performance(body, fps=fps, seconds=seconds)
    plan = {"depth": "hc+ep", "multiview": "hps"}
    summary = {"frames": int(len(params)), "fps": fps, "rigs": {}, "files": {}}
    metrics_by_rig = {}
    for rig in rigs:
        method = plan[rig]
        ds_dir, res_dir = out / f"{rig}_dataset", out / f"{rig}_result"
        t0 = time.perf_counter()
        synthesize_in_subprocess(params, body.skeleton, body.dofs, fps, rig, str(ds_dir), seed=seed,
                                 progress=progress, overwrite=overwrite)
        t_synth = time.perf_counter() - t0
        opts = MULTIVIEW_OPTIONS if rig == "multiview" else None
        t0 = time.perf_counter()
        timing = track(ds_dir, method, res_dir, options=opts, overwrite=overwrite, seed=seed,
                       progress=progress)
        t_track = time.perf_counter() - t0
        ds = Dataset.open(ds_dir)
        m = evaluate(load_results(res_dir), ds.groundtruth())
        write_json(m, res_dir / "metrics.json")
        video = render_overlay(res_dir, ds_dir, out / f"{rig}_overlay.mp4", progress=progress)
        metrics_by_rig[f"{rig} ({method})"] = m
        summary["rigs"][rig] = {
            "method": method, "mean_joint_error_mm": m["mean_joint_error_mm"],
            "mpjpe_mm": m["mpjpe_mm"], "marker_mean_m": m["marker_mean_m"],
            "frac_markers_tracked": m["frac_markers_tracked"],
            "frac_markers_failed": m["frac_markers_failed"],
            "tracking_fps": timing.get("fps"), "evaluations_per_frame":
                timing["evaluations"] / max(timing["frames"], 1),
            "synth_seconds": t_synth, "track_seconds": t_track,
            "dataset": str(ds_dir), "result": str(res_dir), "video": str(video.path),
            "video_codec": video.codec}
    plot = out / "errors.png"
    if metrics_by_rig:
        plot_comparison(metrics_by_rig, plot, title="gltrack demo: error over time", fps=fps)
        summary["files"]["plot"] = str(plot)
    summary["seconds"] = time.perf_counter() - t_start
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    summary["files"]["summary"] = str(out / "summary.json")
    return summary


def format_summary(s: dict) -> str:
    """The one-screen summary the CLI prints."""
    lines = [f"gltrack demo: {s['frames']} frames at {s['fps']:g} fps, finished in {s['seconds']:.0f} s", ""]
    lines.append(f"{'rig':10s} {'method':7s} {'joint err':>10s} {'MPJPE':>8s} {'markers ok':>10s} "
                 f"{'failed':>7s} {'track fps':>9s} {'evals/frame':>11s}")
    for rig, r in s["rigs"].items():
        lines.append(f"{rig:10s} {r['method']:7s} {r['mean_joint_error_mm']:8.0f}mm {r['mpjpe_mm']:6.0f}mm "
                     f"{100 * r['frac_markers_tracked']:9.1f}% {100 * r['frac_markers_failed']:6.1f}% "
                     f"{(r['tracking_fps'] or 0):9.2f} {r['evaluations_per_frame']:11.0f}")
    lines.append("")
    for rig, r in s["rigs"].items():
        codec = f" ({r['video_codec']})" if r.get("video_codec") else ""
        lines.append(f"{rig}: dataset {r['dataset']}, result {r['result']} (poses.bvh inside), "
                     f"video {r['video']}{codec}")
    for k, v in s["files"].items():
        lines.append(f"{k}: {v}")
    return "\n".join(lines)
