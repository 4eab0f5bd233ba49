"""Score a tracked take against an independent 3-D reconstruction of it (``eval --reference``).

A real recording has no ground truth, but often a second opinion: Pose2Sim or anipose
triangulate 2-D keypoints of the same videos, a marker system recorded the take, or someone
labelled a few frames by hand in every view and triangulated them. This module reads such a
reconstruction from a ``.trc`` file and measures the distance between its joint centres and
the result's, joint by joint, over the frames both hold.

Joints compared (:data:`COMPARED`): hips, knees, ankles, shoulders, elbows and wrists, left
and right: the joints whose centres every convention places within a few centimetres of each
other. The pelvis, spine, neck and head are left out (each tool draws them somewhere else).
Reference markers are matched by name whatever their spelling (:func:`joint_key`: ``LHip``,
``L_Hip``, ``left_hip``, ``LeftHip`` and gltrack's ``l_hip`` are one joint); other markers are
ignored.

Frames are matched by the TRC's ``Time`` column (seconds from the take's first frame, as
Pose2Sim and ``gltrack export`` write it): row ``t`` is dataset frame ``round(t * fps)``.
Axes: a TRC from Pose2Sim (or ``gltrack export``) is in OpenSim's Y-up relabelling of the
calibration's frame (``axes="opensim"``, :func:`gltrack.export.trc.opensim_axes`); a file in
the calibration's own axes is read with ``axes="calibration"``.

The figures are distances between two estimates, neither of them the truth: the reference's
own error (a triangulated keypoint is typically 1-3 cm off, a hand label more) is part of
them, and so is where each convention puts a joint inside the limb (hip centres above all).
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from gltrack.export import TRC_AXES, trc_frame
from gltrack.export.trc import UNITS, read_trc

log = logging.getLogger(__name__)

#: gltrack joints compared with a reference, in the order they are reported
COMPARED = ("l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle",
            "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist")


def joint_key(name: str) -> str:
    """A spelling-free key of a joint name: lower case, letters only, a leading side word
    shortened to ``l``/``r`` (``"LHip"``, ``"left_hip"``, ``"L_Hip"`` -> ``"lhip"``)."""
    k = re.sub(r"[^a-z]", "", str(name).lower())
    for word, side in (("left", "l"), ("right", "r")):
        if k.startswith(word):
            return side + k[len(word):]
    return k


def _mirror(name: str) -> str:
    return ("r_" + name[2:]) if name.startswith("l_") else ("l_" + name[2:])


def load_reference(path, result: dict, fps: float, axes: str = "opensim") -> dict:
    """Read a reconstruction of the take and put it in the frame of ``result``'s joints.

    Parameters
    ----------
    path : str or Path, a ``.trc`` file
    result : dict, :func:`gltrack.data.results.load_results` (its ``world`` record: axes)
    fps : float, frames per second of the dataset (matches the TRC's ``Time`` to frames)
    axes : {"opensim", "calibration"}, the axes the file is written in (module docstring)

    Returns
    -------
    dict: ``names`` (J,) the gltrack joints found, ``frame`` (T,) int dataset frames,
    ``joints`` (T, J, 3) float64 metres in the result's frame (NaN where the file has no
    value), ``missing`` the compared joints the file does not hold, ``path`` str

    Raises
    ------
    ValueError
        Naming the file and what is wrong: not a TRC, unknown units, no compared joint,
        or times that do not fall on the dataset's frames.
    """
    path = Path(path)
    if axes not in TRC_AXES:
        raise ValueError(f"reference axes must be one of {TRC_AXES}, got {axes!r}")
    if path.suffix.lower() != ".trc":
        raise ValueError(f"{path}: a reference must be a .trc file (Pose2Sim, OpenSim, "
                         "gltrack export)")
    trc = read_trc(path)
    units = trc["units"].strip().lower()
    if units not in UNITS:
        raise ValueError(f"{path}: field 'Units' is {trc['units']!r}; expected one of "
                         f"{sorted(UNITS)}")
    keys = {joint_key(n): i for i, n in enumerate(trc["names"])}
    names = [j for j in COMPARED if joint_key(j) in keys]
    if not names:
        raise ValueError(f"{path}: no marker named like a hip, knee, ankle, shoulder, elbow or "
                         f"wrist (e.g. 'LHip', 'r_knee'); the file has {trc['names'][:12]}")
    missing = [j for j in COMPARED if j not in names]
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    t = trc["time"] * fps
    frame = np.rint(t).astype(np.int64)
    if len(frame) and (np.any(np.abs(t - frame) > 0.25) or np.any(frame < 0)):
        raise ValueError(f"{path}: column 'Time' does not fall on the dataset's frames at "
                         f"{fps:g} frames/s (e.g. {trc['time'][0]:g} s)")
    pts = trc["points"][:, [keys[joint_key(j)] for j in names]] / UNITS[units]
    # file axes -> the result's frame: trc_frame maps the result's frame to the file's
    pts = pts @ trc_frame(result, axes)
    if missing:
        log.warning("%s holds no %s: those joints are not compared", path, ", ".join(missing))
    return {"names": names, "frame": frame, "joints": pts, "missing": missing,
            "path": str(path)}


def compare_reference(result: dict, ref: dict) -> dict:
    """Distances between the result's joints and a reconstruction's, over the frames both hold.

    Parameters
    ----------
    result : dict, :func:`gltrack.data.results.load_results` (``joints``, ``joint_names``,
        ``frame``)
    ref : dict, :func:`load_reference`

    Returns
    -------
    dict (JSON-ready):
        ``file``; ``frames`` compared; ``joints`` {name: {"median_mm", "mean_mm", "n"}};
        ``median_mm`` and ``mean_mm`` over every compared joint of every frame;
        ``exchanged_frames``: the share of frames whose joints are closer to the reference with
        the result's left and right exchanged (limbs taken the wrong way round);
        ``per_frame`` {"frame", "mean_mm"}; ``missing`` the joints the file lacks.

    Raises
    ------
    ValueError
        No frame of the reference is in the result.
    """
    res_names = [str(n) for n in result["joint_names"]]
    absent = [j for j in ref["names"] if j not in res_names]
    if absent:
        raise ValueError(f"the result has no joint {absent[0]!r} to compare")
    rows = {int(f): i for i, f in enumerate(np.asarray(result["frame"]))}
    both = [(i, rows[int(f)]) for i, f in enumerate(ref["frame"]) if int(f) in rows]
    if not both:
        raise ValueError(f"{ref['path']}: none of its frames ({_span(ref['frame'])}) is in the "
                         f"result ({_span(result['frame'])})")
    ri, ti = (np.array(v) for v in zip(*both))
    cols = [res_names.index(j) for j in ref["names"]]
    mirror = [res_names.index(_mirror(j)) if _mirror(j) in res_names else c
              for j, c in zip(ref["names"], cols)]
    R = ref["joints"][ri]                                   # (F, J, 3)
    X = np.asarray(result["joints"], dtype=np.float64)
    d = 1000.0 * np.linalg.norm(X[ti][:, cols] - R, axis=-1)        # (F, J) mm
    d_ex = 1000.0 * np.linalg.norm(X[ti][:, mirror] - R, axis=-1)
    frame_mean = np.array([np.nanmean(r) if np.isfinite(r).any() else np.nan for r in d])
    frame_ex = np.array([np.nanmean(r) if np.isfinite(r).any() else np.nan for r in d_ex])
    ok = np.isfinite(frame_mean)
    if not ok.any():
        raise ValueError(f"{ref['path']}: no compared joint has a value in the frames the "
                         "result holds")
    joints = {}
    for k, j in enumerate(ref["names"]):
        v = d[:, k][np.isfinite(d[:, k])]
        if v.size:
            joints[j] = {"median_mm": float(np.median(v)), "mean_mm": float(v.mean()),
                         "n": int(v.size)}
    allv = d[np.isfinite(d)]
    return {"file": ref["path"], "frames": int(ok.sum()), "joints": joints,
            "median_mm": float(np.median(allv)), "mean_mm": float(allv.mean()),
            "exchanged_frames": float(np.mean(frame_ex[ok] < frame_mean[ok])),
            "per_frame": {"frame": [int(f) for f in ref["frame"][ri][ok]],
                          "mean_mm": [float(v) for v in frame_mean[ok]]},
            "missing": list(ref["missing"])}


def _span(frames) -> str:
    f = np.asarray(frames)
    return f"frames {int(f.min())}..{int(f.max())}" if f.size else "no frames"


def reference_table(cmp: dict) -> str:
    """The printed summary of :func:`compare_reference`: one line per joint, then the median
    and mean over all of them."""
    lines = [f"against the reconstruction {cmp['file']} ({cmp['frames']} frames; distances "
             "between two estimates, mm):",
             f"  {'joint':<11} {'median':>7} {'mean':>7} {'frames':>6}"]
    for j, v in cmp["joints"].items():
        lines.append(f"  {j:<11} {v['median_mm']:7.1f} {v['mean_mm']:7.1f} {v['n']:6d}")
    lines.append(f"  {'all':<11} {cmp['median_mm']:7.1f} {cmp['mean_mm']:7.1f}")
    lines.append(f"  frames closer with left and right exchanged: "
                 f"{100 * cmp['exchanged_frames']:.0f} %")
    if cmp["missing"]:
        lines.append(f"  not in the file: {', '.join(cmp['missing'])}")
    return "\n".join(lines)
