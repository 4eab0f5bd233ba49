"""Pose-error metrics: 3D joint error, MPJPE, PA-MPJPE and Ganapathi-style marker errors.

Pure numpy functions. Positions are metres; the summary keys that end in ``_mm`` are millimetres,
the ones that end in ``_m`` are metres.

Joint set
---------
Joint errors are taken over a HumanEva-style set of 15 joints (:data:`EVAL_JOINTS`): pelvis, neck,
head, shoulders, elbows, wrists, hips, knees and ankles, intersected with the names present in
both the result and the ground truth. Spine and clavicle joints are left out because motion
capture skeletons place them inconsistently, which would make errors depend on the rig, not the
tracker.

Missing ground truth (NaN coordinates, e.g. an occluded marker) is ignored by every metric.

Heading
-------
A track can sit on the subject's outline while facing the wrong way (a silhouette, a set of
blobs or a depth image of a body fits its turned-round twin almost as well), and a mean joint
error does not say so. :func:`heading_errors` compares which way the body faces: the angle
between the estimated and the true across-body direction (left hip minus right hip plus left
shoulder minus right shoulder), both taken in the plane perpendicular to the true trunk axis
(pelvis to neck), so it needs no up axis and holds in any world frame. Above 90 degrees the
track is turned round (``frac_turned_round``).

Marker errors (Ganapathi et al. 2010)
-------------------------------------
Per frame, ``mean_i ||m_i - m'_i||`` and ``max_i ||m_i - m'_i||`` over the visible markers. A marker
whose error is ``<= 0.1 m`` counts as tracked and one ``>= 0.3 m`` as a failure.
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

#: Joints scored by the joint metrics (HumanEva-style), in gltrack names.
EVAL_JOINTS = (
    "pelvis", "neck", "head",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
    "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle",
)
ROOT_JOINT = "pelvis"
TRACKED_M = 0.1
FAILED_M = 0.3

#: Summary keys of :func:`evaluate`, in the order reports show them.
SUMMARY_KEYS = (
    "mean_joint_error_mm", "mpjpe_mm", "pa_mpjpe_mm", "marker_mean_m", "marker_max_m",
    "frac_markers_tracked", "frac_markers_failed", "heading_error_deg", "frac_turned_round",
    "frames",
)
#: Joints :func:`heading_errors` needs on both sides.
HEADING_JOINTS = ("pelvis", "neck", "l_hip", "r_hip", "l_shoulder", "r_shoulder")
#: Heading error above which a frame counts as turned round, degrees.
TURNED_ROUND_DEG = 90.0


def _as_points(x, name):
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"{name} must be (N, J, 3), got shape {x.shape}")
    return x


def _check_pair(pred, gt):
    pred = _as_points(pred, "prediction")
    gt = _as_points(gt, "ground truth")
    if pred.shape != gt.shape:
        raise ValueError(f"prediction {pred.shape} and ground truth {gt.shape} differ in shape")
    return pred, gt


def _nanmean_rows(d):
    """Mean over axis 1 ignoring NaN; NaN (without a warning) for rows with nothing valid."""
    valid = ~np.isnan(d)
    n = valid.sum(axis=1)
    s = np.where(valid, d, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def point_distances(pred, gt):
    """Euclidean distance per point.

    Parameters
    ----------
    pred, gt : (N, J, 3) float, metres

    Returns
    -------
    (N, J) float64, metres; NaN where either point has a NaN coordinate.
    """
    pred, gt = _check_pair(pred, gt)
    return np.linalg.norm(pred - gt, axis=2)


def mean_joint_error(pred, gt):
    """Mean 3D joint error per frame, in the world frame (no alignment).

    Parameters
    ----------
    pred, gt : (N, J, 3) float, metres

    Returns
    -------
    (N,) float64, metres
    """
    return _nanmean_rows(point_distances(pred, gt))


def mpjpe(pred, gt, root=0):
    """Root-relative mean per-joint position error per frame.

    Both skeletons are translated so that joint ``root`` is at the origin before comparing, which
    removes global translation error (but not global rotation).

    Parameters
    ----------
    pred, gt : (N, J, 3) float, metres
    root : int or None
        Index of the root joint. None uses the mean of the valid joints instead.

    Returns
    -------
    (N,) float64, metres
    """
    pred, gt = _check_pair(pred, gt)
    if root is None:
        # Centroids over the joints valid in the ground truth, so both are taken over the same set.
        mask = ~np.isnan(gt).any(axis=2, keepdims=True)
        cnt = np.maximum(mask.sum(axis=1, keepdims=True), 1)
        pc = np.where(mask, pred, 0.0).sum(axis=1, keepdims=True) / cnt
        gc = np.where(mask, gt, 0.0).sum(axis=1, keepdims=True) / cnt
    else:
        pc, gc = pred[:, root:root + 1], gt[:, root:root + 1]
    return mean_joint_error(pred - pc, gt - gc)


def procrustes_align(pred, gt, scale=True):
    """Similarity transform of ``pred`` that best fits ``gt`` in least squares (Umeyama 1991).

    Parameters
    ----------
    pred, gt : (J, 3) float, metres; rows with NaN in either are ignored for the fit.
    scale : bool
        Also fit a uniform scale.

    Returns
    -------
    (J, 3) float64
        ``s * R @ pred + t`` for every row of ``pred``; all NaN when fewer than 3 rows are valid.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    ok = ~(np.isnan(pred).any(axis=1) | np.isnan(gt).any(axis=1))
    if ok.sum() < 3:
        return np.full_like(pred, np.nan)
    p, g = pred[ok], gt[ok]
    mp, mg = p.mean(axis=0), g.mean(axis=0)
    p0, g0 = p - mp, g - mg
    u, sig, vt = np.linalg.svd(g0.T @ p0)
    # Reflection guard: a proper rotation, never a mirror image of the prediction.
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[-1] = -1.0
    rot = u @ np.diag(d) @ vt
    var_p = (p0 ** 2).sum()
    s = float((sig * d).sum() / var_p) if scale and var_p > 0 else 1.0
    return s * (pred - mp) @ rot.T + mg


def pa_mpjpe(pred, gt, scale=True):
    """Per-frame Procrustes-aligned mean joint error.

    Parameters
    ----------
    pred, gt : (N, J, 3) float, metres
    scale : bool
        Fit a uniform scale as well as rotation and translation (the usual PA-MPJPE).

    Returns
    -------
    (N,) float64, metres
    """
    pred, gt = _check_pair(pred, gt)
    aligned = np.stack([procrustes_align(p, g, scale) for p, g in zip(pred, gt)]) if len(pred) \
        else pred
    return mean_joint_error(aligned, gt)


def marker_errors(pred, gt, tracked=TRACKED_M, failed=FAILED_M):
    """Ganapathi et al. (2010) marker errors.

    Parameters
    ----------
    pred, gt : (N, M, 3) float, metres; NaN in ``gt`` marks an invisible marker.
    tracked, failed : float, metres
        Error thresholds for a tracked (``<=``) and a failed (``>=``) marker.

    Returns
    -------
    dict of (N,) float64
        ``mean`` and ``max`` marker error (metres), ``frac_tracked`` and ``frac_failed`` (fraction
        of the frame's visible markers), ``visible`` (count).
    """
    d = point_distances(pred, gt)
    valid = ~np.isnan(d)
    n = valid.sum(axis=1)
    has = n > 0
    dz = np.where(valid, d, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac_t = np.where(has, (valid & (dz <= tracked)).sum(axis=1) / np.maximum(n, 1), np.nan)
        frac_f = np.where(has, (valid & (dz >= failed)).sum(axis=1) / np.maximum(n, 1), np.nan)
    mx = np.where(has, np.where(valid, d, -np.inf).max(axis=1, initial=-np.inf), np.nan)
    return {"mean": _nanmean_rows(d), "max": mx, "frac_tracked": frac_t, "frac_failed": frac_f,
            "visible": n.astype(np.int64)}


def heading_errors(pred, gt):
    """Per-frame angle between the estimated and the true facing direction, degrees.

    Parameters
    ----------
    pred, gt : (N, 6, 3) positions of :data:`HEADING_JOINTS` (pelvis, neck, l_hip, r_hip,
        l_shoulder, r_shoulder), metres, any world frame (both in the same one)

    Returns
    -------
    (N,) degrees in [0, 180]; NaN where a joint is missing (NaN) or the trunk axis or an
    across-body direction vanishes

    Notes
    -----
    The across-body direction ``(l_hip - r_hip) + (l_shoulder - r_shoulder)`` of each side is
    projected on the plane perpendicular to the *true* trunk axis (pelvis to neck); the angle
    between the two projections is the heading error. A body turned about its trunk by ``a``
    gives ``|a|``; its turned-round twin 180.
    """
    pred, gt = _check_pair(pred, gt)
    if pred.shape[1] != len(HEADING_JOINTS):
        raise ValueError(f"heading_errors needs the {len(HEADING_JOINTS)} joints "
                         f"{HEADING_JOINTS}, got {pred.shape[1]}")
    axis = gt[:, 1] - gt[:, 0]
    n = np.linalg.norm(axis, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = axis / n

        def across(x):
            a = (x[:, 2] - x[:, 3]) + (x[:, 4] - x[:, 5])
            a = a - np.sum(a * axis, axis=1, keepdims=True) * axis
            return a / np.linalg.norm(a, axis=1, keepdims=True)

        a, b = across(pred), across(gt)
        # atan2 of sine and cosine: exact near 0 and 180 degrees, where arccos is not
        return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1),
                                     np.sum(a * b, axis=1)))


def common_names(a, b, wanted=None):
    """Names present in both ``a`` and ``b`` (restricted to ``wanted``), in the order of ``wanted``
    (or of ``a``), with their indices into ``a`` and ``b``.

    Returns
    -------
    names : list of str
    ia, ib : (K,) int64
    """
    a, b = [str(x) for x in a], [str(x) for x in b]
    order = a if wanted is None else [str(x) for x in wanted]
    names = [n for n in order if n in a and n in b]
    return names, np.array([a.index(n) for n in names], np.int64), \
        np.array([b.index(n) for n in names], np.int64)


def _finite_mean(x):
    x = np.asarray(x, dtype=np.float64)
    x = x[~np.isnan(x)]
    return float(x.mean()) if x.size else float("nan")


def _turned_round(deg):
    """Share of the frames with a heading (NaN: none) whose error exceeds
    :data:`TURNED_ROUND_DEG`."""
    deg = np.asarray(deg, dtype=np.float64)
    ok = np.isfinite(deg)
    return float(np.mean(deg[ok] > TURNED_ROUND_DEG)) if ok.any() else float("nan")


def evaluate(result, groundtruth, joints=EVAL_JOINTS):
    """Score a tracking result against ground truth.

    Parameters
    ----------
    result : dict
        As from :func:`gltrack.data.results.load_results`: ``joints`` (N, J, 3) m,
        ``joint_names`` (J,), optional ``markers`` (N, M, 3) m and ``marker_names`` (M,),
        optional ``frame`` (N,) int, the dataset frame of each row (default ``0..N-1``).
    groundtruth : dict
        As from :meth:`gltrack.data.dataset.Dataset.groundtruth`: ``joints`` (G, J', 3) m,
        ``joint_names``, optional ``markers`` (G, M', 3) m and ``marker_names``.
    joints : sequence of str
        Joint names to score (intersected with both name lists).

    Returns
    -------
    dict
        The summary keys of :data:`SUMMARY_KEYS` (floats; ``frames`` int) plus ``joints`` (the
        names scored), ``per_joint`` ({joint: {"mean_mm", "max_mm"}}: each scored joint's
        error over the frames, which says where a mean error comes from), ``marker_source``
        (``"markers"`` or ``"joints"`` when either side has no markers and the scored joints
        stand in for them) and ``per_frame``: a dict of (N,) arrays
        ``frame``, ``joint_error_mm``, ``mpjpe_mm``, ``pa_mpjpe_mm``, ``marker_mean_m``,
        ``marker_max_m``, ``frac_markers_tracked``, ``frac_markers_failed``,
        ``heading_error_deg`` (:func:`heading_errors`; NaN without the joints it needs).
        ``heading_error_deg`` in the summary is its mean over frames and ``frac_turned_round``
        the share of frames above :data:`TURNED_ROUND_DEG`.
        ``marker_max_m`` in the summary is the mean over frames of the per-frame maximum, as
        Ganapathi et al. average both measures over a sequence.
    """
    pj = _as_points(result["joints"], "result joints")
    gj = _as_points(groundtruth["joints"], "ground-truth joints")
    n = len(pj)
    frame = np.asarray(result.get("frame", np.arange(n)), dtype=np.int64)
    if frame.shape != (n,):
        raise ValueError(f"result frame indices {frame.shape} do not match {n} result frames")
    if n and (frame.min() < 0 or frame.max() >= len(gj)):
        raise ValueError(f"result frames {frame.min()}..{frame.max()} exceed the ground truth's "
                         f"{len(gj)} frames")
    names, ip, ig = common_names(result["joint_names"], groundtruth["joint_names"], joints)
    if not names:
        raise ValueError("result and ground truth share none of the evaluated joints "
                         f"{list(joints)}")
    missing = [j for j in joints if j not in names]
    if missing:
        log.warning("joints missing from result or ground truth, not scored: %s", missing)
    pred, gt = pj[:, ip], gj[frame][:, ig]

    per = {"frame": frame, "joint_error_mm": 1000.0 * mean_joint_error(pred, gt)}
    dist = 1000.0 * point_distances(pred, gt)  # (N, J) mm
    root = names.index(ROOT_JOINT) if ROOT_JOINT in names else None
    if root is None:
        log.warning("no %s joint: MPJPE is relative to the joint centroid", ROOT_JOINT)
    per["mpjpe_mm"] = 1000.0 * mpjpe(pred, gt, root)
    per["pa_mpjpe_mm"] = 1000.0 * pa_mpjpe(pred, gt)
    hn, hp, hg = common_names(result["joint_names"], groundtruth["joint_names"], HEADING_JOINTS)
    if len(hn) == len(HEADING_JOINTS):
        order = [hn.index(j) for j in HEADING_JOINTS]
        per["heading_error_deg"] = heading_errors(pj[:, hp[order]], gj[frame][:, hg[order]])
    else:
        per["heading_error_deg"] = np.full(n, np.nan)

    pm, gm = result.get("markers"), groundtruth.get("markers")
    source = "markers"
    if pm is None or gm is None or np.asarray(pm).size == 0 or np.asarray(gm).size == 0:
        log.info("no markers on one side: marker errors use the scored joints")
        source, mp_, mg_ = "joints", pred, gt
    else:
        pm, gm = _as_points(pm, "result markers"), _as_points(gm, "ground-truth markers")[frame]
        rn, gn = result.get("marker_names"), groundtruth.get("marker_names")
        if rn is not None and gn is not None and len(rn) and len(gn):
            mnames, im, ig2 = common_names(rn, gn)
            if not mnames:
                raise ValueError("result and ground truth share no marker names")
            pm, gm = pm[:, im], gm[:, ig2]
        elif pm.shape[1] != gm.shape[1]:
            raise ValueError(f"result has {pm.shape[1]} markers, ground truth {gm.shape[1]}, "
                             "and no marker names to match them")
        mp_, mg_ = pm, gm
    me = marker_errors(mp_, mg_)
    per.update(marker_mean_m=me["mean"], marker_max_m=me["max"],
               frac_markers_tracked=me["frac_tracked"], frac_markers_failed=me["frac_failed"])

    # Fractions pool all visible marker observations, so frames with few visible markers weigh less.
    vis = me["visible"]
    tot = vis.sum()
    out = {
        "mean_joint_error_mm": _finite_mean(per["joint_error_mm"]),
        "mpjpe_mm": _finite_mean(per["mpjpe_mm"]),
        "pa_mpjpe_mm": _finite_mean(per["pa_mpjpe_mm"]),
        "marker_mean_m": _finite_mean(per["marker_mean_m"]),
        "marker_max_m": _finite_mean(per["marker_max_m"]),
        "frac_markers_tracked": float(np.nansum(per["frac_markers_tracked"] * vis) / tot)
        if tot else float("nan"),
        "frac_markers_failed": float(np.nansum(per["frac_markers_failed"] * vis) / tot)
        if tot else float("nan"),
        "heading_error_deg": _finite_mean(per["heading_error_deg"]),
        "frac_turned_round": _turned_round(per["heading_error_deg"]),
        "frames": int(n),
        "joints": names,
        "per_joint": {name: {"mean_mm": _finite_mean(dist[:, j]),
                             "max_mm": float(np.nanmax(dist[:, j]))
                             if np.isfinite(dist[:, j]).any() else float("nan")}
                      for j, name in enumerate(names)},
        "marker_source": source,
        "per_frame": per,
    }
    return out
