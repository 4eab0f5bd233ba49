"""Quality of a tracking result without ground truth: silhouette IoU and joint jitter.

Two figures any take has, recorded or synthetic:

* **silhouette IoU** per camera: ``|M & F| / |M | F|`` of the model's silhouette at the estimate
  (M) and the frame's foreground mask (F), counted by the multi-view trackers with the scoring
  engine (each camera resampled to ``iou_tile`` pixels square, 256 by default) over the pixels
  the costs do not block, and recorded per frame as
  ``info["iou"]`` (one value per colour camera, 0..1) in ``frames.jsonl``. Summarised per
  camera as the mean and the minimum over the frames, and the frames below
  :data:`IOU_LOW` (0.6: the issue's "no frame below" bound; a silhouette that poor means a limb
  or the whole body is off the person). Where the tracker records them (``info["model_on_fg"]``
  and ``info["fg_covered"]``), the mean shares of the model's silhouette on the foreground and
  of the foreground the model covers say which side loses: a low first share, the model sticks
  out of the masks (too large, a limb off the person); a low second one, the masks hold what the
  model does not explain (background taken for the person, a limb the model missed).
* **joint jitter**: for each result frame t whose neighbours t - 1 and t + 1 were tracked too,
  the mean over the joints of ``|x_j(t+1) - 2 x_j(t) + x_j(t-1)|``, the norm of the second
  difference of joint j's position (its change of velocity from one frame to the next), in
  millimetres per frame^2. Summarised as the mean and the 95th percentile over those frames.
  A norm of a difference of positions, it does not depend on the frame the joints are written
  in (user or internal). A smooth real motion gives a few mm/frame^2 at 30-60 frames/s (a hand
  swinging at 2 m/s turning round in 0.3 s: about 7 mm/frame^2 at 30 frames/s); tens of mm mean
  the estimate shakes from frame to frame.

Joints are :data:`gltrack.eval.metrics.EVAL_JOINTS` present in the result (all joints when none
is).
"""
from __future__ import annotations

import logging
import warnings

import numpy as np

from gltrack.eval.metrics import EVAL_JOINTS

log = logging.getLogger(__name__)

#: IoU below which a frame is listed as poor.
IOU_LOW = 0.6


def joint_jitter(joints, frames=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame joint jitter: mean over joints of the norm of the second difference.

    Parameters
    ----------
    joints : (N, J, 3) float, metres, rows in frame order
    frames : (N,) int, dataset frame of each row (default ``0..N-1``); only rows whose
        neighbours are the frames just before and after count

    Returns
    -------
    frame : (K,) int64, the middle frame t of each scored triple
    jitter_mm : (K,) float64, mm per frame^2, ``mean_j |x_j(t+1) - 2 x_j(t) + x_j(t-1)|``
        (joints with a non-finite coordinate are left out; NaN if none is left)
    """
    X = np.asarray(joints, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"joints must be (N, J, 3), got {X.shape}")
    n = len(X)
    f = np.arange(n) if frames is None else np.asarray(frames, dtype=np.int64)
    if f.shape != (n,):
        raise ValueError(f"frames {f.shape} do not match {n} rows of joints")
    order = np.argsort(f, kind="stable")
    X, f = X[order], f[order]
    if n < 3:
        return np.zeros(0, np.int64), np.zeros(0)
    ok = (f[1:-1] - f[:-2] == 1) & (f[2:] - f[1:-1] == 1)
    acc = np.linalg.norm(X[2:] - 2.0 * X[1:-1] + X[:-2], axis=2)[ok]  # (K, J) m
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frame with no finite joint: NaN
        per = 1000.0 * np.nanmean(np.where(np.isfinite(acc), acc, np.nan), axis=1)
    return f[1:-1][ok], per


def _finite(x):
    x = np.asarray(x, dtype=np.float64)
    return x[np.isfinite(x)]


def quality_summary(result, infos: dict, camera_names=None, low: float = IOU_LOW) -> dict:
    """Summarise the ground-truth-free quality of a result.

    Parameters
    ----------
    result : dict from :func:`gltrack.data.results.load_results` (``joints`` (N, J, 3) m,
        ``joint_names``, ``frame`` (N,))
    infos : dict frame -> info, from :func:`gltrack.data.results.frame_infos`
    camera_names : list of str, names of the cameras the IoU lists follow (the dataset's
        colour cameras); default ``cam0``, ``cam1``, ...
    low : float, IoU below which a frame is listed

    Returns
    -------
    dict
        ``cameras`` (C,) names; ``iou_mean``, ``iou_min`` (C,) floats (NaN for a camera no frame
        has a value for); ``iou_frames_below`` dict camera -> list of frames with IoU < ``low``;
        ``iou_low`` = ``low``; ``iou_frames`` (frames with an IoU record);
        ``iou_frames_self_refined`` (frames the tracker scored against masks it refined with
        its own estimate, ``info["masks_refined"]``);
        ``model_on_fg_mean``, ``fg_covered_mean`` (C,) floats (NaN where not recorded);
        ``jitter_mean_mm``, ``jitter_p95_mm`` (mm/frame^2, NaN with fewer than 3 consecutive
        frames), ``jitter_frames``, ``jitter_joints`` (names); ``per_frame``: ``frame`` (N,),
        ``iou_<camera>``, ``model_on_fg_<camera>``, ``fg_covered_<camera>`` (N,) (NaN where not
        recorded) and ``jitter_mm`` (N,) (NaN at the ends of a run of frames);
        ``start``: the choice between start hypotheses the runner recorded on the first frame
        (``info["start"]``: ``means``, ``kept``, ``uncertain``, ``turned_deg``,
        ``knees_at_limit``), or None;
        ``restarts``: one dict per re-start check (``frame``, ``restarted``, ``uncertain``);
        ``keypoint_median_mm``, ``keypoint_mean_mm``, ``keypoint_frames``: the estimate's
        mean joint distance to the dataset's triangulated keypoints (``info["keypoint_m"]``,
        recorded by trackers that use them; NaN and 0 frames otherwise), per frame as
        ``per_frame["keypoint_mm"]``.
    """
    frames = np.asarray(result.get("frame", np.arange(len(result["joints"]))), dtype=np.int64)
    order = np.argsort(frames, kind="stable")
    frames = frames[order]
    ious = [infos.get(int(f), {}).get("iou") for f in frames]
    C = max((len(v) for v in ious if isinstance(v, (list, tuple))), default=0)
    names = list(camera_names or [])
    if len(names) != C:
        if names and C:
            log.warning("frames.jsonl has %d IoU values per frame, the dataset %d colour "
                        "cameras: cameras named by index", C, len(names))
        names = [f"cam{k}" for k in range(C)]

    def per_camera(key):
        """(N, C) of info[key] per frame and camera, NaN where not recorded."""
        out = np.full((len(frames), C), np.nan)
        for i, f in enumerate(frames):
            v = infos.get(int(f), {}).get(key)
            if isinstance(v, (list, tuple)) and len(v) == C:
                out[i] = [np.nan if x is None else float(x) for x in v]
        return out

    def col_mean(col):
        col = _finite(col)
        return float(col.mean()) if col.size else float("nan")

    table = per_camera("iou")
    shares = {key: per_camera(key) for key in ("model_on_fg", "fg_covered")}
    recorded = np.isfinite(table).any(axis=1) if C else np.zeros(len(frames), bool)
    mean, mn, below = [], [], {}
    for k, name in enumerate(names):
        col = _finite(table[:, k])
        mean.append(col_mean(col))
        mn.append(float(col.min()) if col.size else float("nan"))
        below[name] = [int(f) for f, x in zip(frames, table[:, k]) if np.isfinite(x) and x < low]

    jnames = list(result["joint_names"])
    idx = [jnames.index(j) for j in EVAL_JOINTS if j in jnames] or list(range(len(jnames)))
    J = np.asarray(result["joints"], dtype=np.float64)[order][:, idx]
    jf, jit = joint_jitter(J, frames)
    per_jit = np.full(len(frames), np.nan)
    per_jit[np.searchsorted(frames, jf)] = jit
    good = _finite(jit)
    per = {"frame": frames}
    for k, name in enumerate(names):
        per[f"iou_{name}"] = table[:, k]
        for key, tab in shares.items():
            per[f"{key}_{name}"] = tab[:, k]
    per["jitter_mm"] = per_jit
    kp = np.array([np.nan if infos.get(int(f), {}).get("keypoint_m") is None
                   else 1000.0 * float(infos[int(f)]["keypoint_m"]) for f in frames])
    per["keypoint_mm"] = kp
    kp_ok = _finite(kp)
    refined = sum(bool(infos.get(int(f), {}).get("masks_refined")) for f in frames)
    start = next((infos[int(f)]["start"] for f in frames
                  if isinstance(infos.get(int(f), {}).get("start"), dict)), None)
    restarts = [{"frame": r.get("frame"), "restarted": bool(r.get("restarted")),
                 "uncertain": bool((r.get("decision") or {}).get("uncertain"))}
                for r in (infos.get(int(f), {}).get("restart") for f in frames)
                if isinstance(r, dict)]
    return {
        "cameras": names, "iou_mean": mean, "iou_min": mn, "iou_frames_below": below,
        "iou_low": float(low), "iou_frames": int(recorded.sum()),
        "iou_frames_self_refined": int(refined),
        **{f"{key}_mean": [col_mean(tab[:, k]) for k in range(C)]
           for key, tab in shares.items()},
        "jitter_mean_mm": float(good.mean()) if good.size else float("nan"),
        "jitter_p95_mm": float(np.percentile(good, 95)) if good.size else float("nan"),
        "jitter_frames": int(good.size), "jitter_joints": [jnames[i] for i in idx],
        "start": start, "restarts": restarts,
        "keypoint_median_mm": float(np.median(kp_ok)) if kp_ok.size else float("nan"),
        "keypoint_mean_mm": float(kp_ok.mean()) if kp_ok.size else float("nan"),
        "keypoint_frames": int(kp_ok.size),
        "per_frame": per,
    }


def quality_table(q: dict) -> str:
    """The summary of :func:`quality_summary` as text: one line per camera, then the jitter."""
    lines = []
    if q["cameras"]:
        w = max(6, *(len(c) for c in q["cameras"]))
        def fmt(v, width):
            return f"{'n/a' if not np.isfinite(v) else f'{v:.3f}':>{width}}"

        nan = [float("nan")] * len(q["cameras"])
        on_fg, covered = q.get("model_on_fg_mean", nan), q.get("fg_covered_mean", nan)
        shares = bool(np.isfinite(on_fg).any() or np.isfinite(covered).any())
        extra = f"  {'model on fg':>11}  {'fg covered':>10}" if shares else ""
        lines.append(f"{'camera':<{w}}  {'mean IoU':>8}  {'min IoU':>7}{extra}  "
                     f"frames < {q['iou_low']:g}")
        for c, m, lo, a, b_ in zip(q["cameras"], q["iou_mean"], q["iou_min"], on_fg, covered):
            b = q["iou_frames_below"][c]
            shown = ", ".join(str(f) for f in b[:8]) + (", ..." if len(b) > 8 else "")
            extra = f"  {fmt(a, 11)}  {fmt(b_, 10)}" if shares else ""
            lines.append(f"{c:<{w}}  {fmt(m, 8)}  {fmt(lo, 7)}{extra}  {len(b)}"
                         + (f" ({shown})" if b else ""))
        source = ("recomputed against the dataset's masks as they are now (full resolution, "
                  "no environment layers)" if q.get("iou_source") == "recomputed"
                  else "frames.jsonl info 'iou', recorded while tracking")
        lines.append(f"silhouette IoU of {q['iou_frames']} frames ({source})")
        if q.get("iou_frames_self_refined") and q.get("iou_source") != "recomputed":
            lines.append(f"{q['iou_frames_self_refined']} of them scored against masks the "
                         "track refined with its own estimate (mask_refine): not an "
                         "independent check; --iou-now scores against the dataset's masks")
        if shares:
            lines.append("model on fg: share of the model's silhouette on the foreground (low: "
                         "the model sticks out of the masks); fg covered: share of the "
                         "foreground the model covers (low: the masks hold what the model does "
                         "not explain)")
    else:
        lines.append("silhouette IoU: n/a (frames.jsonl records none: not a multi-view tracker, "
                     "or no frames.jsonl)")
    if q["jitter_frames"]:
        lines.append(f"joint jitter [mm/frame^2]: mean {q['jitter_mean_mm']:.1f}, 95th percentile "
                     f"{q['jitter_p95_mm']:.1f} ({q['jitter_frames']} frames, "
                     f"{len(q['jitter_joints'])} joints)")
    else:
        lines.append("joint jitter: n/a (fewer than 3 consecutive frames)")
    if q.get("keypoint_frames"):
        lines.append(f"distance to the triangulated keypoints [mm]: median "
                     f"{q['keypoint_median_mm']:.0f}, mean {q['keypoint_mean_mm']:.0f} "
                     f"({q['keypoint_frames']} frames; the tracker fits them, so this says how "
                     "far the silhouettes pulled it away, not how right either is)")
    lines += _start_lines(q.get("start"), q.get("restarts") or [])
    return "\n".join(lines)


def _start_lines(start: dict | None, restarts: list) -> list[str]:
    """How the track began and was re-started, as text lines: an uncertain start (a tie
    between a body and its turned-round twin) is the first thing to check on a real take."""
    lines = []
    if start and start.get("chosen"):
        lines.append(f"start: hypothesis {start.get('kept')} of {start.get('hypotheses')}, kept "
                     f"by {start['chosen']} (not decided by the frames)")
    elif start:
        means = ", ".join(f"{m:.3f}" for m in start.get("means", []))
        turned = start.get("turned_deg")
        apart = "" if turned is None else \
            "; turned " + ", ".join(f"{t:.0f}" for t in turned) + " deg from the kept one"
        knees = start.get("knees_at_limit")
        if knees is not None:
            apart += "; knees at their extension limit in " + \
                ", ".join(f"{100 * k:.0f}" for k in knees) + " % of the frames"
        lines.append(f"start: {start.get('hypotheses')} hypotheses tracked {start.get('frames')} "
                     f"frames, mean {start.get('measure')} {means}{apart}; kept "
                     f"{start.get('kept')}")
        if start.get("uncertain"):
            other = next((j for j in range(int(start.get("hypotheses") or 0))
                          if j != start.get("kept")), None)
            lines.append("start UNCERTAIN: the hypotheses explained the first frames about "
                         "equally well; check in the overlay (gltrack render) that the body "
                         "faces the right way" + ("" if other is None else
                                                  f" (if not: --start-hypothesis {other})"))
    if restarts:
        done = [r["frame"] for r in restarts if r["restarted"]]
        lines.append(f"re-start checks: {len(restarts)}, re-started at "
                     + (", ".join(str(f) for f in done) if done else "none"))
    return lines
