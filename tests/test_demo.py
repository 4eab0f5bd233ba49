"""`gltrack demo` end to end (short performance), as a user runs it: a separate process."""
import json
import subprocess
import sys

import cv2
import numpy as np


def test_demo_writes_everything(tmp_path):
    out = tmp_path / "demo"
    res = subprocess.run([sys.executable, "-m", "gltrack", "-q", "demo", "--out", str(out), "--seconds", "1.0"],
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "joint err" in res.stdout and "depth" in res.stdout and "multiview" in res.stdout
    summary = json.loads((out / "summary.json").read_text())
    for rig in ("depth", "multiview"):
        r = summary["rigs"][rig]
        assert r["mean_joint_error_mm"] < 250, r
        for name in ("poses.npz", "poses.bvh", "timing.json", "frames.jsonl", "metrics.json"):
            assert (out / f"{rig}_result" / name).is_file()
        assert r["video"] == str(out / f"{rig}_overlay.mp4")
        cap = cv2.VideoCapture(r["video"])
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == summary["frames"]
        # the codec the summary reports is the one the file holds
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode().lower()
        assert fourcc in {"h264": ("h264", "avc1"), "mpeg4": ("fmp4", "mp4v")}[r["video_codec"]]
        assert f"({r['video_codec']})" in res.stdout
        ok, frame = cap.read()
        assert ok and frame.std() > 10, "the video shows a picture"
    img = cv2.imread(str(out / "errors.png"))
    assert img is not None and img.shape[0] > 300
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20, "the plot is not blank"


def test_demo_rejects_bad_usage(tmp_path):
    res = subprocess.run([sys.executable, "-m", "gltrack", "demo", "--out", str(tmp_path), "--seconds", "0"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "seconds" in res.stderr
