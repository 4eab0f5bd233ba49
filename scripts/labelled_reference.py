"""Triangulate hand-labelled joints of a shared take into a reference TRC.

The shared recordings have no ground truth. ``scripts/data/*_keypoints.json`` hold 2-D joint
centres labelled by hand in all four views of five frames of a take (each file's ``caveats``
and ``notes`` say how good they are):

- ``pose2sim_balancing_keypoints.json``: the Pose2Sim take, 13 joints (default);
- ``caliscope_4cam_keypoints.json``: the seated caliscope take, 7 upper-body joints.

This script triangulates a file's labels with the take's own calibration
(:func:`gltrack.camera.triangulate`) and writes a ``.trc`` as Pose2Sim writes one (millimetres,
``LShoulder``-style names; OpenSim Y-up axes made from the file's ``up`` axis, or the
calibration's own axes with ``--axes calibration``), which ``gltrack eval --reference``
compares a tracked result with::

    python scripts/labelled_reference.py --out p2s_hand.trc      # ../shared beside the repo
    gltrack eval r/ p2s/ --reference p2s_hand.trc
    python scripts/labelled_reference.py --keypoints scripts/data/caliscope_4cam_keypoints.json \\
        --axes calibration --out cal_hand.trc
    gltrack eval rc/ cal/ --reference cal_hand.trc --reference-axes calibration

The TRC's times are the labelled frames over the file's ``fps`` (the dataset's frame rate, as
``gltrack ingest`` set it from the videos or the take's timestamps). It prints each frame's
median and worst reprojection residual (pixels): the labels' own consistency.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from gltrack.camera import triangulate
from gltrack.data.calibration import load_any_calibration
from gltrack.export.trc import opensim_axes, write_trc

DATA = Path(__file__).resolve().parent / "data"
LABELS = DATA / "pose2sim_balancing_keypoints.json"
#: the spelling Pose2Sim's TRC files use
P2S_NAMES = {"nose": "Nose", "l_shoulder": "LShoulder", "r_shoulder": "RShoulder",
             "l_elbow": "LElbow", "r_elbow": "RElbow", "l_wrist": "LWrist", "r_wrist": "RWrist",
             "l_hip": "LHip", "r_hip": "RHip", "l_knee": "LKnee", "r_knee": "RKnee",
             "l_ankle": "LAnkle", "r_ankle": "RAnkle"}
#: keys every keypoints file has (``value``, ``caveats`` and ``notes`` are for people)
REQUIRED = ("take", "calibration", "fps", "up", "joints", "frames")


def load_labels(path) -> dict:
    """Read a keypoints file and check its top-level fields.

    Raises
    ------
    ValueError
        A missing field or a joint without a TRC name, naming the file and the field.
    """
    labels = json.loads(Path(path).read_text())
    for key in REQUIRED:
        if key not in labels:
            raise ValueError(f"{path}: no {key!r} field")
    unknown = [j for j in labels["joints"] if j not in P2S_NAMES]
    if unknown:
        raise ValueError(f"{path}: joints: {unknown[0]!r} is not one of {sorted(P2S_NAMES)}")
    return labels


def reference_points(labels: dict, cameras) -> tuple[list, np.ndarray, np.ndarray]:
    """Triangulate a keypoints file's frames.

    Parameters
    ----------
    labels : dict, the keypoints JSON
    cameras : list of gltrack.camera.Camera, named as the file's camera keys

    Returns
    -------
    frames : list of int
    points : (F, J, 3) float64, metres, the calibration's frame (NaN: seen by < 2 views)
    residual : (F, C, J) float64, pixels (NaN where not labelled)
    """
    by_name = {c.name: c for c in cameras}
    joints = labels["joints"]
    frames = sorted(int(f) for f in labels["frames"])
    pts, res = [], []
    for f in frames:
        views = labels["frames"][str(f)]
        missing = [c for c in views if c not in by_name]
        if missing:
            raise ValueError(f"frame {f}: camera {missing[0]!r} is not in the calibration "
                             f"({sorted(by_name)})")
        cams = [by_name[c] for c in views]
        uv = np.array([[(v[j][:2] if v.get(j) else (np.nan, np.nan)) for j in joints]
                       for v in views.values()], dtype=np.float64)
        p, r = triangulate(cams, uv)
        pts.append(p)
        res.append(r)
    return frames, np.array(pts), np.array(res)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keypoints", default=str(LABELS),
                    help="the keypoints file (default: the Pose2Sim take's)")
    ap.add_argument("--shared", default=str(Path(__file__).resolve().parents[1].parent / "shared"),
                    help="the shared data folder (default ../shared beside the repository)")
    ap.add_argument("--axes", choices=("opensim", "calibration"), default="opensim",
                    help="write OpenSim Y-up axes (as Pose2Sim does; default) or the "
                         "calibration's own")
    ap.add_argument("--out", required=True, help="the .trc file to write")
    args = ap.parse_args(argv)
    try:
        labels = load_labels(args.keypoints)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    calib = Path(args.shared) / labels["take"].removeprefix("../shared/") / labels["calibration"]
    if not calib.is_file():
        print(f"error: {calib}: no such file (give --shared)", file=sys.stderr)
        return 1
    frames, pts, res = reference_points(labels, load_any_calibration(calib))
    for f, r in zip(frames, res):
        print(f"frame {f}: residual median {np.nanmedian(r):.1f} px, max {np.nanmax(r):.1f} px")
    names = [P2S_NAMES[j] for j in labels["joints"]]
    if args.axes == "opensim":
        # the calibration's axes relabelled to OpenSim's Y-up, as Pose2Sim writes its TRCs
        pts = pts @ opensim_axes(labels["up"]).T
    write_trc(args.out, names, pts, float(labels["fps"]), frames)
    print(f"wrote {args.out} ({len(frames)} frames, {len(names)} joints, {args.axes} axes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
