"""Reports of :func:`gltrack.eval.metrics.evaluate`: summary table, per-frame CSV, error plot, JSON.

matplotlib is imported here only, and only by :func:`plot_errors`, with the Agg backend.
"""
from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path

import numpy as np

from gltrack.eval.metrics import SUMMARY_KEYS, TURNED_ROUND_DEG

log = logging.getLogger(__name__)

_LABELS = {
    "mean_joint_error_mm": ("mean 3D joint error", "mm"),
    "mpjpe_mm": ("MPJPE (root-relative)", "mm"),
    "pa_mpjpe_mm": ("PA-MPJPE (Procrustes)", "mm"),
    "marker_mean_m": ("marker error, mean", "m"),
    "marker_max_m": ("marker error, max per frame", "m"),
    "frac_markers_tracked": ("markers tracked (<= 0.1 m)", ""),
    "frac_markers_failed": ("markers failed (>= 0.3 m)", ""),
    "heading_error_deg": ("heading error (facing direction)", "deg"),
    "frac_turned_round": ("frames turned round (heading > 90 deg)", ""),
    "frames": ("frames", ""),
}


def _fmt(key, value):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if key == "frames":
        return str(int(value))
    if key.startswith("frac_"):
        return f"{100.0 * value:.1f} %"
    if key.endswith("_mm") or key.endswith("_deg"):
        return f"{value:.1f}"
    return f"{value:.4f}"


def summary_table(metrics):
    """The summary metrics as an aligned text table (one metric a line)."""
    rows = [(f"{_LABELS[k][0]}" + (f" [{_LABELS[k][1]}]" if _LABELS[k][1] else ""),
             _fmt(k, metrics.get(k))) for k in SUMMARY_KEYS]
    width = max(len(r[0]) for r in rows)
    lines = [f"{name:<{width}}  {value:>10}" for name, value in rows]
    extra = []
    if metrics.get("per_joint"):  # names the joints scored, with their errors
        extra.extend(per_joint_lines(metrics["per_joint"]))
    elif "joints" in metrics:
        extra.append(f"joints scored: {len(metrics['joints'])} ({', '.join(metrics['joints'])})")
    if metrics.get("marker_source") == "joints":
        extra.append("marker errors use the scored joints (no markers on one side)")
    if "body" in metrics:  # the results folder's body.json
        b = metrics["body"]
        extra.append(f"body: {b['source']} ({b['preset']} DOF preset, height "
                     f"{b['height_m']:.3f} m)")
        if "error_vs_dataset" in b:
            extra.append(f"body vs the dataset's: {body_error_text(b['error_vs_dataset'])}")
    return "\n".join(lines + extra)


def body_error_text(e: dict) -> str:
    """One line of a body's error against the true one (:func:`gltrack.body.measure.body_error`
    keys, plus ``height_vs_surface_mm`` where the dataset records its subject's surface)."""
    text = (f"bones {e['mean_bone_mm']:.0f} mm mean, {e['max_bone_mm']:.0f} mm max "
            f"({e['worst_bone']}), height {e['height_mm']:+.0f} mm")
    if e.get("height_vs_surface_mm") is not None:
        text += f" (against the subject's surface {e['height_vs_surface_mm']:+.0f} mm)"
    return text


def per_joint_lines(per_joint, width: int = 96) -> list[str]:
    """The mean error of each joint over the frames, ``name mm`` pairs wrapped at ``width``
    characters, under a heading that names the worst joint."""
    items = [(k, v["mean_mm"]) for k, v in per_joint.items()]
    finite = [(k, v) for k, v in items if v is not None and not math.isnan(v)]
    head = f"mean error of each of the {len(items)} joints scored [mm]"
    if finite:
        worst = max(finite, key=lambda kv: kv[1])
        head += f" (worst: {worst[0]} {worst[1]:.0f})"
    lines, line = [head + ":"], " "
    for k, v in items:
        cell = f" {k} " + ("n/a" if v is None or math.isnan(v) else f"{v:.0f}")
        if len(line) + len(cell) > width and line.strip():
            lines.append(line)
            line = " "
        line += cell
    if line.strip():
        lines.append(line)
    return lines


def per_frame_columns(metrics):
    """Column names of the per-frame table, ``frame`` first."""
    per = metrics["per_frame"]
    return ["frame"] + [k for k in per if k != "frame"]


def write_csv(metrics, path):
    """Write the per-frame table as CSV (header row; NaN written as empty cells)."""
    per = metrics["per_frame"]
    cols = per_frame_columns(metrics)
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for i in range(len(per["frame"])):
            row = []
            for c in cols:
                v = per[c][i]
                if c == "frame":
                    row.append(int(v))
                else:
                    row.append("" if np.isnan(v) else f"{float(v):.6g}")
            w.writerow(row)
    return path


def to_jsonable(metrics):
    """The metrics as plain JSON types: NaN becomes null, per-frame arrays become lists."""
    def clean(v):
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, np.ndarray):
            return [clean(x) for x in v.tolist()]
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, (np.integer,)):
            return int(v)
        if isinstance(v, (float, np.floating)):
            return None if math.isnan(v) or math.isinf(v) else float(v)
        return v

    return clean(metrics)


def write_json(metrics, path):
    """Write the metrics (summary keys, ``joints``, ``per_joint``, ``marker_source``,
    ``per_frame``, and ``body`` when the result records one) as JSON."""
    path = Path(path)
    path.write_text(json.dumps(to_jsonable(metrics), indent=1) + "\n")
    return path


def plot_errors(metrics, path, title=None, fps=None):
    """Plot joint errors (mm) and marker errors (m) over time to an image file (PNG by suffix).

    Parameters
    ----------
    metrics : dict from :func:`gltrack.eval.metrics.evaluate`
    path : path of the image
    title : str, optional
    fps : float, optional
        Frames per second; the x axis is seconds when given, frames otherwise.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = metrics["per_frame"]
    x = np.asarray(per["frame"], dtype=np.float64)
    xlabel = "frame"
    if fps:
        x, xlabel = x / fps, "time [s]"
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(9, 6), constrained_layout=True)
    for key, label in (("joint_error_mm", "3D joint error"), ("mpjpe_mm", "MPJPE"),
                       ("pa_mpjpe_mm", "PA-MPJPE")):
        ax1.plot(x, per[key], label=label, lw=1.2)
    _shade_turned_round(ax1, x, per.get("heading_error_deg"))
    ax1.set_ylabel("error [mm]")
    ax1.legend(loc="upper left")
    ax1.grid(alpha=0.3)
    ax2.plot(x, per["marker_mean_m"], label="marker mean", lw=1.2)
    ax2.plot(x, per["marker_max_m"], label="marker max", lw=1.2)
    ax2.axhline(0.1, color="g", ls="--", lw=0.8, label="tracked (0.1 m)")
    ax2.axhline(0.3, color="r", ls="--", lw=0.8, label="failed (0.3 m)")
    ax2.set_ylabel("marker error [m]")
    ax2.set_xlabel(xlabel)
    ax2.legend(loc="upper left")
    ax2.grid(alpha=0.3)
    if title:
        ax1.set_title(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def _shade_turned_round(ax, x, heading_deg):
    """Shade the frames whose heading error exceeds TURNED_ROUND_DEG (one legend entry)."""
    if heading_deg is None:
        return
    h = np.asarray(heading_deg, dtype=np.float64)
    bad = np.isfinite(h) & (h > TURNED_ROUND_DEG)
    if not bad.any() or len(x) < 2:
        return
    step = float(np.median(np.diff(x)))
    label = f"turned round (heading > {TURNED_ROUND_DEG:.0f} deg)"
    for i in np.nonzero(bad)[0]:
        ax.axvspan(x[i] - step / 2, x[i] + step / 2, color="tab:red", alpha=0.15, lw=0,
                   label=label)
        label = None


def plot_comparison(metrics_by_name: dict, path, title=None, fps=None):
    """One figure, several runs: mean 3-D joint error (mm) and mean marker error (m) over time.

    Parameters
    ----------
    metrics_by_name : {label: metrics dict from :func:`gltrack.eval.metrics.evaluate`}
    path : image path (PNG by suffix)
    fps : frames per second for a time axis (frames otherwise)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(9, 6), constrained_layout=True)
    for label, m in metrics_by_name.items():
        per = m["per_frame"]
        x = np.asarray(per["frame"], dtype=np.float64)
        if fps:
            x = x / fps
        ax1.plot(x, per["joint_error_mm"], lw=1.4,
                 label=f"{label}: mean {m['mean_joint_error_mm']:.0f} mm")
        ax2.plot(x, per["marker_mean_m"], lw=1.4, label=label)
    ax1.set_ylabel("3-D joint error [mm]")
    ax2.set_ylabel("mean marker error [m]")
    ax2.axhline(0.1, color="grey", ls="--", lw=0.8)
    ax2.text(0, 0.1, " tracked <= 0.1 m", va="bottom", fontsize=8, color="grey")
    ax2.set_xlabel("time [s]" if fps else "frame")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
        ax.set_ylim(bottom=0)
    if title:
        ax1.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
