"""Triangulate the hand-labelled joints of the Pose2Sim take into a reference TRC.

The shared Pose2Sim take has no ground truth. ``scripts/data/pose2sim_balancing_keypoints.json``
holds 2-D joint centres labelled by hand in all four views of five frames (10, 30, 50, 70, 90;
its ``caveats`` say how good they are). This script triangulates them with the take's own
calibration (:func:`gltrack.camera.triangulate`) and writes a ``.trc`` as Pose2Sim writes one
(OpenSim Y-up axes, millimetres, ``LHip``-style names), which ``gltrack eval --reference``
compares a tracked result with::

    python scripts/pose2sim_reference.py --out p2s_hand.trc      # ../shared beside the repo
    gltrack eval r/ p2s/ --reference p2s_hand.trc

It prints each frame's worst reprojection residual (pixels): the labels' own consistency.
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

LABELS = Path(__file__).resolve().parent / "data" / "pose2sim_balancing_keypoints.json"
#: the spelling Pose2Sim's TRC files use
P2S_NAMES = {"nose": "Nose", "l_shoulder": "LShoulder", "r_shoulder": "RShoulder",
             "l_elbow": "LElbow", "r_elbow": "RElbow", "l_wrist": "LWrist", "r_wrist": "RWrist",
             "l_hip": "LHip", "r_hip": "RHip", "l_knee": "LKnee", "r_knee": "RKnee",
             "l_ankle": "LAnkle", "r_ankle": "RAnkle"}
FPS = 60.0  # the take's frame rate (its videos' and the calibration's)


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
    ap.add_argument("--shared", default=str(Path(__file__).resolve().parents[1].parent / "shared"),
                    help="the shared data folder (default ../shared beside the repository)")
    ap.add_argument("--out", required=True, help="the .trc file to write")
    args = ap.parse_args(argv)
    labels = json.loads(LABELS.read_text())
    calib = Path(args.shared) / labels["take"].removeprefix("../shared/") / labels["calibration"]
    if not calib.is_file():
        print(f"error: {calib}: no such file (give --shared)", file=sys.stderr)
        return 1
    frames, pts, res = reference_points(labels, load_any_calibration(calib))
    for f, r in zip(frames, res):
        print(f"frame {f}: residual median {np.nanmedian(r):.1f} px, max {np.nanmax(r):.1f} px")
    names = [P2S_NAMES[j] for j in labels["joints"]]
    # Pose2Sim's Z-up calibration relabelled to OpenSim's Y-up, as Pose2Sim writes its TRCs
    write_trc(args.out, names, pts @ opensim_axes("z").T, FPS, frames)
    print(f"wrote {args.out} ({len(frames)} frames, {len(names)} joints)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
